"""From a log file to an estimate, with every choice made from the log recorded.

:func:`read_any` reads any supported format (by extension: ``.ulg`` PX4, ``.bin`` ArduPilot DataFlash,
``.tlog`` MAVLink, anything else CSV), refuses a thrust of zeros or one held constant, and checks the
conventions against physics (:mod:`vtol_impedance.logs.checks`; for a CSV file every combination of
the conventions that apply to it is tried). :func:`estimate_file` then takes the nominal vehicle from the
arguments, a vehicle preset or the log's parameters, resamples (gap threshold from the log's rates) and
estimates. What was chosen and why is in ``LogEstimate.info["choices"]``.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, scalar
from ..io import explain_path
from .airframe import airframe_option, check_airframe
from .checks import ConventionReport, ImplausibleTime, check_conventions, check_thrust_signal, time_plausible
from .csvlog import CsvTable, read_csv_table, table_to_raw
from .estimate import LogEstimate, check_inertia, estimate, uses_rotor_speeds
from .frames import TIME_UNITS, Conventions
from .timeseries import RawLog, resample, typical_period
from .verdict import LogRefused, judge

FORMATS = {".ulg": "ulog", ".bin": "dataflash", ".tlog": "tlog"}
#: A CSV file longer than this is checked on its most dynamic block of rows (the checks need minutes, not
#: hours of flight).
CHECK_ROWS = 30000


def log_format(path: str | os.PathLike[str]) -> str:
    """``"ulog"``, ``"dataflash"``, ``"tlog"`` or ``"csv"`` from the file name."""
    from ..errors import path_like

    path_like("path", path)
    return FORMATS.get(Path(path).suffix.lower(), "csv")


def _check_block(table: CsvTable) -> CsvTable:
    n = len(table.cols[table.time_role])
    if n <= CHECK_ROWS:
        return table
    v = np.column_stack([table.cols[k] for k in ("vx", "vy", "vz")])
    starts = np.append(np.arange(0, n - CHECK_ROWS, CHECK_ROWS // 4), n - CHECK_ROWS)  # the last rows too
    act = [float(np.nansum(np.nanstd(v[s : s + CHECK_ROWS], 0))) for s in starts]
    s = int(starts[int(np.argmax(act))])
    cols = {k: c[s : s + CHECK_ROWS] for k, c in table.cols.items()}
    return CsvTable(table.path, table.header, cols, table.time_role, list(table.notes))


#: Fewest samples of a signal a log is estimated from: half a second at 100 Hz, five time constants of the
#: default estimator (wn = 10 rad/s); fewer tell nothing, not even which conventions the file follows.
MIN_LOG_SAMPLES = 50
#: Shortest stretch of flight (after --start/--end) an estimate is made on, s.
MIN_WINDOW_S = 1.0


def _long_enough(raw: RawLog, path: Path) -> None:
    """Refuse a log whose needed signals have fewer than :data:`MIN_LOG_SAMPLES`; an optional one (the torque,
    the rotor speeds: an ESC stream asked for only while a ground station probed) is left out, noted."""
    for name in ("torque_B", "rotor_speed"):
        sig = getattr(raw, name)
        if sig is not None and len(sig.t) < MIN_LOG_SAMPLES:
            raw.notes.append(
                f"{sig.name} ({sig.source}) has {len(sig.t)} sample(s), too few to use (at least {MIN_LOG_SAMPLES}):"
                " left out"
            )
            setattr(raw, name, None)
    short = [(s.name, len(s.t)) for s in raw.signals() if len(s.t) < MIN_LOG_SAMPLES]
    if short:
        name, n = min(short, key=lambda x: x[1])
        raise InputError(
            f"{path}: the {name} has {n} sample{'s' if n != 1 else ''}, too few to estimate from (at least "
            f"{MIN_LOG_SAMPLES}: half a second at 100 Hz)"
        )


def read_any(
    path: str | os.PathLike[str],
    *,
    conventions: str = "check",
    world: str = "ned",
    body: str = "frd",
    angle_unit: str = "rad",
    quat_order: str = "wxyz",
    quat_direction: str = "body-to-world",
    time_unit: str | None = None,
    rate_unit: str | None = None,
    velocity_world: str | None = None,
    columns: dict[str, str] | None = None,
    rotor_speed_unit: str = "rpm",
    sysid: int | None = None,
    compid: int | None = None,
) -> tuple[RawLog, ConventionReport]:
    """Read a log of any supported format and check it (module docstring). The frame and unit arguments
    are a CSV file's declared conventions; ``conventions`` is ``"check"``, ``"auto"`` or ``"unchecked"``
    (which skips only the conventions' check against physics: the thrust-carries-the-weight check of the
    estimate still runs). ``sysid``/``compid``: the vehicle of a tlog with several
    (:func:`~vtol_impedance.logs.mavlog.read_tlog`)."""
    from ..errors import choice, instance, path_like
    from .checks import MODES

    choice("conventions", conventions, MODES)
    path_like("path", path)
    if columns is not None:
        instance("columns", columns, dict)
    path = Path(path)
    if not path.is_file():
        raise InputError(f"cannot read log file {path}: {explain_path(path) or 'not a regular file'}")
    fmt = log_format(path)
    for name, val in (("sysid", sysid), ("compid", compid)):
        if val is not None and fmt != "tlog":
            raise InputError(f"--{name} chooses a vehicle of a MAVLink telemetry log (.tlog); {path} is {fmt}")
        if val is not None and not (isinstance(val, int | np.integer) and 0 <= val <= 255):
            raise InputError(f"--{name} must be a MAVLink id, an integer 0..255, got {val!r}")
    if fmt != "csv":
        if fmt == "ulog":
            from .ulog import read_ulog

            raw = read_ulog(path)
        elif fmt == "dataflash":
            from .mavlog import read_dataflash

            raw = read_dataflash(path)
        else:
            from .mavlog import read_tlog

            raw = read_tlog(path, sysid, compid)
        _long_enough(raw, path)
        if raw.thrust is not None:
            raw.thrust = check_thrust_signal(raw.thrust, raw.notes, (raw.velocity_W, raw.omega_B))
        raw, rep = check_conventions(raw, conventions)
        return raw, rep
    table = read_csv_table(path, columns)
    if time_unit is None:
        time_unit = "us" if table.time_role == "timestamp_us" else "s"
    declared = Conventions(
        world=world, body=body, angle_unit=angle_unit, quat_order=quat_order, quat_direction=quat_direction,
        time_unit=time_unit, velocity_world=velocity_world, rate_unit=rate_unit,
    )  # fmt: skip
    raw = table_to_raw(table, declared, rotor_speed_unit)
    _long_enough(raw, path)
    notes: list[str] = []
    if raw.thrust is not None:
        check_thrust_signal(
            raw.thrust, notes, (raw.velocity_W, raw.omega_B)
        )  # zeros or constant: refused before anything else
    block = _check_block(table)
    t_col = block.cols[block.time_role]
    cache: dict = {}

    def reread(c: Conventions) -> RawLog:
        if not time_plausible(t_col * TIME_UNITS[c.time_unit]):
            raise ImplausibleTime
        r = table_to_raw(block, c, rotor_speed_unit, check_quaternion=False, cache=cache)
        if r.thrust is not None:
            r.thrust = check_thrust_signal(r.thrust, [], (r.velocity_W, r.omega_B))
        return r

    if block is table:
        raw_block = raw
    else:
        raw_block = table_to_raw(block, declared, rotor_speed_unit)
        notes.append(f"conventions checked on rows {len(t_col)} of the most dynamic part of the file")
    if raw_block.thrust is not None:
        raw_block.thrust = check_thrust_signal(raw_block.thrust, [], (raw_block.velocity_W, raw_block.omega_B))
    _, rep = check_conventions(raw_block, conventions, declared, reread, table.relevant_conventions())
    if rep.chosen is not None and rep.chosen != declared:
        raw = table_to_raw(table, rep.chosen, rotor_speed_unit)
    if raw.thrust is not None:
        raw.thrust = check_thrust_signal(raw.thrust, raw.notes, (raw.velocity_W, raw.omega_B))
    raw.notes.extend(notes)
    return raw, rep


def _vehicle(
    raw: RawLog, mass: float | None, inertia: Any, vehicle: Any
) -> tuple[float, np.ndarray | None, tuple[np.ndarray, np.ndarray] | None, list[str]]:
    """The nominal mass, inertia (or ``None``: force only) and rotor geometry, and where each came from;
    ``vehicle`` is a :class:`~vtol_impedance.model.VehicleParams`, a preset name or a vehicle TOML."""
    if isinstance(vehicle, str | os.PathLike):
        from ..model.vehicle import load_preset

        vehicle = load_preset(str(vehicle))
    choices = []
    geometry = None
    if mass is not None:
        m, m_src = float(mass), "given (--mass)"
    elif vehicle is not None:
        m, m_src = float(vehicle.mass), f"the vehicle {vehicle.name}"
    elif raw.mass is not None:  # as --mass would be checked, naming where it came from
        try:
            m = scalar(f"the log's mass ({raw.vehicle_source})", raw.mass, lo=MIN_MASS_KG, hi=MAX_MASS_KG)
        except InputError as exc:
            raise InputError(f"{exc}; give the vehicle's own with --mass KG or --vehicle") from None
        m_src = raw.vehicle_source
    else:
        raise InputError(
            "the estimator needs the vehicle's nominal mass: give --mass KG or --vehicle NAME|FILE.toml (the log "
            "has no mass parameter)"
        )
    if raw.mass is not None and mass is not None and abs(raw.mass - float(mass)) > 0.02 * float(mass):
        choices.append(f"mass: the log's parameters say {raw.mass:.4g} kg; using the given {float(mass):.4g} kg")
    choices.append(f"mass: {m:.4g} kg, {m_src}")
    if inertia is not None:
        I_B, i_src = check_inertia(inertia), "given (--inertia)"
    elif vehicle is not None:
        I_B, i_src = np.asarray(vehicle.inertia, dtype=float), f"the vehicle {vehicle.name}"
    elif raw.inertia is not None:
        try:
            I_B, i_src = check_inertia(raw.inertia), raw.vehicle_source
        except InputError as exc:
            raise InputError(f"the log's inertia ({raw.vehicle_source}): {exc}; give it with --inertia or --vehicle") \
                from None
    else:
        I_B, i_src = None, "none given: the force only (the moment needs --inertia or --vehicle)"
    choices.append("inertia: " + ("" if I_B is None else f"diag {np.round(np.diag(I_B), 6).tolist()} kg m^2, ") + i_src)
    if raw.rotor_geometry is not None:
        geometry = raw.rotor_geometry
        choices.append(f"rotor geometry: the log's parameters ({len(geometry[0])} rotors)")
    elif vehicle is not None:
        from .rotors import geometry_from_vehicle

        geometry = geometry_from_vehicle(vehicle)
        choices.append(f"rotor geometry: the vehicle {vehicle.name} ({len(geometry[0])} rotors)")
    return m, I_B, geometry, choices


#: Heaviest vehicle a mass is accepted for, kg (the largest multirotors carry a few hundred).
MAX_MASS_KG = 1e4
#: Lightest, kg: a fifth of the smallest flying multirotors (nano quadrotors weigh 20-30 g). Below it a
#: mass is a unit slip (grams read as tonnes), and the fits it scales degenerate into confident nonsense.
MIN_MASS_KG = 0.005


def estimate_file(
    path: str | os.PathLike[str],
    mass: float | None = None,
    inertia: Any = None,
    params: Any = None,
    *,
    vehicle: Any = None,
    rate_hz: float = 100.0,
    max_gap_s: float | None = None,
    t_start: float | None = None,
    t_end: float | None = None,
    read_options: dict[str, Any] | None = None,
    airframe: str = "auto",
    force: bool = False,
    **estimate_options: Any,
) -> LogEstimate:
    """Read, check, resample and estimate a log file (module docstring). ``vehicle``: a
    :class:`~vtol_impedance.model.vehicle.VehicleParams` for the nominal mass, inertia and rotor geometry
    where they are not given; ``read_options`` go to :func:`read_any`, ``estimate_options`` to
    :func:`~vtol_impedance.logs.estimate.estimate`. A log of a vehicle that is not a multirotor is refused
    (:mod:`.airframe`) unless ``airframe="multirotor"``. The estimate's columns are then tested against
    physics (:mod:`.verdict`): a log they contradict raises :class:`~vtol_impedance.logs.verdict.LogRefused`
    unless ``force``, which records the override in ``info["verdict"]`` and the warnings."""
    from ..errors import path_like

    path_like("path", path)
    rate_hz = scalar("resampling rate (rate_hz, Hz)", rate_hz, lo=1.0, hi=10000.0)
    if mass is not None:
        mass = scalar("mass (kg)", mass, lo=MIN_MASS_KG, hi=MAX_MASS_KG)
    airframe_option(airframe)
    # values checked before the file is read: a NaN window or a 1e30 kg vehicle is a typing error
    if t_start is not None:
        t_start = scalar("start (s)", t_start)
    if t_end is not None:
        t_end = scalar("end (s)", t_end)
    if t_start is not None and t_end is not None and not t_end > t_start:
        raise InputError(f"the window must end after it starts, got start {t_start:g} s and end {t_end:g} s")
    if mass is not None:
        mass = scalar("mass (kg)", mass, lo=MIN_MASS_KG, hi=MAX_MASS_KG)
    if estimate_options.get("hover_thrust") is not None:
        scalar("hover thrust", estimate_options["hover_thrust"], lo=0.0, hi=1.0, lo_open=True)
    raw, rep = read_any(path, **(read_options or {}))
    kind, kind_warning = check_airframe(raw.meta, raw.params, airframe)  # before the mass is asked for
    m, I_B, geometry, vchoices = _vehicle(raw, mass, inertia, vehicle)
    vchoices.insert(0, kind)
    thrust_from = estimate_options.get("thrust_from", "auto")
    k_T = estimate_options.get("thrust_coefficient")
    if raw.rotor_speed is not None and thrust_from == "auto" and not uses_rotor_speeds(raw, thrust_from, k_T):
        raw.notes.append(
            f"rotor speeds ({raw.rotor_speed.source}) at {1 / typical_period(raw.rotor_speed.t):.3g} Hz, below "
            "20 Hz: not used (the thrust comes from the commands; --thrust-from rotors to use them)"
        )
        raw.rotor_speed = None  # neither on the grid nor in the gap threshold
    elif raw.rotor_speed is not None and thrust_from == "commands":
        raw.rotor_speed = None
    flight = resample(raw, rate_hz, max_gap_s, t_start, t_end)
    span = float(flight.t[-1] - flight.t[0])
    if span < MIN_WINDOW_S:
        where = "" if t_start is None and t_end is None else " in the window --start/--end"
        raise InputError(
            f"the log holds {span:.3g} s of flight{where} ({len(flight.t)} samples on the grid); an estimate needs "
            f"at least {MIN_WINDOW_S:g} s (the estimator settles in half a second, the thrust calibrations "
            "average over half a second)"
        )
    if estimate_options.get("rotor_geometry") is None and geometry is not None:
        estimate_options["rotor_geometry"] = geometry
    est = estimate(flight, m, I_B, params, **estimate_options)
    thrust_col = raw.thrust.source if raw.thrust is not None else "thrust"
    if est.info.get("thrust_coefficient") is not None:
        thrust_col = f"rotor speeds ({raw.rotor_speed.source})"
    verdict = judge(
        flight, est.thrust_N, m, thrust_column=thrust_col, undetermined=rep.undetermined,
        kinematics=rep.evidence_chosen,
    )  # fmt: skip
    if verdict.outcome == "refused":
        if not force:
            raise LogRefused(verdict, str(path), rep.warnings + est.warnings)
        verdict.forced = True
    est.info["verdict"] = verdict.to_dict()
    choices = list(raw.choices) + vchoices + [f"max gap: {flight.max_gap_source}"]
    choices.append(f"thrust: {est.info['thrust']}")
    if "torque" in est.info:
        choices.append(f"torque: {est.info['torque']}")
    est.info["choices"] = choices
    est.info["conventions"] = rep.to_dict()
    # accepted or undecided (a test left out for too little motion; conventions the data cannot decide are
    # already a warning of the convention check): a note; a forced refusal: a warning
    said = [f"verdict {verdict.outcome}: {verdict.message()}"] if not verdict.forced else []
    est.notes = rep.notes + est.notes + said
    forced = [f"verdict overridden (--force): {verdict.message()}"] if verdict.forced else []
    est.warnings = forced + rep.warnings + ([kind_warning] if kind_warning else []) + est.warnings
    return est


__all__ = ["FORMATS", "estimate_file", "log_format", "read_any"]
