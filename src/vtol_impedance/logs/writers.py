"""Writers of flight logs in the formats the readers take: PX4 ULog, ArduPilot DataFlash, MAVLink tlog and
CSV. They write the sample logs that ship with the package and the test suite's logs with a known
wrench; the readers are independent of them (``pyulog`` and ``pymavlink`` parse what they write).

* ULog, from the file-format description in PX4's documentation: header, flag bits, formats (nested
  types such as ``esc_report[8]`` included), info, parameters, subscriptions, then data messages in time
  order.
* DataFlash, from ArduPilot's format: every message is ``0xA3 0x95 type`` and its fields packed little
  endian; ``FMT`` messages (type 128: type, length, name, format, columns) define the others. Format
  characters scale as ArduPilot's do (``c``: int16 x 100, ``e``: int32 x 100, ...); values are given in
  physical units and scaled here.
* tlog: each MAVLink packet (packed by ``pymavlink``'s MAVLink 2 ardupilotmega dialect) preceded by its
  receive time as 8-byte big-endian microseconds.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..io import write_text, write_with

# ----------------------------------------------------------------------------------------------------- ULog

_ULOG_TYPES = {
    "uint64_t": "Q", "int64_t": "q", "float": "f", "double": "d", "bool": "?", "uint8_t": "B", "int8_t": "b",
    "uint16_t": "H", "int16_t": "h", "uint32_t": "I", "int32_t": "i",
}  # fmt: skip


@dataclass
class Nested:
    """An array field of nested structures: ``count`` elements of type ``type_name`` with ``fields[name] =
    (c_type, values (N, count))``."""

    type_name: str
    count: int
    fields: dict[str, tuple[str, np.ndarray]]


def _ulog_msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def ulog_bytes(
    topics: dict[str, dict[str, Any]],
    params: dict[str, float] | None = None,
    sys_version: str = "v1.14.0",
) -> bytes:
    """A ULog file's bytes. ``topics[name] = {"timestamp": uint64 microseconds, field: values}``: 1-D values
    become ``float`` fields, ``(N, k)`` values ``float[k]``, a ``(c_type, values)`` pair a field of that C
    type, a :class:`Nested` an array of nested structures. Parameters are floats."""
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))
    out += _ulog_msg(b"B", bytes(8) + bytes(8) + struct.pack("<3Q", 0, 0, 0))
    layouts: dict[str, tuple[str, list[Any]]] = {}
    nested_done: set[str] = set()
    for name, fields in topics.items():
        parts, fmt, order = ["uint64_t timestamp"], "<Q", []
        for f, v in fields.items():
            if f == "timestamp":
                continue
            if isinstance(v, Nested):
                if v.type_name not in nested_done:
                    sub = ";".join(f"{ct} {sf}" for sf, (ct, _) in v.fields.items())
                    out += _ulog_msg(b"F", f"{v.type_name}:{sub};".encode())
                    nested_done.add(v.type_name)
                parts.append(f"{v.type_name}[{v.count}] {f}")
                fmt += "".join(_ULOG_TYPES[ct] for ct, _ in v.fields.values()) * v.count
                order.append(v)
                continue
            ctype = "float"
            if isinstance(v, tuple):
                ctype, v = v
            v = np.asarray(v)
            if v.ndim == 2:
                parts.append(f"{ctype}[{v.shape[1]}] {f}")
                fmt += _ULOG_TYPES[ctype] * v.shape[1]
            else:
                parts.append(f"{ctype} {f}")
                fmt += _ULOG_TYPES[ctype]
            order.append((ctype, v))
        out += _ulog_msg(b"F", f"{name}:{';'.join(parts)};".encode())
        layouts[name] = (fmt, order)
    key = b"char[%d] ver_sw_release_str" % len(sys_version)
    out += _ulog_msg(b"I", bytes([len(key)]) + key + sys_version.encode())
    for k, v in (params or {}).items():
        pk = f"float {k}".encode()
        out += _ulog_msg(b"P", bytes([len(pk)]) + pk + struct.pack("<f", v))
    for i, name in enumerate(topics):
        out += _ulog_msg(b"A", struct.pack("<BH", 0, i) + name.encode())
    rows = []
    for i, (name, fields) in enumerate(topics.items()):
        fmt, order = layouts[name]
        packer = struct.Struct(fmt)
        ts = np.asarray(fields["timestamp"], dtype=np.uint64)
        for k in range(len(ts)):
            vals: list[Any] = [int(ts[k])]
            for item in order:
                if isinstance(item, Nested):
                    for e in range(item.count):
                        for ct, arr in item.fields.values():
                            x = arr[k, e]
                            vals.append(float(x) if ct in ("float", "double") else int(x))
                    continue
                ct, v = item
                cast = float if ct in ("float", "double") else (bool if ct == "bool" else int)
                vals += [cast(x) for x in v[k]] if v.ndim == 2 else [cast(v[k])]
            rows.append((int(ts[k]), i, packer.pack(*vals)))
    rows.sort(key=lambda r: (r[0], r[1]))
    for _, i, data in rows:
        out += _ulog_msg(b"D", struct.pack("<H", i) + data)
    return bytes(out)


def write_ulog(path: Path, topics: dict[str, dict[str, Any]], params: dict[str, float] | None = None,
               sys_version: str = "v1.14.0") -> Path:  # fmt: skip
    """:func:`ulog_bytes` written atomically to ``path``."""
    data = ulog_bytes(topics, params, sys_version)
    return write_with(Path(path), lambda fh: fh.write(data))


# ------------------------------------------------------------------------------------------------ DataFlash

#: DataFlash format character -> (struct code, multiplier from the stored integer to the physical value).
DF_FORMATS = {
    "a": ("64s", None), "b": ("b", None), "B": ("B", None), "h": ("h", None), "H": ("H", None),
    "i": ("i", None), "I": ("I", None), "f": ("f", None), "d": ("d", None), "n": ("4s", None),
    "N": ("16s", None), "Z": ("64s", None), "c": ("h", 0.01), "C": ("H", 0.01), "e": ("i", 0.01),
    "E": ("I", 0.01), "L": ("i", 1e-7), "M": ("B", None), "q": ("q", None), "Q": ("Q", None),
}  # fmt: skip
DF_HEAD = b"\xa3\x95"
DF_FMT_TYPE = 128


@dataclass
class DFMessage:
    """One DataFlash message type: its ``FMT`` definition and its rows (``columns[name] = values``,
    physical units; strings for ``n``/``N``/``Z`` fields)."""

    name: str
    fmt: str
    columns: dict[str, Any]


def _df_pack(fmt: str, values: list[Any]) -> bytes:
    codes, vals = "<", []
    for ch, v in zip(fmt, values, strict=True):
        code, mul = DF_FORMATS[ch]
        codes += code
        if code.endswith("s"):
            vals.append(v.encode() if isinstance(v, str) else bytes(v))
        elif mul is not None:
            vals.append(int(round(float(v) / mul)))
        elif code in "fd":
            vals.append(float(v))
        else:
            vals.append(int(v))
    return struct.pack(codes, *vals)


def dataflash_bytes(messages: list[DFMessage]) -> bytes:
    """A DataFlash log: ``FMT`` for every message type, then all rows in time order (``TimeUS``)."""
    fmt_fmt = "BBnNZ"
    out = bytearray()
    fmt_len = 3 + struct.calcsize("<" + "".join(DF_FORMATS[c][0] for c in fmt_fmt))
    out += (
        DF_HEAD
        + bytes([DF_FMT_TYPE])
        + _df_pack(fmt_fmt, [DF_FMT_TYPE, fmt_len, "FMT", fmt_fmt, "Type,Length,Name,Format,Columns"])
    )
    rows = []
    for type_id, msg in enumerate(messages, start=64):
        length = 3 + struct.calcsize("<" + "".join(DF_FORMATS[c][0] for c in msg.fmt))
        out += DF_HEAD + bytes([DF_FMT_TYPE]) + _df_pack(fmt_fmt, [type_id, length, msg.name, msg.fmt,
                                                                   ",".join(msg.columns)])  # fmt: skip
        cols = list(msg.columns.values())
        n = len(cols[0])
        for k in range(n):
            body = DF_HEAD + bytes([type_id]) + _df_pack(msg.fmt, [c[k] for c in cols])
            rows.append((int(msg.columns["TimeUS"][k]) if "TimeUS" in msg.columns else 0, type_id, body))
    rows.sort(key=lambda r: (r[0], r[1]))
    for _, _, body in rows:
        out += body
    return bytes(out)


def write_dataflash(path: Path, messages: list[DFMessage]) -> Path:
    data = dataflash_bytes(messages)
    return write_with(Path(path), lambda fh: fh.write(data))


# ----------------------------------------------------------------------------------------------------- tlog


def tlog_bytes(
    messages: list[tuple[float, str, dict[str, Any]]], system: int = 1, component: int = 1, protocol: int = 2
) -> bytes:
    """A tlog: ``messages = [(receive time in s, MAVLink message name, fields)]`` packed as MAVLink 2 (or 1,
    ``protocol``; ardupilotmega dialect) in time order, each after its receive time in big-endian
    microseconds. A message may carry a fourth element ``(system, component)``: its sender (default
    ``system``, ``component``), for a tlog of several vehicles."""
    if protocol == 1:
        from pymavlink.dialects.v10 import ardupilotmega as dialect
    else:
        from pymavlink.dialects.v20 import ardupilotmega as dialect

    senders: dict[tuple[int, int], Any] = {}
    out = bytearray()
    for t, name, fields, *src in sorted(messages, key=lambda m: m[0]):
        key = tuple(src[0]) if src else (system, component)
        if key not in senders:  # one sender per source: each keeps its own sequence numbers
            senders[key] = dialect.MAVLink(None, srcSystem=key[0], srcComponent=key[1])
        cls = getattr(dialect, f"MAVLink_{name.lower()}_message")
        out += struct.pack(">Q", int(round(t * 1e6))) + cls(**fields).pack(senders[key])
    return bytes(out)


def write_tlog(path: Path, messages: list[tuple[float, str, dict[str, Any]]], protocol: int = 2) -> Path:
    data = tlog_bytes(messages, protocol=protocol)
    return write_with(Path(path), lambda fh: fh.write(data))


# ------------------------------------------------------------------------------------------------------ CSV


def csv_text(columns: dict[str, np.ndarray], formats: dict[str, str] | None = None, default: str = "%.9g") -> str:
    """CSV text with a header; ``formats[name]`` per column (``%.17g`` writes a float exactly); NaN as an
    empty field (a signal not logged in that row)."""
    names = list(columns)
    fmts = [(formats or {}).get(n, default) for n in names]
    cols = [np.asarray(columns[n]) for n in names]
    lines = [",".join(names)]
    for k in range(len(cols[0])):
        lines.append(",".join("" if (isinstance(c[k], float | np.floating) and np.isnan(c[k])) else f % c[k]
                              for f, c in zip(fmts, cols, strict=True)))  # fmt: skip
    return "\n".join(lines) + "\n"


def write_csv(path: Path, columns: dict[str, np.ndarray], formats: dict[str, str] | None = None,
              default: str = "%.9g") -> Path:  # fmt: skip
    return write_text(Path(path), csv_text(columns, formats, default))


__all__ = [
    "DFMessage",
    "Nested",
    "csv_text",
    "dataflash_bytes",
    "tlog_bytes",
    "ulog_bytes",
    "write_csv",
    "write_dataflash",
    "write_tlog",
    "write_ulog",
]
