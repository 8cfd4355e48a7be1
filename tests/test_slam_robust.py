"""The pose graph against wrong loop closures: the screen and the robust loss (PoseGraphConfig),
against analytic references (a graph with known truth and injected outliers, chi-square
quantiles, GTSAM's batch marginals)."""

import gtsam
import numpy as np
import pytest
from scipy import stats

import vogjax as vj
from vogjax import slam
from vogjax.geometry import exp_se3, inverse, log_se3
from vogjax.slam.backend import screen_limit

from .test_slam import ate, drifting_square

GAUSSIAN = slam.PoseGraphConfig(screen="none", robust_loss="none")
COVARIANCE = np.diag([1e-4] * 3 + [4e-3] * 3)  # 0.01 rad, 0.063 m


def revisits(truth: np.ndarray, rng, per_lap: int) -> list:
    """Closures of every later-lap submap with the same corner of earlier laps: the true
    relative pose with noise drawn from COVARIANCE."""
    closures = []
    for k in range(per_lap, len(truth)):
        for i in range(k % per_lap, k - per_lap + 1, per_lap):
            noise = exp_se3(rng.multivariate_normal(np.zeros(6), COVARIANCE))
            closures.append((i, k, inverse(truth[i]) @ truth[k] @ noise))
    return closures


def wrong(T_i_k: np.ndarray, rng) -> np.ndarray:
    """T_i_k off by 1-3 m in x-y and 5-20 degrees of yaw, as the outlier benchmark injects."""
    angle, distance = rng.uniform(0, 2 * np.pi), rng.uniform(1.0, 3.0)
    yaw = np.radians(rng.uniform(5, 20)) * rng.choice([-1, 1])
    return T_i_k @ exp_se3(np.array([0, 0, yaw, distance * np.cos(angle), distance * np.sin(angle), 0]))


def solve(config, truth, nav, closures, outliers=frozenset(), step_s=20.0) -> tuple[np.ndarray, list]:
    """The graph fed as the pipeline feeds it: a node, an update, its closures, an update."""
    pg = slam.PoseGraph(prior_pose=truth[0], config=config)
    checks = []
    by_k = {}
    for n, (i, k, T) in enumerate(closures):
        by_k.setdefault(k, []).append((n, i, T))
    for k, T_nav in enumerate(nav):
        pg.add_submap(T_nav, step_s)
        pg.update()
        for n, i, T in by_k.get(k, []):
            checks.append((n in outliers, pg.add_loop_closure(i, k, T, COVARIANCE)))
        pg.update()
    return pg.poses(), checks


def spread_m(a: np.ndarray, b: np.ndarray) -> float:
    """RMS distance (m) between the positions of two solutions."""
    return float(np.sqrt(np.mean(np.sum((a[:, :3, 3] - b[:, :3, 3]) ** 2, axis=1))))


@pytest.mark.parametrize("seed", range(4))
def test_wrong_closures_cannot_bend_the_graph(seed):
    """10% of the closures of the later laps made 1-3 m and 5-20 degrees wrong. The reference:
    the Gaussian graph without them (what a perfect rejection leaves). The Gaussian graph with
    them lies a quarter of a metre or more from it; screened and robust, within a few
    centimetres, with every wrong closure refused and no more than one right one."""
    rng = np.random.default_rng(seed)
    truth, nav = drifting_square(rng, laps=3, step_s=20.0)
    closures = revisits(truth, rng, len(nav) // 3)
    picks = rng.choice(np.arange(len(closures) // 3, len(closures)), size=len(closures) // 10, replace=False)
    outliers = frozenset(int(n) for n in picks)
    corrupted = [(i, k, wrong(T, rng) if n in outliers else T) for n, (i, k, T) in enumerate(closures)]
    right = [c for n, c in enumerate(closures) if n not in outliers]
    reference, _ = solve(GAUSSIAN, truth, nav, right, step_s=20.0)
    gaussian, _ = solve(GAUSSIAN, truth, nav, corrupted, outliers, step_s=20.0)
    robust, checks = solve(slam.PoseGraphConfig(), truth, nav, corrupted, outliers, step_s=20.0)
    assert spread_m(gaussian, reference) > 0.25
    assert spread_m(robust, reference) < 0.03
    assert all(not check.accepted for is_outlier, check in checks if is_outlier)
    assert sum(not check.accepted for is_outlier, check in checks if not is_outlier) <= 1
    assert ate(robust, truth) <= 1.1 * ate(reference, truth)


@pytest.mark.parametrize("directions", range(1, 7))
def test_screen_limit_is_the_chi_square_quantile(directions):
    for sigmas in (1.0, 2.0, 3.0, 5.0):
        probability = stats.norm.cdf(sigmas) - stats.norm.cdf(-sigmas)
        expected = np.sqrt(stats.chi2.ppf(probability, directions))
        assert screen_limit(sigmas, directions) == pytest.approx(expected, rel=1e-9)
    assert screen_limit(3.0, 1) == pytest.approx(3.0, rel=1e-12)


def test_screen_distance_equals_the_batch_marginals_mahalanobis():
    """The screen's distance of a closure: its error at the estimate, whitened by its covariance
    plus the relative pose's covariance, computed here from GTSAM's batch Marginals and a
    numerically differentiated relative pose (independent of the Adjoint the screen uses)."""
    rng = np.random.default_rng(5)
    truth, nav = drifting_square(rng, laps=1)
    config = slam.PoseGraphConfig(screen_sigmas=50.0, robust_loss="none")
    pg = slam.PoseGraph(prior_pose=truth[0], config=config)
    for T in nav:
        pg.add_submap(T, 60.0)
    pg.update()
    i, k = 2, len(nav) - 3
    measured = inverse(truth[i]) @ truth[k]
    basis = np.eye(6)[:, [2, 3, 4]]  # yaw, x, y
    check = pg.add_loop_closure(i, k, measured, COVARIANCE, basis)
    # reference: batch marginals of the same odometry graph
    graph, values = pg._isam.getFactorsUnsafe(), pg._isam.calculateEstimate()
    joint = gtsam.Marginals(graph, values).jointMarginalCovariance([i, k]).fullMatrix()
    poses = pg.poses()
    P = inverse(poses[i]) @ poses[k]

    def relative(xi):  # log(P^-1 (T_i Exp(xi_i))^-1 T_k Exp(xi_k))
        return log_se3(inverse(P) @ inverse(poses[i] @ exp_se3(xi[:6])) @ poses[k] @ exp_se3(xi[6:]))

    eps = 1e-6
    A = np.stack([(relative(eps * e) - relative(-eps * e)) / (2 * eps) for e in np.eye(12)], axis=1)
    innovation = basis.T @ (A @ joint @ A.T + COVARIANCE) @ basis
    error = basis.T @ log_se3(inverse(P) @ measured)
    expected = np.sqrt(error @ np.linalg.solve(innovation, error))
    assert check.accepted and check.directions == 3
    assert check.distance == pytest.approx(expected, rel=1e-5)
    assert check.limit == pytest.approx(screen_limit(50.0, 3))


def test_a_refused_closure_leaves_the_graph_as_it_was():
    rng = np.random.default_rng(1)
    truth, nav = drifting_square(rng, laps=1)
    pg = slam.PoseGraph(prior_pose=truth[0])
    for T in nav:
        pg.add_submap(T, 60.0)
    before = pg.update()
    factors = list(pg.factors)
    far = inverse(truth[1]) @ truth[20]
    far[:3, 3] += [40.0, 0.0, 0.0]  # 40 m off: far beyond what the drift allows
    check = pg.add_loop_closure(1, 20, far, COVARIANCE)
    assert not check.accepted and check.distance > check.limit
    assert pg.factors == factors
    assert np.array_equal(pg.update(), before)


@pytest.mark.parametrize("loss", ["huber", "cauchy", "geman_mcclure", "dcs"])
def test_robust_losses_keep_a_consistent_closure_far_from_the_estimate(loss):
    """A closure the graph cannot check yet (its error 0.8 m against sigmas of 1 mm, the graph
    uncertain by half a metre) keeps its weight whatever the loss: iSAM2 would otherwise weigh
    it at next to nothing at the estimate it enters at and never look again."""
    pg = slam.PoseGraph(config=slam.PoseGraphConfig(robust_loss=loss))
    T = np.eye(4)
    for _ in range(3):
        T = T.copy()
        T[0, 3] += 5.0
        pg.add_submap(T, 60.0)
    pg.update()
    claimed = np.eye(4)
    claimed[:3, 3] = [10.0, 0.8, 0.0]
    check = pg.add_loop_closure(0, 2, claimed, np.diag([1e-6] * 6))
    assert check.accepted and check.scale > 100
    relative = inverse(pg.update()[0]) @ pg.poses()[2]
    np.testing.assert_allclose(relative[:3, 3], [10.0, 0.8, 0.0], atol=0.01)


def test_pose_graph_config_is_checked():
    with pytest.raises(ValueError, match="screen"):
        slam.PoseGraphConfig(screen="pcm")
    with pytest.raises(ValueError, match="robust_loss"):
        slam.PoseGraphConfig(robust_loss="tukey")
    with pytest.raises(ValueError, match="screen_sigmas"):
        slam.PoseGraphConfig(screen_sigmas=0.0)
    with pytest.raises(ValueError, match="config"):
        slam.PoseGraph(vj.NavNoise(), config=vj.MapConfig())
