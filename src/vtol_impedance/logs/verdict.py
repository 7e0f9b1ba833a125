"""Whether a log's columns are right: a verdict from physics, after the conventions are chosen.

The convention check (:mod:`vtol_impedance.logs.checks`) ranks readings of a file against each other; it
cannot say that *no* reading fits (a velocity played backwards, a thrust column of noise, rows shuffled).
This module tests the chosen reading against physics on the resampled flight, with the thrust already in
newtons, and separates "the columns are wrong" from "a large external force acts" (an agile flight's
drag, a push, a payload): an external force is what the estimator exists to find, so a test that a large
force fails is a wrong test. Three tests, each on a signal band where an external force cannot hide a
wrong column:

* **kinematics**: the body rates are the attitude's rate of change, ``[w_B]x = R^T dR/dt``: the kinematic
  score of the convention check (:func:`~vtol_impedance.logs.checks.evidence`, 0 agree, about 1 unrelated
  or opposite); no force enters it. Refused above :data:`KIN_LIMIT` where the attitude moves.
* **force balance**, horizontal and vertical: ``m a = m g e3 - u R e3 + f_ext`` (world NED) on band-passed
  signals (0.5 s averages minus 4 s averages: :data:`BAND_S`), jointly with a drag model linear and
  quadratic in the velocity, ``f_ext,j = D_j v_j + D2_j |v| v_j`` (per world axis, fitted by least squares on
  the same band; the quadratic term takes an agile flight's aerodynamic drag of up to half the weight, which
  a linear one left as 0.21-0.30 of unexplained force). What is left, ``rel``,
  is the RMS of the unexplained acceleration over the sum of the RMS of the measured and the predicted
  acceleration (plus a noise floor :data:`ACCEL_FLOOR`). A steady force (payload, wind, a tether) lies
  below the band; drag, the force of an agile flight, is correlated with the velocity and taken by ``D``;
  a push or a contact acts for a few seconds of the flight, so the score is a low quantile
  (:data:`QUANTILE`) over :data:`WINDOW_S` windows and fails only where the failing windows are at least
  :data:`COVERAGE` of the airborne ones, and a wrong column is wrong in every window (a log with fewer than
  :data:`MIN_WINDOWS` windows of motion leaves the test out: one push would decide it). Each horizontal
  axis is also scored alone where it moves (:data:`AXIS_MOTION`): one axis wrong in a flight mostly
  along the other. A velocity played backwards, a thrust of noise or two velocity columns swapped leave
  ``rel`` at 0.2-1; a correct log about 0.01-0.12 (:data:`DYN_LIMIT`). The fitted drag must oppose the
  velocity: a drag that pushes along it (:data:`DRAG_LIMIT`) is a velocity that runs against the thrust.
* **thrust and rotor speeds** (where the log has both): ``u`` and ``sum w_i^2`` on the same band must be
  proportional (relative residual of the least-squares scale, :data:`ROTOR_LIMIT`); no force enters it.

A test where the flight does not move enough to tell (:data:`KIN_MOTION`, :data:`DYN_MOTION`) is left
out, and says so. The verdict: ``"refused"`` when a test fails (it names the column and the residual),
``"undecided"`` when the convention check could not decide between readings or a test was left out but
nothing contradicts physics (estimated, with a note), else ``"accepted"``.
:func:`~vtol_impedance.logs.estimate_file` raises :class:`LogRefused` on a refusal unless ``force=True``,
which records the override. The limits are set on the labelled corpus of ``tests/test_logs_verdict.py``
(docs/guide/logs.md, "What the log check accepts and refuses", gives both error rates).

Left out: the log's position (no reader keeps it), so velocity against the position's derivative is not
tested; a wind that changes within seconds (gusts) is a force the drag model cannot explain and counts
against the log where it lasts most of the flight.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..conventions import G
from ..errors import InputError
from ..model.kinematics import rotation_zyx
from .checks import Evidence, _moving_average, evidence
from .timeseries import FlightLog

#: Band of the force-balance test: averages over the first (s) minus averages over the second (s).
BAND_S = (0.5, 4.0)
#: Windows over which the force-balance score is taken, s; the verdict uses a low quantile of them.
WINDOW_S = 4.0
#: The force-balance score is this percentile of the windows' residuals: a wrong column is wrong in every
#: window, a push or a contact acts in a few (a median let one push in three windows refuse a correct log).
QUANTILE = 25.0
#: A force balance fails only where its failing windows are at least this share of the airborne windows: a
#: push or a contact the thrust answers without the vehicle moving fails the windows it lasts (three of seven
#: in a 30 s hover with a 4 s push), a wrong column fails the flight.
COVERAGE = 0.5
#: The force balance judges a log on at least this many windows with motion (fewer: left out, since a push
#: or a contact in one of two windows would decide the median).
MIN_WINDOWS = 3
#: A relative force-balance residual above this (low quantile of windows) refuses the log: on the labelled corpus
#: (tests/test_logs_verdict.py) a correct log scores at most 0.12, a wrong one it refuses at least 0.21.
DYN_LIMIT = 0.16
#: Noise floor of the band-passed accelerations, m/s^2.
ACCEL_FLOOR = 0.05
#: The band-passed measured acceleration needs this RMS (m/s^2) in a window to count (not the predicted one:
#: a hover whose thrust answers a push moves the prediction alone, and that window would judge the push).
DYN_MOTION = 0.1
#: A horizontal axis is also scored alone (one axis wrong in a flight mostly along the other) where its
#: band-passed acceleration has this RMS in a window, m/s^2: a motion well above a push's share.
AXIS_MOTION = 0.3
#: A fitted drag that pushes along the velocity by more than this share of g per m/s of RMS band speed
#: refuses the log.
DRAG_LIMIT = 0.05
#: Kinematic relative residual above this (where the attitude moves) refuses the log (a correct log of the
#: corpus scores at most 0.17, body x and y rates swapped at least 0.50).
KIN_LIMIT = 0.35
#: The attitude must move this much (RMS rate, rad/s) for the kinematic test.
KIN_MOTION = 0.02
#: A body axis turning this much (RMS rate, rad/s) is also tested alone, against the same limit: on the
#: corpus's correct logs an axis past it scores at most 0.03, Euler-angle rates logged as body rates
#: 0.38-0.89 on roll or pitch (an agile flight yawing at 1 rad/s and faster), where the whole score is 0.22-0.27.
KIN_AXIS_MOTION = 0.1
#: On a body axis turning past :data:`KIN_AXIS_MOTION`, body rates more than this share larger or smaller
#: than the attitude's rate of change refuse the log: a gyro's scale (its full-scale range set wrong, x2 or
#: x0.5) leaves the residual under :data:`KIN_LIMIT` (|1 - k| / (1 + k) is 0.33 for k = 2) while the moment
#: estimate comes out wrong. On the corpus's correct logs such an axis's gain is within 0.01 of 1; a correct
#: loop logged at 10 Hz (rates sampled too slowly for its turns) reads 0.79.
KIN_GAIN_LIMIT = 0.35
#: Relative residual of thrust against the rotors' sum of squared speeds above this refuses the log.
ROTOR_LIMIT = 0.35
#: What a verdict can be (module docstring).
OUTCOMES = ("accepted", "undecided", "refused")


@dataclass
class PhysicsTest:
    """One physics test: its value against its limit; ``status`` ``"pass"``, ``"fail"`` or ``"left out"``;
    ``columns`` the suspect column(s), ``detail`` the finding in words."""

    name: str
    value: float
    limit: float
    status: str
    columns: str
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        v = None if not np.isfinite(self.value) else round(float(self.value), 4)
        return {"test": self.name, "value": v, "limit": self.limit, "status": self.status, "columns": self.columns,
                "detail": self.detail}  # fmt: skip


@dataclass
class Verdict:
    """The outcome of the physics tests on a log (module docstring): ``outcome`` one of :data:`OUTCOMES`;
    ``forced`` when a refusal was overridden (``--force``)."""

    outcome: str
    tests: list[PhysicsTest] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    forced: bool = False

    @property
    def failed(self) -> list[PhysicsTest]:
        return [t for t in self.tests if t.status == "fail"]

    def message(self) -> str:
        """The verdict in one sentence."""
        if self.outcome == "refused":
            parts = [f"{t.name}: {t.detail} (suspect: {t.columns})" for t in self.failed]
            head = "the log's columns contradict physics, whatever external force acts: " + "; ".join(parts)
            names = {t.name for t in self.failed}
            if {"horizontal force balance", "vertical force balance"} <= names and "kinematics" not in names:
                head += (
                    ". Both balances fail and the rates agree with the attitude: the velocity, which they share, "
                    "is the likeliest"
                )
            if self.forced:
                return head + ". Estimated anyway (--force): the estimate is not to be trusted"
            return head
        if self.outcome == "undecided":
            return "the log agrees with physics; " + "; ".join(self.reasons)
        return "the log agrees with physics (" + ", ".join(t.name for t in self.tests if t.status == "pass") + ")"

    def to_dict(self) -> dict[str, Any]:
        return {"outcome": self.outcome, "forced": self.forced, "reasons": list(self.reasons),
                "tests": [t.to_dict() for t in self.tests], "message": self.message()}  # fmt: skip


class LogRefused(InputError):
    """A log whose columns contradict physics (:mod:`vtol_impedance.logs.verdict`); ``verdict`` says why."""

    def __init__(self, verdict: Verdict, what: str = "", warnings: list[str] | None = None) -> None:
        self.verdict = verdict
        also = ""
        if warnings:  # what the estimate already doubted may be the cause (a hover thrust 30 % off)
            also = " The estimate also warned, perhaps the cause: " + " | ".join(warnings) + "."
        super().__init__(
            (f"{what}: " if what else "") + verdict.message() + "." + also + " If the columns are right (check "
            "them), --force estimates anyway and records the override"
        )


def _segments(flight: FlightLog, min_len: int) -> list[slice]:
    starts = np.flatnonzero(flight.restart)
    ends = np.append(starts[1:], len(flight.t))
    return [slice(int(a), int(b)) for a, b in zip(starts, ends, strict=True) if b - a >= min_len]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.atleast_2d(x.T).T ** 2, -1)))) if len(x) else 0.0


def _kinematics(ev: Evidence) -> PhysicsTest:
    """The convention check's kinematic score (:func:`~vtol_impedance.logs.checks.evidence`) as a test."""
    if ev.no_stretch:
        return PhysicsTest("kinematics", ev.kin, KIN_LIMIT, "left out", "",
                           "the dropouts leave no stretch of a second to compare the body rates with the attitude on")  # fmt: skip
    if not ev.kin_motion > KIN_MOTION:
        return PhysicsTest("kinematics", ev.kin, KIN_LIMIT, "left out", "",
                           f"the attitude hardly moves ({ev.kin_motion:.3g} rad/s)")  # fmt: skip
    # each axis that turns on its own too: a fast yaw dominates the whole score and hides roll and pitch rates
    # of another quantity (Euler-angle rates logged as body rates: 0.22 in all, 0.89 on x)
    axes = [i for i in range(3) if ev.kin_axis_motion[i] > KIN_AXIS_MOTION]
    worst = max(axes, key=lambda i: ev.kin_axis[i], default=None)
    score, where = ev.kin, ""
    if worst is not None and ev.kin_axis[worst] > ev.kin:
        score, where = float(ev.kin_axis[worst]), f" on body axis {'xyz'[worst]}"
    detail = (f"body rates against the attitude's rate of change: relative residual {score:.2f}{where} (limit "
              f"{KIN_LIMIT:g})")  # fmt: skip
    flipped = [i for i in axes if ev.kin_gain[i] < 0]
    if score > KIN_LIMIT or flipped:  # a residual this large, or of the opposite sign: not a scale
        if flipped:
            detail += f"; body axis {'xyz'[flipped[0]]}'s rates have the opposite sign (a body frame or a column?)"
        return PhysicsTest("kinematics", score, KIN_LIMIT, "fail", "the body rates (wx, wy, wz) or the attitude",
                           detail)  # fmt: skip
    off = [i for i in axes if not abs(ev.kin_gain[i] - 1.0) <= KIN_GAIN_LIMIT]
    if off:  # the right shape at the wrong size: the residual passes, the gain does not
        i = max(off, key=lambda j: abs(ev.kin_gain[j] - 1.0))
        k = float(ev.kin_gain[i])
        return PhysicsTest("kinematics", abs(k - 1.0), KIN_GAIN_LIMIT, "fail", "the body rates (wx, wy, wz)",
                           f"body rates on body axis {'xyz'[i]} are {k:.3g} times the attitude's rate of change "
                           f"(1 expected, within {KIN_GAIN_LIMIT:g}): a gyro's scale or unit (its full-scale "
                           "range?)")  # fmt: skip
    return PhysicsTest("kinematics", score, KIN_LIMIT, "pass", "the body rates (wx, wy, wz) or the attitude",
                       detail)  # fmt: skip


def force_balance(
    flight: FlightLog, thrust_N: np.ndarray, mass: float, segs: list[slice] | None = None
) -> dict[str, Any]:
    """The band-passed force balance with a fitted drag (module docstring): per axis group
    (horizontal, vertical) the low quantile of the relative residual over windows (module docstring), how
    many windows had motion, the fitted drag ``D`` (N per m/s, world NED, negative opposes the velocity)
    and the RMS band speed."""
    if segs is None:
        segs = _segments(flight, int(2 * BAND_S[1] * flight.rate_hz))
    n1 = max(1, int(round(BAND_S[0] * flight.rate_hz)))
    n2 = max(3, int(round(BAND_S[1] * flight.rate_hz)))
    A, P, V, Q, W = [], [], [], [], []
    for s in segs:
        t = flight.t[s]
        a = _moving_average(np.gradient(flight.v_W[s], t, axis=0), n1)
        b = rotation_zyx(flight.eta[s])[:, :, 2]
        p = _moving_average(np.array([0.0, 0.0, G]) - thrust_N[s, None] * b / mass, n1)
        v = _moving_average(flight.v_W[s], n1)
        q = _moving_average(np.linalg.norm(flight.v_W[s], axis=-1, keepdims=True) * flight.v_W[s], n1)
        air = _moving_average(thrust_N[s], n2) > 0.5 * mass * G  # not on the ground
        keep = air & (np.arange(len(t)) >= n2 // 2) & (np.arange(len(t)) < len(t) - n2 // 2)
        A.append((a - _moving_average(a, n2))[keep])
        P.append((p - _moving_average(p, n2))[keep])
        V.append((v - _moving_average(v, n2))[keep])
        Q.append((q - _moving_average(q, n2))[keep])
        W.append(np.floor((t[keep] - flight.t[0]) / WINDOW_S).astype(int) + 1000 * len(W))
    a, p, v, q, win = (np.concatenate(x) if x else np.zeros((0, 3)) for x in (A, P, V, Q, W))
    out: dict[str, Any] = {}
    if len(a) < 10:
        return {"horizontal": None, "vertical": None}
    n_windows = len(np.unique(win))  # airborne windows, moving or not
    d = a - p  # what the thrust does not explain: the external force over the mass
    # per axis, a drag linear and quadratic in the velocity (|v| v_j: an agile flight's aerodynamic force)
    D, Dq = np.zeros(3), np.zeros(3)
    for j in range(3):
        X = np.column_stack([v[:, j], q[:, j]])
        D[j], Dq[j] = np.linalg.lstsq(X, d[:, j], rcond=None)[0] if np.any(X) else (0.0, 0.0)
    res = d - D * v - Dq * q
    # the drag as one linear coefficient, for its sign test: its part along the velocity
    D = D + Dq * np.array([float(q[:, j] @ v[:, j] / max(v[:, j] @ v[:, j], 1e-12)) for j in range(3)])

    def score(sl: slice, motion: float = DYN_MOTION) -> tuple[float, int]:
        """Median over the windows with motion on these axes, and how many there were."""
        scores = []
        for w in np.unique(win):
            m = win == w
            if m.sum() < 10:
                continue
            ra, rp = _rms(a[m, sl]), _rms(p[m, sl])
            if max(ra, rp) >= motion:
                scores.append(_rms(res[m, sl]) / (ra + rp + ACCEL_FLOOR))
        if not scores:
            return float("nan"), 0
        # an event (a push, a contact) is wrong in the windows it lasts, a wrong column in the whole flight:
        # below half of the airborne windows failing, the score is the best of the failing ones' neighbours
        failing = sum(x > DYN_LIMIT for x in scores)
        if failing < COVERAGE * n_windows:
            return float(min(DYN_LIMIT, np.percentile(scores, QUANTILE))), len(scores)
        return float(np.percentile(scores, QUANTILE)), len(scores)

    for name, sl in (("horizontal", slice(0, 2)), ("vertical", slice(2, 3))):
        rel, moved = score(sl)
        if name == "horizontal":  # and each horizontal axis alone: one axis wrong in a flight along the other
            for j in (0, 1):
                r_j, n_j = score(slice(j, j + 1), AXIS_MOTION)
                if n_j >= MIN_WINDOWS and r_j > rel:
                    rel = r_j
        out[name] = {
            "rel": rel,
            "windows": moved,
            "D_N_per_mps": (mass * D[sl]).tolist(),
            "v_rms": [_rms(v[:, j]) for j in range(3)][sl],
        }
    return out


def judge(
    flight: FlightLog,
    thrust_N: np.ndarray,
    mass: float,
    *,
    thrust_column: str = "thrust",
    undetermined: list[str] | None = None,
    kinematics: Evidence | None = None,
) -> Verdict:
    """Run the tests (module docstring) on the resampled flight with its thrust in newtons.

    Parameters
    ----------
    flight : FlightLog
        The resampled log (world NED, body FRD, SI).
    thrust_N : numpy.ndarray
        ``(N,)`` collective thrust on the flight's grid, N.
    mass : float
        Nominal mass, kg.
    thrust_column : str
        What the thrust came from, named in a refusal.
    undetermined : list of str, optional
        Conventions the convention check could not decide (the verdict is then at best ``"undecided"``).
    kinematics : Evidence, optional
        The convention check's evidence for the reading used (its kinematic score is reused); computed from
        ``flight.raw`` when not given.

    Returns
    -------
    Verdict
    """
    from ..errors import as_finite, instance, scalar

    instance("flight", flight, FlightLog)
    thrust_N = as_finite("thrust_N", thrust_N)
    if thrust_N.shape != flight.t.shape:
        raise InputError(f"thrust_N must have the flight's shape {flight.t.shape}, got {thrust_N.shape}")
    mass = scalar("mass", mass, lo=0.0, lo_open=True)
    segs = _segments(flight, int(2 * BAND_S[1] * flight.rate_hz))
    tests: list[PhysicsTest] = []
    reasons: list[str] = []
    if not segs:
        return Verdict("undecided", [], ["no stretch of the log is long enough for the physics tests"])
    tests.append(_kinematics(kinematics if kinematics is not None else evidence(flight.raw)))
    fb = force_balance(flight, thrust_N, mass, segs)
    for name in ("horizontal", "vertical"):
        r = fb[name]
        cols = "the velocity (vx, vy, vz) or the attitude" if name == "horizontal" else f"the {thrust_column} or vz"
        if r is None or r["windows"] < MIN_WINDOWS:
            n = 0 if r is None else r["windows"]
            tests.append(PhysicsTest(f"{name} force balance", float("nan"), DYN_LIMIT, "left out", cols,
                                     f"{n} window(s) of {WINDOW_S:g} s with motion, {MIN_WINDOWS} needed to tell a "
                                     "push from a wrong column"))  # fmt: skip
            continue
        detail = (
            f"the {name} acceleration the velocity shows and the one thrust and attitude predict differ by "
            f"{r['rel']:.2f} of their size after a fitted drag (limit {DYN_LIMIT:g}; {QUANTILE:g}th percentile of "
            f"{r['windows']} windows of {WINDOW_S:g} s)"
        )
        status = "fail" if r["rel"] > DYN_LIMIT else "pass"
        tests.append(PhysicsTest(f"{name} force balance", r["rel"], DYN_LIMIT, status, cols, detail))
        push = max((Dj * vj / (mass * G) for Dj, vj in zip(r["D_N_per_mps"], r["v_rms"], strict=True)), default=0.0)
        if name == "horizontal":
            tests.append(PhysicsTest("drag sign", push, DRAG_LIMIT, "fail" if push > DRAG_LIMIT else "pass",
                              "the velocity (vx, vy, vz)",
                              f"the force the velocity implies pushes along it ({100 * push:.1f} % of the weight, "
                              "drag opposes it)"))  # fmt: skip
    sq = None if flight.rotor_speed is None else np.sum(flight.rotor_speed**2, -1)
    if sq is not None and flight.thrust is not None:
        tests.append(_rotors(flight, sq, segs))
    failed = [t for t in tests if t.status == "fail"]
    if failed:
        return Verdict("refused", tests, [t.detail for t in failed])
    if undetermined:
        reasons.append(
            "the data cannot decide " + ", ".join(undetermined) + " (several readings fit equally; they are consistent)"
        )
    reasons += [f"{t.name} left out: {t.detail}" for t in tests if t.status == "left out"]
    return Verdict("undecided" if reasons else "accepted", tests, reasons)


def _rotors(flight: FlightLog, sq: np.ndarray, segs: list[slice]) -> PhysicsTest:
    """The logged thrust command (any unit) against the rotors' sum of squared speeds on the force
    balance's band (a hover thrust that drifts with the battery lies below it): the relative residual of
    the least-squares scale, ``sqrt(1 - c^2)`` for their correlation ``c``; a negative scale fails."""
    n1 = max(1, int(round(BAND_S[0] * flight.rate_hz)))
    n2 = max(3, int(round(BAND_S[1] * flight.rate_hz)))
    xs, ys = [], []
    for s in segs:
        x = _moving_average(sq[s], n1)
        y = _moving_average(flight.thrust[s], n1)
        air = (x > 0.3 * np.percentile(x, 95)) & (np.arange(len(x)) >= n2 // 2) & (np.arange(len(x)) < len(x) - n2 // 2)
        xs.append((x - _moving_average(x, n2))[air])
        ys.append((y - _moving_average(y, n2))[air])
    x, y = np.concatenate(xs), np.concatenate(ys)
    k = float(x @ y / max(x @ x, 1e-300))
    score = float(np.sqrt(np.mean((y - k * x) ** 2)) / max(np.sqrt(np.mean(y**2)), 1e-300)) if k > 0 else float("inf")
    return PhysicsTest("thrust against rotor speeds", score, ROTOR_LIMIT, "fail" if score > ROTOR_LIMIT else "pass",
                "the thrust column or the rotor-speed columns",
                f"the thrust's variation and the rotors' squared speeds differ by {score:.2f} of the thrust's "
                f"variation (limit {ROTOR_LIMIT:g})")  # fmt: skip


__all__ = ["LogRefused", "PhysicsTest", "Verdict", "force_balance", "judge"]
