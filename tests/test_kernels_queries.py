"""Ray casts four ways: a CPU's, reading every voxel's state from a dense box
(cast_rays_dense) or from a padded block grid (cast_rays_on_grid) at every step; a GPU's,
looking a block up in the grid on entering it (cast_rays); and through the hash table. All agree
with the step-by-step reference and with each other bit for bit, and the tables follow the blocks
as the map grows."""

import numpy as np
import pytest

import vogjax as vj
from vogjax.maps import blockmap, blocks

from . import reference as ref

WAYS = {  # (on a CPU, dense box budget, dense grid budget): the kind of tables they give
    "dense": ((True, blockmap.DENSE_STATE_BYTES, blocks.GRID_CELLS), "dense"),
    "grid": ((True, 0, blocks.GRID_CELLS), "grid"),
    "gpu": ((False, blockmap.DENSE_STATE_BYTES, blocks.GRID_CELLS), "device"),
    "hash": ((False, blockmap.DENSE_STATE_BYTES, 0), "device"),
}


def casts_four_ways(vmap, monkeypatch, origins, directions, ranges):
    """The map's ray casts each way (WAYS), tables built afresh for each."""
    results = []
    for (cpu, dense_bytes, grid_cells), kind in WAYS.values():
        with monkeypatch.context() as m:
            m.setattr(vmap, "_cpu_casts", cpu)
            m.setattr(blockmap, "DENSE_STATE_BYTES", dense_bytes)
            m.setattr(blocks, "GRID_CELLS", grid_cells)  # 0: no dense grid, blocks found by hashing
            vmap.store._grid, vmap._ray_tables_cache = None, None
            results.append(vmap.raycast(origins, directions, ranges))
            tables = vmap._ray_tables()
            assert tables.kind == kind
            assert [k for k in ("columns", "bases") if getattr(tables, k).shape[0] > 0] == {
                "dense": ["columns"],
                "grid": ["bases"],
                "device": [],
            }[kind]
            assert (tables.grid.dims[0] > 0) == (grid_cells > 0)
            vmap.store._grid, vmap._ray_tables_cache = None, None
    return results


def test_grid_and_hash_paths_match_the_reference_as_the_map_grows(monkeypatch):
    rng = np.random.default_rng(31)
    cfg = vj.MapConfig(voxel_size=0.2)
    vmap, cells = vj.VoxelMap(cfg), {}
    origins = rng.uniform(-1, 1, (300, 3))
    directions = rng.normal(size=(300, 3))
    ranges = rng.uniform(0.5, 8.0, 300)
    for step in range(3):  # each batch adds blocks: the tables must be rebuilt before the next cast
        o, p, s = ref.random_scans(rng, 3, 60, spread=3.0 + 2 * step)
        vmap.integrate_scans(o, p, s)
        for k in range(3):
            ref.insert_scan(cells, o[k], p[s == k], cfg)
        expected = [ref.raycast(cells, a, b, r, cfg) for a, b, r in zip(origins, directions, ranges)]
        for result in casts_four_ways(vmap, monkeypatch, origins, directions, ranges):
            np.testing.assert_array_equal(result.hit, [e[0] for e in expected])
            np.testing.assert_allclose(result.distance, [e[1] for e in expected], rtol=1e-6, atol=1e-6)
            np.testing.assert_array_equal(result.num_unknown, [e[2] for e in expected])
            np.testing.assert_array_equal(result.num_free, [e[3] for e in expected])
    assert vmap.store.grid().dims != (0, 0, 0)


def hostile_rays(rng, box_lo, box_hi, targets, voxel_size, count):
    """Rays from inside the map's box, from just outside it (within the 64 voxels a cast walks
    rather than skips, on every side, so the padded grid's clamps are crossed both ways), from
    far away, along the axes and diagonals, from voxel corners, with short, long and huge ranges."""
    centre, extent = (box_lo + box_hi) / 2, (box_hi - box_lo) / 2
    near = centre + rng.uniform(-1, 1, (count, 3)) * (extent + 70 * voxel_size)
    far = centre + rng.choice([-1.0, 1.0], (count, 3)) * rng.uniform(1e2, 1e5, (count, 3)) * voxel_size
    corners = np.round(near / voxel_size) * voxel_size  # on voxel and block boundaries
    origins = np.concatenate([near, far, corners])
    n = origins.shape[0]
    directions = rng.normal(size=(n, 3))
    axis = rng.integers(0, 3, n)
    along = rng.random(n) < 0.3  # axis-parallel: two steps never taken
    directions[along] = 0.0
    directions[along, axis[along]] = rng.choice([-1.0, 1.0], along.sum())
    diagonal = rng.random(n) < 0.15  # ties between the axes at every block corner
    directions[diagonal] = rng.choice([-1.0, 1.0], (diagonal.sum(), 3))
    towards = rng.random(n) < 0.5  # many aimed at the map's occupied voxels (`targets`)
    directions[towards] = targets[rng.integers(0, len(targets), towards.sum())] - origins[towards]
    ranges = rng.choice([0.05, 0.7, 4.0, 40.0, 1e3, 7.2e7, 1e300], n) * rng.uniform(0.5, 1.5, n)
    return origins, directions, ranges


@pytest.mark.parametrize("seed", [0, 1])
def test_the_cpu_and_gpu_kernels_agree_bit_for_bit_on_hostile_rays(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    cfg = vj.MapConfig(voxel_size=0.25)
    vmap = vj.VoxelMap(cfg)
    o, p, s = ref.random_scans(rng, 6, 80, spread=6.0)
    vmap.integrate_scans(o + [3.0, -2.0, 1.0], p + [3.0, -2.0, 1.0], s)  # the box away from the origin
    lo, hi = vmap.store.block_box()
    centres, log_odds = vmap.voxels()
    origins, directions, ranges = hostile_rays(
        rng,
        lo * 8 * cfg.voxel_size,
        (hi + 1) * 8 * cfg.voxel_size,
        centres[log_odds >= cfg.log_occupied],
        cfg.voxel_size,
        600,
    )
    results = casts_four_ways(vmap, monkeypatch, origins, directions, ranges)
    for other in results[1:]:
        for field in ("hit", "distance", "num_unknown", "num_free"):
            assert np.array_equal(getattr(results[0], field), getattr(other, field)), field
    assert results[0].hit.sum() > 200 and (~results[0].hit).sum() > 200  # both outcomes exercised


def test_a_map_of_scattered_blocks_casts_through_the_grid_and_a_compact_one_through_the_box():
    rng = np.random.default_rng(5)
    cfg = vj.MapConfig(voxel_size=0.1)
    compact, scattered = vj.VoxelMap(cfg), vj.VoxelMap(cfg)
    o, p, s = ref.random_scans(rng, 4, 200, spread=2.0)
    compact.integrate_scans(o, p, s)
    scattered.integrate_scans(
        np.concatenate([o, o + 30.0]), np.concatenate([p, p + 30.0]), np.concatenate([s, s + 4])
    )  # two clusters 30 m apart: a box of mostly nothing
    for vmap, kind in ((compact, "dense"), (scattered, "grid")):
        vmap.raycast(o, p[:4] - o, 5.0)
        tables = vmap._ray_tables()
        padded_blocks = np.prod(tables.padded_dims)
        assert tables.kind == kind, (kind, padded_blocks, vmap.num_blocks)
        assert (padded_blocks <= max(4 * vmap.num_blocks, 4096)) == (kind == "dense")
