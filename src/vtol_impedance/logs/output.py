"""Files of a log estimate: the time series as CSV and Parquet, and a JSON summary (atomic writes)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..io import write_text, write_with
from .estimate import LogEstimate


def summary(est: LogEstimate) -> dict[str, Any]:
    """Per-component mean, RMS and largest magnitude of the causal estimate, plus how the log was read."""
    stats = {}
    for name, arr in (("f_W_N", est.f_W), ("tau_B_Nm", est.tau_B)):
        if arr is not None:
            stats[name] = {
                "mean": arr.mean(0).tolist(),
                "rms": np.sqrt((arr**2).mean(0)).tolist(),
                "max_abs": np.abs(arr).max(0).tolist(),
            }
    return {"info": est.info, "bias": est.bias, "notes": est.notes, "stats": stats}


def write_estimate(est: LogEstimate, folder: Path, summ: dict[str, Any] | None = None) -> list[Path]:
    """``wrench.csv``, ``wrench.parquet`` and ``estimate.json`` (``summ``, default :func:`summary`) into
    ``folder``."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    cols = est.columns()
    names = list(cols)
    data = np.column_stack([np.asarray(cols[n], dtype=float) for n in names])
    buf = io.StringIO()
    buf.write(",".join(names) + "\n")
    np.savetxt(buf, data, delimiter=",", fmt="%.9g")
    table = pa.table({n: np.asarray(cols[n]) for n in names})
    summ = summary(est) if summ is None else summ
    meta = {b"vtol_impedance": json.dumps(summ, default=str).encode()}
    table = table.replace_schema_metadata(meta)
    return [
        write_text(folder / "wrench.csv", buf.getvalue()),
        write_with(folder / "wrench.parquet", lambda fh: pq.write_table(table, fh)),
        write_text(folder / "estimate.json", json.dumps(summ, indent=1, default=str)),
    ]
