"""A minimal ULog writer for tests, written from the file-format description in PX4's documentation
(header, flag bits, format, info, parameter, subscription and data messages). It is independent of
pyulog, which reads what it writes."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

_TYPES = {"uint64_t": "Q", "float": "f", "double": "d", "bool": "?", "uint8_t": "B", "int32_t": "i"}


def _msg(kind: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), kind[0]) + payload


def write_ulog(
    path: Path,
    topics: dict[str, dict[str, np.ndarray]],
    params: dict[str, float] | None = None,
    sys_version: str = "v1.14.0",
    truncate_at: int | None = None,
    release: int | None = None,
    git_hash: str | None = None,
) -> Path:
    """``topics[name] = {"timestamp": uint64 microseconds, field: values}``; a field whose values are 2-D
    (N, k) becomes an array field ``float field[k]``. All other fields are float32."""
    out = bytearray(b"ULog\x01\x12\x35" + bytes([1]) + struct.pack("<Q", 0))
    out += _msg(b"B", bytes(8) + bytes(8) + struct.pack("<3Q", 0, 0, 0))
    layouts = {}
    for name, fields in topics.items():
        parts, fmt = ["uint64_t timestamp"], "<Q"
        order = []
        for f, v in fields.items():
            if f == "timestamp":
                continue
            v = np.asarray(v)
            if v.ndim == 2:
                parts.append(f"float[{v.shape[1]}] {f}")
                fmt += "f" * v.shape[1]
            else:
                parts.append(f"float {f}")
                fmt += "f"
            order.append(f)
        out += _msg(b"F", f"{name}:{';'.join(parts)};".encode())
        layouts[name] = (fmt, order)
    key = b"char[%d] ver_sw_release_str" % len(sys_version)
    out += _msg(b"I", bytes([len(key)]) + key + sys_version.encode())
    if release is not None:  # PX4's encoded version: major, minor, patch, type (0 dev, 255 release)
        key = b"uint32_t ver_sw_release"
        out += _msg(b"I", bytes([len(key)]) + key + struct.pack("<I", release))
    if git_hash is not None:
        key = b"char[%d] ver_sw" % len(git_hash)
        out += _msg(b"I", bytes([len(key)]) + key + git_hash.encode())
    for k, v in (params or {}).items():
        pk = f"float {k}".encode()
        out += _msg(b"P", bytes([len(pk)]) + pk + struct.pack("<f", v))
    for i, name in enumerate(topics):
        out += _msg(b"A", struct.pack("<BH", 0, i) + name.encode())
    rows = []
    for i, (name, fields) in enumerate(topics.items()):
        fmt, order = layouts[name]
        ts = np.asarray(fields["timestamp"], dtype=np.uint64)
        for k in range(len(ts)):
            vals = [int(ts[k])]
            for f in order:
                v = np.asarray(fields[f])
                vals += list(map(float, v[k])) if v.ndim == 2 else [float(v[k])]
            rows.append((int(ts[k]), i, struct.pack(fmt, *vals)))
    rows.sort(key=lambda r: (r[0], r[1]))
    for _, i, data in rows:
        out += _msg(b"D", struct.pack("<H", i) + data)
    if truncate_at is not None:
        out = out[:truncate_at]
    path.write_bytes(bytes(out))
    return path
