"""Integration against the brute-force reference and OctoMap; batch equals sequential."""

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import vogjax as vj
from vogjax.kernels import integration
from vogjax.maps import integrator, parallel, voxelmap

from . import reference as ref


def as_dict(vmap):
    centres, values = vmap.voxels()
    keys = np.floor(centres / vmap.config.voxel_size).astype(int)
    return {tuple(k): v for k, v in zip(keys.tolist(), values)}


def test_single_scans_match_reference_exactly():
    rng = np.random.default_rng(0)
    cfg = vj.MapConfig()
    origins, points, scan = ref.random_scans(rng, 6, 60, spread=5.0, far=0.15)
    vmap, cells = vj.VoxelMap(cfg), {}
    for s in range(6):
        vmap.integrate_scan(origins[s], points[scan == s])
        ref.insert_scan(cells, origins[s], points[scan == s], cfg)
    ours = as_dict(vmap)
    assert ours.keys() == cells.keys()
    assert all(ours[k] == cells[k] for k in cells)  # same float32 operations: bit for bit


def test_clamping_and_repeated_hits_match_reference():
    # The same beams over and over drive voxels into both clamps.
    rng = np.random.default_rng(1)
    cfg = vj.MapConfig(voxel_size=0.25)
    origin = np.zeros(3, np.float32)
    points = (rng.normal(size=(40, 3)) * 1.5).astype(np.float32)
    vmap, cells = vj.VoxelMap(cfg), {}
    for _ in range(12):
        vmap.integrate_scan(origin, points)
        ref.insert_scan(cells, origin, points, cfg)
    ours = as_dict(vmap)
    assert ours == cells
    values = np.array(list(ours.values()))
    assert values.max() == cfg.log_clamp_max and values.min() == cfg.log_clamp_min


def test_matches_octomap_on_random_scans():
    octomap = pytest.importorskip("octomap")
    rng = np.random.default_rng(2)
    cfg = vj.MapConfig()
    tree = octomap.OcTree(cfg.voxel_size)
    tree.setProbHit(cfg.prob_hit)
    tree.setProbMiss(cfg.prob_miss)
    tree.setClampingThresMin(cfg.clamp_min)
    tree.setClampingThresMax(cfg.clamp_max)
    origins, points, scan = ref.random_scans(rng, 30, 200, spread=8.0, far=0.1)
    for s in range(30):
        tree.insertPointCloud(
            points[scan == s].astype(np.float64), origins[s].astype(np.float64), maxrange=cfg.max_range
        )
    vmap = vj.VoxelMap(cfg)
    vmap.integrate_scans(origins, points, scan)

    octo = {}
    for leaf in tree.begin_leafs():  # pruned leaves stand for several voxels
        n = int(round(leaf.getSize() / cfg.voxel_size))
        corner = np.floor((np.array(leaf.getCoordinate()) - leaf.getSize() / 2) / cfg.voxel_size + 0.5).astype(int)
        for offset in np.ndindex(n, n, n):
            octo[tuple((corner + offset).tolist())] = leaf.getValue()
    ours = as_dict(vmap)
    assert len(ours) > 100_000
    assert ours.keys() == octo.keys()
    diff = max(abs(ours[k] - octo[k]) for k in octo)
    assert diff <= 1e-5


@pytest.mark.parametrize("scans_per_pass, num_scans", [(16, 4 * 16 + 9), (256, 300), (288, 300)])
def test_batch_equals_sequential_across_passes_and_budget_splits(monkeypatch, scans_per_pass, num_scans):
    # several passes on either device (a GPU takes 2048 scans per pass by default); the CPU
    # replays passes of up to 256 scans (8 words per voxel) with apply_marks_few_words, those of
    # 288 (9 words) with apply_marks, the GPU's kernel
    monkeypatch.setattr(voxelmap, "SCANS_PER_PASS", scans_per_pass)
    monkeypatch.setattr(voxelmap, "SCANS_PER_PASS_CUDA", scans_per_pass)
    monkeypatch.setattr(parallel, "CPU_THREADS", 4)  # parts to OR even on a one-core runner
    replayed = []  # words per voxel of each replay: long passes must not have been split
    apply = integrator._apply
    monkeypatch.setattr(integrator, "_apply", lambda *args, **kw: replayed.append(args[4]) or apply(*args, **kw))
    kernels = set()  # which replay kernels ran
    launch = wp.launch
    monkeypatch.setattr(
        wp, "launch", lambda kernel, *args, **kw: kernels.add(kernel.key) or launch(kernel, *args, **kw)
    )
    rng = np.random.default_rng(3)
    if scans_per_pass == 16:
        origins, points, scan = ref.random_scans(rng, num_scans, 40, far=0.1)
    else:  # a small box: few blocks per pass, no split by the budget
        origins, points, scan = ref.random_scans(rng, num_scans, 40, spread=1.5)
    sequential = vj.VoxelMap()
    for s in range(origins.shape[0]):
        sequential.integrate_scan(origins[s], points[scan == s])
    batch = vj.VoxelMap()
    order = rng.permutation(points.shape[0])  # scan_index need not be sorted
    replayed.clear()
    kernels.clear()
    batch.integrate_scans(origins, points[order], scan[order])
    if scans_per_pass > 16:
        assert max(replayed) == -(-scans_per_pass // 32)
        cuda = batch.device.is_cuda
        assert ("apply_marks" in kernels) == (cuda or max(replayed) > integration.FEW_WORDS)
        assert ("apply_marks_few_words" in kernels) == (not cuda)
    others = [batch]
    if scans_per_pass == 16:  # budget splits (slow for long passes: each split marks again)
        monkeypatch.setattr(voxelmap, "MARK_BUDGET_BYTES", 1 << 16)  # forces recursive splitting
        monkeypatch.setattr(voxelmap, "MARK_BUDGET_BYTES_CUDA", 1 << 16)
        discarded = []  # markings thrown away (over the budget or the scratch)
        clear = integrator.Scratch.clear
        monkeypatch.setattr(integrator.Scratch, "clear", lambda self: discarded.append(1) or clear(self))
        others.append(vj.VoxelMap())
        others[-1].integrate_scans(origins, points, scan)
        # after the first pass, the blocks per scan it found split the passes before they are marked
        assert 0 < len(discarded) < -(-num_scans // scans_per_pass)
    for other in others:
        a, b = sequential.voxels(), other.voxels()
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    num_scans=st.integers(1, 8),
    beams=st.integers(1, 30),
    voxel_size=st.sampled_from([0.05, 0.1, 0.3]),
)
def test_batch_equals_sequential_property(seed, num_scans, beams, voxel_size):
    rng = np.random.default_rng(seed)
    cfg = vj.MapConfig(voxel_size=voxel_size, max_range=3.0)
    origins, points, scan = ref.random_scans(rng, num_scans, beams, spread=4.0, far=0.2)
    sequential, batch = vj.VoxelMap(cfg), vj.VoxelMap(cfg)
    for s in range(num_scans):
        sequential.integrate_scan(origins[s], points[scan == s])
    batch.integrate_scans(origins, points, scan)
    a, b = sequential.voxels(), batch.voxels()
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_occupied_wins_within_a_scan_but_not_across_scans():
    cfg = vj.MapConfig(voxel_size=0.1)
    origin = np.array([0.05, 0.05, 0.05], np.float32)
    # Beam A ends in voxel x=5; beam B passes through it to x=10.
    a = np.array([[0.55, 0.05, 0.05]], np.float32)
    b = np.array([[1.05, 0.05, 0.05]], np.float32)
    one_scan = vj.VoxelMap(cfg)
    one_scan.integrate_scan(origin, np.concatenate([a, b]))
    assert one_scan.log_odds(a)[0] == cfg.log_hit
    two_scans = vj.VoxelMap(cfg)
    two_scans.integrate_scans(np.stack([origin, origin]), np.concatenate([a, b]), [0, 1])
    assert two_scans.log_odds(a)[0] == np.float32(cfg.log_hit + cfg.log_miss)


def test_beam_beyond_max_range_is_free_up_to_it_and_no_hit():
    cfg = vj.MapConfig(voxel_size=0.1, max_range=2.0)
    vmap = vj.VoxelMap(cfg)
    origin = np.array([0.05, 0.05, 0.05], np.float32)
    vmap.integrate_scan(origin, np.array([[5.05, 0.05, 0.05]], np.float32))
    xs = np.arange(0, 60) * 0.1 + 0.05
    states = vmap.state(np.stack([xs, np.full_like(xs, 0.05), np.full_like(xs, 0.05)], axis=1))
    assert np.all(states[:20] == vj.FREE)  # up to 2 m, the voxel holding the cut end excluded
    assert np.all(states[20:] == vj.UNKNOWN)
    assert vmap.voxels()[1].max() < 0  # no hit anywhere


def test_empty_scan_and_empty_batch_change_nothing():
    vmap = vj.VoxelMap()
    vmap.integrate_scan(np.zeros(3), np.zeros((0, 3)))
    vmap.integrate_scans(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0, int))
    assert vmap.voxels()[0].shape == (0, 3) and vmap.num_blocks == 0
