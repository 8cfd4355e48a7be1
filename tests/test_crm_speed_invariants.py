"""ConfidenceMap's speed-ups change no bit: the chunking of the block listing, the packed scan
order, the rescale test of the update (a map whose bins fall towards underflow mid-scan), and
the block listing's walk over block planes only."""

import numpy as np
import pytest
import warp as wp

from tests.crm_reference import ReferenceCrm
from tests.test_crm import SMALL, random_scans
from vogjax.kernels import confidence as confidence_kernels
from vogjax.kernels import hashing, traversal
from vogjax.maps import confidence
from vogjax.maps.blocks import EMPTY_KEY
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


@pytest.mark.parametrize("spurious", [0.0, 0.01])
def test_conflicting_beams_through_one_voxel_rescale_alike_on_both_paths(spurious):
    # in one scan 300 beams end in one voxel and 300 pass through it: every bin of it falls far
    # below the rescale threshold mid-scan, and more free passes than a pending byte counts
    # reach the voxels before it; the CPU and the sorted path must agree bit for bit (with
    # spurious readings the CPU counts each beam's free passes, then takes them back)
    cfg = SMALL.replace(range_sigma_m=0.05, spurious_probability=spurious)
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


@wp.kernel
def _walk_cone_blocks(
    origins: wp.array(dtype=wp.vec3d),
    directions: wp.array(dtype=wp.vec3d),
    lengths: wp.array(dtype=wp.float64),
    resolution: wp.float64,
    inv_resolution: wp.float64,
    block_keys: wp.array2d(dtype=wp.int64),
    block_counts: wp.array(dtype=wp.int32),
    voxel_counts: wp.array(dtype=wp.int32),
):
    """Reference: the voxel walk of fill_cone_steps, voxel by voxel, listing the block of every
    voxel it takes into the cone (traversal.holds_chord; each block once on entering it)."""
    tid = wp.tid()
    length = lengths[tid]
    w = traversal.ray_walk_begin(origins[tid], directions[tid], resolution, inv_resolution, length)
    voxel, t_max, t_in = wp.vec3i(w.voxel), wp.vec3d(w.t_max), wp.float64(0.0)
    n_blocks = int(0)
    n_voxels = int(0)
    last = wp.int64(-1)  # EMPTY_KEY
    steps = int(0)
    while t_in < length and steps <= w.max_steps:
        if traversal.holds_chord(t_in, wp.min(wp.min(wp.min(t_max[0], t_max[1]), t_max[2]), length), resolution):
            key = hashing.pack_block(hashing.block_of(voxel))
            if key != last:
                block_keys[tid, n_blocks] = key
                n_blocks += 1
                last = key
            n_voxels += 1
        voxel, t_max, t_in, _new = traversal.walk_step(voxel, w.step, t_max, w.t_delta)
        steps += 1
    block_counts[tid] = n_blocks
    voxel_counts[tid] = n_voxels


def _hostile_beams(rng, resolution):
    """Beams from voxel and block corners and plane points along axes and diagonals (planes of
    two or three axes crossed at one distance), and random ones; lengths up to 30 blocks."""
    s = resolution
    corners = np.array(
        [[0, 0, 0], [8 * s, 8 * s, 8 * s], [-8 * s, 0, 4 * s], [3 * s, -5 * s, 0.5 * s], [0.5 * s, 0.5 * s, 0.5 * s]]
    )
    axes = [
        [1, 0, 0],
        [0, -1, 0],
        [0, 0, 1],
        [1, 1, 0],
        [1, -1, 1],
        [-1, -1, -1],
        [1, 2, 0],
        [2, 1, 1],
        [1, 1, 1e-12],
        [0.6, 0.8, 0],
    ]
    starts, directions = [], []
    for c in corners:
        for d in axes:
            starts.append(c)
            directions.append(d)
    starts += list(rng.uniform(-3, 3, (300, 3)))
    directions += list(rng.normal(size=(300, 3)))
    starts, directions = np.array(starts, np.float64), np.array(directions, np.float64)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    lengths = np.concatenate([rng.uniform(0.01, 30 * 8 * s, len(starts) - 300), rng.uniform(0.0, 6.0, 300)])
    return starts, directions, lengths, len(starts) - 300


@pytest.mark.parametrize("resolution", [0.1, 0.25, 0.037])
def test_block_listing_is_the_voxel_walks_blocks(resolution):
    """list_cone_blocks walks block planes only, summing each axis's plane distances as the
    voxel walk does: its blocks are exactly those the voxel walk meets, in order, and its bound
    is the voxel walk's count (above it only where two axes' planes are crossed at once). Blocks
    it listed lately are left out, but each block is listed by some beam."""
    rng = np.random.default_rng(8)
    starts, directions, lengths, hostile = _hostile_beams(rng, resolution)
    n, room = len(starts), 512
    arrays = [
        wp.array(starts, dtype=wp.vec3d),
        wp.array(directions, dtype=wp.vec3d),
        wp.array(lengths, dtype=wp.float64),
    ]
    args = [np.float64(resolution), np.float64(1.0 / resolution)]

    def listing(recent_blocks, beams):
        keys = wp.empty((n, room), dtype=wp.int64)
        counts, bounds = wp.empty(n, dtype=wp.int32), wp.empty(n, dtype=wp.int32)
        for a, b in beams:
            recent = wp.full(recent_blocks, EMPTY_KEY, dtype=wp.int64)
            wp.launch(
                confidence_kernels.list_cone_blocks,
                dim=b - a,
                inputs=[arrays[0][a:b], arrays[1][a:b], arrays[2][a:b], *args, recent],
                outputs=[keys[a:b], counts[a:b], bounds[a:b]],
                device="cpu",
            )
        return keys.numpy(), counts.numpy(), bounds.numpy()

    ref_keys, ref_counts = wp.full((n, room), EMPTY_KEY, dtype=wp.int64), wp.empty(n, dtype=wp.int32)
    ref_voxels = wp.empty(n, dtype=wp.int32)
    wp.launch(
        _walk_cone_blocks, dim=n, inputs=[*arrays, *args], outputs=[ref_keys, ref_counts, ref_voxels], device="cpu"
    )
    ref_keys, ref_counts, ref_voxels = ref_keys.numpy(), ref_counts.numpy(), ref_voxels.numpy()
    # beam by beam (nothing listed lately): every block, in order
    keys, counts, bounds = listing(2048, [(i, i + 1) for i in range(n)])
    np.testing.assert_array_equal(counts, ref_counts)
    np.testing.assert_array_equal(keys, ref_keys)
    assert np.all(bounds >= ref_voxels)
    np.testing.assert_array_equal(bounds[hostile:], ref_voxels[hostile:])  # random beams: no ties
    assert np.any(bounds[:hostile] > ref_voxels[:hostile])  # the hostile ones do tie
    # all at once, a small table of blocks listed lately (collisions): each block listed at least once
    for size in (1, 16, 2048):
        keys, counts, _ = listing(size, [(0, n)])
        np.testing.assert_array_equal(counts, ref_counts)
        assert set(keys[keys != EMPTY_KEY].tolist()) == set(ref_keys[ref_keys != EMPTY_KEY].tolist())
        listed = keys != EMPTY_KEY
        assert np.all(keys[listed] == ref_keys[listed])  # in place


def test_beams_whose_planes_tie_match_the_reference():
    """Beams along diagonals from voxel corners cross two or three axes' planes at once: the
    walk fills fewer voxels than the listing's bound, and the cones are moved back to back."""
    cfg = SMALL.replace(range_sigma_m=0.05)
    s = cfg.voxel_size
    origins = np.array([[0.0, 0.0, 0.0], [s, 2 * s, 0.5 * s]])
    d = np.array([[1, 1, 0], [1, 1, 1], [1, -1, 0], [0, 1, 1], [-1, -1, 1], [1, 0.5, 0]], np.float64)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = np.concatenate([o + d * r for o in origins for r in (1.1, 1.7)]).astype(np.float32)
    scan_index = np.repeat(np.arange(2), 12)
    crm, ref = ConfidenceMap(cfg, "cpu"), ReferenceCrm(cfg)
    for s_ in range(2):
        crm.integrate_scan(origins[s_], points[scan_index == s_])
        ref.integrate_scan(origins[s_].astype(np.float32), points[scan_index == s_])
    centres = crm.voxels()[0]
    keys = [tuple(k) for k in np.floor(centres / cfg.voxel_size).astype(int)]
    assert set(keys) == set(ref.cells)
    np.testing.assert_allclose(crm.distribution(centres), np.array([ref.cells[k] for k in keys]), atol=2e-6)
    batch = ConfidenceMap(cfg, "cpu")
    batch._sorted_path = True
    batch.integrate_scans(origins, points, scan_index)
    for a, b in zip(batch.voxels(), crm.voxels()):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("sorted_path", [False, True])
def test_variances_at_the_end_of_a_batch_are_those_after_every_scan(monkeypatch, sorted_path):
    rng = np.random.default_rng(12)
    origins, points, scan_index = random_scans(rng, 8, 15)
    probe = np.concatenate([points, origins])
    results = []
    for at_end in (0.0, float("inf")):  # always at the end, never
        monkeypatch.setattr(confidence, "VARIANCES_AT_END", at_end)
        crm = ConfidenceMap(SMALL, "cpu")
        crm._sorted_path = sorted_path
        crm.integrate_scans(origins, points, scan_index)
        results.append((*_contents(crm, probe), crm.variance(probe)))
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)
    assert np.isfinite(results[0][2]).all()  # the observed voxels' variances were computed


@pytest.mark.parametrize("free_beams", [253, 254, 255])
def test_a_full_count_of_free_passes_flushes_alike_on_both_paths(free_beams):
    """254 passes fill a voxel's count just as a beam whose free passes are taken back
    (spurious readings) reaches it: the passes go before its factor on both paths (64 bins,
    where the order shows in the bits)."""
    cfg = SMALL.replace(range_sigma_m=0.1, num_bins=64, spurious_probability=0.01)
    origin = np.array([0.1, 0.1, 0.1])
    rng = np.random.default_rng(0)
    d = np.tile([-1.0, 0.0, 0.0], (free_beams, 1)) + rng.uniform(-0.05, 0.05, (free_beams, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    points = np.concatenate([origin + d * 3.0, [[1.5, 0.1, 0.1]]]).astype(np.float32)  # no returns, then a return
    maps = []
    for sorted_path in (False, True):
        crm = ConfidenceMap(cfg, "cpu")
        crm._sorted_path = sorted_path
        crm.integrate_scan(origin, points)
        crm.integrate_scan(origin, points)
        maps.append(_contents(crm, points))
    for a, b in zip(*maps):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("hits, passes", [(800, 12), (1000, 20)])
def test_free_passes_after_hundreds_of_readings_keep_the_next_level(hits, passes):
    """A voxel hundreds of a scan's readings end in, then passed by a few beams of the same
    scan: the passes rule out m = 1 and the evidence leaves m = 14/15 (the reference). Applied
    as one power, the next level lies far below float32's range at first: it is kept (float64
    powers, rescaled), not lost to a uniform reset."""
    cfg = SMALL.replace(range_sigma_m=0.02, num_bins=16)
    origin = np.array([0.1, 0.12, 0.12])
    rng = np.random.default_rng(1)
    points = np.concatenate(
        [
            [1.12, 0.12, 0.12] + rng.uniform(-0.01, 0.01, (hits, 3)),
            [1.9, 0.12, 0.12] + rng.uniform(-0.01, 0.01, (passes, 3)),
        ]
    ).astype(np.float32)
    ref = ReferenceCrm(cfg)
    ref.integrate_scan(origin.astype(np.float32), points)
    voxel = np.array([[1.12, 0.12, 0.12]])
    expected = ref.cells[tuple(np.floor(voxel[0] / cfg.voxel_size).astype(int))]
    for sorted_path in (False, True):
        crm = ConfidenceMap(cfg, "cpu")
        crm._sorted_path = sorted_path
        crm.integrate_scan(origin, points)
        np.testing.assert_allclose(crm.distribution(voxel)[0], expected, atol=2e-6)
