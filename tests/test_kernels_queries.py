"""Ray casts through the block grid (read at every step, as on a CPU, or on entering a block, as on
a GPU) and through the hash table agree with the step-by-step reference, and the grid follows the
blocks as the map grows."""

import numpy as np

import vogjax as vj
from vogjax.maps import blocks

from . import reference as ref


def test_grid_and_hash_paths_match_the_reference_as_the_map_grows(monkeypatch):
    rng = np.random.default_rng(31)
    cfg = vj.MapConfig(voxel_size=0.2)
    vmap, cells = vj.VoxelMap(cfg), {}
    origins = rng.uniform(-1, 1, (300, 3))
    directions = rng.normal(size=(300, 3))
    ranges = rng.uniform(0.5, 8.0, 300)
    for step in range(3):  # each batch adds blocks: the grid must be rebuilt before the next cast
        o, p, s = ref.random_scans(rng, 3, 60, spread=3.0 + 2 * step)
        vmap.integrate_scans(o, p, s)
        for k in range(3):
            ref.insert_scan(cells, o[k], p[s == k], cfg)
        expected = [ref.raycast(cells, a, b, r, cfg) for a, b, r in zip(origins, directions, ranges)]
        results = [vmap.raycast(origins, directions, ranges)]
        with monkeypatch.context() as m:
            m.setattr(vmap, "_look_up_every_step", not vmap._look_up_every_step)  # the other device's way
            results.append(vmap.raycast(origins, directions, ranges))
        with monkeypatch.context() as m:
            m.setattr(blocks, "GRID_CELLS", 0)  # no dense grid: blocks found by hashing
            vmap.store._grid = None
            results.append(vmap.raycast(origins, directions, ranges))
            vmap.store._grid = None
        for result in results:
            np.testing.assert_array_equal(result.hit, [e[0] for e in expected])
            np.testing.assert_allclose(result.distance, [e[1] for e in expected], rtol=1e-6, atol=1e-6)
            np.testing.assert_array_equal(result.num_unknown, [e[2] for e in expected])
            np.testing.assert_array_equal(result.num_free, [e[3] for e in expected])
    assert vmap.store.grid().dims != (0, 0, 0)
