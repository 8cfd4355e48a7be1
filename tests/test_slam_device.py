"""The SLAM front end on a Warp device (issue 16): the correlative searches by direct correlation
and ICP's neighbours from a hash grid give what the host path (FFTs, k-d trees) gives. Run on
the CPU device here, on the GPU where there is one (the kernels are the same)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vogjax import devices, slam
from vogjax.slam import correlative
from vogjax.slam.icp import _GridNeighbours

from .test_slam import revisit_beyond_icps_reach, small_motion, structured_cloud

DEVICE = str(devices.resolve(None))  # the GPU where there is one


def planar_motion(rng, yaw_rad, shift_m):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", rng.uniform(-yaw_rad, yaw_rad)).as_matrix()
    T[:2, 3] = rng.uniform(-shift_m, shift_m, 2)
    return T


def search_batch(rng):
    """Searches of several sizes in one batch: radii (so window widths) and yaw ranges differ,
    one source sees fewer layers than its target, and one has no target point within reach."""
    searches = []
    for radius_m, yaw_radius_rad, n in ((0.9, 0.012, 1500), (1.6, 0.0, 2500), (0.4, 0.02, 800)):
        target = structured_cloud(rng, n)
        truth = planar_motion(rng, 0.01, 0.5 * radius_m)
        source = ((target - truth[:3, 3]) @ truth[:3, :3])[rng.random(len(target)) < 0.6]
        searches.append((source, target, planar_motion(rng, 0.003, 0.2), radius_m, yaw_radius_rad))
    searches[0] = (searches[0][0][searches[0][0][:, 2] < 1.5],) + searches[0][1:]
    far = np.eye(4)
    far[:3, 3] = [100.0, 0.0, 0.0]
    searches.append((searches[1][0], searches[1][1], far, 1.0, 0.0))
    return searches


def assert_same_matches(host, device):
    for h, d in zip(host, device, strict=True):
        assert np.array_equal(h.T_target_source, d.T_target_source)
        np.testing.assert_allclose([d.score, d.runner_up], [h.score, h.runner_up], rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("seed", range(3))
def test_device_correlative_searches_find_the_host_peaks(seed):
    config = slam.CorrelativeConfig(yaw_step_rad=0.004, blur_voxels=[1.0, 0.0, 1.6][seed])
    searches = search_batch(np.random.default_rng(seed))
    host = slam.correlative_xyh_batch(searches, config)
    assert [slam.correlative_xyh(*s, config).score for s in searches] == [m.score for m in host]
    assert host[-1].score == 0.0  # nothing in reach: the initial guess as it is
    assert_same_matches(host, slam.correlative_xyh_batch(searches, config, device=DEVICE))
    # every score of every yaw and offset, not only the peaks
    plans = [correlative._plan(*search, config) for search in searches[:3]]
    scored = list(correlative._device_windows(plans, devices.resolve(DEVICE)))
    assert [(p, n) for p, n, _ in scored] == [(p, n) for p, plan in enumerate(plans) for n in range(len(plan.yaws))]
    fft_windows = [list(correlative._fft_windows(plan)) for plan in plans]
    for p, n, window in scored:
        expected = fft_windows[p][n]
        assert window.shape == expected.shape
        np.testing.assert_allclose(window, expected, rtol=0, atol=1e-5 * max(expected.max(), 1.0))


@pytest.mark.parametrize(
    "budget, value",
    [("MAX_LAUNCH_CELLS", 1), ("MAX_LAUNCH_CELLS", 3000), ("MAX_LAUNCH_SCORES", 700), ("MAX_FIELD_FLOATS", 1)],
)
def test_device_searches_split_over_launches_give_the_same_peaks(monkeypatch, budget, value):
    """Budgets too small for one launch: every (search, yaw) slot is scored once, in order, in
    launches within the budget (but those of a single slot), with the bits of one launch."""
    config = slam.CorrelativeConfig(yaw_step_rad=0.004)
    searches = search_batch(np.random.default_rng(7))
    whole = slam.correlative_xyh_batch(searches, config, device=DEVICE)
    launches = []
    real = correlative._correlate_on_device
    monkeypatch.setattr(
        correlative,
        "_correlate_on_device",
        lambda plans, slots, device: launches.append((plans, list(slots))) or real(plans, slots, device),
    )
    monkeypatch.setattr(correlative, budget, value)
    split = slam.correlative_xyh_batch(searches, config, device=DEVICE)
    plans = launches[0][0]
    assert [slot for _, slots in launches for slot in slots] == [
        (p, n) for p, plan in enumerate(plans) for n in range(len(plan.yaws))
    ]
    use = {
        "MAX_LAUNCH_CELLS": lambda slots: sum(len(plans[p].moved) for p, _ in slots),
        "MAX_LAUNCH_SCORES": lambda slots: sum((2 * plans[p].shift_cells + 1) ** 2 for p, _ in slots),
        "MAX_FIELD_FLOATS": lambda slots: sum(plans[p].field.size for p in {p for p, _ in slots}),
    }[budget]
    assert len(launches) > 2 and all(len(slots) == 1 or use(slots) <= value for _, slots in launches)
    assert any(len(slots) > 1 for _, slots in launches) == (value > 1)
    for a, b in zip(whole, split, strict=True):
        assert np.array_equal(a.T_target_source, b.T_target_source) and (a.score, a.runner_up) == (b.score, b.runner_up)


def test_searches_beyond_the_direct_work_bound_run_on_the_host(monkeypatch):
    """A search whose direct correlation would take too long is the host's FFT search, bit for
    bit; the others still run on the device."""
    config = slam.CorrelativeConfig(yaw_step_rad=0.004)
    searches = search_batch(np.random.default_rng(8))
    host = slam.correlative_xyh_batch(searches, config)
    plans = [correlative._plan(*search, config) for search in searches[:3]]
    works = sorted(correlative._direct_work(plan) for plan in plans)
    monkeypatch.setattr(correlative, "MAX_DIRECT_WORK", works[1])  # the largest one is too much
    launched = []
    real = correlative._correlate_on_device
    monkeypatch.setattr(
        correlative,
        "_correlate_on_device",
        lambda plans, slots, device: launched.extend(plans) or real(plans, slots, device),
    )
    mixed = slam.correlative_xyh_batch(searches, config, device=DEVICE)
    largest = int(np.argmax([correlative._direct_work(plan) for plan in plans]))
    assert len({id(plan) for plan in launched}) == 2
    assert np.array_equal(mixed[largest].T_target_source, host[largest].T_target_source)
    assert (mixed[largest].score, mixed[largest].runner_up) == (host[largest].score, host[largest].runner_up)
    assert_same_matches(host, mixed)


def brute_force_nearest(points, queries, max_distance):
    """The lowest index among the points nearest each query, strictly within max_distance; -1 when none."""
    d2 = ((queries[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
    nearest = np.argmin(d2, axis=1)  # argmin keeps the first of equal values
    return np.where(d2[np.arange(len(queries)), nearest] < max_distance**2, nearest, -1)


def test_device_neighbours_are_the_nearest_points_with_ties_to_the_lowest_index():
    """On a lattice many points are equally near; far out (1e6 m) and between targets that
    overlap in space, each pair still finds only its own target's points."""
    rng = np.random.default_rng(2)
    targets = [
        rng.integers(-5, 6, (400, 3)) * 0.1,
        rng.integers(-5, 6, (300, 3)) * 0.1 + 1e6,
        rng.uniform(-0.5, 0.5, (500, 3)),
    ]
    queries = [
        rng.integers(-12, 13, (600, 3)) * 0.05,
        rng.integers(-12, 13, (200, 3)) * 0.05 + 1e6,
        rng.uniform(-0.7, 0.7, (300, 3)),
    ]
    grid = _GridNeighbours(targets, 0.15, devices.resolve(DEVICE))
    for pairs in ([0, 1, 2], [2, 0]):
        found = grid(pairs, [queries[p] for p in pairs])
        for p, index in zip(pairs, found, strict=True):
            expected = brute_force_nearest(targets[p], queries[p], 0.15)
            assert np.array_equal(index, expected)
            assert (expected >= 0).any() and (expected < 0).any()


@pytest.mark.parametrize("method", ["point_to_plane", "point_to_point_xyh"])
def test_device_icp_equals_the_host_icp_bit_for_bit(method):
    """Nearest neighbours are all ICP takes from the device: on clouds without exact ties the
    alignments are the host's, bit for bit, over pairs of different sizes in one batch."""
    rng = np.random.default_rng(11)
    targets = [structured_cloud(rng, 1500), structured_cloud(rng, 2500), structured_cloud(rng, 900)]
    truths = [small_motion(rng, planar=method != "point_to_plane") for _ in targets]
    sources = [
        ((t - m[:3, 3]) @ m[:3, :3])[::k] + rng.normal(0, 0.003, ((len(t) + k - 1) // k, 3))
        for t, m, k in zip(targets, truths, (1, 2, 3))
    ]
    config = slam.IcpConfig(max_correspondence_m=0.4)
    prepared = [slam.prepare_target(t, config) for t in targets]
    host = slam.icp_batch(sources, prepared, None, method, config)
    device = slam.icp_batch(sources, prepared, None, method, config, device=DEVICE)
    for h, d in zip(host, device, strict=True):
        assert np.array_equal(h.T_target_source, d.T_target_source) and np.array_equal(h.hessian, d.hessian)
        assert (h.converged, h.iterations, h.num_inliers, h.fitness) == (
            d.converged,
            d.iterations,
            d.num_inliers,
            d.fitness,
        )
    assert all(h.converged for h in host)


def test_detector_on_a_device_accepts_the_host_closures():
    """Navigation 1.5 m and 0.8 degrees off: the searches and ICP on the device bring the same
    closure home as on the host."""
    clouds, bounds, nav, times, truth_k = revisit_beyond_icps_reach()
    config = slam.LoopClosureConfig(icp=slam.IcpConfig(max_correspondence_m=0.3, free="all"))
    results = [
        slam.LoopClosureDetector(config=config, device=device).detect(2, clouds, bounds, nav, nav, times)
        for device in (None, DEVICE)
    ]
    (host, host_rejected), (device, device_rejected) = results
    assert [(c.i, c.k) for c in host] == [(c.i, c.k) for c in device] == [(0, 2)]
    assert not host_rejected and not device_rejected
    assert np.array_equal(host[0].T_i_k, device[0].T_i_k) and np.array_equal(host[0].covariance, device[0].covariance)
    np.testing.assert_allclose(device[0].T_i_k, truth_k, atol=0.02)


def test_an_unknown_device_is_refused_by_name():
    with pytest.raises(ValueError, match="device"):
        slam.LoopClosureDetector(device="tpu:3")
    with pytest.raises(ValueError, match="device"):
        slam.correlative_xyh_batch([], device="tpu:3")
    with pytest.raises(ValueError, match="device"):
        slam.icp_batch([], [], device="tpu:3")
