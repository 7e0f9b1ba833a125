"""The compiled engines' noise (compiled.noise) against NumPy's own generator: the same states, the same
numbers bit for bit, the same stream position after a rejection."""

import numpy as np
import pytest

from vtol_impedance.compiled.lanes import W
from vtol_impedance.compiled.noise import generator_states, normals_lanes, standard_normal
from vtol_impedance.sim.sensors import NoiseSource

EDGE_SEEDS = [0, 1, 7, 2**31, 2**32 - 1, 2**32, 2**32 + 1, 2**53 + 1, 2**63 - 1, 2**63, 2**64 - 1, 2**64, 2**70 + 5]


def _numpy_state(seed):
    st = np.random.PCG64(np.random.SeedSequence([seed, 0])).state["state"]
    return st["state"], st["inc"]


def _as_ints(rng, b):
    return int(rng[0, b]) << 64 | int(rng[1, b]), int(rng[2, b]) << 64 | int(rng[3, b])


def test_the_generator_states_are_numpys_seeding():
    rs = np.random.default_rng(11)
    seeds = EDGE_SEEDS + [int(s) for s in rs.integers(0, 2**63, 200)] + [int(s) for s in rs.integers(0, 2**20, 50)]
    rng = generator_states(seeds)
    assert rng.shape == (4, len(seeds)) and rng.dtype == np.uint64
    for b, s in enumerate(seeds):
        assert _as_ints(rng, b) == _numpy_state(s), s


def test_one_vehicles_draws_are_numpys_bit_for_bit_through_every_branch():
    n = 300_000  # enough for the wedge test (about 1 % of draws) and the tail beyond the last layer
    for seed in (3, 2**40 + 9):
        rng = generator_states([5, seed])  # column 1: the other column must not move
        before = rng[:, 0].copy()
        got = np.array([standard_normal(rng, 1) for _ in range(n)])
        g = np.random.default_rng(np.random.SeedSequence([seed, 0]))
        want = g.standard_normal(n)
        np.testing.assert_array_equal(got, want)
        assert np.abs(want).max() > 3.6541528853610088  # the tail (|x| past the ziggurat's base) was drawn
        assert _as_ints(rng, 1) == (g.bit_generator.state["state"]["state"], g.bit_generator.state["state"]["inc"])
        np.testing.assert_array_equal(rng[:, 0], before)


def test_the_lanes_draw_each_vehicles_own_stream_in_order():
    seeds = list(range(100, 100 + W))
    st = generator_states(seeds)
    m = 20_000
    out = np.full((m + 3) * W, np.nan)
    normals_lanes(st, out, 3, m)  # rows 3 .. m + 2 of a lanes buffer
    assert np.isnan(out[: 3 * W]).all()  # the rows before row0 untouched
    got = out[3 * W :].reshape(m, W)
    gens = NoiseSource(seeds).gens
    for i, g in enumerate(gens):
        np.testing.assert_array_equal(got[:, i], g.standard_normal(m), err_msg=f"lane {i}")
        state = g.bit_generator.state["state"]
        assert _as_ints(st, i) == (state["state"], state["inc"]), i  # the same words consumed (rejections too)


def test_the_draws_are_standard_normal():
    """Independently of NumPy: the moments and the tail mass of a million draws from several lanes."""
    st = generator_states(list(range(W)))
    m = 65_536
    out = np.empty(m * W)
    normals_lanes(st, out, 0, m)
    z = out
    n = z.size
    assert abs(z.mean()) < 5 / np.sqrt(n)
    assert abs(z.var() - 1.0) < 5 * np.sqrt(2.0 / n)
    assert abs(np.mean(z**3)) < 5 * np.sqrt(15.0 / n)  # symmetric
    tail = np.mean(np.abs(z) > 3.0)  # P(|Z| > 3) = 0.0026998
    assert abs(tail - 0.0026998) < 5 * np.sqrt(0.0027 / n)


def test_a_noise_source_makes_its_generators_on_the_first_draw():
    src = NoiseSource([4, 5])
    assert src.seeds == [4, 5]
    a = src.block(3)
    assert a.shape == (2, 3, 12)
    want = np.random.default_rng(np.random.SeedSequence([5, 0])).standard_normal(36)
    np.testing.assert_array_equal(a[1].ravel(), want)


@pytest.mark.parametrize("seed", [-1])
def test_a_negative_seed_is_refused_by_numpys_seeding(seed):
    with pytest.raises(ValueError):
        generator_states([seed])
