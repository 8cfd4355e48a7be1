"""Loop closures for odometry whose yaw drifts (`[loop_closure.icp] free = "yaw"`): ICP solves the
yaw with the translation while pitch and roll stay held, the x-y gate widens by the path's lever
on the yaw drift (checked against a Monte Carlo of that drift), and a result whose yaw is further
from the navigation's than the yaw noise allows is rejected as "yaw drift", with its figure."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.test_slam import structured_cloud
from vogjax import slam
from vogjax.config import NavNoise
from vogjax.slam.loop_closure import _yaw_lever_m2


def transform(yaw=0.0, pitch=0.0, roll=0.0, xyz=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()
    T[:3, 3] = xyz
    return T


def test_icp_solving_the_yaw_recovers_it_and_holds_pitch_and_roll():
    rng = np.random.default_rng(5)
    target = structured_cloud(rng, 3000)
    truth = transform(yaw=0.04, xyz=(0.15, -0.1, 0.02))
    source = (target - truth[:3, 3]) @ truth[:3, :3]
    tilted = transform(pitch=0.01, roll=-0.008)  # the start's tilt: held, right or wrong
    config = slam.IcpConfig(free="yaw", max_correspondence_m=0.5)
    result = slam.icp(source, target, tilted, config=config)
    assert result.converged
    # only turned about its own z axis: that axis (the tilt) is where it started
    np.testing.assert_allclose(result.T_target_source[:3, 2], tilted[:3, 2], atol=1e-12)
    yaw = np.arctan2(result.T_target_source[1, 0], result.T_target_source[0, 0])
    assert abs(yaw - 0.04) < 5e-3  # the yaw found, within the held tilt's bias
    # the reference: the same pair with all six directions free lands on the truth
    free = slam.icp(source, target, np.eye(4), config=slam.IcpConfig(free="all", max_correspondence_m=0.5))
    np.testing.assert_allclose(free.T_target_source, truth, atol=2e-3)
    level = slam.icp(source, target, np.eye(4), config=config)
    np.testing.assert_allclose(level.T_target_source, truth, atol=2e-3)
    # holding the yaw (the papers' closures) leaves it where it started
    held = slam.icp(source, target, np.eye(4), config=slam.IcpConfig(free="translation", max_correspondence_m=0.5))
    np.testing.assert_allclose(held.T_target_source[:3, :3], np.eye(3), atol=1e-12)


def test_the_yaw_lever_is_the_variance_a_drifting_yaw_leaves_monte_carlo():
    rng = np.random.default_rng(0)
    count = 40
    times = np.cumsum(rng.uniform(5.0, 15.0, count))
    poses = np.stack([transform(xyz=(x, y, 0.0)) for x, y in rng.uniform(-10, 10, (count, 2))])
    i, k, sigma2_yaw = 3, 35, 1e-7
    lever = _yaw_lever_m2(i, k, poses, times)
    # brute force: each step's yaw increment turns the rest of the path about where it was taken
    trials = 20_000
    dt = np.diff(times[i : k + 1])
    positions = poses[i : k + 1, :2, 3]
    angles = rng.normal(0.0, 1.0, (trials, len(dt))) * np.sqrt(sigma2_yaw * dt)
    end = np.repeat(positions[-1][None], trials, axis=0)
    for j in reversed(range(len(dt))):  # the last turn first: each rotates what follows it
        c, s = np.cos(angles[:, j]), np.sin(angles[:, j])
        arm = end - positions[j]
        end = positions[j] + np.stack([c * arm[:, 0] - s * arm[:, 1], s * arm[:, 0] + c * arm[:, 1]], axis=1)
    measured = np.mean(np.sum((end - positions[-1]) ** 2, axis=1))
    assert measured == pytest.approx(sigma2_yaw * lever, rel=0.05)


def revisit(yaw_off):
    """Submap 2 sees submap 0's place again 200 s later; navigation's yaw is `yaw_off` wrong."""
    rng = np.random.default_rng(8)
    cloud = structured_cloud(rng, 6000)
    truth_k = transform(yaw=0.0, xyz=(0.4, 0.3, 0.0))
    clouds = [cloud, cloud[:10], (cloud - truth_k[:3, 3]) @ truth_k[:3, :3]]
    box = (cloud.min(axis=0) - 0.1, cloud.max(axis=0) + 0.1)
    bounds = [box, None, box]
    nav = np.stack([np.eye(4), transform(xyz=(20.0, 0.0, 0.0)), truth_k @ transform(yaw=yaw_off, xyz=(0.3, 0.2, 0))])
    return clouds, bounds, nav, np.array([0.0, 100.0, 200.0]), truth_k


def test_a_yaw_solving_closure_corrects_a_drifted_yaw_within_the_noise():
    clouds, bounds, nav, times, truth_k = revisit(0.03)
    config = slam.LoopClosureConfig(icp=slam.IcpConfig(free="yaw", max_correspondence_m=0.3, tolerance=1e-3))
    noise = NavNoise(sigma2_x=1e-3, sigma2_y=1e-3, sigma2_yaw=1e-5)
    accepted, rejected = slam.LoopClosureDetector(noise, config).detect(2, clouds, bounds, nav, nav, times)
    assert [(c.i, c.k) for c in accepted] == [(0, 2)] and not rejected
    np.testing.assert_allclose(accepted[0].T_i_k, truth_k, atol=0.02)
    # the translation-only closure of the papers keeps the wrong yaw
    (closure,), _ = slam.LoopClosureDetector(noise).detect(2, clouds, bounds, nav, nav, times)
    assert abs(np.arctan2(closure.T_i_k[1, 0], closure.T_i_k[0, 0]) - 0.03) < 1e-9


def test_a_yaw_further_off_than_the_yaw_noise_allows_is_rejected_with_its_figure():
    clouds, bounds, nav, times, _ = revisit(0.03)
    config = slam.LoopClosureConfig(icp=slam.IcpConfig(free="yaw", max_correspondence_m=0.3, tolerance=1e-3))
    # a gyro-grade yaw: 3 sigma over 200 s is 1.3 mrad, and the result turns navigation by 30
    noise = NavNoise(sigma2_x=1e-3, sigma2_y=1e-3, sigma2_yaw=1e-9)
    accepted, rejected = slam.LoopClosureDetector(noise, config).detect(2, clouds, bounds, nav, nav, times)
    assert not accepted and [r.reason for r in rejected] == ["yaw drift"]
    assert rejected[0].limit == pytest.approx(3.0 * np.sqrt(1e-9 * 200.0))
    assert rejected[0].value == pytest.approx(0.03, abs=5e-3)


# counted into the keys' box, packed keys sorted, and keys too far apart to pack
@pytest.mark.parametrize("spread_m", [5.0, 500.0, 1e17])
def test_registration_clouds_are_the_voxel_means_bit_for_bit(spread_m):
    from vogjax.pipeline.mapper import voxel_means

    rng = np.random.default_rng(2)
    points = rng.uniform(-spread_m, spread_m, (20_000, 3))
    points[::3] = points[1::3][: len(points[::3])] + 0.01  # voxels of several points
    # the reference: every voxel's points summed in their order, voxels sorted by key row
    keys = np.floor(points / 0.4).astype(np.int64)
    rows, inverse = np.unique(keys, axis=0, return_inverse=True)
    sums = np.zeros((len(rows), 3))
    np.add.at(sums, inverse.reshape(-1), points)
    counts = np.bincount(inverse.reshape(-1), minlength=len(rows))
    np.testing.assert_array_equal(voxel_means(points, 0.4), sums / counts[:, None])


@pytest.mark.parametrize(
    "points, voxel_size, named",
    [
        ([[np.nan, 0.0, 0.0], [1.0, 1.0, 1.0]], 0.1, "points"),
        ([[0.0, 0.0]], 0.1, "points"),
        ([[1e300, 0.0, 0.0], [0.0, 0.0, 0.0]], 1e-300, "points"),  # keys past int64: wrapped, then crashed
        ([[0.0, 0.0, 0.0]], 0.0, "voxel_size"),  # every point fell in one "voxel"
        ([[0.0, 0.0, 0.0]], -0.4, "voxel_size"),
    ],
)
def test_registration_clouds_refuse_bad_input_naming_it(points, voxel_size, named):
    from vogjax.slam.clouds import voxel_means

    with pytest.raises(ValueError, match=f"^{named} "):
        voxel_means(np.asarray(points), voxel_size)
