"""Bad input to the confidence-rich map: a ValueError naming the argument, and nothing changed."""

import numpy as np
import pytest

from vogjax.config.crm import CrmConfig
from vogjax.io import write_map_file
from vogjax.maps.confidence import ConfidenceMap

CFG = CrmConfig(voxel_size=0.25, max_range=2.0, range_sigma_m=0.1, num_bins=8)


@pytest.fixture
def crm():
    m = ConfidenceMap(CFG, "cpu")
    rng = np.random.default_rng(0)
    m.integrate_scans(np.zeros((2, 3)), rng.normal(size=(20, 3)), np.repeat([0, 1], 10))
    return m


def snapshot(m):
    return [a.copy() for a in m.voxels()]


def unchanged(m, before):
    for a, b in zip(before, m.voxels()):
        np.testing.assert_array_equal(a, b)


GOOD_POINTS = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


@pytest.mark.parametrize(
    "origin, points, name",
    [
        (np.array([np.nan, 0, 0]), GOOD_POINTS, "origin"),
        (np.zeros(3), np.array([[np.inf, 0, 0]]), "points"),
        (np.zeros(2), GOOD_POINTS, "origin"),
        (np.zeros(3), np.zeros((2, 2)), "points"),
        (np.zeros(3), np.array([["a", "b", "c"]]), "points"),
        (np.zeros(3), np.array([[True, False, True]]), "points"),
        (np.zeros(3), np.array([[1.0, 0, 0], [0.0, 0.0, 0.0]]), "points"),  # a beam without direction
        (np.array([1e7, 0, 0]), GOOD_POINTS, "origin"),
        (np.zeros(3), np.array([[0.0, 0.0, 3e6]]), "points"),  # its cone leaves the key range
    ],
)
def test_integrate_scan_rejects(crm, origin, points, name):
    before = snapshot(crm)
    with pytest.raises(ValueError, match=name):
        crm.integrate_scan(origin, points)
    unchanged(crm, before)


@pytest.mark.parametrize(
    "origins, points, index, name",
    [
        (np.zeros((2, 3)), GOOD_POINTS, np.array([0, 2]), "scan_index"),
        (np.zeros((2, 3)), GOOD_POINTS, np.array([0, -1]), "scan_index"),
        (np.zeros((2, 3)), GOOD_POINTS, np.array([0.0, 1.0]), "scan_index"),
        (np.zeros((2, 3)), GOOD_POINTS, np.array([0]), "scan_index"),
        (np.full((2, 3), np.nan), GOOD_POINTS, np.array([0, 1]), "origins"),
        (np.zeros((2, 3)), np.array([[1.0, 0, 0], [0.0, 0.0, 0.0]]), np.array([0, 1]), "points"),
    ],
)
def test_integrate_scans_rejects(crm, origins, points, index, name):
    before = snapshot(crm)
    with pytest.raises(ValueError, match=name):
        crm.integrate_scans(origins, points, index)
    unchanged(crm, before)


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda m: m.mean(np.array([[np.nan, 0, 0]])), "points"),
        (lambda m: m.variance(np.zeros((3, 2))), "points"),
        (lambda m: m.state(np.array([0, 0, 0])), "points"),
        (lambda m: m.distribution(np.array([[np.inf, 0, 0]])), "points"),
        (lambda m: m.raycast(np.zeros((1, 3)), np.zeros((1, 3)), 1.0), "directions"),
        (lambda m: m.raycast(np.zeros((1, 3)), np.ones((1, 3)), -1.0), "max_range"),
        (lambda m: m.raycast(np.zeros((1, 3)), np.ones((2, 3)), 1.0), "directions"),
        (lambda m: m.raycast(np.zeros((1, 3)), np.ones((1, 3)), 1e7), "max_range"),
    ],
)
def test_queries_reject(crm, call, name):
    with pytest.raises(ValueError, match=name):
        call(crm)


@pytest.mark.parametrize(
    "changes, name",
    [
        ({"num_bins": 1}, "num_bins"),
        ({"num_bins": 65}, "num_bins"),
        ({"num_bins": 8.0}, "num_bins"),
        ({"range_sigma_m": 0.0}, "range_sigma_m"),
        ({"spurious_probability": 1.0}, "spurious_probability"),
        ({"free_threshold": 0.8}, "free_threshold"),
        ({"bin_floor": 0.0}, "bin_floor"),
        ({"bin_floor": 0.009, "num_bins": 64}, "bin_floor"),
        ({"cause_range": "edge"}, "cause_range"),
        ({"max_range": float("nan")}, "max_range"),
    ],
)
def test_config_rejects(changes, name):
    with pytest.raises(ValueError, match=name):
        CrmConfig(**changes)


def test_constructor_rejects_other_configs():
    from vogjax.config import MapConfig

    with pytest.raises(ValueError, match="config"):
        ConfidenceMap(MapConfig(), "cpu")
    with pytest.raises(ValueError, match="device"):
        ConfidenceMap(CFG, "tpu:7")


def _saved(tmp_path, crm):
    path = tmp_path / "map.vog"
    crm.save(path)
    from vogjax.io import read_map_file

    return path, *read_map_file(path, "ConfidenceMap")


def _write(path, metadata, arrays):
    write_map_file(path, "ConfidenceMap", metadata, arrays)
    return path


def test_save_load_round_trip_is_exact(tmp_path, crm):
    path = tmp_path / "map.vog"
    crm.save(path)
    loaded = ConfidenceMap.load(path, device="cpu")
    assert loaded.config == crm.config
    for a, b in zip(crm.voxels(), loaded.voxels()):
        np.testing.assert_array_equal(a, b)
    probe = np.random.default_rng(1).uniform(-3, 3, (200, 3))
    np.testing.assert_array_equal(crm.distribution(probe), loaded.distribution(probe))
    np.testing.assert_array_equal(crm.variance(probe), loaded.variance(probe))
    # and both go on the same way
    more = np.random.default_rng(2).normal(size=(10, 3))
    crm.integrate_scan(np.zeros(3), more)
    loaded.integrate_scan(np.zeros(3), more)
    for a, b in zip(crm.voxels(), loaded.voxels()):
        np.testing.assert_array_equal(a, b)
    copy = crm.copy()
    for a, b in zip(crm.voxels(), copy.voxels()):
        np.testing.assert_array_equal(a, b)


def test_empty_map_round_trip(tmp_path):
    path = tmp_path / "empty.vog"
    ConfidenceMap(CFG, "cpu").save(path)
    loaded = ConfidenceMap.load(path, device="cpu")
    assert len(loaded.voxels()[0]) == 0 and loaded.mean(np.zeros((1, 3)))[0] == CFG.prior_mean


@pytest.mark.parametrize(
    "damage",
    [
        "duplicate_keys",
        "keys_dtype",
        "junk_key",
        "bins_shape",
        "bins_negative",
        "bins_nan",
        "bins_sum",
        "unobserved_not_prior",
        "observed_dtype",
        "missing",
        "config",
        "bins_for_other_count",
    ],
)
def test_load_rejects_damaged_contents(tmp_path, crm, damage):
    path, metadata, arrays = _saved(tmp_path, crm)
    keys, bins, observed = arrays["block_keys"], arrays["bins"].copy(), arrays["observed"]
    if damage == "duplicate_keys":
        keys = np.r_[keys[:1], keys[:1], keys[2:]]
    elif damage == "keys_dtype":
        keys = keys.astype(np.float64)
    elif damage == "junk_key":
        keys = keys.copy()
        keys[0] = -5
    elif damage == "bins_shape":
        bins = bins[:, :, :-1]
    elif damage == "bins_negative":
        i = np.argwhere(observed)[0]
        bins[i[0], i[1], 0] = -0.1
    elif damage == "bins_nan":
        bins[0, 0, 0] = np.nan
    elif damage == "bins_sum":
        i = np.argwhere(observed)[0]
        bins[i[0], i[1]] *= 1.5
    elif damage == "unobserved_not_prior":
        i = np.argwhere(~observed)[0]
        bins[i[0], i[1]] = np.eye(CFG.num_bins)[0]
    elif damage == "observed_dtype":
        observed = observed.astype(np.uint8)
    elif damage == "missing":
        _write(path, metadata, {"block_keys": keys, "bins": bins})
    elif damage == "config":
        metadata = {"config": {**metadata["config"], "num_bins": "many"}}
    elif damage == "bins_for_other_count":
        metadata = {"config": {**metadata["config"], "num_bins": 16}}
    if damage != "missing":
        _write(path, metadata, {"block_keys": keys, "bins": bins, "observed": observed})
    with pytest.raises(ValueError, match="path"):
        ConfidenceMap.load(path, device="cpu")


def test_load_rejects_other_files(tmp_path, crm):
    from vogjax.config import MapConfig
    from vogjax.maps import VoxelMap

    other = tmp_path / "voxels.vog"
    VoxelMap(MapConfig(), "cpu").save(other)
    with pytest.raises(ValueError, match="path"):
        ConfidenceMap.load(other)
    with pytest.raises(ValueError, match="path"):
        ConfidenceMap.load(tmp_path / "missing.vog")
