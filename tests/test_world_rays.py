"""`vogjax.sensors.world_rays` against exact arithmetic, and the same bits however it is batched."""

from fractions import Fraction

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vogjax.geometry import exp_se3
from vogjax.sensors import base
from vogjax.sensors.base import world_rays


def _scans(seed, count, beams):
    rng = np.random.default_rng(seed)
    poses = exp_se3(rng.normal(size=(count, 6)))
    poses[:, :3, 3] = rng.normal(scale=30.0, size=(count, 3))
    origins = rng.normal(scale=0.5, size=(count, 3))
    directions = rng.normal(size=(count, beams, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    ranges = rng.uniform(0.5, 50.0, size=(count, beams)).astype(np.float32)
    no_return = rng.random((count, beams)) < 0.2
    invalid = ~no_return & (rng.random((count, beams)) < 0.1)
    return poses, origins, directions, ranges, no_return, invalid


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    count=st.integers(1, 9),
    beams=st.integers(1, 40),
    chunk=st.integers(1, 200),
)
def test_endpoints_do_not_depend_on_the_batch(seed, count, beams, chunk):
    """Maps are exact only if a scan's rays are the same bits whether it is transformed alone,
    in a batch, or in chunks of any size."""
    poses, origins, directions, ranges, no_return, invalid = _scans(seed, count, beams)
    together = world_rays(poses, origins, directions, ranges, no_return, 11.0, invalid)
    saved = base.RAYS_PER_CHUNK
    try:
        base.RAYS_PER_CHUNK = chunk
        chunked = world_rays(poses, origins, directions, ranges, no_return, 11.0, invalid)
    finally:
        base.RAYS_PER_CHUNK = saved
    np.testing.assert_array_equal(chunked[1], together[1])
    for s in range(count):
        alone = world_rays(
            poses[s : s + 1], origins[s : s + 1], directions[s : s + 1], ranges[s : s + 1],
            no_return[s : s + 1], 11.0, invalid[s : s + 1],
        )  # fmt: skip
        np.testing.assert_array_equal(alone[0][0], together[0][s])
        np.testing.assert_array_equal(alone[1][0], together[1][s])


def test_endpoints_match_exact_arithmetic():
    """Each endpoint is o + R d L to within a few float64 roundings (exact rationals as the
    reference); no-return beams end past the reach, invalid ones at NaN."""
    poses, origins, directions, ranges, no_return, invalid = _scans(7, 3, 25)
    world_origins, endpoints = world_rays(poses, origins, directions, ranges, no_return, 11.0, invalid)
    reach = ranges.dtype.type(11.0 * 1.05 + 0.1)  # in the ranges' precision, as NumPy's where gives it
    for s in range(3):
        R = [[Fraction(float(v)) for v in row] for row in poses[s, :3, :3]]
        t = [Fraction(float(v)) for v in poses[s, :3, 3]]
        o = [sum(R[i][j] * Fraction(float(origins[s, j])) for j in range(3)) + t[i] for i in range(3)]
        np.testing.assert_allclose(world_origins[s], [float(v) for v in o], rtol=0, atol=1e-13)
        for b in range(25):
            if invalid[s, b]:
                assert np.isnan(endpoints[s, b]).all()
                continue
            length = Fraction(float(reach)) if no_return[s, b] else Fraction(float(ranges[s, b]))
            d = [Fraction(float(v)) for v in directions[s, b]]
            exact = [o[i] + sum(R[i][j] * d[j] for j in range(3)) * length for i in range(3)]
            np.testing.assert_allclose(endpoints[s, b], [float(v) for v in exact], rtol=0, atol=1e-12)
