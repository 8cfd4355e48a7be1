"""The planner's view gain and collision checks against brute-force NumPy on small maps."""

import math

import numpy as np
import pytest

import vogjax as vj
from vogjax import planner
from vogjax.config.planner import PAPERS
from vogjax.geometry import pose_from_xyz_yaw
from vogjax.planner.gain import edge_views

from . import reference as ref
from .submap_helpers import random_vog


def ray_voxels(origin, direction, max_range, voxel_size):
    """Voxels a ray enters before max_range, with the distances where it enters and leaves
    each: every boundary crossing per axis, sorted (no stepping)."""
    crossings = [0.0]
    for axis in range(3):
        if direction[axis] == 0:
            continue
        first = math.floor(origin[axis] / voxel_size) + (direction[axis] > 0)
        k = first + np.sign(direction[axis]) * np.arange(max_range / voxel_size + 3)
        t = (k * voxel_size - origin[axis]) / direction[axis]
        crossings += t[t > 0].tolist()
    crossings = np.unique(crossings)
    entries, exits = crossings[:-1], crossings[1:]
    keep = entries < max_range
    keys = np.floor((origin + ((entries + exits) / 2)[:, None] * direction) / voxel_size).astype(np.int64)
    return keys[keep], entries[keep], exits[keep]


def brute_gain(map_, poses, sensor, max_range, region=None, groups=None, frontier=False):
    """Per group of views: sets of unknown, free, occupied voxels seen (first occupied stops);
    with `frontier` a fourth column, the unknown ones with a FREE face neighbour."""
    s = map_.config.voxel_size
    directions = sensor.beam_directions().reshape(-1, 3)
    groups = np.arange(len(poses)) if groups is None else groups
    seen = [{} for _ in range(groups.max() + 1)]
    for pose, group in zip(poses, groups):
        for d in directions:
            direction = pose[:3, :3] @ d
            keys, _, exits = ray_voxels(pose[:3, 3], direction, max_range, s)
            states = map_.state((keys + 0.5) * s)
            for key, state, t_exit in zip(keys, states, exits):
                centre = (key + 0.5) * s
                inside = region is None or bool(np.all((centre >= region[0]) & (centre <= region[1])))
                if t_exit > sensor.min_range_m and inside:
                    seen[group][tuple(key)] = int(state)
                if state == vj.OCCUPIED:
                    break
    counts = np.array(
        [[sum(v == state for v in g.values()) for state in (vj.UNKNOWN, vj.FREE, vj.OCCUPIED)] for g in seen]
    )
    if not frontier:
        return counts
    faces = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    on_frontier = []
    for g in seen:
        unknown = np.array([k for k, v in g.items() if v == vj.UNKNOWN]).reshape(-1, 3)
        neighbours = map_.state(((unknown[:, None] + faces[None]).reshape(-1, 3) + 0.5) * s).reshape(-1, 6)
        on_frontier.append(int(np.any(neighbours == vj.FREE, axis=1).sum()))
    return np.c_[counts, on_frontier]


def small_map(rng, cfg):
    vmap = vj.VoxelMap(cfg)
    vmap.integrate_scans(*ref.random_scans(rng, 4, 150, spread=3.0, far=0.1))
    return vmap


def random_views(rng, count, spread=1.0):
    poses = []
    for _ in range(count):
        pose = pose_from_xyz_yaw(*rng.uniform(-spread, spread, 3), rng.uniform(-np.pi, np.pi))
        poses.append(pose)
    return np.array(poses)


SONAR = vj.sensors.ProfilingSonar(vj.SonarConfig(beams=24, fov_deg=40.0, min_range_m=0.3))


def test_view_gain_matches_brute_force_on_a_voxel_map():
    rng = np.random.default_rng(0)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=4.0)
    vmap = small_map(rng, cfg)
    poses = random_views(rng, 12)
    gain = planner.view_gain(vmap, poses, SONAR, max_range_m=3.0)
    expected = brute_gain(vmap, poses, SONAR, 3.0)
    np.testing.assert_array_equal(np.c_[gain.unknown, gain.free, gain.occupied], expected)
    assert expected[:, 0].sum() > 50 and expected[:, 1].sum() > 50 and expected[:, 2].sum() > 5
    np.testing.assert_allclose(gain.unknown_m3, expected[:, 0] * 0.2**3)
    assert gain.rays == 12 * 24
    # a voxel seen by two rays of a view counts once: fewer voxels than the rays passed through
    walked = sum(
        len(ray_voxels(p[:3, 3], p[:3, :3] @ d, 3.0, 0.2)[0])
        for p in poses[:1]
        for d in SONAR.beam_directions().reshape(-1, 3)
    )
    assert expected[0].sum() < walked


def test_view_gain_counts_only_the_region():
    rng = np.random.default_rng(1)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=4.0)
    vmap = small_map(rng, cfg)
    poses = random_views(rng, 6)
    region = np.array([[-1.0, -2.0, -0.5], [2.0, 1.0, 1.5]])
    gain = planner.view_gain(vmap, poses, SONAR, max_range_m=3.0, region=region)
    np.testing.assert_array_equal(
        np.c_[gain.unknown, gain.free, gain.occupied], brute_gain(vmap, poses, SONAR, 3.0, region)
    )


def test_frontier_gain_counts_the_unknown_voxels_beside_free_water():
    """frontier=True adds, per view, the unknown voxels seen that have a FREE face neighbour
    (brute force: every seen unknown voxel's six neighbours queried); the other counts and
    the default (no frontier counted) are unchanged; the virtual and global maps agree."""
    rng = np.random.default_rng(11)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=4.0)
    vmap = small_map(rng, cfg)
    poses = random_views(rng, 10)
    region = np.array([[-2.0, -2.0, -1.5], [2.0, 2.5, 1.5]])
    expected = brute_gain(vmap, poses, SONAR, 3.0, region, frontier=True)
    gain = planner.view_gain(vmap, poses, SONAR, max_range_m=3.0, region=region, frontier=True)
    np.testing.assert_array_equal(np.c_[gain.unknown, gain.free, gain.occupied, gain.frontier], expected)
    assert 0 < expected[:, 3].sum() < expected[:, 0].sum()
    plain = planner.view_gain(vmap, poses, SONAR, max_range_m=3.0, region=region)
    np.testing.assert_array_equal(plain.unknown, gain.unknown)
    assert not plain.frontier.any()
    vog, gmap = vog_and_global(rng)
    views = random_views(rng, 6, spread=1.5)
    virtual = planner.view_gain(vog, views, SONAR, max_range_m=3.5, frontier=True)
    merged = planner.view_gain(gmap, views, SONAR, max_range_m=3.5, frontier=True)
    np.testing.assert_array_equal(virtual.frontier, brute_gain(vog, views, SONAR, 3.5, frontier=True)[:, 3])
    np.testing.assert_array_equal(virtual.frontier, merged.frontier)


def vog_and_global(rng, submaps=5):
    vog = random_vog(rng, submaps, vj.MapConfig(voxel_size=0.2, max_range=4.0), scans=2, beams=80, spread=2.5)
    gmap = vj.GlobalMap(vog.config)
    gmap.merge(vog)
    return vog, gmap


def test_view_gain_on_global_and_virtual_maps_matches_brute_force():
    rng = np.random.default_rng(2)
    vog, gmap = vog_and_global(rng)
    poses = random_views(rng, 8, spread=1.5)
    for m in (gmap, vog):
        gain = planner.view_gain(m, poses, SONAR, max_range_m=3.5)
        expected = brute_gain(m, poses, SONAR, 3.5)
        np.testing.assert_array_equal(np.c_[gain.unknown, gain.free, gain.occupied], expected)
        assert expected[:, 2].sum() > 0 and expected[:, 1].sum() > 0
    # at voxel centres the virtual map answers what the global map does: the same gains
    virtual = planner.view_gain(vog, poses, SONAR, max_range_m=3.5)
    merged = planner.view_gain(gmap, poses, SONAR, max_range_m=3.5)
    np.testing.assert_array_equal(virtual.unknown, merged.unknown)


def test_overlay_reads_what_adding_the_submaps_would_give():
    rng = np.random.default_rng(3)
    vog, _ = vog_and_global(rng, 4)
    base = vj.GlobalMap(vog.config)
    base.add(vog, [0, 1])
    full = vj.GlobalMap(vog.config)
    full.add(vog, [0, 1, 2, 3])
    poses = random_views(rng, 8, spread=1.5)
    overlay = planner.view_gain(planner.Overlay(base, vog, [2, 3]), poses, SONAR, max_range_m=3.5)
    expected = planner.view_gain(full, poses, SONAR, max_range_m=3.5)
    for field in ("unknown", "free", "occupied"):
        np.testing.assert_array_equal(getattr(overlay, field), getattr(expected, field))
    with pytest.raises(ValueError, match="ids"):
        planner.Overlay(base, vog, [1, 2])


def test_overlay_extra_submaps_read_as_if_added_too():
    """Submaps of another VogMap laid on top (the scans the mapper holds) read as if a global map
    held them as well: gains and collision checks equal those on the merge of all of them."""
    rng = np.random.default_rng(12)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=4.0)
    scans = [ref.random_scans(rng, 2, 80, spread=2.5) for _ in range(4)]
    poses = [pose_from_xyz_yaw(*rng.uniform(-0.5, 0.5, 3), rng.uniform(-1, 1)) for _ in range(4)]
    vog, held, everything = vj.VogMap(cfg), vj.VogMap(cfg), vj.VogMap(cfg)
    for k in range(4):
        for m in (vog, everything) if k < 3 else (held, everything):
            m.submap(m.add_submap(poses[k])).integrate_scans(*scans[k])
    base, merged = vj.GlobalMap(cfg), vj.GlobalMap(cfg)
    base.merge(vog)
    merged.merge(everything)
    overlay = planner.Overlay(base, vog, [], extra=held)
    views = random_views(rng, 8, spread=1.5)
    got = planner.view_gain(overlay, views, SONAR, max_range_m=3.5, frontier=True)
    want = planner.view_gain(merged, views, SONAR, max_range_m=3.5, frontier=True)
    for field in ("unknown", "free", "occupied", "frontier"):
        np.testing.assert_array_equal(getattr(got, field), getattr(want, field))
    assert not np.array_equal(got.unknown, planner.view_gain(base, views, SONAR, max_range_m=3.5).unknown)
    starts, ends = rng.uniform(-1, 1, (20, 3)), rng.uniform(-1, 1, (20, 3))
    np.testing.assert_array_equal(
        planner.edges_clear(overlay, starts, ends, (0.4, 0.4, 0.2), np.zeros(3), 0.5),
        planner.edges_clear(merged, starts, ends, (0.4, 0.4, 0.2), np.zeros(3), 0.5),
    )
    with pytest.raises(ValueError, match="extra"):
        planner.Overlay(base, vog, [], extra=vj.VogMap(vj.MapConfig(voxel_size=0.3)))


def test_edge_gain_counts_each_voxel_once_per_edge():
    rng = np.random.default_rng(4)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=4.0)
    vmap = small_map(rng, cfg)
    starts = np.array([[-0.5, -0.5, 0.2, 0.3], [0.4, 0.1, -0.3, 2.0], [0.0, 0.0, 0.0, -1.0]])
    ends = np.array([[0.8, 0.1, 0.2, 0.9], [0.4, 0.1, 0.6, 2.0], [0.0, 0.0, 0.0, 1.0]])  # last: a turn in place
    gain = planner.edge_gain(vmap, starts, ends, SONAR, step_m=0.25, max_range_m=3.0)
    poses, edge = edge_views(starts, ends, SONAR.T_vehicle_sensor, 0.25, 3.0)
    expected = brute_gain(vmap, poses, SONAR, 3.0, groups=edge)
    np.testing.assert_array_equal(np.c_[gain.unknown, gain.free, gain.occupied], expected)
    assert gain.rays == len(poses) * 24
    # views: the edge's end is the last one, consecutive ones at most a step apart
    assert np.allclose(poses[edge == 0][-1] @ np.linalg.inv(SONAR.T_vehicle_sensor), pose_from_xyz_yaw(*ends[0]))
    steps = np.linalg.norm(np.diff(poses[edge == 0][:, :3, 3], axis=0), axis=1)
    assert steps.max() <= 0.25 + 1e-9
    assert np.bincount(edge)[2] >= np.ceil(2.0 * 3.0 / 0.25)  # a 2 rad turn, 0.25 m at 3 m
    # summing the views' own gains counts shared voxels again
    per_view = planner.view_gain(vmap, poses[edge == 0], SONAR, max_range_m=3.0)
    assert per_view.unknown.sum() > gain.unknown[0]


@pytest.mark.parametrize("states", [(0,), (0, 2), (1,), (2, 1, 0)])
def test_edge_counts_of_some_states_equal_theirs_in_the_full_count_and_mark_the_others(states):
    """The planner counts only the states it weighs (the unknown voxels by default): those
    columns equal the brute-force count, the frontier column too, and the states left out read
    -1, never 0 (the frontier's column too when the unknown voxels are left out)."""
    from vogjax.planner.gain import edge_counts
    from vogjax.planner.source import opened

    rng = np.random.default_rng(11)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=4.0)
    vmap = small_map(rng, cfg)
    starts = np.c_[rng.uniform(-1, 1, (6, 3)), rng.uniform(-np.pi, np.pi, 6)]
    ends = starts + np.c_[rng.normal(0, 0.5, (6, 3)), rng.normal(0, 0.5, 6)]
    poses, edge = edge_views(starts, ends, SONAR.T_vehicle_sensor, 0.25, 3.0)
    expected = brute_gain(vmap, poses, SONAR, 3.0, groups=edge, frontier=True)
    with opened(vmap) as source:
        counts, rays = edge_counts(source, starts, ends, SONAR, 0.25, 3.0, None, True, states)
    for state in range(3):
        if state in states:
            np.testing.assert_array_equal(counts[:, state], expected[:, state])
        else:
            assert np.all(counts[:, state] == -1)
    np.testing.assert_array_equal(counts[:, 3], expected[:, 3] if 0 in states else -1)
    assert expected[:, 0].sum() > 0 and expected[:, 1].sum() > 0  # both kinds seen: the check can tell them apart
    assert rays == len(poses) * 24
    with opened(vmap) as source, pytest.raises(ValueError, match="states"):
        edge_counts(source, starts, ends, SONAR, 0.25, 3.0, None, False, (0, 3))


def test_view_gain_splits_across_cores_without_changing_counts(monkeypatch):
    from vogjax.maps import parallel

    rng = np.random.default_rng(5)
    vmap = small_map(rng, vj.MapConfig(voxel_size=0.2, max_range=4.0))
    poses = random_views(rng, 200)
    monkeypatch.setattr(parallel, "MIN_ITEMS_PER_PART", 10**9)  # one part
    whole = planner.view_gain(vmap, poses, SONAR, max_range_m=3.0)
    monkeypatch.setattr(parallel, "MIN_ITEMS_PER_PART", 16)
    monkeypatch.setattr(parallel, "CPU_THREADS", 4)
    split = planner.view_gain(vmap, poses, SONAR, max_range_m=3.0)
    np.testing.assert_array_equal(whole.unknown, split.unknown)
    np.testing.assert_array_equal(whole.free, split.free)


def test_view_gain_rejects_bad_input():
    vmap = vj.VoxelMap(vj.MapConfig())
    pose = np.eye(4)[None]
    with pytest.raises(ValueError, match="T_world_sensor"):
        planner.view_gain(vmap, np.ones((1, 4, 4)), SONAR)
    with pytest.raises(ValueError, match="max_range_m"):
        planner.view_gain(vmap, pose, SONAR, max_range_m=-1.0)
    with pytest.raises(ValueError, match="region"):
        planner.view_gain(vmap, pose, SONAR, region=[[1, 1, 1], [0, 0, 0]])
    with pytest.raises(ValueError, match="map"):
        planner.view_gain(object(), pose, SONAR)
    with pytest.raises(ValueError, match="sensor"):
        planner.view_gain(vmap, pose, object())


def swept_keys(start, end, half, s):
    """Keys of every voxel whose cube, grown by `half`, the segment meets (closed slab test)."""
    lo = np.floor((np.minimum(start, end) - half) / s).astype(int) - 1
    hi = np.floor((np.maximum(start, end) + half) / s).astype(int) + 1
    keys = np.stack(np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij"), -1).reshape(-1, 3)
    cube_lo, cube_hi = keys * s - half, (keys + 1) * s + half
    d = end - start
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (cube_lo - start) / d, (cube_hi - start) / d
    flat = d == 0
    t0 = np.where(flat, -np.inf, np.minimum(a, b)).max(axis=1).clip(min=0)
    t1 = np.where(flat, np.inf, np.maximum(a, b)).min(axis=1).clip(max=1)
    meets = (t0 <= t1) & np.all(~flat | ((start >= cube_lo) & (start <= cube_hi)), axis=1)
    return keys[meets]


def brute_clear(map_, start, end, box, vehicle, clearance, layer_only=False, obstacle=(0.0, 0.0, 0.0)):
    """Every voxel of the edge's bounding box whose cube, grown by the half box, the segment
    meets: none may be occupied, nor unknown away from the vehicle (with layer_only: away from
    it, or above or below its box); and no occupied voxel in the box grown by `obstacle` per
    axis either, but for those that box holds at the vehicle's position."""
    s, half = map_.config.voxel_size, np.asarray(box) / 2
    keys = swept_keys(start, end, half, s)
    states = map_.state((keys + 0.5) * s)
    centres = (keys + 0.5) * s
    at_vehicle = np.all((keys * s <= vehicle + half) & ((keys + 1) * s >= vehicle - half), axis=1)
    near = np.linalg.norm(centres - vehicle, axis=1) <= clearance
    if layer_only:  # the voxel's cube meets the height of the box at the vehicle
        near &= np.abs(centres[:, 2] - vehicle[2]) <= half[2] + s / 2
    # the centre line's layer in the voxel's column, where the line passes nearest in x-y
    d = end - start
    flat = d[:2] @ d[:2]
    layer_free = np.zeros(len(keys), bool)
    t = None
    if flat > 0:
        t = np.clip((centres[:, :2] - start[:2]) @ d[:2] / flat, 0, 1)
    elif layer_only and d[2] != 0:  # straight up or down: the line's height nearest the voxel's
        t = np.clip((centres[:, 2] - start[2]) / d[2], 0, 1)
    if t is not None:
        layer = np.c_[keys[:, :2], np.floor((start[2] + t * d[2]) / s).astype(int)]
        layer_free = map_.state((layer + 0.5) * s) == vj.FREE
        if layer_only and flat > 0:  # the layer's voxel in the vehicle's box is water: the vehicle is there
            layer_free |= np.all((layer * s <= vehicle + half) & ((layer + 1) * s >= vehicle - half), axis=1)
        layer_free &= layer[:, 2] != keys[:, 2]
    clear = not np.any((states == vj.OCCUPIED) & ~at_vehicle) and not np.any(
        (states == vj.UNKNOWN) & ~at_vehicle & ~near & ~layer_free
    )
    wide_half = half + np.asarray(obstacle)
    wide = swept_keys(start, end, wide_half, s)
    occupied = wide[map_.state((wide + 0.5) * s) == vj.OCCUPIED]
    held = np.all((occupied * s <= vehicle + wide_half) & ((occupied + 1) * s >= vehicle - wide_half), axis=1)
    return clear and not np.any(~held)


def test_edges_clear_matches_brute_force():
    rng = np.random.default_rng(6)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=6.0)
    vmap = vj.VoxelMap(cfg)
    # free space all around, two walls in it
    origins = rng.uniform(-0.3, 0.3, (30, 3))
    directions = rng.normal(size=(30 * 400, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    points = np.repeat(origins, 400, axis=0) + directions * 4.0
    walls = np.c_[np.full(300, 1.7), rng.uniform(-1, 1, 300), rng.uniform(-1, 1, 300)]
    walls2 = np.c_[rng.uniform(-2, 0, 300), np.full(300, -1.6), rng.uniform(-1, 1, 300)]
    vmap.integrate_scans(np.zeros((1, 3)), np.r_[walls, walls2], np.zeros(600, np.int64))
    vmap.integrate_scans(origins, points, np.repeat(np.arange(30), 400))
    box = np.array([0.6, 0.8, 0.4])
    vehicle = np.array([0.05, 0.1, 0.0])
    starts = np.tile(vehicle, (60, 1))
    starts[30:] = rng.uniform(-1.5, 1.5, (30, 3))
    ends = starts + rng.normal(size=(60, 3)) * 1.2
    ends[5] = starts[5]  # a turn in place
    ends[6:12] = starts[6:12] + np.c_[np.zeros((6, 2)), rng.uniform(-1.0, 1.0, 6)]  # straight up or down
    ends[36:42] = starts[36:42] + np.c_[np.zeros((6, 2)), rng.uniform(-1.0, 1.0, 6)]
    for clearance, layer_only in ((0.0, False), (0.9, False), (0.9, True)):
        clear = planner.edges_clear(vmap, starts, ends, box, vehicle, clearance, layer_only)
        expected = [brute_clear(vmap, a, b, box, vehicle, clearance, layer_only) for a, b in zip(starts, ends)]
        np.testing.assert_array_equal(clear, expected)
        assert 5 < np.sum(expected) < 55
    # known obstacles kept 0.5 m farther off in x and y: fewer edges pass, as brute force says
    wide = planner.edges_clear(vmap, starts, ends, box, vehicle, 0.9, True, (0.5, 0.5, 0.0))
    expected = [brute_clear(vmap, a, b, box, vehicle, 0.9, True, (0.5, 0.5, 0.0)) for a, b in zip(starts, ends)]
    np.testing.assert_array_equal(wide, expected)
    assert np.sum(wide) < np.sum(planner.edges_clear(vmap, starts, ends, box, vehicle, 0.9, True))
    # the virtual map of a submap holding the same scans answers the same
    vog = vj.VogMap(cfg)
    i = vog.add_submap(np.eye(4))
    vog.submap(i).integrate_scans(np.zeros((1, 3)), np.r_[walls, walls2], np.zeros(600, np.int64))
    vog.submap(i).integrate_scans(origins, points, np.repeat(np.arange(30), 400))
    np.testing.assert_array_equal(
        planner.edges_clear(vog, starts, ends, box, vehicle, 0.9),
        planner.edges_clear(vmap, starts, ends, box, vehicle, 0.9),
    )


def test_a_climb_into_unseen_water_is_refused_and_into_seen_water_allowed():
    """The clearance never lets a climb enter water no beam has crossed: with layer_only, a
    vertical edge from a vehicle that has seen only its own layer is blocked; once the water
    above has been seen free (from afar: here, scans from the side), the same edge passes."""
    cfg = vj.MapConfig(voxel_size=0.1, max_range=8.0)
    vmap = vj.VoxelMap(cfg)
    y, z = np.meshgrid(np.linspace(-1.5, 1.5, 31), np.linspace(-0.2, 0.2, 5))
    ahead = np.c_[np.full(y.size, 4.0), y.ravel(), z.ravel()]
    vmap.integrate_scans(np.array([[-2.0, 0.0, 0.0]]), ahead, np.zeros(len(ahead), np.int64))  # its own layer
    box, vehicle = np.array([1.0, 1.0, 0.5]), np.zeros(3)
    up = (np.zeros((1, 3)), np.array([[0.0, 0.0, 0.3]]))  # less than the box is tall: still blind
    assert planner.edges_clear(vmap, *up, box, vehicle, 1.5)  # blind: the clearance sphere lets it through
    assert not planner.edges_clear(vmap, *up, box, vehicle, 1.5, layer_only=True)[0]
    assert brute_clear(vmap, up[0][0], up[1][0], box, vehicle, 1.5, True) is False
    y, z = np.meshgrid(np.linspace(-1.5, 1.5, 31), np.linspace(0.0, 1.6, 17))
    above = np.c_[np.full(y.size, 4.0), y.ravel(), z.ravel()]
    vmap.integrate_scans(np.array([[-6.0, 0.0, 0.8]]), above, np.zeros(len(above), np.int64))
    assert planner.edges_clear(vmap, *up, box, vehicle, 1.5, layer_only=True)[0]


def room_map(rng, walls=True):
    """Free water observed all around the origin (0.2 m voxels), with two walls in it."""
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.2, max_range=6.0))
    origins = rng.uniform(-0.3, 0.3, (30, 3))
    directions = rng.normal(size=(30 * 600, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    if walls:
        wall = np.c_[np.full(400, 1.9), rng.uniform(-1.5, 0.5, 400), rng.uniform(-1, 1, 400)]
        vmap.integrate_scans(np.zeros((1, 3)), wall, np.zeros(400, np.int64))
    vmap.integrate_scans(origins, np.repeat(origins, 600, axis=0) + directions * 3.5, np.repeat(np.arange(30), 600))
    return vmap


BOUNDS = np.array([[-3.0, -3.0, -1.0], [3.0, 3.0, 1.0]])
SMALL = planner.PlannerConfig(
    **{
        **PAPERS,
        "edge_length_m": 1.0,
        "max_nodes": 8,
        "tolerance_nodes": 24,
        "gain_range_m": 3.0,
        "gain_step_m": 0.2,
        "clearance_m": 0.6,
        "max_heading_change_rad": 1.0,
        "seed": 5,
    }
)


def node_gains(vmap, states, parents, config, sensor):
    """Every node's score, recomputed edge by edge with edge_gain: the papers' discounted branch
    gain, or the branch's gain per second of flight (an edge taking the longer of its
    translation at the speed limit and its turn at the yaw-rate limit, plus the overhead)."""
    gains, distances, seconds = np.zeros(len(states)), np.zeros(len(states)), np.zeros(len(states))
    for n in range(1, len(states)):
        p = parents[n]
        turn = abs((states[n, 3] - states[p, 3] + np.pi) % (2 * np.pi) - np.pi)
        length = np.linalg.norm(states[n, :3] - states[p, :3])
        # an edge costs its length, or the distance flown in the time its turn takes if longer
        distances[n] = distances[p] + max(length, config.turn_cost_m_per_rad * turn)
        seconds[n] = seconds[p] + max(length / 0.25, turn / 0.15) + config.edge_overhead_s
        g = planner.edge_gain(vmap, states[p][None], states[n][None], sensor, config.gain_step_m, config.gain_range_m)
        if config.selection == "discounted":
            gains[n] = gains[p] + planner.discounted(g.unknown_m3[0], distances[n], config.discount)
        else:
            gains[n] = gains[p] + g.unknown_m3[0]
    if config.selection == "discounted":
        return gains, gains
    return gains, np.divide(gains, seconds, out=np.zeros_like(gains), where=seconds > 0)


TIME_RULE = {
    "selection": "gain_rate",
    "yaw_along_path": True,
    "sloped_fraction": 0.5,
    "vertical_fraction": 0.25,
    "blind_vertical": False,
    "obstacle_margin_m": 0.2,
    "min_edge_length_m": 0.3,
    "margin_z_m": 0.1,
}


@pytest.mark.parametrize(
    "turn_cost, rule",
    [(0.0, {}), (SMALL.turn_cost_m_per_rad, {}), (SMALL.turn_cost_m_per_rad, TIME_RULE)],
)
def test_plan_grows_a_valid_tree_whose_best_branch_is_returned(turn_cost, rule):
    rng = np.random.default_rng(7)
    vmap = room_map(rng)
    T = pose_from_xyz_yaw(0.1, -0.2, 0.1, 0.4)
    config = SMALL.replace(turn_cost_m_per_rad=turn_cost, **rule)
    slope_up, slope_down = np.tan(np.deg2rad(10.0)), np.tan(np.deg2rad(30.0))  # SONAR's fan: -30 to +10 deg
    plan = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR).plan(vmap, T)
    states, parents = plan.tree_states, plan.tree_parents
    assert plan.nodes == len(states) - 1 >= SMALL.max_nodes and plan.rays > 0 and plan.seconds > 0
    np.testing.assert_allclose(states[0], [0.1, -0.2, 0.1, 0.4], atol=1e-12)
    lo, hi = BOUNDS[0] + np.array(SMALL.box_m) / 2, BOUNDS[1] - np.array(SMALL.box_m) / 2
    sloped = 0
    for n in range(1, len(states)):
        p = parents[n]
        assert 0 <= p < n
        assert np.linalg.norm(states[n, :3] - states[p, :3]) <= SMALL.edge_length_m + 1e-9
        turn = abs((states[n, 3] - states[p, 3] + np.pi) % (2 * np.pi) - np.pi)
        length = np.linalg.norm(states[n, :3] - states[p, :3])
        assert turn <= SMALL.max_heading_change_rad + 1e-9
        if config.yaw_along_path:  # no edge turns longer than its translation takes
            assert turn <= 0.15 * length / 0.25 + 1e-9
        assert length >= config.min_edge_length_m - 1e-9
        flat, rise = np.linalg.norm(states[n, :2] - states[p, :2]), states[n, 2] - states[p, 2]
        if flat > 1e-9 and config.sloped_fraction > 0:  # climbs and descents within the fan's look
            assert -slope_down * flat - 1e-9 <= rise <= slope_up * flat + 1e-9
            sloped += abs(rise) > 1e-6
        assert np.all((states[n, :3] >= lo - 1e-9) & (states[n, :3] <= hi + 1e-9))
        assert brute_clear(
            vmap,
            states[p, :3],
            states[n, :3],
            np.array(config.checked_box_m),
            states[0, :3],
            SMALL.clearance_m,
            not config.blind_vertical,
            config.obstacle_margins_m(),
        )
    assert (sloped > 0) == (config.sloped_fraction > 0)
    gains, scores = node_gains(vmap, states, parents, config, SONAR)
    best = int(np.argmax(scores))
    assert plan.score == pytest.approx(scores.max(), rel=1e-9) and plan.score > 0
    assert plan.gain_m3 == pytest.approx(gains[best], rel=1e-9) and plan.gain_m3 > 0
    branch = []
    while best > 0:
        branch.append(states[best])
        best = parents[best]
    np.testing.assert_array_equal(plan.waypoints, np.array(branch[::-1]))
    # the same seed plans the same tree
    again = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR).plan(vmap, T)
    np.testing.assert_array_equal(again.tree_states, states)


def test_receding_horizon_and_tolerance():
    rng = np.random.default_rng(8)
    vmap = room_map(rng, walls=False)
    config = SMALL.replace(clearance_m=0.0)
    nbv = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR)
    first = nbv.plan(vmap, pose_from_xyz_yaw(0.0, 0.0, 0.0, 0.0))
    assert len(first.waypoints) >= 2
    # flown to the first node: the next tree starts with the rest of the best branch
    second = nbv.plan(vmap, pose_from_xyz_yaw(*first.waypoints[0]))
    rest = first.waypoints[1:]
    np.testing.assert_allclose(second.tree_states[1 : 1 + len(rest)], rest)
    np.testing.assert_array_equal(second.tree_parents[1 : 1 + len(rest)], np.arange(len(rest)))
    # nothing unknown in reach: no gain, so the tree grows on to N_tol
    region = np.array([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]])  # known free water only
    flat = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR, region=region).plan(
        vmap, pose_from_xyz_yaw(0.0, 0.0, 0.0, 0.0)
    )
    assert flat.gain_m3 == 0 and flat.nodes >= config.tolerance_nodes


def shortest_seconds(n: int, edges: list, seconds: np.ndarray, start: int) -> np.ndarray:
    """Bellman-Ford over an undirected graph: the least time from `start` to every vertex."""
    best = np.full(n, np.inf)
    best[start] = 0.0
    for _ in range(n):
        for (i, j), t in zip(edges, seconds):
            best[j] = min(best[j], best[i] + t)
            best[i] = min(best[i], best[j] + t)
    return best


def test_global_step_takes_the_quickest_trip_to_the_best_vertex_left_behind():
    """After a few plans (each flying its first edge), a global step's trip runs along edges of
    the explored graph to an unvisited vertex; its gain is that vertex's tree edge counted on the
    current map, its time the quickest way there (Bellman-Ford), and no other candidate has more
    gain per second; every edge it did not fly before is collision-free now."""
    rng = np.random.default_rng(13)
    vmap = room_map(rng)
    config = SMALL.replace(**TIME_RULE, global_step=True)
    nbv = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR)
    T = pose_from_xyz_yaw(0.0, 0.0, 0.0, 0.0)
    for _ in range(4):
        plan = nbv.plan(vmap, T)
        T = pose_from_xyz_yaw(*plan.waypoints[0])
    nbv.plan(vmap, T)  # the vehicle's vertex: where the trip starts
    trip = nbv.reposition(vmap, T)
    graph = nbv.graph
    assert len(trip.waypoints) >= 1 and trip.score > 0
    index = {tuple(v): k for k, v in enumerate(graph.states)}
    hops = [graph.last_visit] + [index[tuple(w)] for w in trip.waypoints]
    pairs = {(i, j) for i, j, _ in graph.edges} | {(j, i) for i, j, _ in graph.edges}
    assert all((a, b) in pairs for a, b in zip(hops[:-1], hops[1:]))
    target = hops[-1]
    assert not graph.visited[target]
    parent = graph.states[graph.parent[target]]
    again = planner.edge_gain(
        vmap, parent[None], graph.states[target][None], SONAR, config.gain_step_m, config.gain_range_m
    )
    assert trip.gain_m3 == pytest.approx(again.unknown_m3[0], rel=1e-12)
    a, b = graph.states[[e[0] for e in graph.edges]], graph.states[[e[1] for e in graph.edges]]
    turn = np.abs((b[:, 3] - a[:, 3] + np.pi) % (2 * np.pi) - np.pi)
    seconds = np.maximum(np.linalg.norm(b[:, :3] - a[:, :3], axis=1) / 0.25, turn / 0.15) + config.edge_overhead_s
    times = shortest_seconds(len(graph.states), [e[:2] for e in graph.edges], seconds, graph.last_visit)
    assert trip.branch_s == pytest.approx(times[target], rel=1e-9)
    pool = graph.candidates(graph.states[graph.last_visit, :3], 48, config.edge_length_m)
    gains = graph.promised[pool]  # counted again by the step
    assert trip.score == pytest.approx(np.max(gains / times[pool]), rel=1e-9)
    flown = {(i, j) for i, j, f in graph.edges if f} | {(j, i) for i, j, f in graph.edges if f}
    box = np.array(config.checked_box_m)
    for a_, b_ in zip(hops[:-1], hops[1:]):
        if (a_, b_) not in flown:
            start, end = graph.states[a_, :3], graph.states[b_, :3]
            assert brute_clear(vmap, start, end, box, start, config.clearance_m, True, config.obstacle_margins_m())
    # the papers' rule keeps no graph and takes no global step
    papers = planner.NbvPlanner(SMALL, bounds=BOUNDS, sensor=SONAR)
    papers.plan(vmap, T)
    assert len(papers.graph) == 0 and len(papers.reposition(vmap, T).waypoints) == 0


def test_risk_hook_discounts_every_edge():
    rng = np.random.default_rng(9)
    vmap = room_map(rng)
    T = pose_from_xyz_yaw(0.0, 0.0, 0.0, 0.0)
    plain = planner.NbvPlanner(SMALL, bounds=BOUNDS, sensor=SONAR).plan(vmap, T)
    seen = []

    def risk(starts, ends):
        seen.append(len(starts))
        return np.full(len(starts), 0.5)

    risky = planner.NbvPlanner(SMALL.replace(risk_weight=2.0), bounds=BOUNDS, sensor=SONAR, risk=risk).plan(vmap, T)
    np.testing.assert_array_equal(risky.tree_states, plain.tree_states)
    assert risky.gain_m3 == pytest.approx(plain.gain_m3 * np.exp(-1.0)) and sum(seen) == plain.nodes
    with pytest.raises(ValueError, match="risk"):
        planner.NbvPlanner(SMALL.replace(risk_weight=1.0), bounds=BOUNDS)
    with pytest.raises(ValueError, match="risk"):
        planner.NbvPlanner(
            SMALL.replace(risk_weight=1.0), bounds=BOUNDS, sensor=SONAR, risk=lambda s, e: -np.ones(len(s))
        ).plan(vmap, T)


def test_planner_rejects_bad_input():
    with pytest.raises(ValueError, match="bounds"):
        planner.NbvPlanner(SMALL)
    with pytest.raises(ValueError, match="bounds"):
        planner.NbvPlanner(SMALL, bounds=[[0, 0, 0], [0.5, 3, 3]])
    with pytest.raises(ValueError, match="tolerance_nodes"):
        planner.PlannerConfig(max_nodes=20, tolerance_nodes=10)
    nbv = planner.NbvPlanner(SMALL, bounds=BOUNDS)
    with pytest.raises(ValueError, match="T_world_vehicle"):
        nbv.plan(vj.VoxelMap(), np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="map"):
        nbv.plan("map", np.eye(4))


def test_edge_seconds_and_the_drift_margin_follow_their_formulas():
    config = planner.PlannerConfig(max_speed_mps=0.5, max_yaw_rate_rps=0.2, edge_overhead_s=0.7)
    rng = np.random.default_rng(11)
    length, turn = rng.uniform(0, 3, 50), rng.uniform(-np.pi, np.pi, 50)
    expected = [max(a / 0.5, abs(b) / 0.2) + 0.7 for a, b in zip(length, turn)]  # FUEL's time, plus the stop
    np.testing.assert_allclose(config.edge_seconds(length, turn), expected, rtol=1e-12)
    assert config.edge_seconds(1.0, 0.0) == pytest.approx(2.7)
    margins = planner.PlannerConfig(obstacle_margin_m=0.1, drift_margin_sigmas=2.0, max_drift_margin_m=0.5)
    assert margins.obstacle_margins_m() == (0.1, 0.1, 0.0)
    assert margins.obstacle_margins_m(0.2) == pytest.approx((0.5, 0.5, 0.0))
    assert margins.obstacle_margins_m(3.0) == pytest.approx((0.6, 0.6, 0.0))  # capped at 0.5 m of drift margin
    with pytest.raises(ValueError, match="drift_m"):
        planner.NbvPlanner(SMALL, bounds=BOUNDS, sensor=SONAR).plan(room_map(rng), np.eye(4), drift_m=-0.1)


def test_a_plan_keeps_occupied_voxels_off_by_the_drift_margin_and_is_regrown_when_it_blocks():
    rng = np.random.default_rng(7)
    vmap = room_map(rng)
    T = pose_from_xyz_yaw(0.1, -0.2, 0.1, 0.4)
    config = SMALL.replace(**TIME_RULE, drift_margin_sigmas=1.0, max_drift_margin_m=0.4)

    def edges(plan):
        return [(plan.tree_states[parent], plan.tree_states[n]) for n, parent in enumerate(plan.tree_parents) if n]

    def clear(a, b, margins):
        return brute_clear(vmap, a[:3], b[:3], np.array(config.checked_box_m), T[:3, 3], 0.6, True, margins)

    # every edge of a plan under 0.4 m of drift clears the wider margin (brute force), while some
    # edge of the plan without drift would not
    wide = config.obstacle_margins_m(0.4)
    drifted = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR).plan(vmap, T, drift_m=0.4)
    assert drifted.score > 0 and drifted.nodes >= SMALL.max_nodes
    assert all(clear(a, b, wide) for a, b in edges(drifted))
    plain = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR).plan(vmap, T)
    assert not all(clear(a, b, wide) for a, b in edges(plain))
    # a shortest edge longer than any edge blocks the tree: it is grown again with the base
    # margins and no shortest edge, and each of its edges clears those
    blocked = config.replace(min_edge_length_m=2 * config.edge_length_m)
    regrown = planner.NbvPlanner(blocked, bounds=BOUNDS, sensor=SONAR).plan(vmap, T, drift_m=0.4)
    assert regrown.nodes >= SMALL.max_nodes and regrown.score > 0
    assert all(clear(a, b, config.obstacle_margins_m()) for a, b in edges(regrown))
    assert not all(clear(a, b, wide) for a, b in edges(regrown))


def test_a_plan_refused_midway_leaves_the_planner_as_it_was():
    """A risk callable's NaN refused the plan after samples were drawn: the next plan differed
    from a fresh planner's, and the drift margins of the refused plan stayed."""
    rng = np.random.default_rng(9)
    vmap = room_map(rng)
    T = pose_from_xyz_yaw(0.0, 0.0, 0.0, 0.0)
    calls = []

    def risk(starts, ends):
        calls.append(len(starts))
        return np.full(len(starts), np.nan if len(calls) == 2 else 0.5)

    config = SMALL.replace(risk_weight=1.0)
    fresh = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR, risk=risk)
    tried = planner.NbvPlanner(config, bounds=BOUNDS, sensor=SONAR, risk=risk)
    margins = tried._obstacle_margins
    calls.clear()
    calls.append(0)  # the next call is the second: NaN
    with pytest.raises(ValueError, match="risk"):
        tried.plan(vmap, T, drift_m=0.4)
    assert tried._obstacle_margins == margins
    calls.clear()
    calls.extend([0, 0])  # no NaN from here on
    again = tried.plan(vmap, T)
    first = fresh.plan(vmap, T)
    np.testing.assert_array_equal(again.tree_states, first.tree_states)
