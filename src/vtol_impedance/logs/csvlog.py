"""Flight logs as CSV: one header row, then one row per sample, comma separated.

Columns (names as below, one of their :data:`ALIASES` such as ``time``, ``vel_x`` or ``p, q, r``, or
mapped with ``columns={"vx": "my_vx", ...}``; extra columns are ignored; a missing column is reported with
the ``--column`` mapping that most likely fixes it):

==================  ==========================================================================
``t_s``             time, in seconds unless ``time_unit`` says ``ms``, ``us`` or ``ns`` (or
                    ``timestamp_us``, in microseconds unless ``time_unit`` says otherwise)
``vx, vy, vz``      velocity in the world frame, m/s (``velocity_world``, default ``world``)
``roll, pitch, yaw`` ZYX Euler angles (body to world), rad or deg (``angle_unit``), or instead
``q0, q1, q2, q3``  a unit quaternion, order ``quat_order`` (``wxyz``/``xyzw``) and direction
                    ``quat_direction`` (``body-to-world``/``world-to-body``)
``wx, wy, wz``      body rates in the body frame (``body="frd"`` or ``"flu"``), rad/s or deg/s
                    (``rate_unit``, default ``angle_unit``)
``thrust_n``        collective thrust in newtons, or instead
``thrust_norm``     normalised collective thrust (0..1) with ``hover_thrust`` given, a
                    ``hover_thrust`` column (used per sample), or a hover segment to fit it from
``tx, ty, tz``      optional body torque commands, N m, body frame; without them the moment
                    estimate is skipped unless rotor speeds and a rotor geometry give it
``rpm1 .. rpm8``    optional measured rotor speeds (ESC telemetry), in ``rotor_speed_unit``
                    (``rpm``, default, or ``rad/s``), numbered as the vehicle's rotors
==================  ==========================================================================

The frames and units are a :class:`~vtol_impedance.logs.frames.Conventions`. Reading happens in two
steps so that the convention checks can re-read the same numbers under other conventions:
:func:`read_csv_table` parses the file once, :func:`table_to_raw` converts it under one set of
conventions.

Every row must have as many fields as the header; a last row cut short (a truncated file) is dropped
and reported. Samples may have empty fields (a signal logged at a lower rate): those rows are skipped for
that signal only, so each signal keeps its own clock.
"""

from __future__ import annotations

import csv
import difflib
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io import explain_path
from . import frames
from .frames import ANGLE_UNITS, ROTOR_SPEED_UNITS, TIME_UNITS, Conventions
from .timeseries import RawLog, Signal

MAX_ROTORS = 8
COLUMNS = (
    "t_s", "timestamp_us", "vx", "vy", "vz", "roll", "pitch", "yaw", "q0", "q1", "q2", "q3",
    "wx", "wy", "wz", "thrust_n", "thrust_norm", "hover_thrust", "tx", "ty", "tz",
    *(f"rpm{i}" for i in range(1, MAX_ROTORS + 1)),
)  # fmt: skip

#: Other names real exporters write for each role (PX4's ulog2csv, MAVLink and ROS exports, spreadsheets),
#: matched without regard to case when the file has no column of the role's own name; two columns that
#: both match one role are refused (which is meant?). ``vn, ve, vd`` name north, east, down: a file with
#: them is in NED (the default ``--world``). A name that would fit two roles (``thrust``: newtons or
#: normalised?) is nobody's alias.
ALIASES: dict[str, tuple[str, ...]] = {
    "t_s": ("t", "time", "time_s", "times", "sec", "seconds", "elapsed_s"),
    "timestamp_us": ("timestamp", "time_us", "time_usec", "timeus", "t_us"),
    "vx": ("vel_x", "v_x", "velocity_x", "vel.x", "vn", "v_n", "vel_n", "vel_north"),
    "vy": ("vel_y", "v_y", "velocity_y", "vel.y", "ve", "v_e", "vel_e", "vel_east"),
    "vz": ("vel_z", "v_z", "velocity_z", "vel.z", "vd", "v_d", "vel_d", "vel_down"),
    "roll": ("roll_rad", "phi", "attitude_roll"),
    "pitch": ("pitch_rad", "theta", "attitude_pitch"),
    "yaw": ("yaw_rad", "psi", "heading_rad", "attitude_yaw"),
    **{f"q{i}": (f"q[{i}]", f"q_{i}", f"q.{i}", f"quat_{i}", f"quat[{i}]") for i in range(4)},
    "wx": ("p", "rollspeed", "roll_rate", "rollrate", "gyro_x", "xgyro", "omega_x", "w_x", "rate_x", "p_rad_s"),
    "wy": ("q", "pitchspeed", "pitch_rate", "pitchrate", "gyro_y", "ygyro", "omega_y", "w_y", "rate_y", "q_rad_s"),
    "wz": ("r", "yawspeed", "yaw_rate", "yawrate", "gyro_z", "zgyro", "omega_z", "w_z", "rate_z", "r_rad_s"),
    "thrust_n": ("thrust_newton", "thrust_newtons", "collective_thrust_n", "thrust_total_n"),
    "thrust_norm": ("throttle", "thrust_normalized", "thrust_normalised", "collective_thrust_norm"),
    "hover_thrust": ("hover_throttle", "thr_hover", "hover_thrust_norm"),
    "tx": ("tau_x", "torque_x", "mx", "moment_x"),
    "ty": ("tau_y", "torque_y", "my", "moment_y"),
    "tz": ("tau_z", "torque_z", "mz", "moment_z"),
    **{f"rpm{i}": (f"rpm_{i}", f"motor{i}_rpm", f"esc{i}_rpm", f"rpm[{i}]") for i in range(1, MAX_ROTORS + 1)},
}

__all__ = ["ALIASES", "ANGLE_UNITS", "COLUMNS", "CsvTable", "read_csv", "read_csv_table", "table_to_raw"]


@dataclass
class CsvTable:
    """The numbers of a CSV log by role (raw, in the file's own frames and units) and what was found."""

    path: Path
    header: list[str]
    cols: dict[str, np.ndarray]
    time_role: str
    notes: list[str] = field(default_factory=list)

    @property
    def has_quaternion(self) -> bool:
        return all(f"q{i}" in self.cols for i in range(4))

    @property
    def rotor_roles(self) -> list[str]:
        roles = []
        for i in range(1, MAX_ROTORS + 1):
            if f"rpm{i}" not in self.cols:
                break
            roles.append(f"rpm{i}")
        return roles

    def relevant_conventions(self) -> tuple[str, ...]:
        """The convention fields that change how this file is read."""
        names = ["world", "velocity_world", "body", "rate_unit", "time_unit"]
        names += ["quat_order", "quat_direction"] if self.has_quaternion else ["angle_unit"]
        return tuple(names)


def _read_rows(path: Path, notes: list[str]) -> tuple[list[str], list[list[str]], list[int]]:
    """The header, the data rows and each data row's line in the file (blank lines skipped)."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.reader(fh)
            numbered = [(reader.line_num, r) for r in reader]
    except UnicodeDecodeError:
        raise InputError(
            f"{path} is not a text CSV file (a ULog needs the .ulg extension, a DataFlash log .bin, a MAVLink "
            "telemetry log .tlog)"
        ) from None
    numbered = [(n, r) for n, r in numbered if r and any(c.strip() for c in r)]
    if not numbered:
        raise InputError(f"{path} is empty")
    header = [h.strip() for h in numbered[0][1]]
    body = [r for _, r in numbered[1:]]
    lines = [n for n, _ in numbered[1:]]
    if not body:
        raise InputError(f"{path} has a header but no data rows")
    if len(body[-1]) < len(header):
        notes.append(f"last row of {path.name} is cut short (truncated file): dropped")
        body, lines = body[:-1], lines[:-1]
    for r, n in zip(body, lines, strict=True):
        if len(r) != len(header):
            raise InputError(f"{path}: line {n} has {len(r)} fields, the header has {len(header)}")
    return header, body, lines


def _column(path: Path, header: list[str], rows: list[list[str]], name: str, lines: list[int]) -> np.ndarray:
    j = header.index(name)
    cells = np.char.strip(np.array([r[j] for r in rows], dtype=str))
    cells = np.where((cells == "") | (np.char.lower(cells) == "nan"), "nan", cells)
    try:
        return cells.astype(float)
    except ValueError:
        for i, cell in enumerate(cells):
            try:
                float(cell)
            except ValueError:
                raise InputError(f"{path}: line {lines[i]}, column {name!r}: {cell!r} is not a number") from None
        raise  # pragma: no cover - astype and float agree


#: Largest magnitude a CSV cell of a signal may hold (velocity, attitude, rates, thrust, torque, rotor speeds,
#: in any unit the reader takes: rpm, deg/s, percent): far beyond any flight, so a larger one is a corrupt cell.
CELL_LIMIT = 1e6


def read_csv_table(path: str | os.PathLike[str], columns: dict[str, str] | None = None) -> CsvTable:
    """Parse a CSV log once: every known role's column as floats (NaN where empty)."""
    from ..errors import instance, path_like

    path_like("path", path)
    if columns is not None:
        instance("columns", columns, dict)
    path = Path(path)
    if not path.is_file():
        raise InputError(f"cannot read log file {path}: {explain_path(path) or 'not a regular file'}")
    notes: list[str] = []
    header, rows, lines = _read_rows(path, notes)
    mapping = {k: k for k in COLUMNS}
    for k, v in (columns or {}).items():
        if k not in COLUMNS:
            close = difflib.get_close_matches(k, COLUMNS, 3, 0.5)
            hint = f" (did you mean {' or '.join(close)}?)" if close else ""
            raise InputError(f"unknown column role {k!r}{hint}; roles are {', '.join(COLUMNS)}")
        if v not in header:
            raise InputError(
                f"{path}: --column {k}={v}: the file has no column {v!r}{_close_hint(v, header)}; it has: "
                f"{', '.join(header)}"
            )
        mapping[k] = v
    for role in COLUMNS:
        if role in (columns or {}) or role in header:
            continue
        names = {role.lower(), *(a.lower() for a in ALIASES.get(role, ()))}
        hits = [h for h in header if h.lower() in names]
        if len(hits) > 1:
            raise InputError(
                f"{path}: columns {' and '.join(repr(h) for h in hits)} both name the role {role} (accepted aliases); "
                f"which one is meant? choose with --column {role}={hits[0]}"
            )
        if hits:
            mapping[role] = hits[0]
            notes.append(f"column {hits[0]!r} read as {role} (an accepted alias)")
    present = {role for role, col in mapping.items() if col in header}
    shared: dict[str, list[str]] = {}
    for role in sorted(present):
        shared.setdefault(mapping[role], []).append(role)
    for col, roles in shared.items():
        if len(roles) > 1:
            raise InputError(
                f"{path}: column {col!r} is mapped to more than one role ({', '.join(roles)}); map each once"
            )
        if header.count(col) > 1:
            raise InputError(
                f"{path}: column {col!r} appears {header.count(col)} times in the header; which one is meant?"
            )

    used = {mapping[r] for r in present}

    def need(group: tuple[str, ...], what: str) -> None:
        miss = [c for c in group if c not in present]
        if miss:
            free = [h for h in header if h not in used]
            fixes = []
            for role in miss:
                cands = _candidates(role, free)
                if cands:
                    fixes.append(f"--column {role}={cands[0]}" + (f" (or {', '.join(cands[1:])})" if cands[1:] else ""))
            advice = (
                "; if the file names them otherwise, map them: " + ", ".join(fixes)
                if fixes
                else "; map a column of another name with --column ROLE=NAME"
            )
            raise InputError(
                f"{path}: {what} needs column(s) {', '.join(mapping[c] for c in miss)}; the file has: "
                f"{', '.join(header)}{advice}"
            )

    if "t_s" in present:
        time_role = "t_s"
    elif "timestamp_us" in present:
        time_role = "timestamp_us"
    else:
        need(("t_s",), "time")
    need(("vx", "vy", "vz"), "velocity")
    need(("wx", "wy", "wz"), "body rates")
    if not {"q0", "q1", "q2", "q3"} <= present:
        need(("roll", "pitch", "yaw"), "attitude (or q0..q3)")
    if "thrust_n" in present and "thrust_norm" in present:
        raise InputError(f"{path}: give thrust_n (newtons) or thrust_norm (normalised), not both")
    if not ({"thrust_n", "thrust_norm"} & present or "rpm1" in present):
        need(("thrust_n",), "collective thrust (or thrust_norm, or rotor speeds rpm1..)")
    cols = {role: _column(path, header, rows, mapping[role], lines) for role in COLUMNS if role in present}
    for role, v in cols.items():  # one garbled cell is named, not left to poison the checks' averages
        if role in ("t_s", "timestamp_us"):
            continue
        bad = np.flatnonzero(np.isfinite(v) & (np.abs(np.where(np.isfinite(v), v, 0.0)) > CELL_LIMIT))  # inf: a gap
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"{path}: line {lines[i]}, column {mapping[role]!r}: {v[i]:g} is beyond any flight's value (|x| <= "
                f"{CELL_LIMIT:g} in any unit this reader takes; {bad.size} such cell(s)): a corrupt cell? fix or "
                "remove the row"
            )
    if {"q0", "q1", "q2", "q3"} <= present:
        for r in ("roll", "pitch", "yaw"):
            cols.pop(r, None)
    return CsvTable(path, header, cols, time_role, notes)


def _close_hint(name: str, header: list[str]) -> str:
    close = difflib.get_close_matches(name, header, 3, 0.6)
    return f" (close: {', '.join(close)})" if close else ""


def _candidates(role: str, free: list[str], n: int = 3) -> list[str]:
    """The file's unmapped columns most like the role's name or one of its aliases (difflib), best first."""
    lower = {h.lower(): h for h in free}
    score: dict[str, float] = {}
    for name in (role, *ALIASES.get(role, ())):
        for m in difflib.get_close_matches(name.lower(), list(lower), n, 0.6):
            r = difflib.SequenceMatcher(None, name.lower(), m).ratio()
            score[lower[m]] = max(score.get(lower[m], 0.0), r)
    return sorted(score, key=lambda h: -score[h])[:n]


def _signal(name: str, source: str, t: np.ndarray, cols: list[np.ndarray], hold: bool = False) -> Signal:
    v = np.stack(cols, -1)
    have = ~np.all(np.isnan(v), axis=1)  # rows where this signal was not logged at all
    return Signal(name, source, t[have], v[have], hold)


def table_to_raw(
    table: CsvTable,
    conv: Conventions,
    rotor_speed_unit: str = "rpm",
    check_quaternion: bool = True,
    cache: dict | None = None,
) -> RawLog:
    """The table's signals in world NED / body FRD, SI units, read under ``conv``. ``cache`` (a dict kept
    between calls on the same table) reuses every signal whose conventions did not change: the convention
    checks read one table under hundreds of conventions."""
    from ..errors import choice, instance

    instance("table", table, CsvTable)
    instance("conv", conv, Conventions)
    choice("rotor_speed_unit", rotor_speed_unit, tuple(ROTOR_SPEED_UNITS))
    c = table.cols
    notes = list(table.notes)
    if rotor_speed_unit not in ROTOR_SPEED_UNITS:
        raise InputError(f"rotor speed unit must be one of {', '.join(ROTOR_SPEED_UNITS)}, got {rotor_speed_unit!r}")

    def cached(key: tuple, make):
        if cache is None:
            return make()
        if key not in cache:
            cache[key] = make()
        return cache[key]

    t = cached(("t", conv.time_unit), lambda: c[table.time_role] * TIME_UNITS[conv.time_unit])
    a_scale = np.pi / 180.0 if conv.angle_unit == "deg" else 1.0
    r_scale = np.pi / 180.0 if conv.rate_unit == "deg" else 1.0

    def attitude() -> Signal:
        if table.has_quaternion:
            att = _signal("attitude", "q0..q3", t, [c[f"q{i}"] for i in range(4)])
            q = att.values
            if not check_quaternion:  # exploring conventions: a non-unit quaternion reads as garbage, not error
                q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-12)
            R = frames.quaternion_rotation(q, conv.quat_order, conv.quat_direction)
        else:
            att = _signal("attitude", "roll, pitch, yaw", t, [c[k] * a_scale for k in ("roll", "pitch", "yaw")])
            R = frames.euler_rotation(*att.values.T)
        att.values = frames.eta_ned_frd(R, conv.world, conv.body)
        return att

    def velocity() -> Signal:
        vel = _signal("velocity", f"vx, vy, vz ({conv.velocity_world.upper()})", t, [c["vx"], c["vy"], c["vz"]])
        vel.values = frames.world_vector_to_ned(vel.values, conv.velocity_world)
        return vel

    def body_rates() -> Signal:
        w = _signal("body rates", f"wx, wy, wz ({conv.body.upper()})", t, [c[k] * r_scale for k in ("wx", "wy", "wz")])
        w.values = frames.body_vector_to_frd(w.values, conv.body)
        return w

    form = (conv.quat_order, conv.quat_direction) if table.has_quaternion else (conv.angle_unit,)
    att = cached(("att", conv.time_unit, *form, conv.world, conv.body, check_quaternion), attitude)
    vel = cached(("vel", conv.time_unit, conv.velocity_world), velocity)
    rates = cached(("rates", conv.time_unit, conv.rate_unit, conv.body), body_rates)
    raw_kw: dict = {}
    thrust = None
    if "thrust_n" in c:
        thrust = _signal("thrust", "thrust_n [N]", t, [c["thrust_n"]], hold=True)
        raw_kw["thrust_unit"] = "N"
    elif "thrust_norm" in c:
        thrust = _signal("thrust", "thrust_norm", t, [c["thrust_norm"]], hold=True)
        raw_kw["thrust_unit"] = "normalized"
        if "hover_thrust" in c:
            h = _signal("hover thrust", "hover_thrust column", t, [c["hover_thrust"]])
            if len(h.t) >= 2:
                raw_kw["hover"] = h
            elif len(h.t) == 1:
                raw_kw["hover_thrust"] = float(h.values[0, 0])
                raw_kw["hover_source"] = "the hover_thrust column (one value)"
            else:
                notes.append("the hover_thrust column holds no value (every cell empty or NaN): not used")
    torque = None
    if {"tx", "ty", "tz"} <= set(c):
        torque = _signal("torque", f"tx, ty, tz [N m] ({conv.body.upper()})", t, [c["tx"], c["ty"], c["tz"]], True)
        torque.values = frames.body_vector_to_frd(torque.values, conv.body)
    rotor_roles = table.rotor_roles
    if rotor_roles:
        k = ROTOR_SPEED_UNITS[rotor_speed_unit]
        raw_kw["rotor_speed"] = _signal(
            "rotor speeds", f"{', '.join(rotor_roles)} [{rotor_speed_unit}]", t, [c[r] * k for r in rotor_roles]
        )
        raw_kw["n_rotors"] = len(rotor_roles)
    if torque is None:
        notes.append("no body torque columns (tx, ty, tz): the moment needs rotor speeds and a rotor geometry")
    meta = {"format": "csv", "file": str(table.path), "conventions": conv.to_dict()}
    if rotor_roles:
        meta["rotor_speed_unit"] = rotor_speed_unit
    return RawLog(vel, att, rates, thrust, torque, notes=notes, meta=meta, **raw_kw)


def read_csv(
    path: str | os.PathLike[str],
    world: str = "ned",
    body: str = "frd",
    angle_unit: str = "rad",
    quat_order: str = "wxyz",
    quat_direction: str = "body-to-world",
    columns: dict[str, str] | None = None,
    *,
    time_unit: str | None = None,
    rate_unit: str | None = None,
    velocity_world: str | None = None,
    rotor_speed_unit: str = "rpm",
    conventions: Conventions | None = None,
) -> RawLog:
    """Read a CSV log (see the module docstring for the columns) into world NED / body FRD signals.

    The conventions are the keyword arguments or ``conventions`` (which then wins). ``time_unit``
    defaults to seconds for a ``t_s`` column and microseconds for ``timestamp_us``.
    """
    from ..errors import instance, path_like

    path_like("path", path)
    if columns is not None:
        instance("columns", columns, dict)
    if conventions is not None:
        instance("conventions", conventions, Conventions)
    if not isinstance(angle_unit, str) or angle_unit not in ANGLE_UNITS:
        raise InputError(f"angle unit (angle_unit) must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")
    if angle_unit not in ANGLE_UNITS:
        raise InputError(f"angle unit must be one of {', '.join(ANGLE_UNITS)}, got {angle_unit!r}")
    table = read_csv_table(path, columns)
    if conventions is None:
        if time_unit is None:
            time_unit = "us" if table.time_role == "timestamp_us" else "s"
        conventions = Conventions(
            world=world, body=body, angle_unit=angle_unit, quat_order=quat_order, quat_direction=quat_direction,
            time_unit=time_unit, velocity_world=velocity_world, rate_unit=rate_unit,
        )  # fmt: skip
    return table_to_raw(table, conventions, rotor_speed_unit)
