"""Coarse levels: OctoMap's inner nodes (octomap-python's `search(x, depth=16-k)` after
`updateInnerOccupancy`), kept current through integration and the global map's undo/redo, and
conservative ray casts (a hypothesis property against a float64 reference walk)."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import vogjax as vj
from vogjax.maps.levels import MAX_LEVEL

from . import reference as ref
from .submap_helpers import random_pose, random_vog

octomap = pytest.importorskip("octomap")
LEVELS = range(7)


def octomap_tree(cfg, origins, points, scan):
    tree = octomap.OcTree(cfg.voxel_size)
    tree.setProbHit(cfg.prob_hit)
    tree.setProbMiss(cfg.prob_miss)
    tree.setClampingThresMin(cfg.clamp_min)
    tree.setClampingThresMax(cfg.clamp_max)
    for s in range(len(origins)):
        tree.insertPointCloud(
            points[scan == s].astype(np.float64), origins[s].astype(np.float64), maxrange=cfg.max_range
        )
    tree.updateInnerOccupancy()
    return tree


def octomap_level(tree, voxel_size, level):
    """{coarse key: float32 log-odds} of every node at depth 16 - level, and of every pruned leaf
    above it expanded to the coarse voxels it covers (OctoMap's own iterator, no vogjax)."""
    depth = 16 - level
    size = voxel_size * 2**level
    cells = {}
    for node in tree.begin_tree(depth):
        d = node.getDepth()
        if d != depth and not node.isLeaf():
            continue
        n = 2 ** (depth - d)
        corner = np.floor((np.array(node.getCoordinate()) - node.getSize() / 2) / size + 0.5).astype(int)
        for offset in np.ndindex(n, n, n):
            cells[tuple((corner + offset).tolist())] = np.float32(node.getValue())
    return cells


def our_level(vmap, level):
    centres, values = vmap.voxels(level)
    keys = np.floor(centres / (vmap.config.voxel_size * 2**level)).astype(np.int64)
    return dict(zip(map(tuple, keys.tolist()), values))


@pytest.fixture(scope="module")
def scans():
    rng = np.random.default_rng(7)
    return ref.random_scans(rng, 12, 150, spread=6.0, far=0.1)


def test_every_level_equals_octomaps_inner_nodes_bit_for_bit(scans):
    cfg = vj.MapConfig()
    origins, points, scan = scans
    tree = octomap_tree(cfg, origins, points, scan)
    # levels built after the first half and kept current through the second
    kept = vj.VoxelMap(cfg)
    half = len(origins) // 2
    kept.integrate_scans(origins[:half], points[scan < half], scan[scan < half])
    assert kept.state(points[:1], level=6).shape == (1,) and kept.levels_kept == 6
    kept.integrate_scans(origins[half:], points[scan >= half], scan[scan >= half] - half)
    late = vj.VoxelMap(cfg)  # built once, from the whole map
    late.integrate_scans(origins, points, scan)
    rng = np.random.default_rng(1)
    centres, _ = late.voxels()
    queries = np.concatenate([centres[rng.choice(len(centres), 1500)] + rng.uniform(-0.4, 0.4, (1500, 3))])
    for level in LEVELS:
        expected = octomap_level(tree, cfg.voxel_size, level)
        assert our_level(kept, level) == expected == our_level(late, level)
        nodes = [tree.search(q, depth=16 - level) for q in queries]
        theirs = np.array([_log_odds_or_zero(n) for n in nodes], np.float32)
        np.testing.assert_array_equal(kept.log_odds(queries, level), theirs)
        occupied = np.array([_occupied(tree, n, cfg) for n in nodes])
        np.testing.assert_array_equal(kept.state(queries, level) == vj.OCCUPIED, occupied)
    assert len(octomap_level(tree, cfg.voxel_size, 0)) > 20_000  # a map of some size
    assert 0 < len(octomap_level(tree, cfg.voxel_size, 6)) < 200


def _log_odds_or_zero(node):
    try:
        return node.getLogOdds()
    except octomap.NullPointerException:
        return 0.0


def _occupied(tree, node, cfg):
    try:
        return node.getLogOdds() >= cfg.log_occupied
    except octomap.NullPointerException:
        return False


def test_coarse_ray_casts_and_lines_walk_the_coarse_voxels(scans):
    """At level k the queries are level 0's on a map of voxels of voxel_size * 2^k holding the
    coarse values: the brute-force reference walk on those cells answers the same, also for
    rays that leave the map (the unknown voxels past it counted in closed form)."""
    cfg = vj.MapConfig()
    vmap = vj.VoxelMap(cfg)
    vmap.integrate_scans(*scans)
    rng = np.random.default_rng(3)
    origins, directions = rng.uniform(-1.5, 1.5, (300, 3)), rng.normal(size=(300, 3))
    # a third long enough to leave the map: the stretch past it is counted, not walked
    ranges = np.concatenate([rng.uniform(0.02, 3.0, 200), rng.uniform(8.0, 25.0, 100)])
    starts, ends = rng.uniform(-5, 5, (100, 3)), rng.uniform(-5, 5, (100, 3))
    for level in (1, 2, 3):
        coarse = dataclasses.replace(cfg, voxel_size=cfg.voxel_size * 2**level)
        cells = our_level(vmap, level)
        result = vmap.raycast(origins, directions, ranges, level=level)
        expected = [ref.raycast(cells, o, d, r, coarse) for o, d, r in zip(origins, directions, ranges)]
        hit, distance, unknown, free = (np.array(x) for x in zip(*expected))
        np.testing.assert_array_equal(result.hit, hit)
        np.testing.assert_allclose(result.distance, distance, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(result.num_unknown, unknown)
        np.testing.assert_array_equal(result.num_free, free)
        assert 20 < hit.sum() < 300 - 20 * (level == 1), hit.sum()  # both outcomes at level 1
        values, lengths = vmap.line_query(starts, ends, level=level)
        for i in range(len(starts)):
            line = ref.line_values(cells, starts[i], ends[i], coarse)
            assert lengths[i] == len(line)
            np.testing.assert_array_equal(values[i, : lengths[i]], np.float32(line))


def test_grid_aligned_coarse_rays_from_near_the_map_walk_as_a_step_by_step_walk():
    """Rays through voxel edges and corners, from lattice points a few coarse voxels around the
    map, long enough to leave it: a walk resumed from recomputed boundaries can break such ties
    the other way, so before the map's box no level resumes closer than 64 voxels; past the box
    nothing can be hit. Hit, distance and free count equal the reference walk; the unknown count
    past the box (in closed form) may differ by the rounding of its last boundary."""
    rng = np.random.default_rng(5)
    vog = random_vog(rng, 3)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    for level in (1, 2):
        coarse = dataclasses.replace(vog.config, voxel_size=vog.config.voxel_size * 2**level)
        cells = our_level(gmap, level)
        origins = np.round(rng.uniform(-12, 12, (400, 3))) * coarse.voxel_size
        directions = rng.choice([-1.0, 0.0, 1.0, 2.0, 0.5], (400, 3))
        directions[~directions.any(axis=1), 0] = 1.0
        result = gmap.raycast(origins, directions, 30.0, level=level)
        expected = [ref.raycast(cells, o, d, 30.0, coarse) for o, d in zip(origins, directions)]
        hit, distance, unknown, free = (np.array(x) for x in zip(*expected))
        np.testing.assert_array_equal(result.hit, hit)
        np.testing.assert_allclose(result.distance, distance, rtol=1e-6, atol=1e-6)
        np.testing.assert_array_equal(result.num_free, free)
        assert np.abs(result.num_unknown - unknown).max() <= 2
        assert 20 < hit.sum() < 380, hit.sum()


def test_coarse_levels_after_loop_closures_equal_a_fresh_merge():
    rng = np.random.default_rng(11)
    vog = random_vog(rng, 4)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    gmap.state(np.zeros((1, 3)), level=4)  # levels 1-4 from here on
    for step in range(4):
        ids = rng.choice(vog.num_submaps, 2, replace=False)
        poses = vog.poses(ids)
        poses[:, :3, 3] += rng.normal(0, 0.3, (2, 3))  # a loop closure's correction
        vog.set_poses(ids, poses)
        if step == 2:
            i = vog.add_submap(random_pose(rng))
            vog.submap(i).integrate_scans(*ref.random_scans(rng, 2, 60, spread=2.5))
            gmap.add(vog, [i])
        report = gmap.update_poses(vog, eps_rot=0.0, eps_trans=0.0)
        assert len(report.reapplied) == 2
    fresh = vj.GlobalMap(vog.config)
    fresh.merge(vog)
    origins, directions = rng.uniform(-2, 2, (2000, 3)), rng.normal(size=(2000, 3))
    for level in range(1, 5):
        ours, theirs = gmap.voxels(level), fresh.voxels(level)
        np.testing.assert_array_equal(ours[0], theirs[0])
        np.testing.assert_array_equal(ours[1], theirs[1])
        assert gmap.store_at(level).live_blocks == fresh.store_at(level).live_blocks
        a, b = gmap.raycast(origins, directions, 6.0, level), fresh.raycast(origins, directions, 6.0, level)
        for name in ("hit", "distance", "num_unknown", "num_free"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # and each level is OctoMap's rule on the map's own voxels: the max of the level below
    for level in range(1, 5):
        below = our_level(gmap, level - 1)
        expected = {}
        for key, value in below.items():
            parent = tuple(k >> 1 for k in key)
            expected[parent] = max(expected.get(parent, -np.inf), value)
        assert our_level(gmap, level) == expected


def _levels_equal(ours, theirs, levels):
    for level in levels:
        a, b = ours.voxels(level), theirs.voxels(level)
        np.testing.assert_array_equal(a[0], b[0])
        np.testing.assert_array_equal(a[1].view(np.int32), b[1].view(np.int32))  # bit for bit


def test_levels_updated_after_every_scan_equal_a_fresh_build_at_every_step(monkeypatch):
    """Levels 1-3 are recomputed from the written blocks, levels 4-6 only from the level-3
    blocks whose voxels changed (a block that kept its bits gives its parent nothing new), so an
    update after each scan often stops after three levels: after every scan, every level equals
    one built from scratch, and propagation stopped early at least once (the pruned path ran)."""
    from vogjax.maps import levels as levels_module

    stopped = []
    fill = levels_module.Levels._fill

    def counting(self, level, depth, below, keys, cells=None):
        changed = fill(self, level, depth, below, keys, cells)
        above = np.unique(levels_module.shift_keys(keys, depth))
        assert np.isin(changed, above).all()
        stopped.append(len(changed) < len(above))
        return changed

    monkeypatch.setattr(levels_module.Levels, "_fill", counting)
    cfg = vj.MapConfig()
    rng = np.random.default_rng(3)
    origins, points, scan = ref.random_scans(rng, 24, 120, spread=4.0)
    kept = vj.VoxelMap(cfg)
    kept.store_at(6)
    for k in range(len(origins)):
        kept.integrate_scans(origins[k : k + 1], points[scan == k], np.zeros((scan == k).sum(), int))
        kept.store_at(6)
        fresh = vj.VoxelMap(cfg)
        fresh.integrate_scans(origins[: k + 1], points[scan <= k], scan[scan <= k])
        _levels_equal(kept, fresh, range(1, 7))
    assert any(stopped) and not all(stopped)


@pytest.mark.parametrize("threads", [1, 2])
def test_levels_after_calls_of_several_passes_equal_a_fresh_build(monkeypatch, threads):
    """A call integrates its scans in passes that share one scratch; the blocks each pass wrote
    are noted for the levels, and must survive the passes after it and the calls before the next
    coarse query (a one-thread CPU reused the scratch's key buffer under them: the levels missed
    every pass but the last)."""
    from vogjax.maps import parallel, voxelmap

    monkeypatch.setattr(parallel, "CPU_THREADS", threads)
    monkeypatch.setattr(voxelmap, "SCANS_PER_PASS", 3)
    cfg = vj.MapConfig()
    rng = np.random.default_rng(5)
    origins, points, scan = ref.random_scans(rng, 16, 1400, spread=5.0)  # 2 parts a pass on 2 threads
    kept = vj.VoxelMap(cfg)
    kept.store_at(6)
    for calls in ((0, 10), (10, 11), (11, 12), (12, 16)):  # no query between the calls
        rows = (scan >= calls[0]) & (scan < calls[1])
        kept.integrate_scans(origins[calls[0] : calls[1]], points[rows], scan[rows] - calls[0])
    fresh = vj.VoxelMap(cfg)
    fresh.integrate_scans(origins, points, scan)
    _levels_equal(kept, fresh, range(1, 7))


def _block_bits(vmap):
    """{packed key: (512,) int32 bits of the block's log-odds} of a map's live blocks."""
    store = vmap.store
    keys = store.slot_keys.numpy()[: store.num_blocks]
    values = store.layers["log_odds"].numpy().reshape(-1, 512)[: store.num_blocks].view(np.int32)
    return {int(k): values[i].copy() for i, k in enumerate(keys) if k != -1}


@pytest.mark.parametrize("threads", [1, 2])
def test_the_cells_noted_for_the_levels_are_those_whose_voxels_changed(monkeypatch, threads):
    """The levels recompute a written block only above the 2x2x2 cells integration reports
    changed, so those reports must be exact: per written block, the cells where a voxel's bits
    differ from before the scan (NumPy), none missing; scans of 4,500 beams split in two parts
    on two threads (the parts' boundaries must not cut a block's report)."""
    from vogjax.maps import levels as levels_module
    from vogjax.maps import parallel

    monkeypatch.setattr(parallel, "CPU_THREADS", threads)
    noted = []
    note = levels_module.Levels.note

    def recording(self, base, keys, cells=None, distinct=False):
        noted.append((np.array(keys), None if cells is None else np.array(cells)))
        note(self, base, keys, cells, distinct)

    monkeypatch.setattr(levels_module.Levels, "note", recording)
    rng = np.random.default_rng(11)
    origins, points, scan = ref.random_scans(rng, 4, 4500, spread=5.0)
    vmap = vj.VoxelMap(vj.MapConfig())
    vmap.store_at(3)
    unobserved = np.full(512, np.float32(np.nan)).view(np.int32)
    for k in range(len(origins)):
        before = _block_bits(vmap)
        vmap.integrate_scans(origins[k : k + 1], points[scan == k], np.zeros((scan == k).sum(), int))
        after = _block_bits(vmap)
        keys, cells = noted[-1]
        assert cells is not None and set(after) - set(before) <= set(keys.tolist())
        for key, mask in zip(keys.tolist(), cells.tolist()):
            changed = (after[key] != before.get(key, unobserved)).reshape(4, 2, 4, 2, 4, 2).any(axis=(1, 3, 5))
            assert mask == sum(1 << int(bit) for bit in np.flatnonzero(changed.ravel()))
        fresh = vj.VoxelMap(vmap.config)
        fresh._store = vmap.store
        _levels_equal(vmap, fresh, range(1, 4))


def test_global_map_levels_updated_after_every_undo_equal_a_fresh_merge():
    """The same with releases: a global map's voxels go back to unknown when a submap moves
    away, coarse blocks empty and are released; queried after every update_poses."""
    rng = np.random.default_rng(12)
    vog = random_vog(rng, 4)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    gmap.store_at(5)
    for step in range(6):
        ids = rng.choice(vog.num_submaps, 1 + step % 2, replace=False)
        poses = vog.poses(ids)
        poses[:, :3, 3] += rng.normal(0, 0.2 if step % 3 else 3.0, (len(ids), 3))
        vog.set_poses(ids, poses)
        gmap.update_poses(vog, eps_rot=0.0, eps_trans=0.0)
        gmap.store_at(5)
        fresh = vj.GlobalMap(vog.config)
        fresh.merge(vog)
        _levels_equal(gmap, fresh, range(1, 6))
        for level in range(1, 6):
            assert gmap.store_at(level).live_blocks == fresh.store_at(level).live_blocks


def test_a_virtual_maps_coarse_levels_follow_its_poses_and_submaps(monkeypatch):
    merges = []
    merge = vj.GlobalMap.merge
    monkeypatch.setattr(vj.GlobalMap, "merge", lambda self, *a, **k: merges.append(1) or merge(self, *a, **k))
    rng = np.random.default_rng(4)
    vog = random_vog(rng, 3)
    s = vog.config.voxel_size
    points = (np.floor(rng.uniform(-4, 4, (3000, 3)) / s) + 0.5) * s  # level 0 agrees at voxel centres
    origins, directions = rng.uniform(-2, 2, (500, 3)), rng.normal(size=(500, 3))
    expected_merges = {"none": 1, "poses": 0, "integrate old": 1, "add": 0, "fill last": 0, "fill last again": 0}
    for change, merged in expected_merges.items():
        merges.clear()
        if change == "poses":
            vog.set_poses([1], [random_pose(rng)])
        elif change == "integrate old":  # a submap written after it was summed, no copy kept: merged
            vog.submap(0).integrate_scans(*ref.random_scans(rng, 1, 40, spread=2.0))
        elif change == "add":
            i = vog.add_submap(random_pose(rng))
            vog.submap(i).integrate_scans(*ref.random_scans(rng, 1, 40, spread=2.0))
        elif change.startswith("fill last"):  # the submap being filled: undone from its copy
            vog.submap(vog.num_submaps - 1).integrate_scans(*ref.random_scans(rng, 1, 40, spread=2.0))
            vog.set_poses([0], [random_pose(rng)])
        vog.coarse_map()
        assert len(merges) == merged, change
        fresh = vj.GlobalMap(vog.config)
        fresh.merge(vog)
        for level in (0, 2, 3):
            np.testing.assert_array_equal(vog.log_odds(points, level), fresh.log_odds(points, level))
            np.testing.assert_array_equal(vog.state(points, level), fresh.state(points, level))
        a, b = vog.raycast(origins, directions, 5.0, level=2), fresh.raycast(origins, directions, 5.0, level=2)
        np.testing.assert_array_equal(a.hit, b.hit)
        np.testing.assert_array_equal(a.distance, b.distance)
        la, lb = vog.line_query(points[:50], points[50:100], 2), fresh.line_query(points[:50], points[50:100], 2)
        np.testing.assert_array_equal(la[0], lb[0])


block_coordinate = st.integers(-(1 << 20), (1 << 20) - 1)


def test_a_virtual_maps_coarse_queries_check_their_arguments_before_merging():
    vog = random_vog(np.random.default_rng(4), 2)
    calls = [
        lambda: vog.state(np.zeros((2, 2)), level=2),
        lambda: vog.log_odds([[np.nan, 0.0, 0.0]], level=1),
        lambda: vog.raycast(np.zeros((1, 3)), np.zeros((1, 3)), 5.0, level=2),
        lambda: vog.raycast(np.zeros((1, 3)), np.ones((1, 3)), -1.0, level=2),
        lambda: vog.line_query(np.zeros((1, 3)), [[np.inf, 0.0, 0.0]], level=3),
    ]
    for call in calls:
        with pytest.raises(ValueError):
            call()
        assert vog._coarse is None  # refused before the coarse map was built
    assert vog.state(np.zeros((1, 3)), level=2).shape == (1,) and vog._coarse is not None


def test_a_coarse_ray_stops_counting_where_the_key_range_ends_as_level_0_does():
    """The key range is 2^23 level-0 voxels each way: a coarse walk ends at the same metres,
    not 2^k times farther (it counted voxels no key can name as unknown)."""
    cfg = vj.MapConfig(voxel_size=0.1)
    vmap = vj.VoxelMap(cfg)
    vmap.integrate_scans(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0]]), np.zeros(1, int))
    for direction in ([-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]):
        walked_m = []
        for level in range(6):
            r = vmap.raycast(np.array([[-2.0, 0.05, 0.05]]), np.array([direction]), 5e6, level=level)
            walked_m.append((int(r.num_unknown[0]) + int(r.num_free[0])) * cfg.voxel_size * 2**level)
        reach_m = 2**23 * cfg.voxel_size - np.dot([-2.0, 0.05, 0.05], direction)  # to the key range's face
        for level, metres in enumerate(walked_m):
            assert abs(metres - reach_m) <= 2 * cfg.voxel_size * 2**level, (direction, level, metres)


def test_a_coarse_query_during_a_scan_of_a_moved_submap_waits_for_it_and_stays_exact():
    """A planner's coarse query while SLAM writes the newest submap, whose pose just changed:
    the coarse map must not judge the submap by its revision before the write and then undo
    what the write put in (it did: the sums went negative, and stayed wrong)."""
    import threading
    import time

    rng = np.random.default_rng(0)
    vog = random_vog(rng, 2)
    last = vog.add_submap(random_pose(rng))
    vog.submap(last).integrate_scans(*ref.random_scans(rng, 1, 60, spread=2.0))
    vog.state(np.zeros((1, 3)), level=2)  # the coarse map made, the submaps applied
    poses = vog.poses([last])
    poses[0, :3, 3] += 0.3
    vog.set_poses([last], poses)
    submap = vog.submap(last)
    scans = ref.random_scans(np.random.default_rng(1), 4, 100_000, spread=3.0)
    writer = threading.Thread(target=lambda: submap.integrate_scans(*scans))
    writer.start()
    deadline = time.monotonic() + 30
    while not submap._lock._writing and writer.is_alive() and time.monotonic() < deadline:
        time.sleep(1e-4)
    in_flight = submap._lock._writing
    vog.state(np.zeros((1, 3)), level=2)
    writer.join()
    assert in_flight, "the scan finished before the query: the case was not exercised"
    keys, sums, counts = vog.coarse_map().sums()
    fresh = vj.GlobalMap(vog.config)
    fresh.merge(vog)
    want = fresh.sums()
    assert np.array_equal(keys, want[0]) and np.array_equal(sums, want[1]) and np.array_equal(counts, want[2])
    centres, _ = fresh.voxels(2)
    np.testing.assert_array_equal(vog.state(centres, level=2), fresh.state(centres, level=2))


@settings(max_examples=200, deadline=None)
@given(blocks=st.lists(st.tuples(block_coordinate, block_coordinate, block_coordinate), min_size=1, max_size=20))
def test_shifting_packed_keys_equals_shifting_the_coordinates(blocks):
    from vogjax.maps.blocks import pack_blocks, unpack_blocks
    from vogjax.maps.levels import shift_keys

    blocks = np.array(blocks, np.int64)
    keys = pack_blocks(blocks)
    for levels in range(0, 16):
        np.testing.assert_array_equal(shift_keys(keys, levels), pack_blocks(blocks >> levels))
        np.testing.assert_array_equal(unpack_blocks(shift_keys(keys, levels)), blocks >> levels)


def test_the_fill_kernel_writes_nothing_when_a_parent_block_is_missing():
    """A block whose parent is missing would index slot -1: the kernel flags it with the levels
    whose parents are missing and writes nothing (the host allocates them and fills it again)."""
    import warp as wp

    from vogjax.kernels import levels as kernels
    from vogjax.maps.blocks import BlockStore, pack_blocks
    from vogjax.maps.levels import ALL_CELLS, LAYERS

    device = wp.get_device("cpu")
    base, coarse = BlockStore(device, LAYERS), BlockStore(device, LAYERS)
    keys = pack_blocks(np.array([[0, 0, 0], [5, -3, 2]]))
    base.ensure_blocks(wp.array(keys, dtype=wp.int64, device=device))
    base.layers["log_odds"].fill_(1.5)
    coarse.ensure_blocks(wp.array(keys[:1], dtype=wp.int64, device=device))  # [5, -3, 2]'s parent missing
    flags = wp.zeros(2, dtype=wp.int32, device=device)
    tables = [coarse.table_keys, coarse.table_slots] * 3
    wp.launch(
        kernels.fill_levels_above_blocks,
        dim=2,
        inputs=[
            wp.array(keys, dtype=wp.int64, device=device),
            wp.full(2, ALL_CELLS, dtype=wp.uint64, device=device),
            wp.array([2], dtype=wp.int32, device=device),
            1,
            base.table_keys,
            base.table_slots,
            base.layers["log_odds"],
            *tables,
            *[coarse.layers["log_odds"]] * 3,
        ],
        outputs=[flags],
        device=device,
    )
    assert flags.numpy()[1] == -1 - 1 and flags.numpy()[0] & kernels.REGION_OBSERVED
    values = coarse.layers["log_odds"].numpy()[:512].reshape(8, 8, 8)
    assert np.all(values[:4, :4, :4] == 1.5) and np.isnan(values[4:]).all() and np.isnan(values[:, 4:]).all()


def _max_child_in_child_order(values):
    """OctoMap's getMaxChildLogOdds over a dense (2n, 2n, 2n) float32 array: children taken in
    computeChildIdx order (x fastest, then y, then z), the first of equal values kept (so the
    sign of a zero is that of the first zero child), unobserved (NaN) children ignored."""
    n = values.shape[0] // 2
    out = np.full((n, n, n), np.nan, np.float32)
    for x, y, z in np.ndindex(n, n, n):
        best = np.float32(np.nan)
        for child in range(8):
            v = values[2 * x + (child & 1), 2 * y + (child >> 1 & 1), 2 * z + (child >> 2 & 1)]
            if not np.isnan(v) and (np.isnan(best) or v > best):
                best = v
        out[x, y, z] = best
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), block=st.tuples(*[st.integers(-40, 40)] * 3))
def test_filled_levels_keep_the_first_maximum_in_child_order_signed_zeros_included(seed, block):
    """Levels 1-3 above one block of values drawn from a few ties (+0 and -0 among them) and
    NaN, against the child-order reference, bit for bit: a fill reading the block in another
    order would keep the other zero where +0 and -0 tie."""
    import warp as wp

    from vogjax.maps.blocks import BlockStore, pack_blocks
    from vogjax.maps.levels import LAYERS, Levels

    rng = np.random.default_rng(seed)
    choices = np.array([np.nan, 0.0, -0.0, 0.4, -0.4, 1.25], np.float32)
    values = choices[rng.integers(0, len(choices), (8, 8, 8))]
    device = wp.get_device("cpu")
    base = BlockStore(device, LAYERS)
    base.ensure_blocks(wp.array(pack_blocks(np.array([block])), dtype=wp.int64, device=device))
    base.layers["log_odds"].assign(values.reshape(-1))  # slot 0; index (x * 8 + y) * 8 + z
    levels = Levels(device, releases=False)
    levels.extend(base, 3)
    expected = values
    for level in (1, 2, 3):
        expected = _max_child_in_child_order(expected)
        store = levels.store(level)
        parent = np.array(block) >> level
        slot = store.find(wp.array(pack_blocks(parent[None]), dtype=wp.int64, device=device)).numpy()[0]
        mine = store.layers["log_odds"].numpy()[slot * 512 : (slot + 1) * 512].reshape(8, 8, 8)
        n = 8 >> level
        corner = (np.array(block) & ((1 << level) - 1)) * n
        region = mine[corner[0] : corner[0] + n, corner[1] : corner[1] + n, corner[2] : corner[2] + n]
        np.testing.assert_array_equal(region.view(np.uint32), expected.view(np.uint32), err_msg=f"level {level}")


def test_bad_levels_are_refused_naming_the_argument():
    vmap = vj.VoxelMap()
    for bad in (-1, MAX_LEVEL + 1, 1.0, True, "2"):
        with pytest.raises(ValueError, match=r"^level must be an integer in \[0, 15\]"):
            vmap.state(np.zeros((1, 3)), level=bad)
        with pytest.raises(ValueError, match="^level must"):
            vmap.raycast(np.zeros((1, 3)), np.ones((1, 3)), 1.0, level=bad)
    assert vmap.levels_kept == 0
    assert vmap.state(np.zeros((1, 3)), level=MAX_LEVEL).tolist() == [vj.UNKNOWN]


# ------------------------------------------------------------------ conservative ray casts
def reference_hit(cells, origin, direction, max_range, cfg):
    """(hit key, entry, exit) of the first OCCUPIED voxel of a float64 Amanatides-Woo walk, or None."""
    s = cfg.voxel_size
    o, d = np.asarray(origin, np.float64), np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    key = list(ref.key_of(o, s))
    step = [int(np.sign(c)) for c in d]
    with np.errstate(over="ignore", divide="ignore"):  # a subnormal component: its boundaries at inf
        t_max = [((key[i] + (step[i] > 0)) * s - o[i]) / d[i] if step[i] else math.inf for i in range(3)]
        t_delta = [s / abs(d[i]) if step[i] else math.inf for i in range(3)]
    t = 0.0
    while t < max_range:
        if ref.state_of(cells.get(tuple(key)), cfg) == 2:
            return tuple(key), t, min(t_max)
        dim = ref._octomap_dim(t_max)
        t = t_max[dim]
        key[dim] += step[dim]
        t_max[dim] += t_delta[dim]
    return None


coordinate = st.one_of(st.integers(-12, 12).map(lambda k: k * 0.1), st.floats(-1.2, 1.2, allow_nan=False))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    origin=st.tuples(coordinate, coordinate, coordinate),
    direction=st.tuples(*[st.one_of(st.sampled_from([0.0, 1.0, -1.0, 0.5]), st.floats(-1, 1))] * 3).filter(
        lambda d: any(abs(c) > 1e-3 for c in d)
    ),
    level=st.integers(1, 4),
)
def test_a_coarse_ray_never_passes_where_level_0_is_occupied(seed, origin, direction, level):
    """Wherever level 0 hits a voxel the ray spends more than a millionth of an edge in, the
    coarse cast hits at or before it; and every OCCUPIED voxel is OCCUPIED at every level."""
    rng = np.random.default_rng(seed)
    cfg = vj.MapConfig()
    vmap = vj.VoxelMap(cfg)
    vmap.integrate_scans(*ref.random_scans(rng, 3, 40, spread=1.5))
    cells = our_level(vmap, 0)
    # rays from the hypothesis origin fanning out, plus the drawn direction (grid-aligned ones too)
    directions = np.concatenate([np.array([direction]), rng.normal(size=(63, 3))])
    origins = np.repeat(np.array([origin]), 64, axis=0)
    fine = vmap.raycast(origins, directions, 4.0)
    coarse = vmap.raycast(origins, directions, 4.0, level=level)
    for i in np.flatnonzero(fine.hit):
        found = reference_hit(cells, origins[i], directions[i], 4.0, cfg)
        assert found is not None
        _, t_in, t_out = found
        if t_out - t_in > 1e-6 * cfg.voxel_size:
            assert coarse.hit[i] and coarse.distance[i] <= fine.distance[i] + 1e-5
    centres, values = vmap.voxels()
    occupied = centres[values >= cfg.log_occupied]
    jitter = rng.uniform(-0.5, 0.5, occupied.shape) * cfg.voxel_size * 0.999
    assert np.all(vmap.state(occupied + jitter, level) == vj.OCCUPIED)


# ------------------------------------------------------------------ the planner on a coarse level
def room(rng, voxel_size=0.1):
    """Free water observed around the origin with a wall in it."""
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=voxel_size, max_range=6.0))
    wall = np.c_[np.full(600, 1.9), rng.uniform(-1.5, 0.5, 600), rng.uniform(-1, 1, 600)]
    vmap.integrate_scans(np.zeros((1, 3)), wall, np.zeros(600, np.int64))
    origins = rng.uniform(-0.3, 0.3, (20, 3))
    directions = rng.normal(size=(20 * 500, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    vmap.integrate_scans(origins, np.repeat(origins, 500, axis=0) + directions * 3.0, np.repeat(np.arange(20), 500))
    return vmap


def test_the_planner_on_a_coarse_level_plans_as_on_a_map_of_its_voxels():
    from vogjax import planner
    from vogjax.geometry import pose_from_xyz_yaw
    from vogjax.maps.blocks import BlockStore

    vmap = room(np.random.default_rng(2))
    sonar = vj.sensors.ProfilingSonar(vj.SonarConfig(beams=24, fov_deg=40.0, min_range_m=0.3))
    bounds = np.array([[-3.0, -3.0, -1.0], [3.0, 3.0, 1.0]])
    config = planner.PlannerConfig(
        edge_length_m=1.0, max_nodes=6, tolerance_nodes=18, gain_range_m=3.0, gain_step_m=0.2, clearance_m=0.6, seed=3
    )
    T = pose_from_xyz_yaw(0.1, -0.2, 0.1, 0.4)
    for level in (1, 2):
        # the coarse voxels as a map of their own, planned on at level 0
        keys, layers = vmap.store_at(level).host_blocks()
        coarse = vj.VoxelMap(dataclasses.replace(vmap.config, voxel_size=vmap.config.voxel_size * 2**level))
        coarse._store = BlockStore.from_host(coarse.device, coarse.store.layer_specs, keys, layers)
        ours = planner.NbvPlanner(config.replace(collision_level=level, gain_level=level), bounds, sonar).plan(vmap, T)
        theirs = planner.NbvPlanner(config, bounds, sonar).plan(coarse, T)
        np.testing.assert_array_equal(ours.tree_states, theirs.tree_states)
        assert ours.gain_m3 == theirs.gain_m3 > 0 and ours.rays == theirs.rays
    # a virtual map's coarse level is its global map's
    vog = vj.VogMap(vmap.config)
    vog.add_submap(np.eye(4))
    vog.submap(0).integrate_scans(np.zeros((1, 3)), vmap.voxels()[0][::50], np.zeros(len(vmap.voxels()[0][::50]), int))
    gmap = vj.GlobalMap(vmap.config)
    gmap.merge(vog)
    mixed = config.replace(collision_level=2, gain_level=1)
    a = planner.NbvPlanner(mixed, bounds, sonar).plan(vog, T)
    b = planner.NbvPlanner(mixed, bounds, sonar).plan(gmap, T)
    np.testing.assert_array_equal(a.tree_states, b.tree_states)
    i = vog.add_submap(np.eye(4))
    vog.submap(i).integrate_scans(np.zeros((1, 3)), np.ones((3, 3)), np.zeros(3, int))
    overlay = planner.Overlay(gmap, vog, [i])
    with pytest.raises(ValueError, match="level 1: an Overlay has no coarse levels"):
        planner.NbvPlanner(mixed, bounds, sonar).plan(overlay, T)
