"""ConfidenceMap: the confidence-rich map of Agha-mohammadi (*Confidence-aware Occupancy Grid
Mapping*) on the hashed 8x8x8 voxel blocks, integrated and queried in Warp.

Each voxel holds a distribution over its occupancy level m in [0, 1], not one probability, so
the map reports how sure it is (the variance) besides what it believes (the mean), and beams are
explained by a forward sensor model instead of a hand-tuned inverse sensor model.

Decisions the paper leaves open, made here (each one tested):

- **Discretisation.** The distribution lives on `num_bins` levels m_k = k/(K-1), both ends
  included (a voxel can be certainly free or certainly full; a midpoint grid would floor the
  error of a free voxel at 1/(2K)). K = 16 by default: on sonar scans of the tank its means lie
  within 0.014 on average of a 64-bin filter's (8 bins: 0.027, 32 bins: 0.005) at 73 bytes per
  voxel (41, 137); benchmarks/bench_crm.py measures the trade-off.
- **Prior.** Uniform over the levels: mean 0.5, variance (K+1)/(12(K-1)). A never-observed
  voxel answers exactly these, and a beam meets it with bounce probability 0.5 (the paper's
  random worlds are half full). A long reading through unexplored space is then improbable
  under any single cause, which is why `spurious_probability` defaults to 0 (the paper's
  model): above 0, such readings read as spurious and the map stops growing into the unknown.
- **Sensor model.** The range of a cause voxel is spread evenly over the beam's chord through
  it (for sigma much larger than a voxel this is the paper's N(||G_c - x||, R)); a reading past
  `max_range` is "no return", explained by the cause at infinity or by a voxel whose noisy
  reading would have landed past the range; returns may be spurious with
  `spurious_probability` (uniform over the range). Voxels more than `cone_sigmas` sigma past a
  return are not causes. Details and the update formula: `vogjax.kernels.confidence`.
- **A scan.** All beams of a scan are explained by the map as it was before the scan, and a
  voxel crossed by several of them takes all their likelihood factors (the beams' noises are
  independent), in a fixed order (by endpoint coordinates, so the order the points come in
  changes no bit). Then it is renormalised, no bin is left below `bin_floor`, and it is
  renormalised again (the floor plays the part of OctoMap's clamping).
- **Unknown.** Nothing reads as zero for "unknown": mean and variance layers hold NaN until a
  voxel is first updated, and queries answer the prior there.

Conventions follow VoxelMap: voxel k covers [k*s, (k+1)*s); inputs are float32 world
coordinates; bad input raises ValueError naming the argument before anything changes;
`integrate_scans` gives the same map, bit for bit, as `integrate_scan` scan by scan; queries
may run from many threads while updates wait for them.

Memory: 4*K + 9 bytes per voxel of an allocated block (K float32 bins, mean, variance, one
flag byte): 73 bytes at K = 16, against VoxelMap's 4.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import math
import warnings
from os import PathLike

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax import devices
from vogjax.config.crm import CrmConfig
from vogjax.io import read_map_file, write_map_file
from vogjax.kernels import confidence, confidence_queries, hashing
from vogjax.maps import parallel
from vogjax.maps.blockmap import FREE, MAX_LINE_VOXELS, OCCUPIED, UNKNOWN, ray_arguments
from vogjax.maps.blocks import BLOCK_VOXELS, EMPTY_KEY, BlockStore, pack_blocks, unpack_blocks, voxel_keys
from vogjax.maps.locking import ReadWriteLock
from vogjax.validation import float_array, index_array, within_key_range

# Scans integrated per pass (a pass lists, allocates and walks its beams' cones together).
SCANS_PER_PASS = 64
# Cone voxels per pass; a pass above it is split (about 36 bytes of scratch each, 80 on CUDA).
STEP_BUDGET = 1 << 21
# Blocks a listing thread remembers, so that it lists each of them about once (8 bytes each; a
# power of two: a block's hash picks its place).
RECENT_BLOCKS = 2048
# A batch computes its variances at its end when its cones' voxel steps reach this many times
# the voxels of its blocks (else after every scan).
VARIANCES_AT_END = 1.0
# Passes whose cones' blocks are listed in one launch are merged while their beams times the
# blocks a cone may cross stay below this (8 bytes of scratch each; one pass may exceed it).
PLAN_ENTRIES = 1 << 21


@dataclasses.dataclass(frozen=True)
class ConfidenceRaycast:
    """What `ConfidenceMap.raycast` found along each of R rays.

    The counts, variances and reach probability are over the voxels a ray passed before its hit
    (or over its whole range), never-observed ones at the prior.

    Attributes
    ----------
    hit : (R,) ndarray of bool
        A voxel whose mean reaches occupied_threshold was met within the range.
    distance : (R,) ndarray of float32
        Where the ray enters that voxel, metres; the range where there was no hit.
    num_unknown : (R,) ndarray of int32
        Voxels passed whose mean lies between the thresholds (never-observed ones included).
    num_free : (R,) ndarray of int32
        Voxels passed whose mean is at or below free_threshold.
    variance_sum : (R,) ndarray of float32
        Sum of the passed voxels' variances (what a planner weighs as risk, Eq. 34).
    variance_max : (R,) ndarray of float32
        The largest of them.
    reach_probability : (R,) ndarray of float32
        The chance a beam passes them all without bouncing, ``prod(1 - mean)`` (Eq. 16).
    """

    hit: npt.NDArray[np.bool_]
    distance: npt.NDArray[np.float32]
    num_unknown: npt.NDArray[np.int32]
    num_free: npt.NDArray[np.int32]
    variance_sum: npt.NDArray[np.float32]
    variance_max: npt.NDArray[np.float32]
    reach_probability: npt.NDArray[np.float32]


@dataclasses.dataclass(frozen=True)
class _Cones:
    """A pass's cones: first_step (B+1,) host and device, returned (B,) int32; per cone voxel
    (T,): its index in the voxel pool and the likelihood of its beam's reading if it caused it."""

    first_step: np.ndarray
    d_first_step: wp.array
    returned: wp.array
    step_voxel: wp.array
    step_likelihood: wp.array
    band_start: wp.array  # (B,) int32: the steps of a cone before its first nonzero likelihood
    filled: wp.array  # (B,) int32: the steps of a cone (its room, first_step's difference, may hold more)


def _compacted(cones: _Cones, filled: np.ndarray, d_filled: wp.array, device) -> _Cones:
    """The cones with each beam's first `filled` steps only, back to back."""
    first_step = np.zeros(len(filled) + 1, np.int64)
    np.cumsum(filled, out=first_step[1:])
    total = int(first_step[-1])
    compact = _Cones(
        first_step,
        wp.array(first_step.astype(np.int32), dtype=wp.int32, device=device),
        cones.returned,
        wp.empty(total, dtype=wp.int32, device=device),
        wp.empty(total, dtype=wp.float64, device=device),
        cones.band_start,
        d_filled,
    )  # counted from each cone's first step: unchanged
    wp.launch(
        confidence.compact_cone_steps,
        dim=len(filled),
        inputs=[cones.d_first_step, d_filled, compact.d_first_step, cones.step_voxel, cones.step_likelihood],
        outputs=[compact.step_voxel, compact.step_likelihood],
        device=device,
    )
    return compact


_executor: concurrent.futures.ThreadPoolExecutor | None = None


def _background() -> concurrent.futures.ThreadPoolExecutor:
    global _executor
    if _executor is None:
        _executor = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="vogjax-crm")
    return _executor


@dataclasses.dataclass(frozen=True)
class _Beams:
    """Beams in scan order: `on_device`, Warp arrays that passes slice: starts, unit directions
    (N,3) vec3d; lengths (N,) of the cones, ranges (N,) to the readings, float64; returned (N,)
    int32. On the host: lengths (N,) and scan_ends (S,), one past each scan's beams."""

    lengths: np.ndarray
    scan_ends: np.ndarray
    on_device: tuple


class ConfidenceMap:
    """The confidence-rich occupancy map of Agha-mohammadi, on dense 8x8x8 blocks in a hash table.

    Each voxel holds a distribution over its occupancy level m in [0, 1] (`CrmConfig.num_bins`
    levels), so the map reports how sure it is (the variance) besides what it believes (the
    mean); beams are explained by a forward sensor model. A never-observed voxel answers the
    uniform prior (mean 0.5). `integrate_scans` gives the same map, bit for bit, as
    `integrate_scan` scan by scan; queries may run from many threads while updates wait for
    them. Memory: ``4 * num_bins + 9`` bytes per voxel of an allocated block (73 at 16 bins).

    Parameters
    ----------
    config : CrmConfig or None, optional
        Voxel size, range noise, bins, sensor-model constants and thresholds (default:
        ``CrmConfig()``).
    device : str or warp.Device or None, optional
        Warp device; None picks CUDA when available, else the CPU.

    Attributes
    ----------
    config : CrmConfig
        The map's settings.
    device : warp.Device
        Where the map lives.
    prior_resets : int
        Voxel updates that fell back to the prior because every bin underflowed within a scan
        (each also warns: more bins, or fewer readings a scan, avoid it).
    revision : int
        Counts integrations.

    Raises
    ------
    ValueError
        If `config` is not a CrmConfig or `device` is not available.

    Examples
    --------
    >>> import numpy as np
    >>> crm = ConfidenceMap(CrmConfig(voxel_size=0.1), device="cpu")
    >>> crm.integrate_scan([0.0, 0.0, 0.0], [[2.05, 0.05, 0.05]])
    >>> bool(crm.mean([[2.05, 0.05, 0.05]])[0] > 0.5), bool(crm.mean([[1.05, 0.05, 0.05]])[0] < 0.5)
    (True, True)
    """

    def __init__(self, config: CrmConfig | None = None, device: str | wp.Device | None = None):
        if config is not None and not isinstance(config, CrmConfig):
            raise ValueError(f"config must be a CrmConfig, got {type(config).__name__}")
        self.config = config or CrmConfig()
        self.device = devices.resolve(device)
        self._kernels = confidence.for_bins(self.config.num_bins)
        self._prior = self._kernels.Bins(*self.config.prior.tolist())
        self._free_powers = wp.array(self._kernels.free_powers, dtype=self._kernels.Bins64, device=self.device)
        self._resets = wp.zeros(1, dtype=wp.int32, device=self.device)
        # voxel updates that fell back to the prior (every bin underflowed within a scan): see README
        self.prior_resets = 0
        self._store = BlockStore(self.device, self._layer_specs())
        self._lock = ReadWriteLock()
        # The parallel path replays each voxel's factors after a sort; on the CPU one thread
        # walks the scans in order instead (same bits; tests run both).
        self._sorted_path = self.device.is_cuda
        self.revision = 0  # counts integrations

    def _layer_specs(self) -> dict:
        return {
            "bins": (self._kernels.Bins, self._prior),
            "mean": (wp.float32, math.nan),
            "variance": (wp.float32, math.nan),
            "pending": (wp.uint8, 0),
        }

    @property
    def store(self) -> BlockStore:
        """The block storage (layers "bins", "mean", "variance", "pending"); read under `reading()`."""
        return self._store

    def reading(self) -> contextlib.AbstractContextManager[None]:
        """Hold the map's read lock: no update runs while it is held.

        Returns
        -------
        contextlib.AbstractContextManager
            A context manager; other readers may hold the lock at the same time.
        """
        return self._lock.reading()

    # ---------------------------------------------------------------- integration
    def integrate_scan(self, origin: npt.ArrayLike, points: npt.ArrayLike) -> None:
        """Integrate one scan: every beam is explained by the map as it was before the scan.

        Parameters
        ----------
        origin : (3,) array_like of float
            Sensor position, metres, world frame.
        points : (N, 3) array_like of float
            Beam endpoints, metres, world frame; an endpoint farther than max_range from
            `origin` means no return along that beam. The order of the points changes no bit.

        Raises
        ------
        ValueError
            Before anything changes, if an array has the wrong shape or holds NaN or infinite
            values, a point equals the origin (a beam needs a direction), or a beam reaches
            beyond the key range.
        """
        origin = float_array("origin", origin, (3,))
        points = float_array("points", points, (-1, 3))
        beams = self._beams(origin[None], points, np.zeros(points.shape[0], np.int32))
        with self._lock.writing():
            self._integrate_passes(beams)
            self.revision += 1

    def integrate_scans(self, origins: npt.ArrayLike, points: npt.ArrayLike, scan_index: npt.ArrayLike) -> None:
        """Integrate a batch of scans: the same map, bit for bit, as `integrate_scan` in order.

        Parameters
        ----------
        origins : (S, 3) array_like of float
            Sensor position per scan, metres, world frame.
        points : (N, 3) array_like of float
            Beam endpoints, metres (farther than max_range from their origin: no return).
        scan_index : (N,) array_like of int
            The scan each point belongs to, in [0, S).

        Raises
        ------
        ValueError
            Before anything changes, if an array has the wrong shape or holds NaN or infinite
            values, `scan_index` is out of [0, S), a point equals its scan's origin, or a beam
            reaches beyond the key range.
        """
        origins = float_array("origins", origins, (-1, 3))
        points = float_array("points", points, (-1, 3))
        scan_index = index_array("scan_index", scan_index, points.shape[0], origins.shape[0])
        beams = self._beams(origins, points, scan_index)
        with self._lock.writing():
            self._integrate_passes(beams)
            self.revision += 1

    def _beams(self, origins: np.ndarray, points: np.ndarray, scan_index: np.ndarray) -> _Beams:
        """Beam geometry in float64, checked before anything changes. Beams go scan by scan, and
        within a scan by their endpoints' coordinates: the order they were given in changes nothing."""
        cfg = self.config
        within_key_range("origins", origins, cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
        within_key_range("points", points, cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
        order = _scan_order(points, scan_index)
        points, scan_index = points[order], scan_index[order]
        # in place where a temporary would be as large (fresh memory costs a page fault per 4 KiB)
        starts = origins.astype(np.float64)[scan_index]
        directions = points.astype(np.float64)
        directions -= starts
        scratch = np.square(directions)
        ranges = scratch[:, 0] + scratch[:, 1]
        ranges += scratch[:, 2]
        np.sqrt(ranges, out=ranges)  # np.linalg.norm's sums, 5x faster
        if np.any(ranges == 0):
            raise ValueError("points must differ from their scan's origin (a beam needs a direction)")
        directions /= ranges[:, None]
        returned = ranges <= cfg.max_range
        lengths = np.where(
            returned, np.minimum(ranges + cfg.cone_sigmas * cfg.range_sigma_m, cfg.max_range), cfg.max_range
        )
        # a cone reaches cone_sigmas past its reading
        np.multiply(directions, lengths[:, None], out=scratch)
        scratch += starts
        within_key_range("points", scratch, cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
        scan_ends = np.searchsorted(scan_index, np.arange(1, origins.shape[0] + 1)).astype(np.int64)
        returned = returned.astype(np.int32)
        # on a CPU, Warp arrays over the host arrays (kernels only read them; each array keeps its own)
        copy = self.device.is_cuda
        on_device = tuple(
            wp.array(np.ascontiguousarray(a), dtype=dtype, device=self.device, copy=copy)
            for a, dtype in (
                (starts, wp.vec3d),
                (directions, wp.vec3d),
                (lengths, wp.float64),
                (ranges, wp.float64),
                (returned, wp.int32),
            )
        )
        return _Beams(lengths, scan_ends, on_device)

    def _integrate_passes(self, beams: _Beams) -> None:
        """List every cone's blocks and allocate them all at once (a vector layer is costly to
        grow), then update the voxels pass by pass. On the CPU the next pass's cones are walked
        on a second thread while this pass's scans are applied (both only read the table)."""
        passes, keys = [], []
        num_scans, first = len(beams.scan_ends), 0
        plan_beams = PLAN_ENTRIES // self._max_blocks(self.config.max_range)
        while first < num_scans:  # listed in chunks of whole passes
            end = min(first + SCANS_PER_PASS, num_scans)
            while end < num_scans:
                further = min(end + SCANS_PER_PASS, num_scans)
                lo, hi = self._beam_range(beams, first, further)
                if hi - lo > plan_beams:
                    break
                end = further
            self._plan(beams, first, end, passes, keys)
            first = end
        if not keys:
            return
        listed = wp.array(np.unique(np.concatenate(keys)), dtype=wp.int64, device=self.device)
        self._store.ensure_blocks(listed)
        # Variances are read by queries only: a batch whose cones step more often than its
        # blocks hold voxels computes them once at its end, over those blocks; a small one
        # after every scan, for the voxels the scan reached (the same bits either way).
        steps = sum(int(planned[2].sum()) for planned in passes)
        at_end = listed.shape[0] * BLOCK_VOXELS * VARIANCES_AT_END <= steps
        self._resets.zero_()
        self._apply_passes(beams, passes, with_variance=not at_end)
        if at_end:
            self._update_variances(self._store.find(listed))
        resets = int(self._resets.numpy()[0])
        if resets:
            self.prior_resets += resets
            warnings.warn(
                f"ConfidenceMap: {resets} voxel update(s) fell back to the prior: so many readings of "
                f"one scan in one voxel that its {self.config.num_bins} float32 bins could not hold "
                "the evidence (more bins, or fewer readings a scan, avoid it)",
                RuntimeWarning,
                stacklevel=3,
            )

    def _update_variances(self, slots: wp.array) -> None:
        """Variances of the observed voxels of the blocks in `slots`."""
        layers = self._store.layers
        parallel.split_launch(
            lambda part, a, b: wp.launch(
                self._kernels.variance_of_blocks,
                dim=(b - a) * BLOCK_VOXELS,
                inputs=[slots[a:b], layers["bins"], layers["mean"]],
                outputs=[layers["variance"]],
                device=self.device,
            ),
            slots.shape[0],
            parallel.num_parts(self.device, slots.shape[0] * BLOCK_VOXELS),
        )

    def _apply_passes(self, beams: _Beams, passes: list, with_variance: bool) -> None:
        if not passes:
            return
        overlap = not self.device.is_cuda and len(passes) > 1
        cones = self._walk_cones(beams, *passes[0], parts=None)
        for i, planned in enumerate(passes):
            ahead = []
            if i + 1 < len(passes):
                if overlap:
                    # submitted once this pass's launch is prepared: the host work of the two
                    # threads then does not contend for the GIL while the update runs
                    def walk_next(following=passes[i + 1]):
                        ahead.append(_background().submit(self._walk_cones, beams, *following, parts=1))

                    self._update(beams, *planned, cones, with_variance, before_launch=walk_next)
                    cones = ahead[0].result()
                    continue
                ahead.append(self._walk_cones(beams, *passes[i + 1], parts=None))
            self._update(beams, *planned, cones, with_variance)
            cones = ahead[0] if ahead else None

    def _max_blocks(self, length: float) -> int:
        """Blocks a cone of `length` metres crosses at most (but for round-off)."""
        return int(math.ceil(math.sqrt(3.0) * length / (hashing.BLOCK_EDGE * self.config.voxel_size))) + 6

    def _beam_range(self, beams: _Beams, first_scan: int, end_scan: int) -> tuple[int, int]:
        lo = 0 if first_scan == 0 else int(beams.scan_ends[first_scan - 1])
        return lo, int(beams.scan_ends[end_scan - 1])

    def _plan(self, beams: _Beams, first_scan: int, end_scan: int, passes: list, keys: list) -> None:
        """List the cones' blocks of scans [first_scan, end_scan) (one launch): the blocks go to
        `keys`, and the scans to `passes` as (first, end, room per cone, the most of it),
        SCANS_PER_PASS scans each, halved while above STEP_BUDGET voxels."""
        lo, hi = self._beam_range(beams, first_scan, end_scan)
        count = hi - lo
        if count == 0:
            return
        cfg, device = self.config, self.device
        resolution, inv_resolution = np.float64(cfg.voxel_size), np.float64(1.0 / cfg.voxel_size)
        starts, directions, lengths = (a[lo:hi] for a in beams.on_device[:3])
        max_blocks = self._max_blocks(float(beams.lengths[lo:hi].max()))
        parts = parallel.num_parts(device, count)
        while True:
            block_keys = wp.empty((count, max_blocks), dtype=wp.int64, device=device)
            block_counts = wp.empty(count, dtype=wp.int32, device=device)
            step_bounds = wp.empty(count, dtype=wp.int32, device=device)
            recent = wp.full((parts, RECENT_BLOCKS), hashing.EMPTY_KEY, dtype=wp.int64, device=device)
            parallel.split_launch(
                lambda part, a, b: wp.launch(
                    confidence.list_cone_blocks,
                    dim=b - a,
                    inputs=[starts[a:b], directions[a:b], lengths[a:b], resolution, inv_resolution, recent[part]],
                    outputs=[block_keys[a:b], block_counts[a:b], step_bounds[a:b]],
                    device=device,
                ),
                count,
                parts,
            )
            most = int(block_counts.numpy().max())
            if most <= max_blocks:
                break
            max_blocks = most  # round-off made a cone longer than the bound: list again
        steps = step_bounds.numpy().astype(np.int64)  # room per cone; the walk then counts exactly
        listed = block_keys.numpy()
        keys.append(np.unique(listed[listed != EMPTY_KEY]))  # blocks listed lately are left out
        total = np.zeros(count + 1, np.int64)
        np.cumsum(steps, out=total[1:])

        def split(first: int, end: int) -> None:
            a, b = (i - lo for i in self._beam_range(beams, first, end))
            if b == a:
                return
            if total[b] - total[a] > STEP_BUDGET and end - first > 1:
                middle = (first + end) // 2
                split(first, middle)
                split(middle, end)
                return
            passes.append((first, end, steps[a:b], int(steps[a:b].max())))

        for first in range(first_scan, end_scan, SCANS_PER_PASS):
            split(first, min(first + SCANS_PER_PASS, end_scan))

    def _walk_cones(
        self, beams: _Beams, first_scan: int, end_scan: int, steps: np.ndarray, longest: int, parts: int | None
    ) -> _Cones | None:
        """Scans [first_scan, end_scan), their blocks allocated: walk the cones again for each
        voxel's slot and likelihood (in `parts` CPU threads; None: as many as worth it)."""
        lo, hi = self._beam_range(beams, first_scan, end_scan)
        count = hi - lo
        cfg, device, store = self.config, self.device, self._store
        first_step = np.zeros(count + 1, np.int64)
        np.cumsum(steps, out=first_step[1:])
        total = int(first_step[-1])
        if total == 0:
            return None
        resolution, inv_resolution = np.float64(cfg.voxel_size), np.float64(1.0 / cfg.voxel_size)
        starts, directions, lengths, ranges, returned = (a[lo:hi] for a in beams.on_device)
        cones = _Cones(
            first_step,
            wp.array(first_step.astype(np.int32), dtype=wp.int32, device=device),
            returned,
            wp.empty(total, dtype=wp.int32, device=device),
            wp.empty(total, dtype=wp.float64, device=device),
            wp.empty(count, dtype=wp.int32, device=device),
            wp.empty(count, dtype=wp.int32, device=device),
        )
        filled = cones.filled
        parallel.split_launch(
            lambda part, a, b: wp.launch(
                confidence.fill_cone_steps,
                dim=b - a,
                inputs=[
                    starts[a:b],
                    directions[a:b],
                    lengths[a:b],
                    ranges[a:b],
                    cones.returned[a:b],
                    cones.d_first_step[a : b + 1],
                    resolution,
                    inv_resolution,
                    np.float64(cfg.range_sigma_m),
                    np.float64(cfg.max_range),
                    int(cfg.cause_range == "centre"),
                    store.table_keys,
                    store.table_slots,
                ],
                outputs=[cones.step_voxel, cones.step_likelihood, filled[a:b], cones.band_start[a:b]],
                device=device,
            ),
            count,
            parallel.num_parts(device, count) if parts is None else parts,
        )
        counts = filled.numpy().astype(np.int64)
        if np.any(counts < 0):
            raise RuntimeError("internal error: a cone voxel lies in a block its listing missed (please report)")
        if not counts.any():
            return None
        if self._sorted_path and not np.array_equal(counts, steps):
            # planes of two axes crossed at about one distance: a voxel passed in no distance,
            # or a sliver left out, room unused (the CPU path reads each cone's count instead)
            return _compacted(cones, counts, filled, device)
        return cones

    def _update(
        self,
        beams: _Beams,
        first_scan: int,
        end_scan: int,
        steps: np.ndarray,
        longest: int,
        cones: _Cones | None,
        with_variance: bool,
        before_launch=None,
    ) -> None:
        """Apply scans [first_scan, end_scan), their cones walked, one after the other;
        `before_launch()` is called once, just before the (CPU) update is launched."""
        if cones is None:
            if before_launch is not None:
                before_launch()
            return
        lo, _ = self._beam_range(beams, first_scan, end_scan)
        cfg, device, store = self.config, self.device, self._store
        first_step, d_first, d_returned = cones.first_step, cones.d_first_step, cones.returned
        step_voxel, step_likelihood = cones.step_voxel, cones.step_likelihood
        total = int(first_step[-1])

        # the scans one after the other: on the CPU in one launch, on CUDA two launches per scan
        model = [np.float32(cfg.prior_mean), np.float64(cfg.spurious_probability), np.float64(1.0 / cfg.max_range)]
        layers = store.layers
        scan_ends = (beams.scan_ends[first_scan:end_scan] - lo).astype(np.int32)
        if not self._sorted_path:
            inputs = [
                wp.array(scan_ends, dtype=wp.int32, device=device),
                d_first,
                cones.filled,
                cones.band_start,
                d_returned,
                step_voxel,
                step_likelihood,
                *model,
                np.float32(cfg.bin_floor),
                wp.empty(longest, dtype=wp.float32, device=device),
                wp.empty(longest, dtype=wp.float64, device=device),
                wp.empty(total, dtype=wp.int32, device=device),
                self._free_powers,
                int(with_variance),
            ]
            if before_launch is not None:
                before_launch()
            wp.launch(
                self._kernels.integrate_in_order,
                dim=1,
                inputs=inputs,
                outputs=[layers["bins"], layers["mean"], layers["variance"], layers["pending"], self._resets],
                device=device,
            )
            return
        if before_launch is not None:
            before_launch()
        # The pass's steps sorted once, stably by voxel: each voxel's steps of a scan form a run in
        # beam order. Each (voxel, scan) run is a group, and the groups are sorted by scan, so a
        # scan is one launch for its factors and one over its groups (no sort per scan), and
        # nothing is read back: the groups' ranges stay on the device.
        scan_steps = first_step[np.r_[0, scan_ends]]
        num_scans = len(scan_ends)
        keys = wp.empty(2 * total, dtype=wp.int32, device=device)
        order = wp.empty(2 * total, dtype=wp.int32, device=device)
        wp.launch(confidence.sort_keys_of_steps, dim=total, inputs=[step_voxel], outputs=[keys, order], device=device)
        wp.utils.radix_sort_pairs(
            keys, order, total, end_bit=max(int(store.block_capacity * BLOCK_VOXELS - 1).bit_length(), 1)
        )
        step_scan = wp.array(
            np.repeat(np.arange(num_scans, dtype=np.int32), np.diff(scan_steps)), dtype=wp.int32, device=device
        )
        group_scan = wp.empty(2 * total, dtype=wp.int32, device=device)
        group_entry = wp.empty(2 * total, dtype=wp.int32, device=device)
        scan_groups = wp.zeros(num_scans + 1, dtype=wp.int32, device=device)  # the last one stays 0
        wp.launch(
            confidence.flag_scan_groups,
            dim=total,
            inputs=[keys, order, step_scan, num_scans],
            outputs=[group_scan, group_entry, scan_groups],
            device=device,
        )
        wp.utils.radix_sort_pairs(group_scan, group_entry, total, end_bit=max(int(num_scans).bit_length(), 1))
        first_group = wp.empty(num_scans + 1, dtype=wp.int32, device=device)
        wp.utils.array_scan(scan_groups, first_group, inclusive=False)
        scratch = [
            wp.empty(total, dtype=wp.float32, device=device),  # mean before the scan
            wp.empty(total, dtype=wp.float64, device=device),
        ]  # S_i
        factors = wp.empty(total, dtype=wp.vec2f, device=device)
        # Two launches a scan, of the same arguments but the scan's: recorded once, each scan then
        # sets its numbers and dimension (about 5 us a launch instead of 29 for a full wp.launch,
        # the host's share of a scan otherwise).
        factors_of_scan = wp.launch(
            confidence.compute_beam_factors,
            dim=1,
            inputs=[0, d_first, d_returned, step_voxel, step_likelihood, layers["mean"], *model],
            outputs=[*scratch, factors],
            device=device,
            record_cmd=True,
        )
        groups_of_scan = wp.launch(
            self._kernels.apply_scan_groups,
            dim=1,
            inputs=[
                0,
                first_group,
                group_entry,
                keys,
                order,
                step_scan,
                total,
                factors,
                np.float32(cfg.bin_floor),
                self._free_powers,
                int(with_variance),
            ],
            outputs=[layers["bins"], layers["mean"], layers["variance"], self._resets],
            device=device,
            record_cmd=True,
        )
        beam_lo = 0
        for scan, beam_hi in enumerate(scan_ends.tolist()):
            if beam_hi > beam_lo:
                factors_of_scan.set_dim(beam_hi - beam_lo)
                factors_of_scan.set_param_at_index_from_ctype(0, beam_lo)
                factors_of_scan.launch()
            steps_of_scan = int(scan_steps[scan + 1] - scan_steps[scan])
            if steps_of_scan:
                groups_of_scan.set_dim(steps_of_scan)
                groups_of_scan.set_param_at_index_from_ctype(0, scan)
                groups_of_scan.launch()
            beam_lo = beam_hi

    # ---------------------------------------------------------------- point queries
    def _moments(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Stored mean and variance (M,) float32 at each point, NaN where never observed."""
        points = float_array("points", points, (-1, 3))
        count, device, store = points.shape[0], self.device, self._store
        out_mean = wp.empty(count, dtype=wp.float32, device=device)
        out_variance = wp.empty(count, dtype=wp.float32, device=device)
        with self._lock.reading():
            if count:
                wp.launch(
                    confidence_queries.lookup_moments,
                    dim=count,
                    inputs=[
                        wp.array(points, dtype=wp.vec3f, device=device),
                        np.float64(1.0 / self.config.voxel_size),
                        store.table_keys,
                        store.table_slots,
                        store.layers["mean"],
                        store.layers["variance"],
                    ],
                    outputs=[out_mean, out_variance],
                    device=device,
                )
            return out_mean.numpy(), out_variance.numpy()

    def mean(self, points: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Mean occupancy level of the voxels holding some points.

        Parameters
        ----------
        points : (M, 3) array_like of float
            Query points, metres, world frame.

        Returns
        -------
        (M,) ndarray of float32
            The means; the prior's (0.5) where never observed.

        Raises
        ------
        ValueError
            If `points` is not (M, 3) finite numbers.
        """
        mean, _ = self._moments(points)
        return np.where(np.isnan(mean), self.config.prior_mean, mean).astype(np.float32)

    def variance(self, points: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Variance of the occupancy level of the voxels holding some points: how unsure the map is.

        Parameters
        ----------
        points : (M, 3) array_like of float
            Query points, metres, world frame.

        Returns
        -------
        (M,) ndarray of float32
            The variances; the prior's, ``(K + 1) / (12 (K - 1))`` for K bins, where never
            observed.

        Raises
        ------
        ValueError
            If `points` is not (M, 3) finite numbers.
        """
        _, variance = self._moments(points)
        return np.where(np.isnan(variance), self.config.prior_variance, variance).astype(np.float32)

    def observed(self, points: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Whether the voxels holding some points have been updated at least once.

        Parameters
        ----------
        points : (M, 3) array_like of float
            Query points, metres, world frame.

        Returns
        -------
        (M,) ndarray of bool
            True where the voxel has been updated.

        Raises
        ------
        ValueError
            If `points` is not (M, 3) finite numbers.
        """
        mean, _ = self._moments(points)
        return ~np.isnan(mean)

    def state(self, points: npt.ArrayLike) -> npt.NDArray[np.int8]:
        """States of the voxels holding some points, by their means.

        Parameters
        ----------
        points : (M, 3) array_like of float
            Query points, metres, world frame.

        Returns
        -------
        (M,) ndarray of int8
            vj.OCCUPIED at or above occupied_threshold, vj.FREE at or below free_threshold,
            vj.UNKNOWN between them or where never observed.

        Raises
        ------
        ValueError
            If `points` is not (M, 3) finite numbers.
        """
        mean, _ = self._moments(points)
        return classify(mean, self.config)

    def distribution(self, points: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Distributions over the occupancy levels of the voxels holding some points.

        Parameters
        ----------
        points : (M, 3) array_like of float
            Query points, metres, world frame.

        Returns
        -------
        (M, num_bins) ndarray of float32
            Probability of each level ``config.bin_centres``, summing to 1; the prior (uniform)
            where never observed.

        Raises
        ------
        ValueError
            If `points` is not (M, 3) finite numbers.
        """
        points = float_array("points", points, (-1, 3))
        count, device, store = points.shape[0], self.device, self._store
        values = wp.empty(count, dtype=self._kernels.Bins, device=device)
        with self._lock.reading():
            if count:
                wp.launch(
                    self._kernels.lookup_bins,
                    dim=count,
                    inputs=[
                        wp.array(points, dtype=wp.vec3f, device=device),
                        np.float64(1.0 / self.config.voxel_size),
                        store.table_keys,
                        store.table_slots,
                        store.layers["bins"],
                        self._prior,
                    ],
                    outputs=[values],
                    device=device,
                )
            return values.numpy().reshape(count, self.config.num_bins)

    # ---------------------------------------------------------------- ray queries
    def raycast(
        self, origins: npt.ArrayLike, directions: npt.ArrayLike, max_range: float | npt.ArrayLike
    ) -> ConfidenceRaycast:
        """Cast rays: the first voxel whose mean reaches occupied_threshold along each, and what lies before it.

        Every voxel on the way is walked (unknown space has a mean and a variance too), so a ray
        may cross at most MAX_LINE_VOXELS (65536) voxel edges.

        Parameters
        ----------
        origins : (R, 3) array_like of float
            Ray origins, metres, world frame.
        directions : (R, 3) array_like of float
            Directions, any nonzero length (normalised here).
        max_range : float or (R,) array_like of float
            How far each ray looks, metres, positive.

        Returns
        -------
        ConfidenceRaycast
            Per ray: hit, distance, counts of unknown and free voxels passed, the sum and the
            largest of their variances, and the probability of reaching the end.

        Raises
        ------
        ValueError
            If an array has the wrong shape or holds NaN or infinite values, a direction is zero,
            `max_range` is not positive, a ray is longer than MAX_LINE_VOXELS voxels, or it
            reaches beyond the key range.
        """
        origins, directions, ranges = ray_arguments(origins, directions, max_range)
        cfg, device, store = self.config, self.device, self._store
        within_key_range("origins", origins, cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
        check_walk_length("max_range", ranges, cfg.voxel_size)
        within_key_range("max_range", origins + directions * ranges[:, None], cfg.voxel_size, hashing.VOXEL_KEY_LIMIT)
        count = origins.shape[0]
        d_origins = wp.array(origins, dtype=wp.vec3d, device=device)
        d_directions = wp.array(directions, dtype=wp.vec3d, device=device)
        d_ranges = wp.array(ranges, dtype=wp.float64, device=device)
        names = {
            "hit": wp.bool,
            "distance": wp.float32,
            "num_unknown": wp.int32,
            "num_free": wp.int32,
            "variance_sum": wp.float32,
            "variance_max": wp.float32,
            "reach_probability": wp.float32,
        }
        out = {name: wp.empty(count, dtype=dtype, device=device) for name, dtype in names.items()}

        def launch(part: int, lo: int, hi: int) -> None:
            wp.launch(
                confidence_queries.cast_confidence_rays,
                dim=hi - lo,
                inputs=[
                    d_origins[lo:hi],
                    d_directions[lo:hi],
                    d_ranges[lo:hi],
                    np.float64(cfg.voxel_size),
                    np.float64(1.0 / cfg.voxel_size),
                    store.table_keys,
                    store.table_slots,
                    store.layers["mean"],
                    store.layers["variance"],
                    np.float32(cfg.prior_mean),
                    np.float32(cfg.prior_variance),
                    np.float32(cfg.occupied_threshold),
                    np.float32(cfg.free_threshold),
                ],
                outputs=[a[lo:hi] for a in out.values()],
                device=device,
            )

        with self._lock.reading():
            parallel.split_launch(launch, count, parallel.num_parts(device, count))
        return ConfidenceRaycast(**{name: a.numpy() for name, a in out.items()})

    # ---------------------------------------------------------------- contents
    def _host_blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Live blocks sorted by key: keys (B,), bins (B,512,K), mean and variance (B,512)."""
        store, K = self._store, self.config.num_bins
        n = store.num_blocks
        keys = store.slot_keys.numpy()[:n]
        order = np.argsort(keys, kind="stable")
        order = order[keys[order] != EMPTY_KEY]
        bins = store.layers["bins"].numpy()[: n * BLOCK_VOXELS].reshape(n, BLOCK_VOXELS, K)[order]
        mean = store.layers["mean"].numpy()[: n * BLOCK_VOXELS].reshape(n, BLOCK_VOXELS)[order]
        variance = store.layers["variance"].numpy()[: n * BLOCK_VOXELS].reshape(n, BLOCK_VOXELS)[order]
        return keys[order], bins, mean, variance

    def voxels(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """The observed voxels, sorted by voxel key.

        Returns
        -------
        centres : (V, 3) ndarray of float64
            Voxel centres, metres.
        mean : (V,) ndarray of float32
            Their mean occupancy levels.
        variance : (V,) ndarray of float32
            Their variances.
        """
        with self._lock.reading():
            keys, _, mean, variance = self._host_blocks()
        block_index, local = np.nonzero(~np.isnan(mean))
        centres = (voxel_keys(keys, block_index, local) + 0.5) * self.config.voxel_size
        return centres, mean[block_index, local], variance[block_index, local]

    @property
    def num_blocks(self) -> int:
        """Allocated 8x8x8 blocks (each holds 512 voxels, observed or not)."""
        return self._store.live_blocks

    @property
    def bytes_per_voxel(self) -> int:
        """Bytes each voxel of an allocated block takes: the bins, mean, variance and a flag."""
        return 4 * self.config.num_bins + 4 + 4 + 1

    def memory_bytes(self) -> int:
        """Device memory the map holds.

        Returns
        -------
        int
            Bytes of the hash table, the block pool and the per-block scratch.
        """
        return self._store.memory_bytes()

    def copy(self) -> ConfidenceMap:
        """An independent copy, e.g. to predict future readings on.

        Returns
        -------
        ConfidenceMap
            A map of the same settings, device and contents; changing one leaves the other as it
            is.
        """
        with self._lock.reading():
            keys, bins, mean, _ = self._host_blocks()
        return self._from_host(self.config, self.device, keys, bins, ~np.isnan(mean))

    def __repr__(self) -> str:
        return (
            f"ConfidenceMap(voxel_size={self.config.voxel_size}, bins={self.config.num_bins}, "
            f"blocks={self.num_blocks}, device={self.device}, memory={self.memory_bytes() / 2**20:.1f} MiB)"
        )

    # ---------------------------------------------------------------- files
    def save(self, path: str | PathLike) -> None:
        """Write the map, settings included, to one map file, atomically.

        Parameters
        ----------
        path : str or os.PathLike
            The .vog file to write (replaced if it exists; a reader sees the old file or the
            whole new one).

        Raises
        ------
        ValueError
            If `path` cannot be written (see `vogjax.io.write_map_file`).
        """
        with self._lock.reading():
            keys, bins, mean, _ = self._host_blocks()
        write_map_file(
            path,
            "ConfidenceMap",
            {"config": self.config.to_dict()},
            {"block_keys": keys, "bins": bins, "observed": ~np.isnan(mean)},
        )

    @classmethod
    def load(cls, path: str | PathLike, device: str | wp.Device | None = None) -> ConfidenceMap:
        """Read a map written by `save`, checking the whole file and its contents.

        Parameters
        ----------
        path : str or os.PathLike
            The .vog file.
        device : str or warp.Device or None, optional
            Warp device for the map (None: CUDA when available, else the CPU).

        Returns
        -------
        ConfidenceMap
            The map, the same bit for bit as the one saved.

        Raises
        ------
        ValueError
            Naming the path if the file is not a valid ConfidenceMap file (damaged, another kind
            of map, or contents that break the map's invariants).
        """
        metadata, arrays = read_map_file(path, "ConfidenceMap")
        where = f"path {str(path)!r} has invalid map contents"
        try:
            config = CrmConfig.from_dict(metadata["config"])
            keys, bins, observed = arrays["block_keys"], arrays["bins"], arrays["observed"]
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{where}: {error}") from None
        problem = _check_contents(config, keys, bins, observed)
        if problem:
            raise ValueError(f"{where}: {problem}")
        return cls._from_host(config, device, keys, bins, observed)

    @classmethod
    def _from_host(
        cls, config: CrmConfig, device, keys: np.ndarray, bins: np.ndarray, observed: np.ndarray
    ) -> ConfidenceMap:
        crm = cls(config, device)
        store = BlockStore.from_host(crm.device, crm._layer_specs(), keys, {})
        count = keys.shape[0]
        if count:
            voxels = count * BLOCK_VOXELS
            store.layers["bins"][:voxels].assign(
                wp.array(
                    np.ascontiguousarray(bins, np.float32).reshape(voxels, config.num_bins),
                    dtype=crm._kernels.Bins,
                    device=crm.device,
                )
            )
            wp.launch(
                crm._kernels.compute_moments,
                dim=voxels,
                inputs=[
                    wp.array(observed.reshape(-1).astype(np.uint8), dtype=wp.uint8, device=crm.device),
                    store.layers["bins"][:voxels],
                ],
                outputs=[store.layers["mean"][:voxels], store.layers["variance"][:voxels]],
                device=crm.device,
            )
        crm._store = store
        return crm


def check_walk_length(name: str, lengths_m: npt.NDArray[np.floating], voxel_size: float) -> None:
    """Refuse query lines longer than a confidence-map query walks.

    Queries of a ConfidenceMap walk every voxel on their way (unknown space has a mean and a
    variance too), so their work grows with the length: at most MAX_LINE_VOXELS voxel edges.

    Parameters
    ----------
    name : str
        The argument's name, for the error message.
    lengths_m : (R,) ndarray of float
        The lines' lengths, metres.
    voxel_size : float
        The map's voxel edge, metres.

    Raises
    ------
    ValueError
        Naming `name` and the longest entry if it exceeds ``MAX_LINE_VOXELS * voxel_size``.
    """
    longest = MAX_LINE_VOXELS * voxel_size
    if len(lengths_m) and not lengths_m.max() <= longest:
        i = int(np.argmax(lengths_m))
        raise ValueError(
            f"{name}: {lengths_m[i]:.6g} m (entry {i}) is longer than a confidence-map query walks, "
            f"{MAX_LINE_VOXELS} voxels ({longest:g} m at voxel size {voxel_size:g} m): split it"
        )


def _ordered_bits(values: np.ndarray) -> np.ndarray:
    """Finite float32 (N,) as uint64 keys in the same order (-0.0 and 0.0 equal, as they compare)."""
    bits = np.ascontiguousarray(values, np.float32).view(np.uint32).astype(np.uint64)
    keys = np.where(bits >= 0x80000000, np.uint64(0xFFFFFFFF) - bits, bits | np.uint64(0x80000000))
    keys[values == 0] = 0x80000000
    return keys


def _scan_order(points: np.ndarray, scan_index: np.ndarray) -> np.ndarray:
    """np.lexsort((z, y, x, scan)) of finite float32 points (N,3), on packed keys: the same
    permutation (every sort here is stable). Beams of a scan seldom share an x, so one sort on
    (scan, x) mostly settles it (a quarter of lexsort's time); (y, z) then orders the ties."""
    high = (scan_index.astype(np.uint64) << np.uint64(32)) | _ordered_bits(points[:, 0])
    order = np.argsort(high, kind="stable")
    ordered = high[order]
    same = ordered[1:] == ordered[:-1]
    if not same.any():
        return order
    tied = np.zeros(len(order), bool)  # the runs of equal (scan, x), sorted among themselves by (y, z)
    tied[1:] |= same
    tied[:-1] |= same
    at = np.flatnonzero(tied)
    runs = order[at]  # each run in input order: the sort below keeps equal points so (stable)
    low = (_ordered_bits(points[runs, 1]) << np.uint64(32)) | _ordered_bits(points[runs, 2])
    order[at] = runs[np.lexsort((low, high[runs]))]
    return order


def classify(mean: npt.NDArray[np.floating], config: CrmConfig) -> npt.NDArray[np.int8]:
    """States of stored means, by the map's thresholds.

    Parameters
    ----------
    mean : ndarray of float
        Mean occupancy levels; NaN: never observed.
    config : CrmConfig
        The thresholds.

    Returns
    -------
    ndarray of int8
        Of the shape of `mean`: OCCUPIED at or above occupied_threshold, FREE at or below
        free_threshold, UNKNOWN between them or where NaN.
    """
    state = np.full(mean.shape, UNKNOWN, dtype=np.int8)
    with np.errstate(invalid="ignore"):
        state[mean >= config.occupied_threshold] = OCCUPIED
        state[mean <= config.free_threshold] = FREE
    return state


def _check_contents(config: CrmConfig, keys, bins, observed) -> str | None:
    """What is wrong with a loaded map's arrays, or None."""
    K = config.num_bins
    if not (isinstance(keys, np.ndarray) and keys.dtype == np.int64 and keys.ndim == 1):
        return "block_keys must be a 1-D int64 array"
    if len(np.unique(keys)) != len(keys) or np.any(pack_blocks(unpack_blocks(keys)) != keys):
        return "block_keys must be distinct packed block coordinates"
    if not (isinstance(bins, np.ndarray) and bins.dtype == np.float32 and bins.shape == (len(keys), BLOCK_VOXELS, K)):
        return f"bins must be float32 of shape ({len(keys)}, {BLOCK_VOXELS}, {K})"
    if not (
        isinstance(observed, np.ndarray) and observed.dtype == np.bool_ and observed.shape == (len(keys), BLOCK_VOXELS)
    ):
        return f"observed must be bool of shape ({len(keys)}, {BLOCK_VOXELS})"
    if not np.all(np.isfinite(bins)) or np.any(bins < 0):
        return "bins must be finite and non-negative"
    seen = bins[observed]
    if seen.size and np.abs(seen.astype(np.float64).sum(axis=1) - 1.0).max() > 1e-4:
        return "the bins of an observed voxel must sum to 1"
    if np.any(bins[~observed] != config.prior):
        return "a voxel never observed must hold the prior"
    return None


__all__ = ["ConfidenceMap", "ConfidenceRaycast", "classify"]
