"""The inconsistency measure and the variance-aware planning cost of the confidence-rich map."""

import numpy as np
import pytest

from tests.crm_reference import cone
from vogjax.config import SonarConfig
from vogjax.config.crm import CrmConfig
from vogjax.maps.confidence import ConfidenceMap
from vogjax.maps.confidence_cost import (
    choose_path,
    collision_risk,
    edge_risk,
    inconsistency,
    most_likely_ranges,
    path_cost,
)

CFG = CrmConfig(voxel_size=0.1, max_range=4.0, range_sigma_m=0.03, num_bins=8)


def wall_map(scans=15):
    """A wall at x in [2.0, 2.1) seen from the origin along +x, y in [-0.5, 0.5]."""
    crm = ConfidenceMap(CFG, "cpu")
    y = np.linspace(-0.5, 0.5, 41)
    for _ in range(scans):
        crm.integrate_scan(np.array([0.05, 0.0, 0.05]), np.stack([np.full_like(y, 2.05), y, np.full_like(y, 0.05)], 1))
    return crm


def test_inconsistency_is_the_error_beyond_two_sigma():
    mean = np.array([0.9, 0.1, 0.5, 0.02, 0.7])
    variance = np.array([0.01, 0.0, 0.09, 0.0001, 0.0])
    truth = np.array([0.0, 0.0, 1.0, 0.0, 1.0])
    # by hand: |e| - 2 sigma = 0.9 - 0.2, 0.1 - 0, 0.5 - 0.6 (< 0), 0.02 - 0.02 (0), 0.3 - 0
    assert inconsistency(mean, variance, truth) == pytest.approx(0.7 + 0.1 + 0.3)
    with pytest.raises(ValueError, match="variance"):
        inconsistency(mean, -variance - 1, truth)
    with pytest.raises(ValueError, match="truth"):
        inconsistency(mean, variance, truth[:2])


def test_collision_risk_is_mean_plus_variance():
    crm = wall_map()
    points = np.array([[1.05, 0.0, 0.05], [2.05, 0.0, 0.05], [9.0, 9.0, 9.0]])
    risk = collision_risk(crm, points)
    np.testing.assert_allclose(risk, crm.mean(points).astype(np.float64) + crm.variance(points), rtol=1e-7)
    assert risk[0] < 0.1 and risk[1] > 0.9  # known water, the wall
    assert risk[2] == pytest.approx(0.5 + CFG.prior_variance)  # unknown: riskier than water
    with pytest.raises(ValueError, match="crm"):
        collision_risk(object(), points)


def test_path_cost_sums_the_one_step_costs():
    crm = wall_map()
    through_water = np.array([[0.25 + 0.2 * i, 0.0, 0.05] for i in range(8)])
    into_wall = np.array([[1.25 + 0.2 * i, 0.0, 0.05] for i in range(8)])
    water, wall = path_cost(crm, through_water), path_cost(crm, into_wall)
    np.testing.assert_allclose(water.step_cost, collision_risk(crm, through_water), rtol=1e-7)
    assert water.total == pytest.approx(water.step_cost.sum())
    assert water.total < wall.total
    best, costs = choose_path(crm, [into_wall, through_water])
    assert best == 1 and costs[1] == pytest.approx(water.total)


def test_edge_risk_sums_the_voxels_a_segment_passes():
    crm = wall_map()
    rng = np.random.default_rng(8)
    starts = rng.uniform(-0.3, 2.5, (25, 3)) * [1, 0.4, 0.1]
    ends = starts + rng.normal(size=(25, 3)) * [1.0, 0.3, 0.05]
    ends[0] = starts[0]  # a point costs its voxel
    ends[1] = starts[1] + 1e-9  # so does a segment too short to hold a chord in any voxel
    starts[2], ends[2] = [0.1 - 0.75e-7, 0.05, 0.05], [0.1 + 0.75e-7, 0.05, 0.05]  # even across a plane
    # segments from a voxel corner to voxel edges and corners: not the voxels they only touch
    grid = np.stack(np.meshgrid([1.5, 2.2], [-0.3, 0.0, 0.2], [0.0, 0.1]), -1).reshape(-1, 3)
    starts, ends = np.r_[starts, np.zeros_like(grid)], np.r_[ends, grid]
    got = edge_risk(crm, starts, ends)
    for i in range(len(starts)):
        length = float(np.linalg.norm(ends[i] - starts[i]))
        voxels = cone(starts[i], (ends[i] - starts[i]) / max(length, 1e-300), length, CFG.voxel_size)
        if not voxels:
            expected = collision_risk(crm, starts[i : i + 1])[0]
        else:
            centres = np.array([(np.array(k) + 0.5) * CFG.voxel_size for k, _, _ in voxels])
            expected = collision_risk(crm, centres).sum()
        assert got[i] == pytest.approx(expected, rel=1e-6)
    through_wall = edge_risk(crm, np.array([[1.0, 0.0, 0.05]]), np.array([[3.0, 0.0, 0.05]]))
    short_of_it = edge_risk(crm, np.array([[0.0, 0.0, 0.05]]), np.array([[1.9, 0.0, 0.05]]))
    assert through_wall[0] > short_of_it[0]
    with pytest.raises(ValueError, match="ends"):
        edge_risk(crm, starts, ends[:3])


def test_most_likely_ranges_against_a_brute_force_walk():
    crm = wall_map()
    origin = np.array([0.05, 0.0, 0.05])
    slopes = np.r_[np.linspace(-0.2, 0.2, 9), np.linspace(0.5, 0.9, 5)]
    cleared = origin + np.c_[np.ones(5), slopes[9:], np.zeros(5)] * 9.0  # past max_range: no return
    for _ in range(10):
        crm.integrate_scan(origin, cleared)
    directions = np.c_[np.ones(len(slopes)), slopes, np.zeros(len(slopes))]
    got = most_likely_ranges(crm, np.tile(origin, (len(slopes), 1)), directions, 3.0)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    for i in range(len(slopes)):
        voxels = cone(origin, unit[i], 3.0, CFG.voxel_size)
        centres = np.array([(np.array(k) + 0.5) * CFG.voxel_size for k, _, _ in voxels])
        m = crm.mean(centres).astype(np.float64)
        reach = np.r_[1.0, np.cumprod(1 - m)]
        cause = m * reach[:-1]
        if reach[-1] > cause.max():
            assert np.isinf(got[i])
        else:
            _, t0, t1 = voxels[int(np.argmax(cause))]
            assert got[i] == pytest.approx(0.5 * (t0 + t1), abs=1e-9)
    assert np.all(np.abs(got[:9] - 2.05) < 0.15) and np.isinf(got[9:]).sum() >= 3  # the wall; cleared water


def test_predicted_map_rewards_looking_before_passing():
    """Eqs. 29-30: along a path whose sensor keeps looking at the water it will cross, the map
    predicted from the most likely readings is surer than the map as it is, so the path costs
    less; the map itself is untouched."""
    crm = wall_map(scans=4)
    before = crm.voxels()
    waypoints = np.array([[0.45 + 0.2 * i, 0.0, 0.05] for i in range(6)])
    poses = np.tile(np.eye(4), (6, 1, 1))
    poses[:, :3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # the sonar's fan (sensor x-z) horizontal
    poses[:, :3, 3] = [0.05, 0.0, 0.05]
    sonar = SonarConfig(beams=21, fov_deg=20.0, tilt_deg=0.0, min_range_m=0.1, max_range_m=4.0)
    now = path_cost(crm, waypoints)
    predicted = path_cost(crm, waypoints, T_world_sensor=poses, sensor=sonar)
    assert predicted.total < now.total
    assert np.all(predicted.variance < now.variance) and np.all(predicted.mean < now.mean)
    for a, b in zip(before, crm.voxels()):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="sensor"):
        path_cost(crm, waypoints, T_world_sensor=poses)
    with pytest.raises(ValueError, match="T_world_sensor"):
        path_cost(crm, waypoints, T_world_sensor=poses[:2], sensor=sonar)
