"""Map files: round trip, atomic writes, and clear errors for damaged files."""

import os

import numpy as np
import pytest

import vogjax as vj
from vogjax.io import atomic

from . import reference as ref


@pytest.fixture
def saved(tmp_path):
    rng = np.random.default_rng(0)
    vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.2, prob_hit=0.8))
    vmap.integrate_scans(*ref.random_scans(rng, 4, 100))
    path = tmp_path / "map.vog"
    vmap.save(path)
    return vmap, path


def test_round_trip(saved):
    vmap, path = saved
    loaded = vj.VoxelMap.load(path)
    assert loaded.config == vmap.config
    a, b = vmap.voxels(), loaded.voxels()
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    # The loaded map keeps integrating exactly like the original.
    rng = np.random.default_rng(9)
    more = ref.random_scans(rng, 3, 50)
    vmap.integrate_scans(*more)
    loaded.integrate_scans(*more)
    assert np.array_equal(vmap.voxels()[1], loaded.voxels()[1])


def test_empty_map_round_trip(tmp_path):
    vj.VoxelMap().save(tmp_path / "empty.vog")
    assert vj.VoxelMap.load(tmp_path / "empty.vog").num_blocks == 0


def test_write_is_atomic(saved, monkeypatch):
    vmap, path = saved
    original = path.read_bytes()

    def crash(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(atomic.os, "fsync", crash)
    with pytest.raises(OSError):
        vmap.save(path)
    assert path.read_bytes() == original  # the old file is untouched
    assert os.listdir(path.parent) == [path.name]  # and no temporary file is left


@pytest.mark.parametrize(
    "damage, message",
    [
        (lambda b: b[: len(b) // 2], "truncated"),
        (lambda b: b[:10], "truncated"),
        (lambda b: b[:-1] + bytes([b[-1] ^ 1]), "checksum"),
        (lambda b: b"NOTAMAP!" + b[8:], "not a vogjax map"),
        (lambda b: b[:8] + (99).to_bytes(4, "little") + b[12:], "version 99"),
        (lambda b: b + b"extra", "trailing"),
    ],
)
def test_damaged_files_give_clear_errors(saved, damage, message):
    _, path = saved
    path.write_bytes(damage(path.read_bytes()))
    with pytest.raises(ValueError, match=message):
        vj.VoxelMap.load(path)


def test_missing_file(tmp_path):
    with pytest.raises(ValueError, match="cannot be read"):
        vj.VoxelMap.load(tmp_path / "nope.vog")


def test_a_header_is_checksummed_and_format_1_files_still_load(saved, tmp_path):
    vmap, path = saved
    data = path.read_bytes()
    # one changed digit in the JSON header (the config) is caught, not loaded as another map
    damaged = data.replace(b'"voxel_size": 0.2', b'"voxel_size": 0.3', 1)
    assert damaged != data
    path.write_bytes(damaged)
    with pytest.raises(ValueError, match="checksum"):
        vj.VoxelMap.load(path)
    # the same map written as format 1 (payload checksum only, no trailing digest) still loads
    old = bytearray(data[:-32])
    old[8:12] = (1).to_bytes(4, "little")
    (tmp_path / "old.vog").write_bytes(bytes(old))
    loaded = vj.VoxelMap.load(tmp_path / "old.vog")
    assert all(np.array_equal(a, b) for a, b in zip(loaded.voxels(), vmap.voxels()))
