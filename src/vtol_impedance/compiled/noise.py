"""Sensor noise for the compiled engines: the numbers of NumPy's default generator, drawn from arrays of
generator states so that a block of vehicles draws in SIMD lanes.

Each vehicle's noise is NumPy's ``default_rng(SeedSequence([seed, 0])).standard_normal()``
(:class:`vtol_impedance.sim.sensors.NoiseSource`, what the NumPy backend draws). Here the same stream is
computed bit for bit from a ``(4, B)`` array of PCG64 states (rows: state high and low word, increment high
and low word): :func:`generator_states` seeds it (NumPy's ``SeedSequence`` hash, then PCG64's seeding),
:func:`standard_normal` draws one vehicle's next normal (PCG64's 128-bit LCG step and XSL-RR output, then the
256-layer ziggurat with NumPy's tables, which numba ships for its own ``Generator``), :func:`normals_lanes`
draws a row per block lane with the common case vectorised and the rare rejection finished lane by lane.
Why not numba's ``Generator``: a typed list of 4,000 generators took 0.1 s to build, and each draw is an
indirect call into NumPy (about 13 ns on the project's machine, against about 3 ns here in lanes).
``tests/test_noise.py`` compares states and draws with NumPy's own.
"""

from __future__ import annotations

import numba
import numpy as np

from .jit import kernel
from .lanes import W

try:  # numba's copy of NumPy's ziggurat tables (what its own Generator.standard_normal reads)
    from numba.np.random._constants import fi_double, ki_double, wi_double, ziggurat_nor_inv_r, ziggurat_nor_r
except ImportError as exc:  # pragma: no cover - a numba that moved them
    raise ImportError(
        f"vtol_impedance.compiled.noise reads NumPy's ziggurat tables from numba.np.random._constants, which "
        f"numba {numba.__version__} does not have ({exc}); install a numba between 0.60 and 0.68, where they are"
    ) from exc

# the ziggurat's layers (NumPy's tables as numba carries them; the acceptance bounds as int64: they are < 2**52)
_WI = np.ascontiguousarray(wi_double, dtype=np.float64)
_KI = np.ascontiguousarray(ki_double, dtype=np.int64)
_FI = np.ascontiguousarray(fi_double, dtype=np.float64)
_R = float(ziggurat_nor_r)
_INV_R = float(ziggurat_nor_inv_r)

# PCG64's 128-bit multiplier (high and low word; O'Neill's PCG default for 128-bit state, as NumPy's PCG64
# uses it); every operand below is uint64 (numba turns uint64 mixed with int64 into float64)
_M_HI = np.uint64(0x2360ED051FC65DA4)
_M_LO = np.uint64(0x4385DF649FCCF645)
_LO32 = np.uint64(0xFFFFFFFF)
_M52 = np.uint64(0x000FFFFFFFFFFFFF)
_U0, _U1, _U8, _U11 = np.uint64(0), np.uint64(1), np.uint64(8), np.uint64(11)
_U16, _U32, _U58, _U63, _UFF = np.uint64(16), np.uint64(32), np.uint64(58), np.uint64(63), np.uint64(0xFF)
_TO_UNIT = 1.0 / 9007199254740992.0  # 2**-53: NumPy's next_double

# SeedSequence's hash constants (NumPy's SeedSequence, after O'Neill's seed_seq_fe; a pool of four 32-bit words)
_INIT_A, _MULT_A = np.uint64(0x43B0D7E5), np.uint64(0x931E8875)
_INIT_B, _MULT_B = np.uint64(0x8B51F9DD), np.uint64(0x58F38DED)
_MIX_L, _MIX_R = np.uint64(0xCA01F9DD), np.uint64(0x4973F715)


@kernel(inline="always")
def _mulhi(a, b):
    """The high word of the 128-bit product of two uint64, from 32-bit halves (no term overflows)."""
    a0, a1, b0, b1 = a & _LO32, a >> _U32, b & _LO32, b >> _U32
    p10 = a1 * b0
    mid = ((a0 * b0) >> _U32) + (p10 & _LO32) + a0 * b1
    return a1 * b1 + (p10 >> _U32) + (mid >> _U32)


@kernel(inline="always")
def _step(hi, lo, inc_hi, inc_lo):
    """PCG64's step ``state * M + inc`` modulo 2**128, as high and low words."""
    t = lo * _M_LO
    new_lo = t + inc_lo
    carry = _U1 if new_lo < t else _U0
    return _mulhi(lo, _M_LO) + lo * _M_HI + hi * _M_LO + inc_hi + carry, new_lo


@kernel(inline="always")
def _next(rng, b):
    """Column ``b``'s next 64-bit word (XSL-RR output of the stepped state); advances the column."""
    hi, lo = _step(rng[0, b], rng[1, b], rng[2, b], rng[3, b])
    rng[0, b], rng[1, b] = hi, lo
    x = hi ^ lo
    r = hi >> _U58
    return (x >> r) | (x << ((_U0 - r) & _U63))


@kernel(inline="always")
def _layer(r):
    """The ziggurat's quick test of one word: (candidate x, accepted, layer, |x| as an integer)."""
    idx = np.int64(r & _UFF)
    r = r >> _U8
    rabs = np.int64((r >> _U1) & _M52)
    x = rabs * _WI[idx]
    if r & _U1:
        x = -x
    return x, rabs < _KI[idx], idx, rabs


@kernel()
def _finish(rng, b, x, idx, rabs):
    """The rest of a draw whose word failed the quick test (about one in a hundred): the tail beyond the
    last layer, or the wedge test. ``(accepted, value)``; not accepted: the draw starts again."""
    if idx == 0:  # the tail
        while True:
            xx = -_INV_R * np.log1p(-(np.float64(_next(rng, b) >> _U11) * _TO_UNIT))
            yy = -np.log1p(-(np.float64(_next(rng, b) >> _U11) * _TO_UNIT))
            if yy + yy > xx * xx:
                return True, -(_R + xx) if (rabs >> 8) & 1 else _R + xx
    u = np.float64(_next(rng, b) >> _U11) * _TO_UNIT
    return (_FI[idx - 1] - _FI[idx]) * u + _FI[idx] < np.exp(-0.5 * x * x), x


@kernel()
def standard_normal(rng, b):
    """Column ``b``'s next standard normal (NumPy's ``Generator.standard_normal``); advances the column."""
    while True:
        x, ok, idx, rabs = _layer(_next(rng, b))
        if ok:
            return x
        ok, x = _finish(rng, b, x, idx, rabs)
        if ok:
            return x


@kernel()
def normals_lanes(st, out, row0, m):
    """``m`` normals per lane of the block states ``st (4, W)``, into ``out[(row0 + j) * W + i]`` (lane ``i``,
    draw ``j``, the lanes' row layout of :mod:`.lanes`): each lane's stream in order, as :func:`standard_normal`
    would draw it (:func:`draw_lanes` with scratch of its own)."""
    draw_lanes(st, out, row0, m, new_draw_scratch())


@kernel()
def new_draw_scratch():
    """The scratch :func:`draw_lanes` keeps each lane's last word and whether it was accepted at once in
    (``(2, W)`` uint64): a caller drawing every tick allocates it once."""
    return np.empty((2, W), dtype=np.uint64)


@kernel()
def draw_lanes(st, out, row0, m, scratch):
    """:func:`normals_lanes` with the ``scratch`` of :func:`new_draw_scratch` (an allocation a tick less: 12 %
    of the draws' time, twentieth stop)."""
    for j in range(m):
        k = (row0 + j) * W
        for i in range(W):  # vectorised: the accepted word (the common case)
            r = _next(st, i)
            x, ok, _, _ = _layer(r)
            out[k + i] = x
            scratch[0, i] = r
            scratch[1, i] = _U1 if ok else _U0
        for i in range(W):  # lane by lane: a word that failed the quick test
            if scratch[1, i] == _U0:
                x, _, idx, rabs = _layer(scratch[0, i])
                ok, x = _finish(st, i, x, idx, rabs)
                out[k + i] = x if ok else standard_normal(st, i)


@kernel(inline="always")
def _hashmix(v, hc):
    """SeedSequence's hashmix of the 32-bit word ``v`` with the running constant ``hc``: (word, constant)."""
    v = v ^ hc
    hc = (hc * _MULT_A) & _LO32
    v = (v * hc) & _LO32
    return v ^ (v >> _U16), hc


@kernel(inline="always")
def _mix(x, y):
    r = (_MIX_L * x - _MIX_R * y) & _LO32
    return r ^ (r >> _U16)


@kernel()
def _seed_columns(seeds, rng):
    """Column ``b`` of ``rng (4, B)``: PCG64 seeded by ``SeedSequence([seeds[b], 0])`` (the entropy words: the
    seed's 32-bit words, low first, then 0; a pool of four; ``generate_state(4, uint64)``)."""
    words = np.zeros(3, dtype=np.uint64)
    pool = np.empty(4, dtype=np.uint64)
    val = np.empty(4, dtype=np.uint64)
    w = np.empty(2, dtype=np.uint64)
    for b in range(seeds.shape[0]):
        s = seeds[b]
        n = 1
        words[0] = s & _LO32
        if s >> _U32:
            words[1] = s >> _U32
            n = 2
        words[n] = _U0
        n += 1
        hc = _INIT_A
        for i in range(4):
            pool[i], hc = _hashmix(words[i] if i < n else _U0, hc)
        for i_src in range(4):
            for i_dst in range(4):
                if i_src != i_dst:
                    h, hc = _hashmix(pool[i_src], hc)
                    pool[i_dst] = _mix(pool[i_dst], h)
        hc = _INIT_B
        for i in range(4):  # eight 32-bit words, paired low word first
            for h in range(2):
                v = pool[(2 * i + h) % 4] ^ hc
                hc = (hc * _MULT_B) & _LO32
                v = (v * hc) & _LO32
                w[h] = v ^ (v >> _U16)
            val[i] = w[0] | (w[1] << _U32)
        # PCG64's seeding: inc = (seq << 1) | 1; state = step(step(0) + initstate)
        inc_hi = (val[2] << _U1) | (val[3] >> _U63)
        inc_lo = (val[3] << _U1) | _U1
        hi, lo = _step(_U0, _U0, inc_hi, inc_lo)
        lo2 = lo + val[1]
        hi = hi + val[0] + (_U1 if lo2 < lo else _U0)
        hi, lo = _step(hi, lo2, inc_hi, inc_lo)
        rng[0, b], rng[1, b], rng[2, b], rng[3, b] = hi, lo, inc_hi, inc_lo


def generator_states(seeds: list[int]) -> np.ndarray:
    """The ``(4, B)`` PCG64 states of the vehicles' noise streams (``NoiseSource(seeds)``'s generators, as
    numbers). Seeds of 2**64 and more (Python integers) are seeded through NumPy itself."""
    rng = np.empty((4, len(seeds)), dtype=np.uint64)
    small = [i for i, s in enumerate(seeds) if 0 <= s < 2**64]
    if len(small) == len(seeds):
        _seed_columns(np.array(seeds, dtype=np.uint64), rng)
    elif small:
        sub = np.empty((4, len(small)), dtype=np.uint64)
        _seed_columns(np.array([seeds[i] for i in small], dtype=np.uint64), sub)
        rng[:, small] = sub
    for i, s in enumerate(seeds):
        if not 0 <= s < 2**64:
            st = np.random.PCG64(np.random.SeedSequence([int(s), 0])).state["state"]
            rng[:, i] = [st["state"] >> 64, st["state"] & (2**64 - 1), st["inc"] >> 64, st["inc"] & (2**64 - 1)]
    return rng
