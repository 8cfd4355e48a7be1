"""Integration's paths give one map: the dense-box and hashed scratch, scratch regrowth after an
overflow, a box too small for a walk (rerun hashed), one CPU thread or several, against the
brute-force reference of tests/reference.py (OctoMap's update rule) and sequential integration."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import vogjax as vj
from vogjax.maps import integrator, parallel

from . import reference as ref


def contents(vmap):
    """Observed voxel keys (K,3) and log-odds (K,), in lexicographic key order."""
    centres, values = vmap.voxels()
    keys = np.floor(centres / vmap.config.voxel_size).astype(np.int64)
    order = np.lexsort(keys.T[::-1])
    return keys[order], values[order]


def integrated(cfg, origins, points, scan):
    vmap = vj.VoxelMap(cfg)
    vmap.integrate_scans(origins, points, scan)
    return contents(vmap)


def reference_contents(cfg, origins, points, scan):
    cells = {}
    for s in range(origins.shape[0]):
        ref.insert_scan(cells, origins[s], points[scan == s], cfg)
    keys = np.array(sorted(cells), dtype=np.int64).reshape(-1, 3)
    return keys, np.array([cells[tuple(k)] for k in keys.tolist()], np.float32)


def assert_same(a, b):
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


@pytest.fixture
def scans():
    rng = np.random.default_rng(11)
    cfg = vj.MapConfig(voxel_size=0.1)
    return cfg, *ref.random_scans(rng, 40, 50, spread=4.0, far=0.1)


def test_every_path_gives_the_reference_map(scans, monkeypatch):
    cfg, origins, points, scan = scans
    expected = reference_contents(cfg, origins, points, scan)
    assert len(expected[1]) > 50_000
    assert_same(integrated(cfg, origins, points, scan), expected)  # dense box, threads
    with monkeypatch.context() as m:
        m.setattr(integrator, "DENSE_CELLS", 0)  # every block through the hash table
        assert_same(integrated(cfg, origins, points, scan), expected)
    with monkeypatch.context() as m:
        m.setattr(parallel, "MIN_ITEMS_PER_PART", 10**9)  # one thread, one scratch
        assert_same(integrated(cfg, origins, points, scan), expected)
    with monkeypatch.context() as m:
        m.setattr(parallel, "MIN_ITEMS_PER_PART", 16)  # as many threads as cores, small parts
        assert_same(integrated(cfg, origins, points, scan), expected)


def test_scratch_overflow_and_a_box_that_misses_rerun_the_pass(scans, monkeypatch):
    cfg, origins, points, scan = scans
    expected = reference_contents(cfg, origins, points, scan)
    integrator._pool.clear()  # fresh scratches: the smallest, so passes overflow and regrow
    monkeypatch.setattr(integrator, "_MIN_BLOCKS", 1)
    assert_same(integrated(cfg, origins, points, scan), expected)
    # a box 8 blocks short on every side: walks leave it, the pass reruns hashed
    real = integrator._boxes
    monkeypatch.setattr(
        integrator,
        "_boxes",
        lambda *a: [
            None if box is None else (tuple(v + 8 for v in box[0]), tuple(max(1, v - 16) for v in box[1]))
            for box in real(*a)
        ],
    )
    assert_same(integrated(cfg, origins, points, scan), expected)
    integrator._pool.clear()


@settings(max_examples=20, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    num_scans=st.integers(1, 70),
    dense=st.booleans(),
    voxel_size=st.sampled_from([0.05, 0.2]),
)
def test_batch_equals_reference_property(seed, num_scans, dense, voxel_size):
    rng = np.random.default_rng(seed)
    cfg = vj.MapConfig(voxel_size=voxel_size, max_range=3.0)
    origins, points, scan = ref.random_scans(rng, num_scans, 6, spread=4.0, far=0.2)
    old = integrator.DENSE_CELLS
    integrator.DENSE_CELLS = old if dense else 0
    try:
        assert_same(integrated(cfg, origins, points, scan), reference_contents(cfg, origins, points, scan))
    finally:
        integrator.DENSE_CELLS = old


def test_clamped_voxels_skip_updates_exactly():
    # Many scans through the same voxels drive them into both clamps and back: the replay skips
    # updates at a clamp that cannot move the value; the result must equal every update applied.
    rng = np.random.default_rng(5)
    cfg = vj.MapConfig(voxel_size=0.25, max_range=6.0)
    origins = np.repeat(rng.uniform(-0.2, 0.2, (1, 3)), 90, axis=0).astype(np.float32)
    targets = rng.normal(size=(12, 3)) * 1.5
    points = np.concatenate([targets * (1.0 if s % 7 else 1.6) for s in range(90)]).astype(np.float32)
    scan = np.repeat(np.arange(90), 12)
    got = integrated(cfg, origins, points, scan)
    assert_same(got, reference_contents(cfg, origins, points, scan))
    assert got[1].max() == cfg.log_clamp_max and got[1].min() == cfg.log_clamp_min
