"""The correlative search's target field, blurred on the box around the target only, against
the blur of the whole grid (float32, as the search holds it): the same values bit for bit,
wherever the target lies on the grid (faces shared or not)."""

from __future__ import annotations

import sys

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

import vogjax.slam  # noqa: F401  (the module below is shadowed by a function of the same name)

correlative = sys.modules["vogjax.slam.correlative"]


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    shape=st.tuples(st.integers(3, 40), st.integers(3, 40), st.integers(3, 25)),
    blur=st.sampled_from([0.0, 0.6, 1.0, 1.6]),
    points=st.integers(1, 60),
    data=st.data(),
)
def test_box_blur_is_the_whole_grids(seed, shape, blur, points, data):
    rng = np.random.default_rng(seed)
    shape = np.array(shape)
    corner = rng.integers(0, shape)  # a cluster somewhere: near a face, or far from all of them
    spread = rng.integers(1, 8, 3)
    cells = np.clip(corner + rng.integers(-spread, spread + 1, (points, 3)), 0, shape - 1)
    z_lo = data.draw(st.integers(0, int(shape[2]) - 1))
    z_hi = data.draw(st.integers(z_lo + 1, int(shape[2])))
    field = correlative._target_field(cells, shape, z_lo, z_hi, blur)
    whole = np.zeros(shape, np.float32)
    whole[cells[:, 0], cells[:, 1], cells[:, 2]] = 1.0
    if blur > 0:
        whole = ndimage.gaussian_filter(whole, blur)
        whole /= max(float(whole.max()), 1e-12)
    assert field.dtype == np.float32
    np.testing.assert_array_equal(field, whole[:, :, z_lo:z_hi])
