"""ConfidenceMap's speed-ups change no bit: the chunking of the block listing, the packed scan
order, and the rescale test of the update (a map whose bins fall towards underflow mid-scan)."""

import numpy as np
import pytest

from tests.test_crm import SMALL, random_scans
from vogjax.maps import confidence
from vogjax.maps.confidence import ConfidenceMap


def _contents(crm: ConfidenceMap, probe: np.ndarray):
    return (*crm.voxels(), crm.distribution(probe))


@pytest.mark.parametrize("sorted_path", [False, True])
def test_listing_chunks_and_pass_splits_change_no_bit(monkeypatch, sorted_path):
    rng = np.random.default_rng(3)
    origins, points, scan_index = random_scans(rng, 12, 10)
    probe = np.concatenate([points, origins, rng.uniform(-3, 3, (50, 3))])
    results = []
    for scans_per_pass, budget, entries in ((64, 1 << 21, 1 << 21), (3, 150, 1 << 21), (3, 150, 1), (2, 1 << 21, 40)):
        monkeypatch.setattr(confidence, "SCANS_PER_PASS", scans_per_pass)
        monkeypatch.setattr(confidence, "STEP_BUDGET", budget)
        monkeypatch.setattr(confidence, "PLAN_ENTRIES", entries)
        crm = ConfidenceMap(SMALL, "cpu")
        crm._sorted_path = sorted_path
        crm.integrate_scans(origins, points, scan_index)
        results.append(_contents(crm, probe))
    for other in results[1:]:
        for a, b in zip(results[0], other):
            np.testing.assert_array_equal(a, b)


def test_scan_order_is_the_lexsort_of_scan_and_coordinates():
    rng = np.random.default_rng(5)
    specials = np.array([0.0, -0.0, 1.5, -1.5, 1e-45, -1e-45, 3e-39, -3e-39, 1e30, -1e30, 2.0], np.float32)
    for trial in range(100):
        n = int(rng.integers(1, 200))
        if trial % 2:
            points = rng.choice(specials, size=(n, 3)).astype(np.float32)
        else:
            points = rng.normal(size=(n, 3)).astype(np.float32)
        scan_index = rng.integers(0, 4, n).astype(np.int32)
        expected = np.lexsort((points[:, 2], points[:, 1], points[:, 0], scan_index))
        np.testing.assert_array_equal(confidence._scan_order(points, scan_index), expected)


def test_conflicting_beams_through_one_voxel_rescale_alike_on_both_paths():
    # in one scan 300 beams end in one voxel and 300 pass through it: every bin of it falls far
    # below the rescale threshold mid-scan; the CPU and the sorted path must agree bit for bit
    cfg = SMALL.replace(range_sigma_m=0.05)
    rng = np.random.default_rng(11)
    origin = np.array([0.1, 0.1, 0.1])
    jitter = rng.uniform(-0.02, 0.02, (600, 3))
    points = np.concatenate([np.tile([0.9, 0.12, 0.12], (300, 1)), np.tile([1.8, 0.14, 0.14], (300, 1))]) + jitter
    maps = []
    for path in (False, True):
        crm = ConfidenceMap(cfg, "cpu")
        crm._sorted_path = path
        crm.integrate_scan(origin, points)
        crm.integrate_scan(origin, points[::-1])
        maps.append(_contents(crm, points))
    for a, b in zip(*maps):
        np.testing.assert_array_equal(a, b)
    _, mean, variance = maps[0][:3]
    assert np.all(np.isfinite(mean)) and np.all(variance >= 0)
