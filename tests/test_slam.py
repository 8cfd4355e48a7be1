"""SLAM backend: factor Jacobians, ICP, partial factors, loop closures, marginals, bad input."""

import re
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import vogjax as vj
from vogjax import slam
from vogjax.geometry import exp_se3 as _exp
from vogjax.geometry import inverse, log_se3
from vogjax.slam import factors

from .submap_helpers import random_pose


def numeric_jacobian(f, T, eps=1e-6):
    """d f(T Exp(xi)) / d xi by central differences (GTSAM's right perturbation)."""
    J = np.zeros((len(f(T)), 6))
    for j in range(6):
        step = np.zeros(6)
        step[j] = eps
        J[:, j] = (f(T @ _exp(step)) - f(T @ _exp(-step))) / (2 * eps)
    return J


@pytest.mark.parametrize("seed", range(5))
def test_factor_jacobians_match_numerical_ones(seed):
    rng = np.random.default_rng(seed)
    T_a, T_b = random_pose(rng, tilt=0.4), random_pose(rng, tilt=0.4)
    J_a, J_b = factors.xyh_jacobians(T_a, T_b)
    np.testing.assert_allclose(J_a, numeric_jacobian(lambda T: factors.xyh(T, T_b), T_a), atol=1e-6)
    np.testing.assert_allclose(J_b, numeric_jacobian(lambda T: factors.xyh(T_a, T), T_b), atol=1e-6)
    np.testing.assert_allclose(factors.zpr_jacobian(T_a), numeric_jacobian(factors.zpr, T_a), atol=1e-6)


def drifting_square(rng, laps=2, side=8, step_s=60.0, noise=vj.NavNoise()):
    """Ground truth and navigation poses of submaps along a square, navigation drifting per
    Sodhi et al. Eq. 10: relative x, y, yaw noise, absolute z, pitch, roll noise."""
    truth, nav = [np.eye(4)], [np.eye(4)]
    for n in range(1, laps * 4 * side):
        yaw = (n // side) * np.pi / 2
        T = np.eye(4)
        T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        T[:3, 3] = truth[-1][:3, 3] + np.array([np.cos(yaw), np.sin(yaw), 0.0]) * 1.0
        truth.append(T)
        relative = inverse(truth[-2]) @ T
        dx, dy, dh = rng.normal(0, np.sqrt(noise.xyh_variances(step_s)))
        noisy = relative.copy()
        noisy[:2, 3] += [dx, dy]
        c, s = np.cos(dh), np.sin(dh)
        noisy[:2, :2] = np.array([[c, -s], [s, c]]) @ noisy[:2, :2]
        N = nav[-1] @ noisy
        N[2, 3] = T[2, 3] + rng.normal(0, np.sqrt(noise.sigma2_z * step_s))
        nav.append(N)
    return np.stack(truth), np.stack(nav)


def ate(estimate, truth):
    return np.sqrt(np.mean(np.sum((estimate[:, :3, 3] - truth[:, :3, 3]) ** 2, axis=1)))


def test_loop_closures_bring_the_error_well_below_odometry_and_shrink_marginals():
    rng = np.random.default_rng(0)
    step_s = 60.0
    truth, nav = drifting_square(rng, laps=3, step_s=step_s)
    pg = slam.PoseGraph(prior_pose=truth[0])
    for T in nav:
        pg.add_submap(T, step_s)
    odometry_only = pg.update()
    per_lap = len(nav) // 3
    sigmas = np.sqrt(pg.marginals(range(len(nav)))[:, 3, 3])
    assert np.all(np.diff(sigmas[:per_lap]) > 0)  # uncertainty grows along the chain
    before = pg.marginals([len(nav) - 1])[0]
    cov = np.diag([1e-4] * 3 + [1e-3] * 3)
    for k in range(per_lap, len(nav)):  # later laps revisit the places of earlier ones
        for i in range(k % per_lap, k - per_lap + 1, per_lap):
            pg.add_loop_closure(i, k, inverse(truth[i]) @ truth[k], cov)
    optimised = pg.update()
    assert ate(odometry_only, truth) > 0.5
    assert ate(optimised, truth) < 0.35 * ate(odometry_only, truth)
    after = pg.marginals([len(nav) - 1])[0]
    assert np.linalg.det(after[3:5, 3:5]) < 0.1 * np.linalg.det(before[3:5, 3:5])


def test_partial_factor_leaves_the_degenerate_direction_to_odometry():
    pg = slam.PoseGraph()
    T = np.eye(4)
    for _ in range(3):
        T = T.copy()
        T[0, 3] += 5.0
        pg.add_submap(T, 60.0)
    claimed = np.eye(4)
    claimed[:3, 3] = [12.0, 0.8, 0.0]  # x far off, y off: a corridor along x gives no x
    basis = np.eye(6)[:, [0, 1, 2, 4, 5]]  # everything but translation x
    pg.add_loop_closure(0, 2, claimed, np.diag([1e-6] * 6), basis=basis)
    poses = pg.update()
    relative = inverse(poses[0]) @ poses[2]
    assert abs(relative[0, 3] - 10.0) < 0.05  # odometry's x
    assert abs(relative[1, 3] - 0.8) < 0.05  # the loop closure's y
    assert pg.factors[-1][0] == "partial_loop"


def structured_cloud(rng, n=3000):
    """Three walls, a floor and some boxes: constrains every direction."""
    parts = [
        np.c_[rng.uniform(0, 6, n // 5), rng.uniform(0, 4, n // 5), np.zeros(n // 5)],
        np.c_[np.zeros(n // 5), rng.uniform(0, 4, n // 5), rng.uniform(0, 3, n // 5)],
        np.c_[rng.uniform(0, 6, n // 5), np.zeros(n // 5), rng.uniform(0, 3, n // 5)],
        np.c_[rng.uniform(2, 3, n // 5), rng.uniform(1, 2, n // 5), np.full(n // 5, 1.0)],
        np.c_[np.full(n // 5, 4.0), rng.uniform(2, 3, n // 5), rng.uniform(0, 1.5, n // 5)],
    ]
    return np.concatenate(parts)


def small_motion(rng, rotation=0.05, translation=0.2, planar=False):
    xi = np.concatenate([rng.normal(0, rotation, 3), rng.normal(0, translation, 3)])
    if planar:
        xi[[0, 1, 5]] = 0.0
    return _exp(xi)


@pytest.mark.parametrize("method", ["point_to_plane", "point_to_point_xyh"])
def test_icp_recovers_a_known_transform(method):
    rng = np.random.default_rng(1)
    target = structured_cloud(rng)
    truth = small_motion(rng, planar=method == "point_to_point_xyh")
    source = (target - truth[:3, 3]) @ truth[:3, :3]  # source = truth^-1 target
    source += rng.normal(0, 0.005, source.shape)
    result = slam.icp(source, target, np.eye(4), method=method)
    assert result.converged and result.basis.shape[1] == (3 if method == "point_to_point_xyh" else 6)
    error = log_se3(inverse(truth) @ result.T_target_source)
    assert np.linalg.norm(error[:3]) < 0.01 and np.linalg.norm(error[3:]) < 0.02
    assert result.fitness < 1e-3 and result.num_inliers > 0.9 * len(source)


@pytest.mark.parametrize("free", ["all", "yaw"])
def test_icp_judges_its_directions_at_the_clouds_centre(free):
    """Where a cloud sits in its frame changes nothing: the same scene 0, 10 and 30 m from the
    source frame's origin, turned about its own centre, is aligned exactly and reports the same
    eigenvalues (judged at its centre). At the origin a turn of a cloud 30 m off was a twist
    of rotation and 30 times as much translation, below lambda_min per inlier: ICP stopped,
    "converged", 1.3 m and 2.5 degrees off. The Hessian stays GTSAM's, checked against
    central differences of the point-to-plane residuals."""
    rng = np.random.default_rng(3)
    scene = structured_cloud(rng) - [3.0, 2.0, 1.0]
    xi = np.array([0.01, -0.01, 0.04, 0.15, -0.1, 0.05]) if free == "all" else np.array([0, 0, 0.04, 0.15, -0.1, 0])
    config = slam.IcpConfig(max_correspondence_m=0.5, free=free)
    eigenvalues = []
    for offset in (0.0, 10.0, 30.0):
        target = scene + [offset, 0.3 * offset, 0.0]
        centre = np.eye(4)
        centre[:3, 3] = target.mean(axis=0)
        truth = centre @ _exp(xi) @ inverse(centre)
        source = (target - truth[:3, 3]) @ truth[:3, :3]
        result = slam.icp(source, target, config=config)
        assert result.converged and result.basis.shape[1] == (6 if free == "all" else 4)
        error = log_se3(inverse(truth) @ result.T_target_source)
        assert np.abs(error).max() < 1e-6
        np.testing.assert_allclose(result.centre, source.mean(axis=0))
        eigenvalues.append(result.eigenvalues)
        # the reported Hessian against central differences in GTSAM's tangent, correspondences
        # (nearest by brute force) fixed, over the directions ICP may move
        T = result.T_target_source
        moved = source @ T[:3, :3].T + T[:3, 3]
        nearest = np.concatenate(
            [np.argmin(((rows[:, None] - target[None]) ** 2).sum(axis=2), axis=1) for rows in np.split(moved, 6)]
        )
        normals = slam.prepare_target(target, config).normals[nearest]

        def residuals(twist):
            end = T @ _exp(twist)
            return np.einsum("ni,ni->n", normals, source @ end[:3, :3].T + end[:3, 3] - target[nearest])

        J = np.stack([(residuals(e * 1e-6) - residuals(-e * 1e-6)) / 2e-6 for e in np.eye(6)], axis=1)
        # what ICP holds (roll and pitch for "yaw") it holds at the centre: J_centre = J A
        A = slam.centre_adjoint(result.centre)
        J_centre = J @ A
        J_centre[:, :2] *= free == "all"
        A_inv = np.linalg.inv(A)
        reference = A_inv.T @ J_centre.T @ J_centre @ A_inv
        np.testing.assert_allclose(result.hessian, reference, rtol=1e-4, atol=1e-6 * np.abs(reference).max())
        np.testing.assert_allclose(result.basis.T @ result.basis, np.eye(result.basis.shape[1]), atol=1e-12)
        if free == "yaw":  # the basis, in GTSAM's tangent, is blind to the roll and pitch held at the centre
            held = slam.centre_adjoint(result.centre) @ np.eye(6)[:, :2]
            assert np.abs(result.basis.T @ held).max() < 1e-9
    np.testing.assert_allclose(eigenvalues[1], eigenvalues[0], rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(eigenvalues[2], eigenvalues[0], rtol=1e-6, atol=1e-9)


def test_point_to_point_xyh_constrains_only_x_y_and_yaw():
    rng = np.random.default_rng(4)
    target = structured_cloud(rng) + [12.0, -5.0, 2.0]
    result = slam.icp(target[::2], target, method="point_to_point_xyh")
    assert result.converged and result.basis.shape[1] == 3 and result.degenerate
    held = slam.centre_adjoint(result.centre) @ np.eye(6)[:, [0, 1, 5]]  # roll, pitch, z at the centre
    assert np.abs(result.basis.T @ held).max() < 1e-9
    assert np.abs(result.eigenvalues[:3]).max() < 1e-12 * result.eigenvalues.max()


def test_batched_icp_equals_one_pair_at_a_time():
    rng = np.random.default_rng(5)
    targets = [structured_cloud(rng, 1500), structured_cloud(rng, 2500)]
    truths = [small_motion(rng), small_motion(rng)]
    sources = [(t - m[:3, 3]) @ m[:3, :3] for t, m in zip(targets, truths)]
    sources[1] = sources[1][::2]  # pairs of different sizes share the padded arrays
    for method in ("point_to_plane", "point_to_point_xyh"):
        batch = slam.icp_batch(sources, targets, None, method)
        for source, target, together in zip(sources, targets, batch):
            alone = slam.icp(source, target, method=method)
            np.testing.assert_allclose(together.T_target_source, alone.T_target_source, atol=1e-9)
            assert together.iterations == alone.iterations
            assert together.converged == alone.converged


def test_prepared_targets_give_the_same_alignments(monkeypatch):
    """A target prepared once (tree and normals) aligns exactly as the raw cloud does, is not
    changed by preparing, and the detector prepares each submap's cloud once over many calls."""
    rng = np.random.default_rng(6)
    target = structured_cloud(rng, 2000)
    kept = target.copy()
    sources = [(target - m[:3, 3]) @ m[:3, :3] for m in (small_motion(rng), small_motion(rng))]
    prepared = slam.prepare_target(target)
    assert target.flags.writeable and np.array_equal(target, kept)
    # its normals against a brute-force reference: each point's 10 nearest by the full distance
    # matrix, the direction of least spread of their scatter (up to sign)
    sample = rng.choice(len(target), 200, replace=False)
    distances = np.linalg.norm(target[sample, None, :] - target[None, :, :], axis=2)
    for row, point in enumerate(sample):
        patch = target[np.argsort(distances[row])[:10]]
        centred = patch - patch.mean(axis=0)
        reference = np.linalg.svd(centred)[2][-1]
        assert abs(prepared.normals[point] @ reference) > 1 - 1e-6
    assert np.array_equal(prepared.tree.query(target[sample])[1], sample)
    for method in ("point_to_plane", "point_to_point_xyh"):
        raw = slam.icp_batch(sources, [target, target], None, method)
        reused = slam.icp_batch(sources, [prepared, prepared], None, method)
        for a, b in zip(raw, reused):
            assert np.array_equal(a.T_target_source, b.T_target_source) and np.array_equal(a.hessian, b.hessian)
            assert (a.iterations, a.num_inliers, a.fitness) == (b.iterations, b.num_inliers, b.fitness)
    with pytest.raises(ValueError, match="normal_neighbours"):
        slam.icp_batch(sources[:1], [prepared], None, config=slam.IcpConfig(normal_neighbours=7))

    calls = []
    real = slam.loop_closure.prepare_target
    monkeypatch.setattr(
        slam.loop_closure, "prepare_target", lambda cloud, config: calls.append(1) or real(cloud, config)
    )
    bounds = (target.min(axis=0) - 0.1, target.max(axis=0) + 0.1)
    poses = np.stack([np.eye(4)] * 4)
    clouds = [target, sources[1], sources[0], sources[1]]
    all_bounds = [bounds] * 4
    detector = slam.LoopClosureDetector()
    times = np.array([0.0, 600.0, 1200.0, 1800.0])
    detector.detect(2, clouds, all_bounds, poses, poses, times)  # candidates: submap 0
    assert len(calls) == 1
    second = detector.detect(3, clouds, all_bounds, poses, poses, times)  # submaps 0 (kept) and 1
    assert len(calls) == 2 and len(second[0]) + len(second[1]) == 2
    fresh = slam.LoopClosureDetector().detect(3, clouds, all_bounds, poses, poses, times)
    assert [(c.i, c.k) for c in second[0]] == [(c.i, c.k) for c in fresh[0]]
    assert all(np.array_equal(a.T_i_k, b.T_i_k) for a, b in zip(second[0], fresh[0]))
    assert [(r.i, r.reason) for r in second[1]] == [(r.i, r.reason) for r in fresh[1]]
    clouds[0] = target.copy()  # a new object with the same values: kept
    detector.detect(2, clouds, all_bounds, poses, poses, times)
    assert len(calls) == 4  # twice more for the fresh detector
    clouds[0] += 0.01  # changed in place: prepared again
    detector.detect(2, clouds, all_bounds, poses, poses, times)
    assert len(calls) == 5
    detector.config = slam.LoopClosureConfig(
        icp=slam.IcpConfig(max_correspondence_m=0.3, free="translation", normal_neighbours=8)
    )
    detector.detect(2, clouds, all_bounds, poses, poses, times)  # other ICP settings: prepared again
    assert len(calls) == 6
    # a hand-made IcpTarget whose parts do not belong together is refused
    other = slam.prepare_target(sources[0])
    mixed = slam.IcpTarget(prepared.points, other.tree, prepared.normals, prepared.neighbours)
    with pytest.raises(ValueError, match="do not belong together"):
        slam.icp_batch(sources[:1], [mixed])
    assert not prepared.points.flags.writeable and not prepared.normals.flags.writeable


def swath(rng, shape, first_line_m, flat=False):
    """A profiling sonar's swath of a rough seabed with a step (or a flat one): lines 0.25 m
    apart, a point every 5 cm along them, 2 cm noise (thin and anisotropic, where point-to-plane
    ICP can cycle; on a flat one, x and y are unconstrained)."""
    x, y = np.meshgrid(np.arange(0, 3, 0.05), np.arange(first_line_m, 3, 0.25))
    x, y = x.ravel(), y.ravel()
    z = 0.4 * np.sin(shape[0] * x + shape[1]) + 0.3 * np.cos(shape[2] * y + shape[3]) + 0.5 * (x > shape[4])
    return np.c_[x, y, 0.0 * z if flat else z] + rng.normal(0, 0.02, (x.size, 3))


def swath_pairs(seed, count=40):
    """Sources on other lines over part of their targets' swaths, from starts up to 0.3 m and,
    for most, a few degrees off (the held rotation is then not the identity); one in five flat."""
    rng = np.random.default_rng(seed)
    sources, targets, starts = [], [], []
    for n in range(count):
        shape, flat = rng.uniform(0.5, 3, 5), n % 5 == 4
        targets.append(swath(rng, shape, 0.0, flat))
        source = swath(rng, shape, 0.12, flat)
        sources.append(source[source[:, 0] > 0.5])
        start = np.eye(4)
        if n % 4:
            start[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix()
        start[:3, 3] = rng.normal(0, 0.1, 3)
        starts.append(start)
    return sources, targets, starts


@pytest.mark.parametrize("seed, settings", [(0, {}), (0, {"tolerance": 1e-9}), (6, {"max_correspondence_m": 0.5})])
def test_icp_stops_where_its_correspondences_can_only_cycle(monkeypatch, seed, settings):
    """Holding the rotation, a pair whose correspondences come back (not from the step just
    before) after well-conditioned steps stops there: run on to max_iterations instead, the
    same pairs never converge, and every other pair ends exactly as it would have, with a
    tolerance near round-off too, and where steps are ill conditioned (flat swaths: seed 6
    has a pair that would be stopped wrongly if those steps did not reset the memory). With a
    free rotation nothing stops early."""
    sources, targets, starts = swath_pairs(seed)
    icp_module = sys.modules["vogjax.slam.icp"]
    for free in ("translation", "all"):
        config = slam.IcpConfig(free=free, **settings)
        stopping = slam.icp_batch(sources, targets, starts, config=config)
        with monkeypatch.context() as never:
            never.setattr(icp_module, "_returned", lambda cycles, pairs, *_: np.zeros(len(pairs), bool))
            running_on = slam.icp_batch(sources, targets, starts, config=config)
        early = 0
        for a, b in zip(stopping, running_on, strict=True):
            assert a.converged == b.converged
            if a.iterations < b.iterations:
                assert not b.converged and b.iterations == config.max_iterations
                early += 1
            else:
                assert np.array_equal(a.T_target_source, b.T_target_source) and np.array_equal(a.hessian, b.hessian)
                assert (a.iterations, a.fitness, a.num_inliers) == (b.iterations, b.fitness, b.num_inliers)
        assert early >= 3 if free == "translation" else early == 0


def test_icp_at_a_fixed_point_converges_at_a_tolerance_near_round_off(monkeypatch):
    """A pair at its fixed point uses the same correspondences twice running; with a tolerance
    near round-off, that is not a cycle and it converges one iteration later, as without the
    stop (a case a review found: the 192nd of these rotated swath pairs)."""
    rng = np.random.default_rng(7)
    for _ in range(192):
        shape = rng.uniform(0.5, 3, 5)
        target, source = swath(rng, shape, 0.0), swath(rng, shape, 0.12)
        start = np.eye(4)
        start[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix()
        start[:3, 3] = rng.normal(0, 0.1, 3)
    source = source[source[:, 0] > 0.5]
    config = slam.IcpConfig(free="translation", tolerance=1e-9)
    stopping = slam.icp(source, target, start, config=config)
    monkeypatch.setattr(
        sys.modules["vogjax.slam.icp"], "_returned", lambda cycles, pairs, *_: np.zeros(len(pairs), bool)
    )
    running_on = slam.icp(source, target, start, config=config)
    assert stopping.converged and running_on.converged and stopping.iterations == running_on.iterations
    assert np.array_equal(stopping.T_target_source, running_on.T_target_source)


def test_degenerate_scenes_give_a_reduced_basis():
    rng = np.random.default_rng(2)
    plane = np.c_[rng.uniform(0, 10, 2000), rng.uniform(0, 10, 2000), rng.normal(0, 0.002, 2000)]
    corridor = np.concatenate(
        [
            np.c_[rng.uniform(0, 30, 1500), np.zeros(1500), rng.uniform(0, 3, 1500)],
            np.c_[rng.uniform(0, 30, 1500), np.full(1500, 2.0), rng.uniform(0, 3, 1500)],
            np.c_[rng.uniform(0, 30, 1500), rng.uniform(0, 2, 1500), np.zeros(1500)],
        ]
    )
    shift = np.eye(4)
    shift[:3, 3] = [0.3, 0.05, 0.05]
    for cloud, free_directions in ((plane, 3), (corridor, 1)):
        source = cloud @ np.eye(3) - shift[:3, 3]
        result = slam.icp(source, cloud, np.eye(4))
        assert result.basis.shape == (6, 6 - free_directions)
        if free_directions == 1:  # the corridor's free direction is translation along x
            assert abs(result.eigenvectors[3, 0]) > 0.99


def _bad_detector_inputs():
    rng = np.random.default_rng(8)
    cloud = structured_cloud(rng, 300)
    box = (cloud.min(axis=0), cloud.max(axis=0))
    good = dict(k=2, clouds=[cloud] * 3, bounds=[box] * 3, poses=np.stack([np.eye(4)] * 3))
    good.update(nav_poses=good["poses"], times_s=np.array([0.0, 600.0, 1200.0]))
    bent = good["poses"].copy()
    bent[1, 0, 0] = 2.0
    nan_cloud = cloud.copy()
    nan_cloud[5, 1] = np.nan
    cases = {
        "k": [3, -1, True, 1.0],
        "bounds": [[box] * 2, [(box[1], box[0]), box, box], ["box", box, box]],
        "clouds[0]": [[cloud[:, :2], cloud, cloud], [nan_cloud, cloud, cloud]],
        "clouds[2]": [[cloud, cloud, nan_cloud]],
        "poses": [bent, good["poses"][:2]],
        "nav_poses": [bent],
        "times_s": [np.array([0.0, np.nan, 1.0]), np.zeros(2)],
    }
    for name, values in cases.items():
        for value in values:
            key = "clouds" if name.startswith("clouds") else name
            yield name, {**good, key: value}


@pytest.mark.parametrize("name, arguments", list(_bad_detector_inputs()))
def test_detector_refuses_bad_inputs_naming_them(name, arguments):
    detector = slam.LoopClosureDetector()
    with pytest.raises(ValueError, match=re.escape(name)):
        detector.detect(**arguments)
    assert not detector._targets  # refused before any work
    if name != "nav_poses" and name != "times_s":
        with pytest.raises(ValueError, match=re.escape(name)):
            detector.candidates(arguments["k"], arguments["clouds"], arguments["bounds"], arguments["poses"])


def test_repeated_target_points_do_not_bend_the_normals():
    """A target whose points all come twice has the normals and alignment of the points once
    (a point's neighbours were its own copies: a scatter of zero and an arbitrary normal)."""
    rng = np.random.default_rng(9)
    target = structured_cloud(rng, 1500)
    truth = small_motion(rng, 0.02, 0.1)
    source = (target - truth[:3, 3]) @ truth[:3, :3]
    once = slam.prepare_target(target)
    twice = slam.prepare_target(np.concatenate([target, target[::-1]]))
    assert np.array_equal(twice.points, target) and np.array_equal(twice.normals, once.normals)
    a, b = slam.icp(source, once), slam.icp(source, twice)
    assert np.array_equal(a.T_target_source, b.T_target_source)
    with pytest.raises(ValueError, match="distinct points"):
        slam.prepare_target(np.repeat(target[:2], 5, axis=0))


def test_icp_names_its_start_pose():
    rng = np.random.default_rng(10)
    cloud = structured_cloud(rng, 300)
    with pytest.raises(ValueError, match="T_init must"):
        slam.icp(cloud, cloud, np.stack([np.eye(4)] * 2))
    with pytest.raises(ValueError, match="T_init"):
        slam.icp(cloud, cloud, np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="T_inits"):
        slam.icp_batch([cloud], [cloud], np.stack([np.eye(4)] * 2))


@pytest.mark.parametrize("scene", ["room", "floor"])
@pytest.mark.parametrize("offset_m", [0.0, 30.0])
def test_a_perfect_fit_without_registration_sigma_enters_the_graph(scene, offset_m):
    """registration_sigma_m 0 and no floors: the closure's covariance is ICP's own, which for
    an exact fit was below what GTSAM can invert (add_loop_closure refused it, and the run
    stopped). Its variances stop at MIN_CLOSURE_VARIANCE, and a partial closure (a floor: x, y
    and yaw free) stays positive definite; the graph then holds the closure's pose."""
    rng = np.random.default_rng(11)
    cloud = structured_cloud(rng, 2000)
    if scene == "floor":
        cloud = cloud[cloud[:, 2] == 0.0]
    cloud = cloud + [offset_m, 0.0, 0.0]  # far from the frame's origin: the covariance moves there
    truth_k = small_motion(rng, 0.0, 0.05, planar=True)
    clouds = [cloud, cloud[:10], (cloud - truth_k[:3, 3]) @ truth_k[:3, :3]]
    bounds = (cloud.min(axis=0) - 0.1, cloud.max(axis=0) + 0.1)
    poses = np.stack([np.eye(4), np.eye(4), truth_k])
    config = slam.LoopClosureConfig(
        icp=slam.IcpConfig(max_correspondence_m=0.3, free="all"),
        registration_sigma_m=0.0,
        min_sigma_rotation_rad=0.0,
        min_sigma_translation_m=0.0,
    )
    accepted, rejected = slam.LoopClosureDetector(config=config).detect(
        2, clouds, [bounds, None, bounds], poses, poses, np.array([0.0, 600.0, 1200.0])
    )
    assert len(accepted) == 1 and not rejected, rejected
    closure = accepted[0]
    assert closure.fitness < 1e-20
    assert (closure.basis is None) == (scene == "room")
    assert np.linalg.eigvalsh(closure.covariance).min() >= 0.99 * slam.loop_closure.MIN_CLOSURE_VARIANCE
    graph = slam.PoseGraph()
    for T in poses:
        graph.add_submap(T, 600.0)
    graph.add_loop_closure(closure.i, closure.k, closure.T_i_k, closure.covariance, closure.basis)
    estimate = graph.update()
    np.testing.assert_allclose(inverse(estimate[0]) @ estimate[2], truth_k, atol=1e-6)


def test_detector_accepts_true_and_rejects_wrong_loop_closures():
    rng = np.random.default_rng(3)
    cloud = structured_cloud(rng, 2000)
    bounds = (cloud.min(axis=0) - 0.1, cloud.max(axis=0) + 0.1)
    poses = np.stack([np.eye(4)] * 3)
    poses[1, :3, 3] = [20.0, 0, 0]  # far away: not a candidate
    truth_k = small_motion(rng, 0.02, 0.1)
    poses[2] = truth_k
    clouds = [cloud, cloud[:10], (cloud - truth_k[:3, 3]) @ truth_k[:3, :3]]
    times = np.array([0.0, 600.0, 1200.0])
    # every direction ICP solves for enters the factor (this scene's weakest, at its centre, has 0.15 per inlier)
    six_dof = slam.LoopClosureConfig(icp=slam.IcpConfig(max_correspondence_m=0.3, free="all"), min_information=0.01)
    detector = slam.LoopClosureDetector(config=six_dof)
    estimate = poses.copy()
    estimate[2] = small_motion(rng, 0.01, 0.05) @ truth_k  # the current estimate is a bit off
    accepted, rejected = detector.detect(2, clouds, [bounds, None, bounds], estimate, poses, times)
    assert [(c.i, c.k) for c in accepted] == [(0, 2)] and not rejected
    assert accepted[0].basis is None
    np.testing.assert_allclose(accepted[0].T_i_k, truth_k, atol=0.02)
    # Navigation says k is 10 m off from where ICP puts it: more than it can drift in 20 min
    # (3 sigma of sqrt((0.00138 + 0.00138) * 1200 s) = 5.5 m).
    lying_nav = poses.copy()
    lying_nav[2, :3, 3] += [10.0, 0.0, 0.0]
    accepted, rejected = detector.detect(2, clouds, [bounds, None, bounds], estimate, lying_nav, times)
    assert not accepted and [r.reason for r in rejected] == ["drift"]
    # A cloud of another place entirely does not align well enough.
    clouds[2] = np.random.default_rng(9).uniform(0, 5, (2000, 3))
    accepted, rejected = detector.detect(2, clouds, [bounds, None, bounds], estimate, poses, times)
    assert not accepted and rejected[0].reason in ("overlap", "fitness", "not converged")


def test_an_alignment_that_constrains_no_direction_is_rejected_and_no_submap_closes_with_itself():
    rng = np.random.default_rng(3)
    cloud = structured_cloud(rng, 2000)
    bounds = (cloud.min(axis=0) - 0.1, cloud.max(axis=0) + 0.1)
    truth_k = small_motion(rng, 0.02, 0.1)
    poses = np.stack([np.eye(4), np.eye(4), truth_k])
    poses[1, :3, 3] = [20.0, 0, 0]
    clouds = [cloud, cloud[:10], (cloud - truth_k[:3, 3]) @ truth_k[:3, :3]]
    times = np.array([0.0, 600.0, 1200.0])
    # every direction of this scene holds well under 0.6 per inlier: a factor of rank 0, which
    # the pose graph refuses, was returned as accepted
    strict = slam.LoopClosureDetector(config=slam.LoopClosureConfig(min_information=0.6))
    accepted, rejected = strict.detect(2, clouds, [bounds, None, bounds], poses, poses, times)
    assert not accepted and [(r.i, r.reason) for r in rejected] == [(0, "information")]
    assert rejected[0].value < rejected[0].limit == 0.6
    with pytest.raises(ValueError, match="min_separation must be a positive integer"):
        slam.LoopClosureConfig(min_separation=0)


def test_default_closures_constrain_translation_only_with_the_estimated_rotation():
    rng = np.random.default_rng(3)
    cloud = structured_cloud(rng, 2000)
    bounds = (cloud.min(axis=0) - 0.1, cloud.max(axis=0) + 0.1)
    truth_k = small_motion(rng, 0.02, 0.3)
    clouds = [cloud, cloud[:10], (cloud - truth_k[:3, 3]) @ truth_k[:3, :3]]
    poses = np.stack([np.eye(4), np.eye(4), truth_k])
    poses[1, :3, 3] = [20.0, 0, 0]
    estimate = poses.copy()
    estimate[2, :3, 3] += [0.25, -0.15, 0.05]  # the rotation estimate is right, the position off
    accepted, rejected = slam.LoopClosureDetector().detect(
        2, clouds, [bounds, None, bounds], estimate, poses, np.array([0.0, 600.0, 1200.0])
    )
    assert [(c.i, c.k) for c in accepted] == [(0, 2)] and not rejected
    closure = accepted[0]
    # a partial factor over translation directions only: rotation rows of the basis are zero
    assert closure.basis is not None and np.abs(closure.basis[:3]).max() == 0 and closure.basis.shape[1] == 3
    np.testing.assert_allclose(closure.T_i_k[:3, :3], truth_k[:3, :3], atol=1e-12)  # held, as estimated
    np.testing.assert_allclose(closure.T_i_k[:3, 3], truth_k[:3, 3], atol=0.02)


def revisit_beyond_icps_reach():
    """Submap 2 revisits submap 0 (submap 1 is far away) after 30 min, navigation 1.5 m and 0.8
    degrees off: (clouds, bounds, navigation poses, times, the true T_0_2)."""
    rng = np.random.default_rng(4)
    cloud = np.floor(structured_cloud(rng, 6000) / 0.1) * 0.1 + 0.05  # occupied voxel centres
    truth_k = np.eye(4)
    truth_k[:3, 3] = [0.3, -0.2, 0.0]
    clouds = [cloud, cloud[:10], (cloud - truth_k[:3, 3]) @ truth_k[:3, :3]]
    bounds = (cloud.min(axis=0) - 0.1, cloud.max(axis=0) + 0.1)
    nav = np.stack([np.eye(4), np.eye(4), truth_k])
    nav[1, :3, 3] = [20.0, 0, 0]
    off = np.eye(4)
    off[:3, :3] = Rotation.from_euler("z", 0.014).as_matrix()
    off[:3, 3] = [1.2, 0.9, 0.0]
    nav[2] = truth_k @ off
    return clouds, [bounds, None, bounds], nav, np.array([0.0, 900.0, 1800.0]), truth_k


def test_detector_finds_closures_beyond_icps_reach():
    """The correlative search brings ICP home from beyond its reach."""
    clouds, bounds, nav, times, truth_k = revisit_beyond_icps_reach()
    assert slam.icp(clouds[2], clouds[0], nav[2]).T_target_source[0, 3] > truth_k[0, 3] + 0.2  # ICP alone fails
    six_dof = slam.LoopClosureConfig(icp=slam.IcpConfig(max_correspondence_m=0.3, free="all"))
    accepted, rejected = slam.LoopClosureDetector(config=six_dof).detect(2, clouds, bounds, nav, nav, times)
    assert [(c.i, c.k) for c in accepted] == [(0, 2)] and not rejected
    np.testing.assert_allclose(accepted[0].T_i_k, truth_k, atol=0.02)


@pytest.mark.parametrize("seed", range(4))
def test_correlative_search_recovers_planar_offsets(seed):
    rng = np.random.default_rng(seed)
    target = structured_cloud(rng, 5000)
    yaw = rng.uniform(-0.02, 0.02)
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    truth[:2, 3] = rng.uniform(-2, 2, 2)
    source = (target - truth[:3, 3]) @ truth[:3, :3]  # the same place seen from `truth`
    match = slam.correlative_xyh(source, target, np.eye(4), radius_m=2.5, yaw_radius_rad=0.03)
    moved = source @ match.T_target_source[:3, :3].T + match.T_target_source[:3, 3]
    expected = source @ truth[:3, :3].T + truth[:3, 3]
    # whole-voxel shifts and 5 mrad yaw steps: every point within a voxel of where it belongs
    assert np.abs(moved - expected).max() < 0.1 + 5e-3 * 7
    assert match.score > 0.5 and match.ratio < 0.7


def direct_correlation(source, target, T_init, radius_m, yaw_radius_rad, config):
    """correlative_xyh by its definition, without FFTs: the same grid, the target blurred on the
    whole of it, and every yaw and x-y offset scored by summing the field under the moved source
    points one by one. Returns (best score, its yaw, its offset in cells, runner-up)."""
    from scipy import ndimage

    res = config.resolution_m
    moved = source @ T_init[:3, :3].T + T_init[:3, 3]
    pivot = moved.mean(axis=0)
    cells_r = int(np.ceil(radius_m / res))
    reach = np.linalg.norm(moved[:, :2] - pivot[:2], axis=1).max() * yaw_radius_rad
    margin = res * (cells_r + 2) + reach
    lo, hi = moved.min(axis=0) - margin, moved.max(axis=0) + margin
    target = target[np.all((target[:, :2] >= lo[:2] + res) & (target[:, :2] <= hi[:2] - res), axis=1)]
    lo[2] = min(target[:, 2].min(), moved[:, 2].min()) - res
    hi[2] = max(target[:, 2].max(), moved[:, 2].max()) + res
    shape = (np.ceil((hi - lo) / res) + 1).astype(int)
    field = np.zeros(shape)
    t = np.floor((target - lo) / res).astype(int)
    field[t[:, 0], t[:, 1], t[:, 2]] = 1.0
    if config.blur_voxels > 0:
        field = ndimage.gaussian_filter(field, config.blur_voxels)
        field /= field.max()
    steps = int(np.floor(yaw_radius_rad / config.yaw_step_rad))
    offsets = np.arange(-cells_r, cells_r + 1)
    best = (-np.inf, None, None, None)
    for yaw in config.yaw_step_rad * np.arange(-steps, steps + 1):
        c, s = np.cos(yaw), np.sin(yaw)
        points = (moved - pivot) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + pivot
        cells = np.floor((points - lo) / res).astype(int)
        window = np.array(
            [[field[cells[:, 0] + dx, cells[:, 1] + dy, cells[:, 2]].sum() for dy in offsets] for dx in offsets]
        ) / len(points)
        peak = np.unravel_index(np.argmax(window), window.shape)
        if window[peak] > best[0]:
            best = (window[peak], yaw, peak, window)
    score, yaw, peak, window = best
    ii, jj = np.meshgrid(offsets, offsets, indexing="ij")
    far = np.hypot(ii - offsets[peak[0]], jj - offsets[peak[1]]) * res >= config.exclusion_m
    return score, yaw, (offsets[peak[0]], offsets[peak[1]]), window[far].max()


@pytest.mark.parametrize(
    "direct, chunk", [(False, 1 << 22), (True, 1 << 22), (True, 7)], ids=["fft", "direct", "direct-chunked"]
)
@pytest.mark.parametrize("seed, blur", [(0, 1.0), (1, 0.0), (2, 1.6), (3, 1.0)])
def test_correlative_search_equals_direct_correlation(monkeypatch, seed, blur, direct, chunk):
    """The host search, by FFT (on padded sizes) or by its direct correlation of distinct cells
    (over the source's layers, the blur cropped to the target; in chunks of a few lookups too,
    offsets and cells split), scores every yaw and offset as summing the whole grid's field
    point by point does."""
    monkeypatch.setattr(sys.modules["vogjax.slam.correlative"], "_direct_is_cheaper", lambda plan: direct)
    monkeypatch.setattr(sys.modules["vogjax.slam.correlative"], "DIRECT_CHUNK_LOOKUPS", chunk)
    rng = np.random.default_rng(seed)
    target = structured_cloud(rng, 1500)
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_euler("z", rng.uniform(-0.01, 0.01)).as_matrix()
    truth[:3, 3] = [*rng.uniform(-0.6, 0.6, 2), 0.0]
    source = ((target - truth[:3, 3]) @ truth[:3, :3])[rng.random(len(target)) < 0.5]
    source = source[source[:, 2] < 1.5]  # fewer layers than the target: the search keeps only these
    T_init = np.eye(4)
    T_init[:3, 3] = rng.uniform(-0.2, 0.2, 3)
    config = slam.CorrelativeConfig(blur_voxels=blur, yaw_step_rad=0.004)
    match = slam.correlative_xyh(source, target, T_init, 0.9, 0.012, config)
    score, yaw, (dx, dy), runner_up = direct_correlation(source, target, T_init, 0.9, 0.012, config)
    np.testing.assert_allclose([match.score, match.runner_up], [score, runner_up], rtol=1e-5)
    expected = np.eye(4)
    expected[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
    pivot = (source @ T_init[:3, :3].T + T_init[:3, 3]).mean(axis=0)
    expected[:3, 3] = pivot - expected[:3, :3] @ pivot + [dx * 0.1, dy * 0.1, 0.0]
    np.testing.assert_allclose(match.T_target_source, expected @ T_init, atol=1e-12)


def test_a_search_that_scores_zero_everywhere_returns_its_start():
    """Target points in the search's x-y box but on layers the source never reaches: every
    offset scores 0, and the match is T_init (it was the window's first corner)."""
    rng = np.random.default_rng(0)
    source = np.c_[rng.uniform(0, 3, (500, 2)), rng.uniform(0, 0.3, 500)]
    start = small_motion(rng, 0.02, 0.1, planar=True)
    match = slam.correlative_xyh(source, source + [0.0, 0.0, 10.0], start, radius_m=1.0, yaw_radius_rad=0.05)
    assert match.score == 0.0 and match.ratio == 1.0
    np.testing.assert_array_equal(match.T_target_source, start)


def test_correlative_search_reports_ambiguity_along_a_wall():
    rng = np.random.default_rng(5)
    wall = np.c_[rng.uniform(0, 8, 3000), np.zeros(3000), rng.uniform(0, 3, 3000)]
    match = slam.correlative_xyh(wall[:1500], wall, np.eye(4), radius_m=1.0, yaw_radius_rad=0.0)
    assert match.ratio > 0.85  # sliding along the wall scores nearly as well as the answer


@pytest.mark.parametrize(
    "call, argument",
    [
        (lambda pg: pg.add_submap(np.eye(3), 1.0), "T_world_submap_nav"),
        (lambda pg: pg.add_submap(np.diag([1, 1, 2, 1.0]), 1.0), "T_world_submap_nav"),
        (lambda pg: pg.add_submap(np.eye(4), 0.0), "duration_s"),
        (lambda pg: pg.add_loop_closure(0, 5, np.eye(4), np.eye(6)), "k"),
        (lambda pg: pg.add_loop_closure(True, 0, np.eye(4), np.eye(6)), "i must be a submap id"),  # not a bool
        (lambda pg: pg.add_loop_closure(0, 1, np.eye(4), -np.eye(6)), "covariance"),
        (lambda pg: pg.add_loop_closure(0, 1, np.eye(4), np.triu(np.ones((6, 6)))), "covariance"),
        (lambda pg: pg.add_loop_closure(0, 1, np.eye(4), np.eye(5)), "covariance"),
        (lambda pg: pg.add_loop_closure(0, 1, np.eye(4), np.eye(6), basis=np.ones((6, 2))), "basis"),
        (lambda pg: pg.add_loop_closure(0, 1, np.ones((4, 4)), np.eye(6)), "T_i_k"),
        (lambda pg: pg.marginals([7]), "ids"),
        (lambda pg: slam.icp(np.zeros((0, 3)), np.ones((10, 3))), "source"),
        (lambda pg: slam.icp(np.ones((10, 3)), np.full((10, 3), np.nan)), "target"),
        (lambda pg: slam.icp(np.ones((10, 3)), np.ones((10, 3)), method="magic"), "method"),
        (lambda pg: slam.correlative_xyh(np.zeros((0, 3)), np.ones((10, 3)), np.eye(4), 1.0, 0.0), "source"),
        (lambda pg: slam.correlative_xyh(np.ones((10, 3)), np.ones((10, 2)), np.eye(4), 1.0, 0.0), "target"),
        (lambda pg: slam.correlative_xyh(np.ones((10, 3)), np.ones((10, 3)), np.ones((4, 4)), 1.0, 0.0), "T_init"),
        (lambda pg: slam.correlative_xyh(np.ones((10, 3)), np.ones((10, 3)), np.eye(4), -1.0, 0.0), "radius_m"),
        (lambda pg: slam.correlative_xyh(np.ones((10, 3)), np.ones((10, 3)), np.eye(4), 1.0, np.inf), "yaw_radius_rad"),
        (lambda pg: slam.CorrelativeConfig(resolution_m=0.0), "resolution_m"),
        (lambda pg: slam.LoopClosureConfig(max_candidates=-1), "max_candidates"),
        (lambda pg: slam.IcpConfig(lambda_min=0.0), "lambda_min"),
        (lambda pg: slam.LoopClosureConfig(min_overlap_score=float("nan")), "min_overlap_score"),
        (lambda pg: slam.LoopClosureConfig(method="magic"), "method"),
    ],
)
def test_bad_input(call, argument):
    pg = slam.PoseGraph()
    pg.add_submap(np.eye(4))
    pg.add_submap(np.eye(4), 10.0)
    pg.update()
    factors_before = list(pg.factors)
    with pytest.raises(ValueError, match=argument):
        call(pg)
    assert pg.factors == factors_before


@pytest.mark.parametrize("seed", range(4))
def test_align_xy_yaw_recovers_a_rigid_motion_and_beats_every_other_yaw(seed):
    """The x-y-yaw fit behind `trajectory_rmse_m.*_aligned`: it undoes an exact rotation about
    z plus a shift, and on noisy points no yaw on a fine grid (each with its best shift) fits
    better."""
    from vogjax.geometry import align_xy_yaw, pose_from_xyz_yaw

    rng = np.random.default_rng(seed)
    reference = rng.uniform(-20.0, 20.0, (50, 3))
    motion = pose_from_xyz_yaw(*rng.uniform(-5.0, 5.0, 3), rng.uniform(-np.pi, np.pi))
    moved = reference @ motion[:3, :3].T + motion[:3, 3]
    T = align_xy_yaw(moved, reference)
    np.testing.assert_allclose(moved @ T[:3, :3].T + T[:3, 3], reference + [0, 0, motion[2, 3]], atol=1e-9)

    noisy = moved + rng.normal(0.0, 0.5, moved.shape)
    T = align_xy_yaw(noisy, reference)
    best = np.sum((noisy[:, :2] @ T[:2, :2].T + T[:2, 3] - reference[:, :2]) ** 2)
    for yaw in np.linspace(-np.pi, np.pi, 3601):
        R = pose_from_xyz_yaw(0, 0, 0, yaw)[:2, :2]
        turned = noisy[:, :2] @ R.T
        shift = reference[:, :2].mean(axis=0) - turned.mean(axis=0)  # the best shift for this yaw
        assert np.sum((turned + shift - reference[:, :2]) ** 2) >= best - 1e-9


@pytest.mark.parametrize("shape", [(7, 3), (4, 50, 3)])
def test_point_to_plane_jacobian_equals_the_cross_product_form_bit_for_bit(shape):
    """ICP's J = [p x R^T n, R^T n]: written out component by component, the same bits as
    np.cross and np.concatenate give (which ICP used before), for one pair and a batch."""
    import importlib

    icp_module = importlib.import_module("vogjax.slam.icp")
    rng = np.random.default_rng(11)
    source, moved, matched, normals = (rng.normal(size=shape) * 10.0 for _ in range(4))
    rotation = Rotation.random(shape[0] if len(shape) == 3 else None, random_state=3).as_matrix()
    J, residuals = icp_module._plane_system(moved, rotation, source, matched, normals)
    n_rotated = np.einsum("...ni,...ij->...nj", normals, rotation)
    expected = np.concatenate([np.cross(source, n_rotated), n_rotated], axis=-1)
    assert J.shape == expected.shape
    np.testing.assert_array_equal(J, expected)
    np.testing.assert_array_equal(residuals, np.einsum("...ni,...ni->...n", normals, moved - matched))


@pytest.mark.parametrize("seed", range(3))
def test_fft_windows_equal_the_transforms_padded_by_scipy_bit_for_bit(seed):
    """The source's counts laid out on the padded grid give the windows scipy's own zero padding
    (`s=`) gives, to the bit, at every yaw."""
    from scipy import fft

    from vogjax.slam import correlative

    rng = np.random.default_rng(seed)
    target = structured_cloud(rng, 1500)
    source = target[rng.random(len(target)) < 0.5] + [*rng.uniform(-0.3, 0.3, 2), 0.0]
    config = slam.CorrelativeConfig(yaw_step_rad=0.004)
    plan = correlative._plan(source, target, np.eye(4), 0.8, 0.01, config)
    shape = plan.field.shape
    fft_shape = (fft.next_fast_len(shape[0]), fft.next_fast_len(shape[1], real=True))
    field_spectrum = fft.rfft2(plan.field, s=fft_shape, axes=(0, 1))
    windows = list(correlative._fft_windows(plan))
    assert len(windows) == len(plan.yaws) > 1
    for n, window in enumerate(windows):
        counts = np.zeros(shape, np.float32)
        np.add.at(counts, tuple(plan.cells(n).T), 1.0)
        spectrum = (np.conj(fft.rfft2(counts, s=fft_shape, axes=(0, 1))) * field_spectrum).sum(axis=2)
        np.testing.assert_array_equal(window, correlative._window(fft.irfft2(spectrum, s=fft_shape), plan.shift_cells))


def test_registration_on_two_threads_gives_the_bits_of_one(monkeypatch):
    """The yaws of a search, the pairs of an ICP iteration and the halves of a target's normals on
    the launch pool's threads (every search, batch and target, however small): the same matches
    and alignments, bit for bit, as one at a time."""
    import importlib

    from vogjax.maps import parallel
    from vogjax.slam import correlative

    icp_module = importlib.import_module("vogjax.slam.icp")
    rng = np.random.default_rng(12)
    target = structured_cloud(rng, 2000)
    sources, T_inits = [], []
    for _ in range(4):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", rng.uniform(-0.02, 0.02)).as_matrix()
        T[:3, 3] = [*rng.uniform(-0.3, 0.3, 2), 0.0]
        sources.append((target[rng.random(len(target)) < 0.4] - T[:3, 3]) @ T[:3, :3])
        T_inits.append(np.eye(4))
    searches = [(s, target, T, 0.6, 0.03) for s, T in zip(sources, T_inits)]
    config = slam.CorrelativeConfig(yaw_step_rad=0.004)
    calls = []

    def run(two_threads: bool):
        monkeypatch.setattr(parallel, "CPU_THREADS", 2 if two_threads else 1)
        monkeypatch.setattr(correlative, "THREADED_GRID_CELLS", 0)
        monkeypatch.setattr(icp_module, "THREADED_QUERY_POINTS", 0)
        monkeypatch.setattr(icp_module, "THREADED_NORMAL_POINTS", 0)
        matches = slam.correlative_xyh_batch(searches, config)
        seeds = [m.T_target_source for m in matches]
        return matches, slam.icp_batch(sources, [target] * len(sources), seeds, config=slam.IcpConfig(free="all"))

    real = parallel.ordered_map

    def counted(function, items, threaded=True):
        calls.append(parallel.CPU_THREADS)
        return real(function, items, threaded)

    monkeypatch.setattr(parallel, "ordered_map", counted)
    one, two = run(False), run(True)
    assert 2 in calls and 1 in calls
    for a, b in zip(one[0], two[0], strict=True):
        assert np.array_equal(a.T_target_source, b.T_target_source)
        assert (a.score, a.runner_up) == (b.score, b.runner_up)
    for a, b in zip(one[1], two[1], strict=True):
        assert np.array_equal(a.T_target_source, b.T_target_source)
        assert (a.fitness, a.iterations) == (b.fitness, b.iterations)


def test_log_so3_keeps_the_angle_of_rotations_at_and_near_a_half_turn():
    """Against scipy's rotation vectors: exact half turns (where arccos resolves the angle only
    to ~1.5e-8 rad, and R - R^T is round-off) and turns 1e-12 to 1e-1 rad short of one."""
    from vogjax.geometry import log_so3

    rng = np.random.default_rng(5)
    axes = rng.normal(size=(4000, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    short = np.concatenate([np.zeros(1000), 10.0 ** rng.uniform(-12, -1, 3000)])
    vectors = axes * (np.pi - short)[:, None]
    got = log_so3(Rotation.from_rotvec(vectors).as_matrix())
    angle = np.linalg.norm(got, axis=1)
    np.testing.assert_allclose(angle, np.pi - short, atol=1e-7)
    # the axis up to the sign a half turn leaves free, and the rotation itself exactly
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", got / angle[:, None], axes)), 1.0, atol=1e-7)
    np.testing.assert_allclose(
        Rotation.from_rotvec(got).as_matrix(), Rotation.from_rotvec(vectors).as_matrix(), atol=1e-9
    )
    # away from a half turn: the same as scipy's
    generic = rng.normal(size=(1000, 3))
    np.testing.assert_allclose(
        log_so3(Rotation.from_rotvec(generic).as_matrix()),
        Rotation.from_matrix(Rotation.from_rotvec(generic).as_matrix()).as_rotvec(),
        atol=1e-9,
    )
