"""Hypothesis properties of the confidence-rich map."""

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from vogjax.config.crm import CrmConfig
from vogjax.maps.confidence import ConfidenceMap

CFG = CrmConfig(voxel_size=0.25, max_range=2.0, range_sigma_m=0.1, num_bins=8)
SETTINGS = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])

coordinate = st.floats(-1.0, 1.0, allow_nan=False, width=32)
point = st.tuples(coordinate, coordinate, coordinate)


@st.composite
def scans(draw, max_scans=4, max_beams=6):
    """(origins (S,3), points (N,3), scan_index (N,)); endpoints up to 3 m out (some no return)."""
    count = draw(st.integers(1, max_scans))
    origins = np.array(draw(st.lists(point, min_size=count, max_size=count)), np.float32)
    points, index = [], []
    for s in range(count):
        for _ in range(draw(st.integers(0, max_beams))):
            direction = np.array(draw(point), np.float64) + np.array([0.0, 0.0, 1e-3])
            length = draw(st.floats(0.05, 3.0))
            points.append(origins[s] + direction / np.linalg.norm(direction) * length)
            index.append(s)
    points = np.array(points, np.float32).reshape(-1, 3)
    keep = np.linalg.norm(points - origins[np.array(index, int)], axis=1) > 0 if index else np.zeros(0, bool)
    return origins, points[keep], np.array(index, np.int32)[keep]


@SETTINGS
@given(batch=scans(), spurious=st.sampled_from([0.0, 0.05]))
def test_distributions_stay_normalised_and_non_negative(batch, spurious):
    crm = ConfidenceMap(CFG.replace(spurious_probability=spurious), "cpu")
    crm.integrate_scans(*batch)
    crm.integrate_scans(*batch)
    centres, mean, variance = crm.voxels()
    bins = crm.distribution(centres)
    assert np.all(bins >= 0) and np.all(np.isfinite(bins))
    np.testing.assert_allclose(bins.sum(axis=1), 1.0, atol=1e-5)
    assert np.all(bins >= CFG.bin_floor * 0.999)  # floored, then renormalised
    assert np.all((mean >= 0) & (mean <= 1)) and np.all(variance >= 0)


@SETTINGS
@given(batch=scans(max_scans=5), split=st.integers(0, 5))
def test_batch_equals_sequential_bit_for_bit(batch, split):
    origins, points, scan_index = batch
    one, two, each = (ConfidenceMap(CFG, "cpu") for _ in range(3))
    one.integrate_scans(origins, points, scan_index)
    first = scan_index < split  # the same scans in two batches
    two.integrate_scans(origins[:split], points[first], scan_index[first])
    if split < len(origins):
        two.integrate_scans(origins[split:], points[~first], scan_index[~first] - split)
    for s in range(len(origins)):
        each.integrate_scan(origins[s], points[scan_index == s])
    for other in (two, each):
        for a, b in zip(one.voxels(), other.voxels()):
            np.testing.assert_array_equal(a, b)


@SETTINGS
@given(origin=point, target=point, inside=point, repeats=st.integers(3, 8))
def test_variance_shrinks_with_consistent_evidence(origin, target, inside, repeats):
    """The same reading again and again: every voxel the beam crosses well before it (more than
    4 sigma) and the voxel of the reading grow more certain, scan after scan."""
    cfg = CFG.replace(range_sigma_m=0.02)
    origin = np.array(origin, np.float32).astype(np.float64)
    # the reading well inside its voxel (0.075 m from its faces), 0.6 to 2 m away
    key = np.floor((origin + 1.8 * np.array(target, np.float64)) / cfg.voxel_size)
    end = ((key + 0.5 + 0.4 * np.array(inside, np.float64)) * cfg.voxel_size).astype(np.float32)
    distance = float(np.linalg.norm(end - origin))
    assume(0.6 < distance < 1.9)
    direction = (end - origin) / distance
    crm = ConfidenceMap(cfg, "cpu")
    # a voxel's chord ends at most sqrt(3) voxel edges past any point of it
    t = np.arange(0.02, distance - 4 * cfg.range_sigma_m - np.sqrt(3) * cfg.voxel_size, 0.05)
    crossed = origin + direction * t[:, None]
    probes = np.concatenate([crossed, end[None].astype(np.float64)])
    previous = np.full(len(probes), cfg.prior_variance)
    for _ in range(repeats):
        crm.integrate_scan(origin, end[None])
        variance = crm.variance(probes)
        assert np.all(variance <= previous + 1e-7)
        previous = variance
    assert np.all(previous < cfg.prior_variance)
    assert crm.mean(end[None])[0] > cfg.prior_mean and np.all(crm.mean(crossed) < cfg.prior_mean)


@SETTINGS
@given(batch=scans(), probes=st.lists(point, min_size=1, max_size=20))
def test_unknown_answers_the_prior(batch, probes):
    crm = ConfidenceMap(CFG, "cpu")
    crm.integrate_scans(*batch)
    probes = np.array(probes, np.float32) * 6.0  # many out of every beam's reach
    unknown = ~crm.observed(probes)
    np.testing.assert_array_equal(crm.mean(probes)[unknown], CFG.prior_mean)
    np.testing.assert_array_equal(crm.variance(probes)[unknown], CFG.prior_variance)
    np.testing.assert_array_equal(crm.distribution(probes)[unknown], np.tile(CFG.prior, (unknown.sum(), 1)))
    known = crm.observed(probes)
    assert np.all(~np.isnan(crm.mean(probes)[known]))
