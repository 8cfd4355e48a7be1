"""Loop-closure searches bounded by the pose graph: `PoseGraph.relative_covariance` against GTSAM's
batch marginals and a numerically differentiated relative pose, the detector's search radii
against their closed form, and a periodic scene where the navigation's wide search finds an
alias as good as the truth and the graph's narrow one does not."""

import gtsam
import numpy as np
import pytest

from vogjax import slam
from vogjax.geometry import exp_se3, inverse, log_se3
from vogjax.slam import loop_closure

from .test_slam import drifting_square, structured_cloud


def odometry_graph(seed: int, laps: int):
    """A pose graph of a drifting square's odometry alone, updated: (graph, truth, nav)."""
    truth, nav = drifting_square(np.random.default_rng(seed), laps=laps)
    pg = slam.PoseGraph(prior_pose=truth[0])
    for T in nav:
        pg.add_submap(T, 60.0)
    pg.update()
    return pg, truth, nav


def test_relative_covariance_equals_the_batch_marginals_moved_to_the_relative_pose():
    pg, truth, nav = odometry_graph(3, laps=1)
    poses = pg.poses()
    graph, values = pg._isam.getFactorsUnsafe(), pg._isam.calculateEstimate()
    marginals = gtsam.Marginals(graph, values)
    for i, k in [(0, 5), (2, len(nav) - 3), (7, 3)]:
        joint = marginals.jointMarginalCovariance([i, k]).fullMatrix()
        P = inverse(poses[i]) @ poses[k]

        def relative(xi, i=i, k=k, P=P):  # log(P^-1 (T_i Exp(xi_i))^-1 T_k Exp(xi_k))
            return log_se3(inverse(P) @ inverse(poses[i] @ exp_se3(xi[:6])) @ poses[k] @ exp_se3(xi[6:]))

        eps = 1e-6
        A = np.stack([(relative(eps * e) - relative(-eps * e)) / (2 * eps) for e in np.eye(12)], axis=1)
        expected = A @ joint @ A.T
        got = pg.relative_covariance(i, k)
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-9 * np.abs(expected).max())


def test_relative_covariance_follows_the_graph_and_is_a_copy():
    pg, truth, nav = odometry_graph(4, laps=2)
    k, i = len(nav) - 1, len(nav) // 2 - 1  # the same corner, a lap apart
    before = pg.relative_covariance(i, k)
    before[:] = 0.0  # a copy: the graph's own is untouched
    before = pg.relative_covariance(i, k)
    assert np.all(np.diag(before) > 0)
    pg.add_loop_closure(i, k, inverse(truth[i]) @ truth[k], np.diag([1e-6] * 3 + [1e-4] * 3))
    pg.update()
    after = pg.relative_covariance(i, k)
    assert np.all(np.diag(after)[3:5] < 0.1 * np.diag(before)[3:5])  # the closure pins x and y


@pytest.mark.parametrize("i, k", [(-1, 2), (0, 5), (1, 1), (True, 2), (0.0, 2)])
def test_relative_covariance_refuses_bad_ids(i, k):
    pg = slam.PoseGraph()
    for n in range(3):
        pg.add_submap(np.eye(4), 0.0 if n == 0 else 10.0)
    with pytest.raises(ValueError, match="i and k must differ" if i is k else r"\b[ik] must be a submap id"):
        pg.relative_covariance(i, k)


def spy_aligner(monkeypatch) -> list:
    """Record each pair's search radii the detector hands its aligner, then align as usual."""
    seen = []
    aligner = loop_closure.ALIGNERS["correlative_icp"]

    def recorded(pairs, *args):
        seen.extend((radius, yaw) for _, _, _, radius, yaw in pairs)
        return aligner(pairs, *args)

    monkeypatch.setitem(loop_closure.ALIGNERS, "correlative_icp", recorded)
    return seen


def revisit(free="translation"):
    rng = np.random.default_rng(11)
    cloud = structured_cloud(rng, 3000) + [10.0, 0.0, 0.0]  # 10-16 m out along x
    box = (cloud.min(axis=0) - 0.1, cloud.max(axis=0) + 0.1)
    poses = np.stack([np.eye(4)] * 3)
    config = slam.LoopClosureConfig(icp=slam.IcpConfig(max_correspondence_m=0.3, free=free))
    times = np.array([0.0, 900.0, 1800.0])
    return [cloud, cloud[:10], cloud], [box, None, box], poses, times, config


@pytest.mark.parametrize("free", ["translation", "yaw"])
def test_search_radii_follow_the_graphs_sigmas_at_the_cloud(monkeypatch, free):
    clouds, bounds, poses, times, config = revisit(free)
    detector = slam.LoopClosureDetector(config=config)
    nav_radius = min(config.drift_sigmas * np.sqrt((detector.noise.sigma2_x + detector.noise.sigma2_y) * 1800.0), 4.0)
    seen = spy_aligner(monkeypatch)
    detector.detect(2, clouds, bounds, poses, poses, times)  # the navigation alone
    nav_yaw = seen[-1][1]
    assert seen[-1][0] == pytest.approx(nav_radius) and nav_radius > 3.0
    centroid = clouds[2].mean(axis=0)
    for sigma_x_m, sigma_yaw_rad in [(0.1, 0.0), (0.5, 0.0), (0.0, 0.02), (0.05, 0.01), (1e-6, 1e-7), (10.0, 1.0)]:
        covariance = np.diag([1e-12, 1e-12, sigma_yaw_rad**2, sigma_x_m**2, 1e-12, 1e-12])
        detector.detect(2, clouds, bounds, poses, poses, times, lambda i, k, c=covariance: c)
        radius, yaw = seen[-1]
        # the centroid's y moves by its x times the yaw; the x-y spread is the larger axis
        sigma_xy = np.sqrt(max(sigma_x_m**2 + centroid[1] ** 2 * sigma_yaw_rad**2, centroid[0] ** 2 * sigma_yaw_rad**2))
        expected = min(nav_radius, max(3 * sigma_xy, config.min_search_m))
        assert radius == pytest.approx(expected, rel=1e-3)
        if free == "translation":
            assert yaw == 0.0
        else:
            moved = clouds[2][:, :2] - centroid[:2]
            floor = config.min_search_m / np.linalg.norm(moved, axis=1).max()
            assert yaw == pytest.approx(min(nav_yaw, max(3 * sigma_yaw_rad, floor)), rel=1e-6)


@pytest.mark.parametrize(
    "value, message",
    [
        (np.eye(5), "must return a"),
        (np.full((6, 6), np.nan), "must return a"),
        ("a covariance", "must return a"),
        (-np.eye(6), "returned negative variances"),
        (np.eye(6) * 1j, "must return a"),
    ],
)
def test_a_bad_relative_covariance_is_refused_before_any_search(monkeypatch, value, message):
    clouds, bounds, poses, times, config = revisit()
    seen = spy_aligner(monkeypatch)
    with pytest.raises(ValueError, match=r"relative_covariance\(0, 2\) " + message):
        slam.LoopClosureDetector(config=config).detect(2, clouds, bounds, poses, poses, times, lambda i, k: value)
    assert not seen


def posts(spacing_m: float, extent_m: float) -> np.ndarray:
    """Vertical posts on a square grid, sampled every 5 cm in z, with a seabed of points below:
    a scene that repeats every `spacing_m` in x and y."""
    centres = np.arange(0.0, extent_m, spacing_m)
    xy = np.stack(np.meshgrid(centres, centres, indexing="ij"), axis=-1).reshape(-1, 2)
    angles = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    ring = 0.15 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    z = np.arange(0.0, 2.0, 0.05)
    points = (xy[:, None, None, :] + ring[None, :, None, :]).repeat(len(z), axis=2)
    heights = np.broadcast_to(z[None, None, :, None], (*points.shape[:3], 1))
    return np.concatenate([points, heights], axis=-1).reshape(-1, 3)


def test_the_graphs_narrow_search_leaves_out_the_aliases_a_repeating_scene_offers():
    """Posts every 1.6 m: within the navigation's 4 m, offsets of one and two spacings match as
    well as the truth (a runner-up scoring as the peak). The graph, knowing the pair to a few
    centimetres, searches 1 m around its estimate, where the next alias lies outside the
    window: the closure is unambiguous and lands on the truth."""
    target = posts(1.6, 9.7)
    truth = np.eye(4)
    truth[:2, 3] = [3.2 + 0.06, 1.6 - 0.04]  # the source seen from two posts over, a few cm off
    source = (target[np.all(target[:, :2] <= 6.5, axis=1)] - truth[:3, 3]) @ truth[:3, :3]
    box = (target.min(axis=0) - 0.1, target.max(axis=0) + 0.1)
    clouds, bounds = [target, target[:10], source], [box, None, (source.min(axis=0), source.max(axis=0))]
    estimate = np.stack([np.eye(4), np.eye(4), truth])
    estimate[2, :2, 3] += [0.05, -0.03]  # the graph's estimate, centimetres from the truth
    times = np.array([0.0, 1000.0, 2000.0])
    detector = slam.LoopClosureDetector()
    confident = np.diag([1e-8] * 3 + [0.03**2, 0.03**2, 1e-6])
    wide, wide_rejected = detector.detect(2, clouds, bounds, estimate, estimate, times)
    narrow, narrow_rejected = detector.detect(2, clouds, bounds, estimate, estimate, times, lambda i, k: confident)
    ambiguity = wide[0].ambiguity if wide else wide_rejected[0].value
    assert ambiguity > 0.9  # an alias as good as the peak within the navigation's reach
    assert [(c.i, c.k) for c in narrow] == [(0, 2)] and not narrow_rejected
    assert narrow[0].ambiguity < 0.8
    np.testing.assert_allclose(narrow[0].T_i_k[:2, 3], truth[:2, 3], atol=0.05)


def line_batch(first: int, scans: int, jump_at: int | None = None, jump_m: float = 0.0):
    """Scans 0.2 s apart along x, four beams each; from scan `jump_at` on, the navigation jumps
    `jump_m` in y."""
    from vogjax.io.dataset import ScanBatch

    rng = np.random.default_rng(first)
    directions = np.tile([[0.0, 0.0, -1.0]], (4, 1)) + rng.normal(0, 0.05, (4, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    index = np.arange(first, first + scans)
    poses = np.tile(np.eye(4), (scans, 1, 1))
    poses[:, 0, 3] = index * 0.1
    nav = poses.copy()
    if jump_at is not None:
        nav[index >= jump_at, 1, 3] += jump_m
    return ScanBatch(
        time_s=index * 0.2,
        pose_truth=poses,
        pose_nav=nav,
        sonar_origin=np.zeros((scans, 3)),
        sonar_directions=np.tile(directions, (scans, 1, 1)),
        ranges=np.full((scans, 4), 3.0),
        no_return=np.zeros((scans, 4), bool),
        invalid=np.zeros((scans, 4), bool),
        first=first,
    )


@pytest.mark.parametrize("where", ["add", "finish_submap"])
def test_a_jump_the_graph_cannot_weigh_is_refused_before_the_maps_take_it(where):
    """A navigation jump of 600 km in 2 s (over 1e7 drift sigmas) between two submaps: the graph
    refuses it. It used to be refused midway through `add` (or `finish_submap`), with the scans
    in the maps and the submap in the virtual map but not in the graph; now the batch is
    refused whole, and the mapper goes on with good scans as if it had never seen it."""
    from vogjax import pipeline
    from vogjax.config import TimingConfig

    config = pipeline.PipelineConfig(scans_per_submap=10, timing=TimingConfig(every_submaps=0))
    mapper = pipeline.Mapper(config)
    mapper.add(line_batch(0, 15))  # submap 0 closed; scans 10-14 wait for the next
    state = (mapper.scans, mapper.vog.num_submaps, mapper.graph.num_submaps, len(mapper._pending))
    voxels = mapper.standard_map.voxels()
    # the jump from scan 15 on: the base (middle scan) of the submap of scans 10-19
    bad = line_batch(15, 30 if where == "add" else 5, jump_at=15, jump_m=6e5)
    if where == "add":
        with pytest.raises(ValueError, match="drift sigmas"):
            mapper.add(bad)
    else:
        mapper.add(bad)  # the jump sits in the submap being filled
        state = (mapper.scans, mapper.vog.num_submaps, mapper.graph.num_submaps, len(mapper._pending))
        with pytest.raises(ValueError, match="drift sigmas"):
            mapper.finish_submap()
    assert (mapper.scans, mapper.vog.num_submaps, mapper.graph.num_submaps, len(mapper._pending)) == state
    if where == "add":  # the standard map did not take the batch either
        assert all(np.array_equal(a, b) for a, b in zip(voxels, mapper.standard_map.voxels()))
    if where == "add":
        mapper.add(line_batch(15, 30))
        mapper.finish_submap()
        assert mapper.graph.num_submaps == mapper.vog.num_submaps == len(mapper.submaps) == 5
