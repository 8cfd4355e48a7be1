"""Long rays and long lines (issue 17, item 1): any range finds what is in the map, huge or tiny
directions normalise, unknown stretches are counted without walking them, line queries refuse
lines too long to allocate. References: an analytic wall and the brute-force walk of
tests/reference.py."""

import numpy as np
import pytest

import vogjax as vj
from vogjax.kernels import hashing
from vogjax.maps import blockmap

from . import reference as ref

CFG = vj.MapConfig(voxel_size=0.1)


def wall_map(cls=vj.VoxelMap):
    """A wall of occupied voxels at x in [3.0, 3.1), seen three times from (0.05, 0.05, 0.05)."""
    ys, zs = np.meshgrid(np.arange(-5, 5) * 0.1 + 0.05, np.arange(-5, 5) * 0.1 + 0.05)
    wall = np.stack([np.full(ys.size, 3.05), ys.ravel(), zs.ravel()], axis=1)
    origins = np.tile([0.05, 0.05, 0.05], (3, 1))
    points = np.concatenate([wall] * 3)
    scans = np.repeat(np.arange(3), wall.shape[0])
    if cls is vj.VoxelMap:
        vmap = vj.VoxelMap(CFG)
        vmap.integrate_scans(origins, points, scans)
        return vmap
    vog = vj.VogMap(CFG)
    vog.add_submap(np.eye(4))
    vog.submap(0).integrate_scans(origins, points, scans)
    if cls is vj.VogMap:
        return vog
    gmap = vj.GlobalMap(CFG)
    gmap.merge(vog)
    return gmap


@pytest.mark.parametrize("cls", [vj.VoxelMap, vj.GlobalMap, vj.VogMap])
@pytest.mark.parametrize("max_range", [5.0, 7.2e7, 1e300])
def test_any_range_finds_the_wall(cls, max_range):
    # 3 * int(7.2e7 / 0.1) overflowed int32: the walk took no step and missed the wall.
    r = wall_map(cls).raycast([[0.05, 0.05, 0.05]], [[1.0, 0.0, 0.0]], max_range)
    assert r.hit.tolist() == [True]
    assert abs(r.distance[0] - 2.95) < 1e-6
    assert r.num_free[0] == 30 and r.num_unknown[0] == 0


@pytest.mark.parametrize("cls", [vj.VoxelMap, vj.GlobalMap, vj.VogMap])
@pytest.mark.parametrize("scale", [1e200, 1e-200, 1e-320])
def test_huge_and_tiny_directions_normalise(cls, scale):
    # |[1e200, 0, 0]| overflowed to inf and the direction became zero.
    r = wall_map(cls).raycast([[0.05, 0.05, 0.05]] * 2, [[scale, 0.0, 0.0], [scale, scale * 1e-3, 0.0]], 10.0)
    assert r.hit.tolist() == [True, True]
    assert abs(r.distance[0] - 2.95) < 1e-6
    np.testing.assert_allclose(
        blockmap.unit_directions(np.array([[scale, scale, 0.0]])), [[2**-0.5, 2**-0.5, 0.0]], rtol=1e-15
    )


@pytest.mark.parametrize("cls", [vj.VoxelMap, vj.GlobalMap, vj.VogMap])
def test_unknown_space_beyond_the_map_is_counted_up_to_the_key_range(cls):
    # Away from the wall: the map's voxels first (origin voxel free), then unknown voxels to
    # the end of the key range, 2^23 voxels from the origin along -x; none walked one by one.
    r = wall_map(cls).raycast(
        [[0.05, 0.05, 0.05], [0.05, 0.05, 0.05]], [[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], [7.2e7, 1000.1]
    )
    assert r.hit.tolist() == [False, False]
    assert r.distance.tolist() == [np.float32(7.2e7), np.float32(1000.1)]
    assert r.num_free.tolist() == [1, 1]
    # voxels -1, ..., -(2^23) (the last one inside the key range); and -1 .. -10001, entered
    # before 1000.1 m (voxel -k is entered at 0.05 + 0.1 (k - 1) m)
    assert r.num_unknown.tolist() == [hashing.VOXEL_KEY_LIMIT, 10001]


@pytest.mark.parametrize("level", [0, 2])
def test_ranges_either_side_of_the_key_range_shortcut_count_the_same_walk(level):
    # A ray's end is its range without the key range's distances when 2 (|origin| + range) stays
    # under the key range's half-width (queries.ray_cast_start): ranges just under and just
    # over that bound, and past the key range's face, against the count of voxels -1, -2, ...
    # along -x entered before the range (voxel -k at 0.05 + s (k - 1) m, s the level's edge).
    size = 0.1 * 2**level
    limit = hashing.VOXEL_KEY_LIMIT >> level  # the key range's half-width in this level's voxels
    bound = limit * size  # the same metres at every level
    under, over = bound / 2 - 0.05 - 0.5 * size, bound / 2 - 0.05 + 0.5 * size
    vmap = wall_map(vj.VoxelMap)
    ranges = [under, over, bound + 1.0]
    origins, directions = [[0.05, 0.05, 0.05]] * 3, [[-1.0, 0.0, 0.0]] * 3
    r = vmap.raycast(origins, directions, ranges, level=level)
    # voxel 0 of every level holds the origin and starts at x = 0, so voxel -1 is entered at 0.05
    expected = [int(np.ceil((x - 0.05) / size)) for x in ranges[:2]] + [limit]
    assert r.hit.tolist() == [False] * 3
    assert (r.num_free + r.num_unknown).tolist() == [e + 1 for e in expected]


def scattered_map():
    rng = np.random.default_rng(7)
    cfg = vj.MapConfig(voxel_size=0.2, max_range=30.0)
    origins, points, scan = ref.random_scans(rng, 6, 80, spread=5.0)
    vmap, cells = vj.VoxelMap(cfg), {}
    vmap.integrate_scans(origins, points, scan)
    for s in range(6):
        ref.insert_scan(cells, origins[s], points[scan == s], cfg)
    return vmap, cells, cfg, rng


def test_long_rays_from_inside_and_outside_match_the_step_by_step_walk():
    # Ranges of 30-200 m and origins up to 60 m away from a map a few metres wide: stretches
    # before and after the map are skipped in closed form, the reference walks every voxel.
    vmap, cells, cfg, rng = scattered_map()
    inside = rng.uniform(-1, 1, (60, 3))
    outside = rng.normal(size=(60, 3))
    outside = 40 * outside / np.linalg.norm(outside, axis=1, keepdims=True) + rng.uniform(-1, 1, (60, 3))
    toward = -outside + rng.normal(scale=0.05, size=(60, 3))  # aimed at the map, most cross it
    origins = np.concatenate([inside, outside])
    directions = np.concatenate([rng.normal(size=(60, 3)), toward])
    ranges = rng.uniform(30.0, 200.0, 120)
    result = vmap.raycast(origins, directions, ranges)
    expected = [ref.raycast(cells, o, d, r, cfg) for o, d, r in zip(origins, directions, ranges)]
    hit, distance, unknown, free = (np.array(x) for x in zip(*expected))
    np.testing.assert_array_equal(result.hit, hit)
    np.testing.assert_allclose(result.distance, distance, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(result.num_free, free)
    np.testing.assert_array_equal(result.num_unknown, unknown)
    # both kinds of skip exercised: long unknown stretches after the map and before it
    assert (unknown[:60] > 100).sum() > 30 and (unknown[60:] > 100).sum() > 50 and 10 < hit[60:].sum() < 60


def test_line_query_refuses_lines_too_long_to_allocate():
    vmap = wall_map()
    longest = (blockmap.MAX_LINE_VOXELS - 1) * 0.1  # along x from voxel 0: the last voxel allowed
    values, lengths = vmap.line_query([[0.05, 0.05, 0.05]], [[0.05 + longest, 0.05, 0.05]])
    assert lengths.tolist() == [blockmap.MAX_LINE_VOXELS]
    assert values[0, 30] == CFG.log_clamp_max or values[0, 30] > CFG.log_occupied
    for m in (vmap, wall_map(vj.VogMap)):
        with pytest.raises(ValueError, match="ends: line 1 crosses 16000001 voxels"):  # 1600 km
            m.line_query([[0.0, 0.0, 0.0], [-8e5, 0.0, 0.0]], [[1.0, 0.0, 0.0], [8e5, 0.0, 0.0]])


def test_ray_origins_outside_the_key_range_are_refused():
    for m in (wall_map(), wall_map(vj.VogMap)):
        with pytest.raises(ValueError, match="origins lies too far"):
            m.raycast([[1e7, 0.0, 0.0]], [[1.0, 0.0, 0.0]], 1.0)
