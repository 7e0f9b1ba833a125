"""What kind of vehicle flew a log, from what the log says of itself, and whether the estimator's model
applies to it.

The estimator is eq. (5) of the paper: a multirotor whose only propulsive force is the thrust along
``-z_B`` that the throttle (or the rotors) sets. On a fixed wing, a helicopter (collective pitch), a
rover, a boat or a submarine that force is something else, and whatever the model misses (lift,
buoyancy, the ground pushing a rover) would be reported as "external force": such logs are refused.
A VTOL hybrid is a multirotor while it hovers; in forward flight the wing's lift and the pusher's thrust
show as external force, which a warning says.

Where the type comes from: MAVLink's ``HEARTBEAT.type`` (a ``.tlog``), PX4's ``MAV_TYPE`` parameter (a
``.ulg``), ArduPilot's firmware name (``ArduCopter``, ``ArduPlane``, ``ArduSub``, ``Rover``, ``Blimp``) with
its ``FRAME_CLASS`` (helicopters) and ``Q_ENABLE`` (a QuadPlane) parameters. A log that says nothing is
taken as a multirotor, with a note. ``airframe="multirotor"`` (``--airframe multirotor``) overrides a log
that is wrong about itself.
"""

from __future__ import annotations

import math
from typing import Any

from ..errors import InputError

#: MAVLink's MAV_TYPE values (common.xml) of multirotors: thrust along the body's -z from the throttle.
MULTIROTOR_TYPES = {2: "quadrotor", 3: "coaxial", 13: "hexarotor", 14: "octorotor", 15: "tricopter",
                    29: "dodecarotor", 35: "decarotor", 43: "multirotor"}  # fmt: skip
#: MAV_TYPE values of VTOL hybrids (rotors to hover, a wing to cruise; 22 is PX4's standard VTOL).
VTOL_TYPES = {19: "VTOL tailsitter (two rotors)", 20: "VTOL tailsitter (four rotors)", 21: "VTOL tiltrotor",
              22: "VTOL (fixed rotors and a pusher)", 23: "VTOL tailsitter", 24: "VTOL tiltwing",
              25: "VTOL", 47: "VTOL gyrodyne"}  # fmt: skip
#: MAV_TYPE values of vehicles that are neither.
OTHER_TYPES = {1: "fixed wing", 4: "helicopter", 7: "airship", 8: "free balloon", 9: "rocket", 10: "ground rover",
               11: "surface boat", 12: "submarine", 16: "flapping wing", 17: "kite", 28: "parafoil",
               46: "ground quadruped"}  # fmt: skip
#: ArduCopter's FRAME_CLASS values of helicopters (collective pitch: the throttle does not set the thrust).
HELI_FRAME_CLASSES = {6: "helicopter", 11: "dual helicopter", 13: "heli-quad (collective pitch)"}
#: What ``airframe=`` accepts.
AIRFRAMES = ("auto", "multirotor")


def _from_mav_type(code: int, where: str) -> tuple[str, str] | None:
    for kind, table in (("multirotor", MULTIROTOR_TYPES), ("vtol", VTOL_TYPES), ("other", OTHER_TYPES)):
        if code in table:
            return kind, f"a {table[code]} (MAV_TYPE {code}, {where})"
    return None  # a type that names no vehicle (a GCS, a gimbal, generic): no verdict


def _param(params: dict[str, float], name: str) -> int | None:
    value = params.get(name)
    return int(round(value)) if value is not None and math.isfinite(value) else None  # a damaged one says nothing


def classify(meta: dict[str, Any], params: dict[str, float]) -> tuple[str, str] | None:
    """``(kind, description)`` with kind ``"multirotor"``, ``"vtol"`` or ``"other"``, or ``None`` when the
    log does not say."""
    firmware = str(meta.get("firmware", ""))
    q_enable = _param(params, "Q_ENABLE")
    if "ArduSub" in firmware:
        return "other", f"a submarine ({firmware})"
    if "Rover" in firmware:
        return "other", f"a ground rover or boat ({firmware})"
    if "Blimp" in firmware:
        return "other", f"a blimp ({firmware})"
    if "Plane" in firmware:
        if q_enable:
            return "vtol", f"a QuadPlane ({firmware}, Q_ENABLE {q_enable})"
        return "other", f"a fixed wing ({firmware}, Q_ENABLE {q_enable or 0})"
    frame_class = _param(params, "FRAME_CLASS")
    if "Copter" in firmware:
        if frame_class in HELI_FRAME_CLASSES:
            return "other", f"a {HELI_FRAME_CLASSES[frame_class]} ({firmware}, FRAME_CLASS {frame_class})"
        return "multirotor", f"a multirotor ({firmware})"
    if meta.get("mav_type") is not None:
        mav_type = int(meta["mav_type"])
        found = _from_mav_type(mav_type, "the autopilot's HEARTBEAT")
        if mav_type == 1 and q_enable:  # ArduPilot's QuadPlane calls itself a fixed wing
            return "vtol", f"a QuadPlane (HEARTBEAT type 1 with Q_ENABLE {q_enable})"
        if found is not None and frame_class in HELI_FRAME_CLASSES and found[0] == "multirotor":
            return "other", f"a {HELI_FRAME_CLASSES[frame_class]} (FRAME_CLASS {frame_class})"
        if found is not None:
            return found
    if "MAV_TYPE" in params:
        return _from_mav_type(_param(params, "MAV_TYPE") or 0, "the MAV_TYPE parameter")
    return None


def airframe_option(airframe: object) -> str:
    """``airframe`` if it is one of :data:`AIRFRAMES`, else an :class:`InputError` naming it."""
    if not isinstance(airframe, str) or airframe not in AIRFRAMES:
        raise InputError(f"airframe must be one of {', '.join(AIRFRAMES)}, got {airframe!r}")
    return airframe


def check_airframe(meta: dict[str, Any], params: dict[str, float], airframe: str = "auto") -> tuple[str, str | None]:
    """``(what to record, warning or None)``; raises :class:`InputError` for a vehicle that is not a
    multirotor (module docstring) unless ``airframe="multirotor"``."""
    airframe_option(airframe)
    found = classify(meta, params)
    if airframe == "multirotor":
        said = f"; the log says {found[1]}" if found is not None and found[0] != "multirotor" else ""
        return f"vehicle: taken as a multirotor (--airframe multirotor{said})", None
    if found is None:
        return "vehicle: the log does not say what it is; taken as a multirotor", None
    kind, what = found
    if kind == "other":
        raise InputError(
            f"the log is of {what}: the estimator models a multirotor, whose only propulsive force is the "
            "thrust along the body's -z that the throttle sets (eq. (5)); here lift, buoyancy or contact would "
            "show as external force. If the log is wrong about its vehicle, give --airframe multirotor"
        )
    if kind == "vtol":
        return f"vehicle: {what}", (
            f"the log is of {what}: the estimate holds while it hovers as a multirotor; in forward flight "
            "the wing's lift and the pusher's thrust are not in the model and show as external force "
            "(choose hover phases with --start/--end)"
        )
    return f"vehicle: {what}", None


__all__ = ["AIRFRAMES", "airframe_option", "check_airframe", "classify"]
