"""Flight logs as CSV: one header row, then one row per sample, comma separated.

Columns (names as below, or mapped with ``columns={"vx": "my_vx", ...}``; extra columns are ignored):

==================  ==========================================================================
``t_s``             time in seconds (or ``timestamp_us`` in microseconds)
``vx, vy, vz``      velocity in the world frame, m/s (``world="ned"`` or ``"enu"``)
``roll, pitch, yaw`` ZYX Euler angles (body to world), rad or deg (``angle_unit``), or instead
``q0, q1, q2, q3``  a unit quaternion, order ``quat_order`` (``wxyz``/``xyzw``) and direction
                    ``quat_direction`` (``body-to-world``/``world-to-body``)
``wx, wy, wz``      body rates in the body frame (``body="frd"`` or ``"flu"``), rad/s or deg/s
``thrust_n``        collective thrust in newtons, or instead
``thrust_norm``     normalised collective thrust (0..1) with ``hover_thrust`` given, a
                    ``hover_thrust`` column, or a hover segment to fit it from
``tx, ty, tz``      optional body torque commands, N m, body frame; without them the moment
                    estimate is skipped
==================  ==========================================================================

Every row must have as many fields as the header; a last row cut short (a truncated file) is dropped
and reported. Samples may have empty fields (a signal logged at a lower rate): those rows are skipped for
that signal only, so each signal keeps its own clock.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from . import frames
from .timeseries import RawLog, Signal

ANGLE_UNITS = ("rad", "deg")
COLUMNS = (
    "t_s", "timestamp_us", "vx", "vy", "vz", "roll", "pitch", "yaw", "q0", "q1", "q2", "q3",
    "wx", "wy", "wz", "thrust_n", "thrust_norm", "hover_thrust", "tx", "ty", "tz",
)  # fmt: skip


def _read_table(path: Path, notes: list[str]) -> tuple[list[str], list[list[str]]]:
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            rows = list(csv.reader(fh))
    except UnicodeDecodeError:
        raise InputError(f"{path} is not a text CSV file (is it a ULog? use a .ulg extension)") from None
    rows = [r for r in rows if r and any(c.strip() for c in r)]
    if not rows:
        raise InputError(f"{path} is empty")
    header = [h.strip() for h in rows[0]]
    body = rows[1:]
    if not body:
        raise InputError(f"{path} has a header but no data rows")
    if len(body[-1]) < len(header):
        notes.append(f"last row of {path.name} is cut short (truncated file): dropped")
        body = body[:-1]
    for i, r in enumerate(body):
        if len(r) != len(header):
            raise InputError(f"{path}: line {i + 2} has {len(r)} fields, the header has {len(header)}")
    return header, body


def _column(path: Path, header: list[str], rows: list[list[str]], name: str) -> np.ndarray:
    j = header.index(name)
    out = np.empty(len(rows))
    for i, r in enumerate(rows):
        cell = r[j].strip()
        if cell == "" or cell.lower() == "nan":
            out[i] = np.nan
            continue
        try:
            out[i] = float(cell)
        except ValueError:
            raise InputError(f"{path}: line {i + 2}, column {name!r}: {cell!r} is not a number") from None
    return out


def _signal(name: str, source: str, t: np.ndarray, cols: list[np.ndarray], hold: bool = False) -> Signal:
    v = np.stack(cols, -1)
    have = ~np.all(np.isnan(v), axis=1)  # rows where this signal was not logged at all
    return Signal(name, source, t[have], v[have], hold)


def read_csv(
    path: str | os.PathLike[str],
    world: str = "ned",
    body: str = "frd",
    angle_unit: str = "rad",
    quat_order: str = "wxyz",
    quat_direction: str = "body-to-world",
    columns: dict[str, str] | None = None,
) -> RawLog:
    """Read a CSV log (see the module docstring for the columns) into world NED / body FRD signals."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"log file {path} {'is not a file' if path.exists() else 'does not exist'}")
    if angle_unit not in ANGLE_UNITS:
        raise InputError(f"angle unit must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")
    notes: list[str] = []
    header, rows = _read_table(path, notes)
    mapping = {k: k for k in COLUMNS}
    for k, v in (columns or {}).items():
        if k not in COLUMNS:
            raise InputError(f"unknown column role {k!r}; roles are {', '.join(COLUMNS)}")
        mapping[k] = v
    present = {role for role, col in mapping.items() if col in header}

    def need(group: tuple[str, ...], what: str) -> None:
        miss = [mapping[c] for c in group if c not in present]
        if miss:
            raise InputError(f"{path}: {what} needs column(s) {', '.join(miss)}; the file has: {', '.join(header)}")

    def col(role: str) -> np.ndarray:
        return _column(path, header, rows, mapping[role])

    if "t_s" in present:
        t = col("t_s")
    elif "timestamp_us" in present:
        t = col("timestamp_us") * 1e-6
    else:
        need(("t_s",), "time")
    need(("vx", "vy", "vz"), "velocity")
    need(("wx", "wy", "wz"), "body rates")
    scale = np.pi / 180.0 if angle_unit == "deg" else 1.0
    if {"q0", "q1", "q2", "q3"} <= present:
        att = _signal("attitude", "q0..q3", t, [col(c) for c in ("q0", "q1", "q2", "q3")])
        R = frames.quaternion_rotation(att.values, quat_order, quat_direction)
    else:
        need(("roll", "pitch", "yaw"), "attitude (or q0..q3)")
        att = _signal("attitude", "roll, pitch, yaw", t, [col(c) * scale for c in ("roll", "pitch", "yaw")])
        R = frames.euler_rotation(*att.values.T)
    att.values = frames.eta_ned_frd(R, world, body)
    vel = _signal("velocity", f"vx, vy, vz ({world.upper()})", t, [col(c) for c in ("vx", "vy", "vz")])
    vel.values = frames.world_vector_to_ned(vel.values, world)
    rates = _signal("body rates", f"wx, wy, wz ({body.upper()})", t, [col(c) * scale for c in ("wx", "wy", "wz")])
    rates.values = frames.body_vector_to_frd(rates.values, body)
    raw_kw: dict = {}
    if "thrust_n" in present and "thrust_norm" in present:
        raise InputError(f"{path}: give thrust_n (newtons) or thrust_norm (normalised), not both")
    if "thrust_n" in present:
        thrust = _signal("thrust", "thrust_n [N]", t, [col("thrust_n")], hold=True)
        raw_kw["thrust_unit"] = "N"
    elif "thrust_norm" in present:
        thrust = _signal("thrust", "thrust_norm", t, [col("thrust_norm")], hold=True)
        raw_kw["thrust_unit"] = "normalized"
        if "hover_thrust" in present:
            h = col("hover_thrust")
            h = h[np.isfinite(h)]
            if len(h):
                raw_kw["hover_thrust"] = float(np.median(h))
                raw_kw["hover_source"] = "median of the hover_thrust column"
    else:
        need(("thrust_n",), "collective thrust (or thrust_norm)")
    torque = None
    if {"tx", "ty", "tz"} <= present:
        torque = _signal("torque", f"tx, ty, tz [N m] ({body.upper()})", t, [col(c) for c in ("tx", "ty", "tz")], True)
        torque.values = frames.body_vector_to_frd(torque.values, body)
    else:
        notes.append("no body torque columns (tx, ty, tz): the moment estimate is skipped, the force estimate is not")
    meta = {"format": "csv", "file": str(path), "world": world, "body": body, "angle_unit": angle_unit}
    if "q0" in present:
        meta.update(quat_order=quat_order, quat_direction=quat_direction)
    return RawLog(vel, att, rates, thrust, torque, notes=notes, meta=meta, **raw_kw)
