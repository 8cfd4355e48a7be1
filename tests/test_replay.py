"""Replayed CPU launches (`vogjax.maps.replay`) against plain ones: new dimensions, scalars and
arrays all reach the kernel."""

import numpy as np
import warp as wp

from vogjax import devices
from vogjax.maps.replay import Replay


@wp.kernel
def scaled_max(
    a: wp.array(dtype=wp.float32), b: wp.array(dtype=wp.float32), scale: float, out: wp.array(dtype=wp.float32)
):
    tid = wp.tid()
    out[tid] = wp.max(a[tid] * scale, b[tid])  # no sum a compiler could fuse into an FMA


def test_replay_follows_its_arguments():
    devices.init()
    device = wp.get_device("cpu")
    rng = np.random.default_rng(3)
    host = [rng.normal(size=64).astype(np.float32) for _ in range(3)]
    a, b, c = (wp.array(h, dtype=wp.float32, device=device) for h in host)
    out = wp.zeros(64, dtype=wp.float32, device=device)
    replay = Replay(scaled_max, device)
    # (dim, first array, scale): the dimension shrinks and grows, the scale changes, the first
    # array is replaced by another of the same size and back
    for dim, first, scale in [(64, a, 2.0), (64, a, 2.0), (10, a, 2.0), (10, a, -1.5), (30, c, -1.5), (64, a, 0.5)]:
        out.fill_(np.float32(np.nan))
        replay(dim, [first, b, scale], [out])
        x = host[0] if first is a else host[2]
        expected = np.maximum(x[:dim] * np.float32(scale), host[1][:dim])
        np.testing.assert_array_equal(out.numpy()[:dim], expected)
        assert np.all(np.isnan(out.numpy()[dim:]))  # only the first `dim` threads ran
    replay.forget()
    replay(5, [b, a, 1.0], [out])
    np.testing.assert_array_equal(out.numpy()[:5], np.maximum(host[1][:5], host[0][:5]))
