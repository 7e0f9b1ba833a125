"""Metrics, figures and reports. These read results; they never simulate."""

from .metrics import METRIC_COLUMNS, compute_metrics, window_mask

__all__ = ["METRIC_COLUMNS", "compute_metrics", "window_mask"]
