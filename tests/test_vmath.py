"""The compiled kernels' own sine, cosine, arc tangent and arc sine (``compiled.vmath``): within three units in
the last place of the C library's over a million arguments each, with its signs at zeros and NaN kept, and
compiled to packed vector instructions when a loop runs over lanes (which the C library's calls are not)."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from numba import njit

from vtol_impedance.compiled import vmath
from vtol_impedance.compiled.jit import FLAGS, kernel


@kernel()
def _sincos(x, s, c):
    for i in range(x.shape[0]):
        s[i], c[i] = vmath.sincos(x[i])


@kernel()
def _atan2(y, x, out):
    for i in range(x.shape[0]):
        out[i] = vmath.atan2(y[i], x[i])


@kernel()
def _asin(x, out):
    for i in range(x.shape[0]):
        out[i] = vmath.asin(x[i])


def _ulps(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.abs(got - want) / np.spacing(np.maximum(np.abs(want), 1e-300))))


@pytest.mark.parametrize("bound", [1.0, 10.0, 1e3, 1e6])
def test_sine_and_cosine_within_three_ulps_of_the_c_library(bound):
    x = np.random.default_rng(1).uniform(-bound, bound, 1_000_000)
    x[:6] = [0.5 * math.pi, math.pi, -math.pi, 2.5, -bound, bound]
    s, c = np.empty_like(x), np.empty_like(x)
    _sincos(x, s, c)
    assert _ulps(s, np.array([math.sin(v) for v in x])) <= 3
    assert _ulps(c, np.array([math.cos(v) for v in x])) <= 3
    assert np.max(np.abs(s * s + c * c - 1.0)) < 1e-15  # independent of the library: Pythagoras


def test_arc_tangent_within_three_ulps_over_every_quadrant_and_many_scales():
    rng = np.random.default_rng(2)
    y = rng.normal(size=1_000_000) * 10.0 ** rng.uniform(-6, 6, 1_000_000)
    x = rng.normal(size=1_000_000) * 10.0 ** rng.uniform(-6, 6, 1_000_000)
    x[:4], y[:4] = [1.0, -1.0, 1.0, 0.41421356237309503], [1.0, 1.0, -1e-300, 1.0]  # octant edges, tiny angle
    out = np.empty_like(x)
    _atan2(y, x, out)
    assert _ulps(out, np.array([math.atan2(a, b) for a, b in zip(y, x, strict=True)])) <= 3


def test_arc_tangent_keeps_the_c_librarys_signs_and_nan():
    special = [0.0, -0.0, 1.0, -1.0, 1e-310, -1e-310]
    for a in special:
        for b in special + [math.inf, -math.inf]:
            out = np.empty(1)
            _atan2(np.array([a]), np.array([b]), out)
            want = math.atan2(a, b)
            assert out[0] == want and math.copysign(1.0, out[0]) == math.copysign(1.0, want), (a, b)
    out = np.empty(3)
    _atan2(np.array([math.nan, 1.0, math.nan]), np.array([1.0, math.nan, math.nan]), out)
    assert np.isnan(out).all()


def test_arc_sine_within_three_ulps_up_to_the_ends():
    x = np.random.default_rng(3).uniform(-1.0, 1.0, 1_000_000)
    x[:8] = [1.0, -1.0, 0.0, 1.0 - 2**-53, -1.0 + 2**-53, 1e-300, 0.5, -0.5]
    out = np.empty_like(x)
    _asin(x, out)
    assert _ulps(out, np.array([math.asin(v) for v in x])) <= 3
    assert out[0] == math.pi / 2 and out[1] == -math.pi / 2


def test_a_loop_over_lanes_is_vector_code():
    """The point of these functions: a loop over 16 lanes that calls them compiles to packed FMAs, divisions
    and square roots (AVX2 or AVX-512 registers) and no scalar FMA."""
    flags = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    if not re.search(r"\bavx2\b", flags):
        pytest.skip("no AVX2 on this machine")

    @njit(**{**FLAGS, "cache": False})  # compiled here: cached code cannot be read back
    def lanes(buf):
        for i in range(16):
            s, c = vmath.sincos(buf[i])
            buf[16 + i] = vmath.atan2(s, buf[32 + i]) + vmath.asin(c * 0.5) + s * c

    lanes(np.random.default_rng(0).uniform(0.1, 1.0, 64))
    asm = lanes.inspect_asm(lanes.signatures[0])
    packed = len(re.findall(r"vfn?m(?:add|sub)\w*pd\s+%[yz]mm", asm))
    scalar = len(re.findall(r"vfn?m(?:add|sub)\w*sd\s", asm))
    assert packed >= 20 and scalar == 0, (packed, scalar)
    assert re.search(r"vdivpd\s+%[yz]mm", asm) and re.search(r"vsqrtpd\s+%[yz]mm", asm)


def test_the_literal_picks_the_c_library_one_at_a_time():
    """Scalar code keeps the C library's functions (faster one at a time): with ``vector=False`` the numbers
    are the library's to the bit; with ``True`` they are this module's."""

    @njit(**FLAGS)
    def both(x, y, out):
        out[0], out[1] = vmath.sin_cos(x, False)
        out[2], out[3] = vmath.arctan2(y, x, False), vmath.arcsin(0.3 * y, False)
        out[4], out[5] = vmath.sin_cos(x, True)
        out[6], out[7] = vmath.arctan2(y, x, True), vmath.arcsin(0.3 * y, True)

    out = np.empty(8)
    for x, y in ((0.7, 1.9), (-2.2, 0.3), (3.0, -1.1)):
        both(x, y, out)
        assert out[:4].tolist() == [math.sin(x), math.cos(x), math.atan2(y, x), math.asin(0.3 * y)]
        np.testing.assert_allclose(out[4:], out[:4], rtol=4e-16, atol=1e-300)
