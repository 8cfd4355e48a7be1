"""ConfidenceMap against the brute-force reference (tests/crm_reference.py), and its exact promises."""

import numpy as np
import pytest

from tests.crm_reference import ReferenceCrm, cone
from vogjax.config.crm import CrmConfig
from vogjax.maps import FREE, OCCUPIED, UNKNOWN
from vogjax.maps.confidence import ConfidenceMap

SMALL = CrmConfig(voxel_size=0.25, max_range=2.0, range_sigma_m=0.1, num_bins=8)


def random_scans(rng, count, beams, reach=2.6, spread=0.5):
    """Scans from random origins in random directions; some beams past max_range (no return)."""
    origins = rng.uniform(-spread, spread, (count, 3))
    d = rng.normal(size=(count * beams, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = np.repeat(origins, beams, axis=0) + d * rng.uniform(0.3, reach, (count * beams, 1))
    return origins, points, np.repeat(np.arange(count), beams)


def keys_of(centres, cfg):
    return [tuple(k) for k in np.floor(centres / cfg.voxel_size).astype(int)]


@pytest.mark.parametrize(
    "changes", [{}, {"spurious_probability": 0.02}, {"cause_range": "centre"}, {"cone_sigmas": 6.0, "bin_floor": 1e-3}]
)
def test_matches_brute_force_reference(changes):
    cfg = SMALL.replace(**changes)
    rng = np.random.default_rng(3)
    origins, points, scan_index = random_scans(rng, 5, 8)
    crm, ref = ConfidenceMap(cfg, "cpu"), ReferenceCrm(cfg)
    for s in range(5):
        crm.integrate_scan(origins[s], points[scan_index == s])
        ref.integrate_scan(origins[s].astype(np.float32), points[scan_index == s])
    assert_matches(crm, ref)


def assert_matches(crm, ref):
    """The same voxels observed, with the reference's distributions and moments."""
    centres, mean, variance = crm.voxels()
    keys = keys_of(centres, crm.config)
    assert set(keys) == set(ref.cells)
    expected = np.array([ref.cells[k] for k in keys])
    np.testing.assert_allclose(crm.distribution(centres), expected, atol=2e-6)
    moments = np.array([ref.moments(k) for k in keys])
    np.testing.assert_allclose(mean, moments[:, 0], atol=2e-6)
    np.testing.assert_allclose(variance, moments[:, 1], atol=2e-6)


def test_many_free_passes_in_one_scan_match_the_reference():
    """Voxels near the sensor are passed by most of a scan's 60 beams: their free passes are
    counted and applied a chunk at a time (several chunks per voxel per scan)."""
    rng = np.random.default_rng(4)
    origins, points, scan_index = random_scans(rng, 3, 60, spread=0.05)
    for num_bins in (8, 64):
        cfg = SMALL.replace(num_bins=num_bins)
        crm, ref = ConfidenceMap(cfg, "cpu"), ReferenceCrm(cfg)
        for s in range(3):
            crm.integrate_scan(origins[s], points[scan_index == s])
            ref.integrate_scan(origins[s].astype(np.float32), points[scan_index == s])
        centres = crm.voxels()[0]
        expected = np.array([ref.cells[k] for k in keys_of(centres, cfg)])
        np.testing.assert_allclose(crm.distribution(centres), expected, atol=2e-6)


@pytest.mark.parametrize("num_bins", [3, 13])
def test_bin_counts_off_the_sums_four_lanes_match_the_reference(num_bins):
    """bin_sum adds bins in four lanes: counts that leave one to three bins over (13), or that
    fill no lane group at all (3), sum every bin once."""
    test_matches_brute_force_reference({"num_bins": num_bins})


def test_reference_with_the_sensor_model_of_the_paper():
    """cause_range "centre" and no spurious readings: exactly the paper's Eqs. 14-27."""
    test_matches_brute_force_reference({"cause_range": "centre", "spurious_probability": 0.0, "num_bins": 16})


# Voxel edges exact in binary, so readings can lie exactly on them.
EDGES = CrmConfig(voxel_size=0.25, max_range=4.0, range_sigma_m=0.05, num_bins=16)


def grid_wall():
    """Readings on voxel edges and corners of the plane x = 1.5: a beam from the origin to any of
    them leaves a voxel where two or three of its planes meet."""
    j, k = np.meshgrid(np.arange(-4, 5), np.arange(-4, 5))
    return np.stack([np.full(j.size, 1.5), j.ravel() * 0.25, k.ravel() * 0.25], 1)


def test_a_beam_through_a_voxel_edge_leaves_out_the_voxels_it_only_touches():
    """A reading on the edge x = 1.5, y = 0.25 takes the beam from voxel (5,0,0) straight into
    (6,1,0). The walk sums plane distances one plane at a time and met x = 1.5 an ulp after
    y = 0.25, so voxel (5,1,0) was in the cone with a chord of 2e-16 m: at the prior mean it
    halved the reach of the voxel after it and, its chord too short to average the noise over,
    took the reading (mean 0.82) while the reading's voxel stayed at 0.58."""
    crm, ref = ConfidenceMap(EDGES, "cpu"), ReferenceCrm(EDGES)
    for _ in range(5):
        crm.integrate_scan(np.zeros(3), np.array([[1.5, 0.25, 0.0]]))
        ref.integrate_scan(np.zeros(3, np.float32), np.array([[1.5, 0.25, 0.0]]))
    assert not crm.observed(np.array([[1.375, 0.375, 0.125]]))[0]  # voxel (5,1,0)
    assert crm.state(np.array([[1.625, 0.375, 0.125]]))[0] == OCCUPIED  # voxel (6,1,0), the reading's
    assert_matches(crm, ref)


def test_readings_on_voxel_edges_and_corners_match_the_reference():
    points = grid_wall()
    crm, ref = ConfidenceMap(EDGES, "cpu"), ReferenceCrm(EDGES)
    for _ in range(3):
        crm.integrate_scan(np.zeros(3), points)
        ref.integrate_scan(np.zeros(3, np.float32), points)
    assert_matches(crm, ref)
    assert np.all(crm.state(points * (1.6 / 1.5)) == OCCUPIED)  # each reading's voxel, just past the edge
    # ray casts along the same edges count the voxels the beams passed, not the ones they touch
    result = crm.raycast(np.zeros((len(points), 3)), points, 3.0)
    unit = points / np.linalg.norm(points, axis=1, keepdims=True)
    assert result.hit.all()
    for i in range(len(points)):
        expected = _raycast_reference(crm, np.zeros(3), unit[i], 3.0)
        for name, value in expected.items():
            np.testing.assert_allclose(getattr(result, name)[i], value, rtol=1e-5, atol=1e-6, err_msg=name)


def test_sorted_path_gives_the_same_bits_as_the_sequential_one():
    rng = np.random.default_rng(5)
    origins, points, scan_index = random_scans(rng, 12, 20)
    maps = []
    for sorted_path in (False, True):
        crm = ConfidenceMap(SMALL.replace(spurious_probability=0.01), "cpu")
        crm._sorted_path = sorted_path  # the CUDA path, run on the CPU
        crm.integrate_scans(origins, points, scan_index)
        maps.append(crm.voxels())
    for a, b in zip(*maps):
        np.testing.assert_array_equal(a, b)


def test_batch_equals_sequential_bit_for_bit_across_passes(monkeypatch):
    import vogjax.maps.confidence as confidence

    monkeypatch.setattr(confidence, "SCANS_PER_PASS", 3)  # several passes, and passes split by budget
    monkeypatch.setattr(confidence, "STEP_BUDGET", 200)
    rng = np.random.default_rng(7)
    origins, points, scan_index = random_scans(rng, 10, 12)
    batch, single = ConfidenceMap(SMALL, "cpu"), ConfidenceMap(SMALL, "cpu")
    order = rng.permutation(len(points))  # any point order: scans are taken in index order
    batch.integrate_scans(origins, points[order], scan_index[order])
    for s in range(10):
        single.integrate_scan(origins[s], points[scan_index == s][::-1])
    for a, b in zip(batch.voxels(), single.voxels()):
        np.testing.assert_array_equal(a, b)
    probe = np.concatenate([points, origins, rng.uniform(-3, 3, (50, 3))])
    np.testing.assert_array_equal(batch.distribution(probe), single.distribution(probe))


def test_unknown_voxels_answer_the_prior():
    cfg = CrmConfig(num_bins=16)
    crm = ConfidenceMap(cfg, "cpu")
    far = np.array([[50.0, 50.0, 50.0], [-3.0, 2.0, 1.0]])
    assert cfg.prior_mean == np.float32(0.5)
    np.testing.assert_allclose(cfg.prior_variance, (16 + 1) / (12 * 15), rtol=1e-6)
    crm.integrate_scan(np.zeros(3), np.array([[1.0, 0.05, 0.05]]))
    np.testing.assert_array_equal(crm.mean(far), [cfg.prior_mean] * 2)
    np.testing.assert_array_equal(crm.variance(far), [cfg.prior_variance] * 2)
    np.testing.assert_array_equal(crm.distribution(far), np.tile(cfg.prior, (2, 1)))
    np.testing.assert_array_equal(crm.state(far), [UNKNOWN, UNKNOWN])
    assert not crm.observed(far).any()
    # a voxel of an allocated block that no beam crossed is unknown too
    beside = np.array([[0.55, 0.35, 0.05]])
    assert crm.observed(np.array([[0.55, 0.05, 0.05]]))[0] and not crm.observed(beside)[0]
    assert crm.mean(beside)[0] == cfg.prior_mean and crm.variance(beside)[0] == cfg.prior_variance


def test_a_wall_becomes_occupied_and_the_water_in_front_free():
    cfg = CrmConfig(voxel_size=0.1, max_range=5.0, range_sigma_m=0.03)
    crm = ConfidenceMap(cfg, "cpu")
    rng = np.random.default_rng(0)
    for _ in range(20):
        y = rng.uniform(-0.5, 0.5, 30)
        crm.integrate_scan(np.array([0.05, 0.0, 0.05]), np.stack([np.full(30, 2.05), y, np.full(30, 0.05)], 1))
    free = np.array([[x, 0.0, 0.05] for x in (0.55, 1.05, 1.55)])
    wall = np.array([[2.05, 0.0, 0.05]])
    assert np.all(crm.state(free) == FREE) and crm.state(wall)[0] == OCCUPIED
    assert crm.mean(wall)[0] > 0.95 and np.all(crm.mean(free) < 0.05)
    assert np.all(crm.variance(free) < 0.01) and crm.variance(wall)[0] < 0.01


def test_no_return_clears_the_beam_up_to_max_range_and_marks_nothing_occupied():
    cfg = CrmConfig(voxel_size=0.1, max_range=1.0, range_sigma_m=0.05)
    crm = ConfidenceMap(cfg, "cpu")
    for _ in range(30):
        crm.integrate_scan(np.array([0.05, 0.05, 0.05]), np.array([[3.05, 0.05, 0.05]]))
    centres, mean, _ = crm.voxels()
    assert centres[:, 0].max() < 1.1 and len(centres) == 11  # up to max_range (x = 1.05), no further
    assert np.all(mean[:-2] < 0.05)  # the last ones could still have bounced and read past the range


def _raycast_reference(crm, origin, direction, max_range):
    cfg = crm.config
    centres = []
    for key, t_in, _ in cone(origin, direction, max_range, cfg.voxel_size):
        centres.append(((np.array(key) + 0.5) * cfg.voxel_size, t_in))
    mean, variance = crm.mean(np.array([c for c, _ in centres])), crm.variance(np.array([c for c, _ in centres]))
    seen = crm.observed(np.array([c for c, _ in centres]))
    out = {
        "hit": False,
        "distance": max_range,
        "num_unknown": 0,
        "num_free": 0,
        "variance_sum": 0.0,
        "variance_max": 0.0,
        "reach_probability": 1.0,
    }
    for (_centre, t_in), m, v, s in zip(centres, mean, variance, seen):
        if s and m >= cfg.occupied_threshold:
            out.update(hit=True, distance=t_in)
            break
        if s and m <= cfg.free_threshold:
            out["num_free"] += 1
        else:
            out["num_unknown"] += 1
        out["variance_sum"] += float(v)
        out["variance_max"] = max(out["variance_max"], float(v))
        out["reach_probability"] *= 1.0 - float(m)
    return out


def test_raycast_against_a_brute_force_walk():
    rng = np.random.default_rng(11)
    crm = ConfidenceMap(SMALL, "cpu")
    crm.integrate_scans(*random_scans(rng, 30, 20, reach=1.8))
    origins = rng.uniform(-0.4, 0.4, (40, 3))
    directions = rng.normal(size=(40, 3))
    result = crm.raycast(origins, directions, 1.7)
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    assert result.hit.any() and not result.hit.all()
    for i in range(40):
        expected = _raycast_reference(crm, origins[i].astype(np.float64), unit[i], 1.7)
        for name, value in expected.items():
            np.testing.assert_allclose(getattr(result, name)[i], value, rtol=1e-5, atol=1e-6, err_msg=name)


def test_empty_scans_change_nothing():
    crm = ConfidenceMap(SMALL, "cpu")
    crm.integrate_scans(np.zeros((2, 3)), np.zeros((0, 3)), np.zeros(0, np.int32))
    crm.integrate_scan(np.zeros(3), np.zeros((0, 3)))
    assert len(crm.voxels()[0]) == 0 and crm.num_blocks == 0
    assert crm.raycast(np.zeros((0, 3)), np.zeros((0, 3)), 1.0).hit.shape == (0,)


def test_a_voxel_whose_bins_underflow_within_a_scan_is_reset_and_reported():
    """3 bins: 200 readings of one scan end in a voxel (its m = 1/2 level falls out of float32's
    range against m = 1), then a beam of the scan passes it (ruling out m = 1). The bins cannot
    hold the answer: the voxel goes back to the prior, and the map says so (a warning and a
    count), never silently and never NaN."""
    cfg = SMALL.replace(range_sigma_m=0.02, num_bins=3)
    origin = np.array([0.1, 0.12, 0.12])
    rng = np.random.default_rng(1)
    points = np.concatenate([[1.12, 0.12, 0.12] + rng.uniform(-0.01, 0.01, (200, 3)), [[1.9, 0.12, 0.12]]]).astype(
        np.float32
    )
    for sorted_path in (False, True):
        crm = ConfidenceMap(cfg, "cpu")
        crm._sorted_path = sorted_path
        with pytest.warns(RuntimeWarning, match="fell back to the prior"):
            crm.integrate_scan(origin, points)
        assert crm.prior_resets == 1
        np.testing.assert_array_equal(
            crm.distribution(np.array([[1.12, 0.12, 0.12]]))[0], np.full(3, np.float32(1 / 3))
        )
    fine = ConfidenceMap(cfg, "cpu")  # a scan with a tenth of the readings keeps its evidence
    fine.integrate_scan(origin, points[180:])
    assert fine.prior_resets == 0
