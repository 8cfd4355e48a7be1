"""Bad input raises ValueError naming the argument and leaves the map unchanged."""

import numpy as np
import pytest

import vogjax as vj


@pytest.fixture
def vmap():
    m = vj.VoxelMap()
    m.integrate_scan(np.zeros(3), np.random.default_rng(0).normal(size=(50, 3)))
    return m


def unchanged(m, before):
    after = m.voxels()
    return np.array_equal(before[0], after[0]) and np.array_equal(before[1], after[1])


nan_points = np.array([[1.0, np.nan, 0.0]])
inf_points = np.array([[1.0, 0.0, np.inf]])
good = np.ones((2, 3))


@pytest.mark.parametrize(
    "call, argument",
    [
        (lambda m: m.integrate_scan([0, 0, np.nan], good), "origin"),
        (lambda m: m.integrate_scan(np.zeros(3), nan_points), "points"),
        (lambda m: m.integrate_scan(np.zeros(3), inf_points), "points"),
        (lambda m: m.integrate_scan(np.zeros(2), good), "origin"),
        (lambda m: m.integrate_scan(np.zeros(3), np.ones((2, 2))), "points"),
        (lambda m: m.integrate_scan(np.zeros(3), np.ones(6)), "points"),
        (lambda m: m.integrate_scan(np.zeros(3), np.array([["a", "b", "c"]])), "points"),
        (lambda m: m.integrate_scan(np.zeros(3), np.ones((2, 3), dtype=bool)), "points"),
        (lambda m: m.integrate_scan(np.zeros(3), np.ones((2, 3), dtype=complex)), "points"),
        (lambda m: m.integrate_scan(np.zeros(3), np.full((1, 3), 1e7)), "points"),
        (lambda m: m.integrate_scans(np.zeros((2, 3)), good, [0, 2]), "scan_index"),
        (lambda m: m.integrate_scans(np.zeros((2, 3)), good, [0]), "scan_index"),
        (lambda m: m.integrate_scans(np.zeros((2, 3)), good, [0.0, 1.0]), "scan_index"),
        (lambda m: m.integrate_scans(np.zeros((2, 3)), good, [-1, 0]), "scan_index"),
        (lambda m: m.integrate_scans(np.full((2, 3), np.nan), good, [0, 1]), "origins"),
        (lambda m: m.integrate_scans(np.zeros((2, 3)), inf_points, [0]), "points"),
        (lambda m: m.raycast(good, good, 0.0), "max_range"),
        (lambda m: m.raycast(good, good, -1.0), "max_range"),
        (lambda m: m.raycast(good, good, np.inf), "max_range"),
        (lambda m: m.raycast(good, good, [1.0, -2.0]), "max_range"),
        (lambda m: m.raycast(good, good, [1.0]), "max_range"),
        (lambda m: m.raycast(good, np.zeros((2, 3)), 1.0), "directions"),
        (lambda m: m.raycast(good, np.ones((3, 3)), 1.0), "directions"),
        (lambda m: m.raycast(nan_points, np.ones((1, 3)), 1.0), "origins"),
        (lambda m: m.state(nan_points), "points"),
        (lambda m: m.log_odds(np.ones((4, 2))), "points"),
        (lambda m: m.line_query(good, np.ones((3, 3))), "ends"),
        (lambda m: m.line_query(inf_points, np.ones((1, 3))), "starts"),
    ],
)
def test_bad_input_raises_naming_the_argument(vmap, call, argument):
    before = vmap.voxels()
    with pytest.raises(ValueError, match=argument):
        call(vmap)
    assert unchanged(vmap, before)


@pytest.mark.parametrize(
    "field, value",
    [
        ("voxel_size", 0.0),
        ("voxel_size", -0.1),
        ("voxel_size", float("nan")),
        ("max_range", 0.0),
        ("max_range", -5.0),
        ("prob_hit", 1.0),
        ("prob_hit", 0.4),
        ("prob_miss", 0.6),
        ("clamp_min", 0.99),
        ("free_threshold", 0.8),
    ],
)
def test_bad_config_raises_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        vj.MapConfig(**{field: value})


def test_bad_constructor_arguments():
    with pytest.raises(ValueError, match="config"):
        vj.VoxelMap({"voxel_size": 0.1})
    with pytest.raises(ValueError, match="device"):
        vj.VoxelMap(device="cuda:7")
