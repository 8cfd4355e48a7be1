"""Point, ray and line queries against the brute-force reference."""

import numpy as np
import pytest
import warp as wp

import vogjax as vj

from . import reference as ref


def mapped_scene(seed=0, num_scans=8, beams=80):
    rng = np.random.default_rng(seed)
    cfg = vj.MapConfig(voxel_size=0.2)
    origins, points, scan = ref.random_scans(rng, num_scans, beams, spread=5.0)
    vmap, cells = vj.VoxelMap(cfg), {}
    vmap.integrate_scans(origins, points, scan)
    for s in range(num_scans):
        ref.insert_scan(cells, origins[s], points[scan == s], cfg)
    return vmap, cells, cfg, rng


def test_point_queries_match_reference():
    vmap, cells, cfg, rng = mapped_scene()
    queries = rng.uniform(-6, 6, (5000, 3)).astype(np.float32)
    keys = [ref.key_of(q, cfg.voxel_size) for q in queries]
    expected = np.array([cells.get(k, 0.0) for k in keys], np.float32)
    np.testing.assert_array_equal(vmap.log_odds(queries), expected)
    np.testing.assert_allclose(vmap.probability(queries), 1 - 1 / (1 + np.exp(expected.astype(float))), rtol=1e-6)
    states = np.array([ref.state_of(cells.get(k), cfg) for k in keys])
    np.testing.assert_array_equal(vmap.state(queries), states)
    assert {0, 1, 2} <= set(states.tolist())


def test_raycast_matches_reference():
    vmap, cells, cfg, rng = mapped_scene(seed=1)
    origins = rng.uniform(-1, 1, (400, 3))
    directions = rng.normal(size=(400, 3))
    ranges = rng.uniform(0.5, 6.0, 400)
    result = vmap.raycast(origins, directions, ranges)
    expected = [ref.raycast(cells, o, d, r, cfg) for o, d, r in zip(origins, directions, ranges)]
    hit, distance, unknown, free = (np.array(x) for x in zip(*expected))
    np.testing.assert_array_equal(result.hit, hit)
    np.testing.assert_allclose(result.distance, distance, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(result.num_unknown, unknown)
    np.testing.assert_array_equal(result.num_free, free)
    assert 50 < hit.sum() < 350  # both outcomes exercised


def test_raycast_threaded_split_equals_single_launch(monkeypatch):
    vmap, _, _, rng = mapped_scene(seed=2)
    origins = rng.uniform(-1, 1, (9000, 3))
    directions = rng.normal(size=(9000, 3))
    split = vmap.raycast(origins, directions, 4.0)
    monkeypatch.setattr(vj.maps.parallel, "MIN_ITEMS_PER_PART", 10**9)
    single = vmap.raycast(origins, directions, 4.0)
    for name in ("hit", "distance", "num_unknown", "num_free"):
        np.testing.assert_array_equal(getattr(split, name), getattr(single, name))


def test_raycast_of_rays_on_the_device_matches_reference():
    """Warp arrays in, Warp arrays out: on a VoxelMap against the brute-force reference, and on
    a VoxelMap and a GlobalMap bit for bit what the NumPy path answers; float64 (R,3) and
    vec3d rays, one range for all or one per ray."""
    vmap, cells, cfg, rng = mapped_scene(seed=3)
    origins, points, scan = ref.random_scans(np.random.default_rng(3), 8, 80, spread=5.0)
    vog = vj.VogMap(cfg)
    vog.submap(vog.add_submap(np.eye(4))).integrate_scans(origins, points, scan)
    global_map = vj.GlobalMap(cfg)
    global_map.merge(vog)
    origins = rng.uniform(-1, 1, (300, 3))
    directions = rng.normal(size=(300, 3))
    ranges = rng.uniform(0.5, 6.0, 300)
    for m in (vmap, global_map):
        for per_ray in (False, True):
            max_range = wp.array(ranges, dtype=wp.float64, device=m.device) if per_ray else 4.0
            d_origins = wp.array(origins, dtype=wp.float64, device=m.device)
            d_directions = wp.array(directions, dtype=wp.vec3d, device=m.device)
            result = m.raycast(d_origins, d_directions, max_range)
            assert all(isinstance(getattr(result, name), wp.array) for name in ("hit", "distance", "num_unknown"))
            host = m.raycast(origins, directions, ranges if per_ray else 4.0)
            for name in ("hit", "distance", "num_unknown", "num_free"):
                np.testing.assert_array_equal(getattr(result, name).numpy(), getattr(host, name))
            if m is vmap:
                expected = [
                    ref.raycast(cells, o, d, r if per_ray else 4.0, cfg) for o, d, r in zip(origins, directions, ranges)
                ]
                hit, distance, unknown, free = (np.array(x) for x in zip(*expected))
                np.testing.assert_array_equal(result.hit.numpy(), hit)
                np.testing.assert_allclose(result.distance.numpy(), distance, rtol=1e-6, atol=1e-6)
                np.testing.assert_array_equal(result.num_unknown.numpy(), unknown)
                np.testing.assert_array_equal(result.num_free.numpy(), free)
                assert 30 < hit.sum() < 270
    empty = vmap.raycast(wp.zeros((0, 3), dtype=wp.float64), wp.zeros((0, 3), dtype=wp.float64), 1.0)
    assert empty.hit.shape == (0,)


def _bad_rays(fault: str, rng, device):
    origins, directions, ranges = rng.uniform(-1, 1, (50, 3)), rng.normal(size=(50, 3)), rng.uniform(1, 2, 50)
    if fault == "nan origin":
        origins[31, 1] = np.nan
    elif fault == "far origin":
        origins[31, 2] = -1e7
    elif fault == "infinite direction":
        directions[31, 0] = np.inf
    elif fault == "zero direction":
        directions[31] = 0.0
    elif fault == "zero range":
        ranges[31] = 0.0
    elif fault == "nan range":
        ranges[31] = np.nan
    return (
        wp.array(origins, dtype=wp.float64, device=device),
        wp.array(directions, dtype=wp.float64, device=device),
        wp.array(ranges, dtype=wp.float64, device=device),
    )


@pytest.mark.parametrize(
    "fault, message",
    [
        ("nan origin", "origins: ray 31"),
        ("far origin", "origins: ray 31"),
        ("infinite direction", "directions: ray 31"),
        ("zero direction", "directions: ray 31"),
        ("zero range", "max_range: ray 31"),
        ("nan range", "max_range: ray 31"),
    ],
)
def test_raycast_on_the_device_refuses_bad_rays_naming_the_first(fault, message):
    vmap, _, _, rng = mapped_scene(seed=4)
    with pytest.raises(ValueError, match=message):
        vmap.raycast(*_bad_rays(fault, rng, vmap.device))


def test_raycast_on_the_device_refuses_wrong_arrays():
    vmap, _, _, rng = mapped_scene(seed=5)
    good = wp.array(rng.normal(size=(20, 3)), dtype=wp.float64, device=vmap.device)
    cases = [
        ((good, good, np.ones(20)), "max_range must be a number or a float64 Warp array"),
        ((good, good, [3.0]), "max_range must be a number or a float64 Warp array"),
        (
            (wp.array(rng.normal(size=(20, 3)), dtype=wp.float32, device=vmap.device), good, 1.0),
            "origins must be a contiguous float64",
        ),
        (
            (good, wp.array(rng.normal(size=(19, 3)), dtype=wp.float64, device=vmap.device), 1.0),
            r"directions must .* shape \(20, 3\)",
        ),
        ((good, rng.normal(size=(20, 3)), 1.0), "directions must be a Warp array too"),
        ((rng.normal(size=(20, 3)), good, 1.0), "origins must be a Warp array too"),
        (
            (good, good, wp.array(np.ones(19), dtype=wp.float64, device=vmap.device)),
            "max_range must be a float64 Warp array of shape",
        ),
        (
            (good, good, wp.array(np.ones(20), dtype=wp.float32, device=vmap.device)),
            "max_range must be a float64 Warp array",
        ),
        ((good, good, float("nan")), "max_range must be positive"),
        ((good[::2], good[::2], 1.0), "origins must be a contiguous"),
    ]
    for args, message in cases:
        with pytest.raises(ValueError, match=message):
            vmap.raycast(*args)


def test_raycast_on_the_device_draws_the_key_range_where_the_numpy_path_does():
    """At the edge of the key range both paths accept and refuse the same origins (the same
    float64 division), and a single ray works."""
    cfg = vj.MapConfig(voxel_size=0.5403036408139767)
    vmap = vj.VoxelMap(cfg)
    edge = (vj.kernels.hashing.VOXEL_KEY_LIMIT - 2) * cfg.voxel_size
    outcomes = set()
    for x in (4532394.36315397, np.nextafter(edge, 0), edge, np.nextafter(edge, np.inf), -edge, 1.0):
        origin, direction = np.array([[x, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]])
        try:
            host = vmap.raycast(origin, direction, 2.0)
        except ValueError:
            host = None
        try:
            device = vmap.raycast(
                wp.array(origin, dtype=wp.float64, device=vmap.device),
                wp.array(direction, dtype=wp.float64, device=vmap.device),
                2.0,
            )
        except ValueError as error:
            assert "origins: ray 0" in str(error)
            device = None
        assert (host is None) == (device is None), x
        outcomes.add(host is None)
        if host is not None:
            assert device.num_unknown.numpy()[0] == host.num_unknown[0] > 0
    assert outcomes == {True, False}  # both sides of the edge were tried


def test_raycast_analytic_wall():
    # A wall of occupied voxels at x in [2.0, 2.1): rays along +x from x=0.05 enter it at 1.95 m.
    cfg = vj.MapConfig(voxel_size=0.1)
    vmap = vj.VoxelMap(cfg)
    ys, zs = np.meshgrid(np.arange(-5, 5) * 0.1 + 0.05, np.arange(-5, 5) * 0.1 + 0.05)
    wall = np.stack([np.full(ys.size, 2.05), ys.ravel(), zs.ravel()], axis=1)
    origin = np.array([0.05, 0.05, 0.05])
    for _ in range(3):
        vmap.integrate_scan(origin, wall)
    r = vmap.raycast(np.tile(origin, (2, 1)), [[1, 0, 0], [-1, 0, 0]], 5.0)
    assert r.hit.tolist() == [True, False]
    assert abs(r.distance[0] - 1.95) < 1e-6 and r.distance[1] == 5.0
    assert r.num_free[0] == 20 and r.num_unknown[0] == 0  # voxels 0..19 are free
    # Backwards: the origin voxel (free), then voxels -1..-50, entered at 0.05, 0.15, ..., 4.95 m.
    assert r.num_free[1] == 1 and r.num_unknown[1] == 50


def test_line_query_matches_reference():
    vmap, cells, cfg, rng = mapped_scene(seed=3)
    starts = rng.uniform(-3, 3, (200, 3)).astype(np.float32)
    ends = rng.uniform(-3, 3, (200, 3)).astype(np.float32)
    ends[0] = starts[0]  # a line inside one voxel
    values, lengths = vmap.line_query(starts, ends)
    for i in range(200):
        expected = ref.line_values(cells, starts[i], ends[i], cfg)
        assert lengths[i] == len(expected)
        np.testing.assert_array_equal(values[i, : lengths[i]], np.float32(expected))
        assert np.all(np.isnan(values[i, lengths[i] :]))
    assert lengths[0] == 1


def test_queries_on_empty_map_and_far_away_answer_unknown():
    vmap = vj.VoxelMap()
    far = np.array([[1e5, -1e5, 3e5], [0.0, 0.0, 0.0]])
    assert vmap.state(far).tolist() == [vj.UNKNOWN, vj.UNKNOWN]
    assert vmap.log_odds(far).tolist() == [0.0, 0.0]
    assert vmap.probability(far).tolist() == [0.5, 0.5]
    r = vmap.raycast(far, [[1, 0, 0], [0, 0, 1]], 4.0)
    assert not r.hit.any() and r.distance.tolist() == [4.0, 4.0]
    assert r.num_unknown[1] == 40 and r.num_free[1] == 0
    vmap.integrate_scan(np.zeros(3), np.ones((1, 3)))
    assert vmap.state(far[:1]).tolist() == [vj.UNKNOWN]


def test_voxels_reports_every_observed_voxel_once():
    vmap, cells, cfg, _ = mapped_scene(seed=4)
    centres, values = vmap.voxels()
    keys = [tuple(k) for k in np.floor(centres / cfg.voxel_size).astype(int).tolist()]
    assert len(set(keys)) == len(keys) == len(cells)
    assert all(cells[k] == v for k, v in zip(keys, values))
