"""Correlative x-y-yaw search: where two submap clouds overlap best within the navigation's drift.

ICP converges only from within a few voxels of the answer, while navigation drifts metres
between revisits. Depth, pitch and roll are measured absolutely, so the unknowns are x, y and
yaw: for each yaw on a grid, the source cloud is voxelised and cross-correlated with a blurred
occupancy grid of the target over every x-y offset (summed over z layers: directly where the
offsets are few, by FFT where they are many). The peak seeds ICP, and the peak's margin over
the best clearly different offset tells whether the match is unambiguous.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt
import warp as wp
from scipy import fft, ndimage

from vogjax import devices
from vogjax.config import CorrelativeConfig
from vogjax.geometry import rigid_pose, rotation_from_ypr
from vogjax.kernels import registration
from vogjax.maps import parallel
from vogjax.validation import real_array

# Bounds on one search: its grid (float32, plus its FFT), and its work, grid cells times yaw
# steps (one FFT pass per step: 1e9 is about a minute on two CPU cores).
MAX_GRID_CELLS = 5e7
MAX_SEARCH_WORK = 1e9
MAX_RADIUS_M = 1000.0
MAX_COORDINATE_M = 1e7  # beyond it float64 keeps no sub-voxel digits of a grid index
# One device launch's share of a batch of searches: its targets' fields (1 GiB), its source
# cells (192 MiB) and its scores (512 MiB), which also keeps the kernel's int32 indices in range.
MAX_FIELD_FLOATS = 2**28
MAX_LAUNCH_CELLS = 2**24
MAX_LAUNCH_SCORES = 2**26
# A search whose direct correlation takes more field lookups (points x offsets x yaws) runs as
# FFTs on the host: a few seconds of a GPU at most, where the FFTs' cost grows far slower.
MAX_DIRECT_WORK = 1e11


@dataclasses.dataclass(frozen=True)
class CorrelativeMatch:
    """The peak of a correlative x-y-yaw search, and how clearly it stands out.

    Attributes
    ----------
    T_target_source : (4, 4) ndarray of float64
        The pose at the peak: T_init corrected in x, y and yaw.
    score : float
        Mean blurred occupancy of the target under the source points there (1 when every point
        lands on a target voxel; 0 when no target point was in reach, T_target_source then
        being T_init).
    runner_up : float
        The best score at least `CorrelativeConfig.exclusion_m` from the peak in x-y; 0 where
        the window searched holds no offset that far from the peak (a drift bound smaller than
        exclusion_m: no offset the navigation allows could be confused with the peak).
    """

    T_target_source: npt.NDArray[np.float64]
    score: float
    runner_up: float

    @property
    def ratio(self) -> float:
        """``runner_up / score`` (small: unambiguous; 1 when the score is 0)."""
        return self.runner_up / self.score if self.score > 0 else 1.0


def correlative_xyh(
    source: npt.ArrayLike,
    target: npt.ArrayLike,
    T_init: npt.ArrayLike,
    radius_m: float,
    yaw_radius_rad: float,
    config: CorrelativeConfig = CorrelativeConfig(),
) -> CorrelativeMatch:
    """Best x-y-yaw correction of T_init (source -> target frame) within radius_m and yaw_radius_rad.

    The correction rotates about the source cloud's centroid (in the target frame) and then
    shifts by whole voxels in x and y. Depth, pitch and roll stay as T_init has them.

    Parameters
    ----------
    source : (N, 3) array_like of float
        The source cloud, metres, in its own frame; non-empty, finite, within 1e7 m.
    target : (M, 3) array_like of float
        The target cloud, metres; non-empty, finite, within 1e7 m.
    T_init : (4, 4) array_like of float
        The estimate to correct: ``T_target_source``, a rigid transform.
    radius_m : float
        How far to search in x and y, metres, in [0, 1000].
    yaw_radius_rad : float
        How far to search in yaw, radians, in [0, pi].
    config : CorrelativeConfig, optional
        Grid resolution, yaw step, blur and the runner-up's exclusion radius.

    Returns
    -------
    CorrelativeMatch
        The peak's pose, its score and the runner-up's.

    Raises
    ------
    ValueError
        As for `correlative_xyh_batch`.
    """
    return correlative_xyh_batch([(source, target, T_init, radius_m, yaw_radius_rad)], config)[0]


def correlative_xyh_batch(
    searches: list[tuple[npt.ArrayLike, npt.ArrayLike, npt.ArrayLike, float, float]],
    config: CorrelativeConfig = CorrelativeConfig(),
    device: str | wp.Device | None = None,
) -> list[CorrelativeMatch]:
    """`correlative_xyh` for many (source, target, T_init, radius_m, yaw_radius_rad) at once.

    device None: on the host, one search after the other, each by direct correlation (float64
    sums of the field's float32 values, exactly 0 where no point meets the target) where that
    costs less than its FFTs (by the costs measured for `_direct_is_cheaper`), by FFT
    otherwise (the FFT's float32 round-off then: an offset where no point meets the target
    can score 1e-9 instead of 0). A Warp device (a CUDA GPU; "cpu" runs the same kernel on the
    host): every yaw and offset of the searches scored by direct correlation, in as few
    launches as the budgets allow; a search whose direct correlation would take more than
    MAX_DIRECT_WORK lookups runs on the host instead. Host and device agree to the sums'
    round-off (or the FFT's), so they find the same peaks but at near-exact ties.

    Parameters
    ----------
    searches : list of tuple
        (source, target, T_init, radius_m, yaw_radius_rad) per search, as `correlative_xyh`
        takes them.
    config : CorrelativeConfig, optional
        The settings of every search.
    device : str or warp.Device or None, optional
        None: on the host (direct or FFT, whichever costs less); a Warp device: direct
        correlation there.

    Returns
    -------
    list of CorrelativeMatch
        One per search, in order.

    Raises
    ------
    ValueError
        If a cloud is empty, not (N, 3), not finite or beyond 1e7 m, a T_init is not rigid,
        radius_m is not in [0, 1000] or yaw_radius_rad not in [0, pi], a search would need a
        grid of more than 5e7 cells or more than 1e9 cells x yaw steps (a coarser
        resolution_m or a smaller radius), or `device` is not available.
    """
    device = None if device is None else devices.resolve(device)
    if device is None:  # one search at a time: only one field is held
        return [_search_on_host(_plan(*search, config), config) for search in searches]
    plans = [_plan(*search, config) for search in searches]
    direct = [p for p, plan in enumerate(plans) if isinstance(plan, _Plan) and _direct_work(plan) <= MAX_DIRECT_WORK]
    # each search's windows arrive yaw after yaw; only the best so far is kept
    peaks = {p: _Peak() for p in direct}
    for p, n, window in _device_windows([plans[p] for p in direct], device):
        peaks[direct[p]].offer(plans[direct[p]].yaws[n], window / len(plans[direct[p]].moved))
    return [
        peaks[p].match(plan, config) if p in peaks else _search_on_host(plan, config) for p, plan in enumerate(plans)
    ]


def self_score(cloud: npt.ArrayLike, config: CorrelativeConfig = CorrelativeConfig()) -> float:
    """The score a cloud gets against itself, at no offset: what a complete overlap scores.

    A peak's score (`CorrelativeMatch.score`) stays below 1 even where every point lands on the
    target's surface: the blurred field is scaled to its densest cell, and a point on a plane
    of cells gets only part of that. How much less depends on the grid, the blur and how the
    cloud's surfaces are shaped (0.4 for a lidar submap on a 0.3 m grid), so a score is compared
    across sensors only over this reference: ``score / self_score(source)`` is the share of
    the best possible match reached.

    Parameters
    ----------
    cloud : (N, 3) array_like of float
        The cloud, metres; non-empty, finite, within 1e7 m.
    config : CorrelativeConfig, optional
        The grid's resolution and blur (those of the searches it is compared with).

    Returns
    -------
    float
        The mean of the cloud's own blurred occupancy under its points, in (0, 1].

    Raises
    ------
    ValueError
        If the cloud is empty, not (N, 3), not finite or beyond 1e7 m, or its grid would hold
        more than 5e7 cells.
    """
    cloud = real_array("cloud", cloud)
    if cloud.ndim != 2 or cloud.shape[1] != 3 or len(cloud) == 0 or not np.all(np.isfinite(cloud)):
        raise ValueError("cloud must be a non-empty (N, 3) array of finite points")
    if np.abs(cloud).max() > MAX_COORDINATE_M:
        raise ValueError(f"cloud has coordinates beyond {MAX_COORDINATE_M:g} m")
    res = config.resolution_m
    # padded by the blur's reach and more, so the field never reflects at the grid's faces
    pad = 2 * (int(4.0 * config.blur_voxels + 0.5) if config.blur_voxels > 0 else 0) + 2
    lo = cloud.min(axis=0) - pad * res
    extent = np.ceil((cloud.max(axis=0) + pad * res - lo) / res) + 1
    if float(np.prod(extent)) > MAX_GRID_CELLS:
        raise ValueError(
            f"cloud spans a grid of {float(np.prod(extent)):.3g} cells at {res:g} m; at most {MAX_GRID_CELLS:.0e}"
        )
    shape = extent.astype(int)
    cells = np.floor((cloud - lo) / res).astype(int)
    field = _target_field(cells, shape, 0, int(shape[2]), config.blur_voxels)
    return float(np.mean(field[cells[:, 0], cells[:, 1], cells[:, 2]], dtype=np.float64))


def _search_on_host(plan: _Plan | CorrelativeMatch, config: CorrelativeConfig) -> CorrelativeMatch:
    if not isinstance(plan, _Plan):
        return plan
    peak = _Peak()
    for yaw, window in zip(plan.yaws, _direct_windows(plan) if _direct_is_cheaper(plan) else _fft_windows(plan)):
        peak.offer(yaw, window / len(plan.moved))
    return peak.match(plan, config)


def _direct_work(plan: _Plan) -> float:
    """Field lookups of the search by direct correlation: source points x offsets x yaws."""
    return float(len(plan.moved)) * (2 * plan.shift_cells + 1) ** 2 * len(plan.yaws)


@dataclasses.dataclass(frozen=True)
class _Plan:
    """One search set up: the blurred target `field` (nx, ny, nz: the grid's layers the source
    can reach, from layer z_lo), the source `moved` by T_init and turned about `pivot` by each
    of `yaws`, `shift_cells` each way in x and y, and the grid's corner `lo`."""

    T_init: np.ndarray
    moved: np.ndarray
    pivot: np.ndarray
    lo: np.ndarray
    z_lo: int
    resolution_m: float
    shift_cells: int
    field: np.ndarray
    yaws: np.ndarray

    def cells(self, n: int) -> np.ndarray:
        """The source's cells (N,3) on the field at yaws[n], made one yaw at a time: all yaws
        of a large cloud at once could outgrow memory."""
        points = (self.moved - self.pivot) @ rotation_from_ypr(self.yaws[n]).T + self.pivot
        cells = np.floor((points - self.lo) / self.resolution_m).astype(int)
        cells[:, 2] -= self.z_lo
        return cells


def _plan(source, target, T_init, radius_m, yaw_radius_rad, config: CorrelativeConfig) -> _Plan | CorrelativeMatch:
    """The search's grid, field and source cells, or its answer when no target point is in reach."""
    source, target = real_array("source", source), real_array("target", target)
    for name, cloud in (("source", source), ("target", target)):
        if cloud.ndim != 2 or cloud.shape[1] != 3 or len(cloud) == 0 or not np.all(np.isfinite(cloud)):
            raise ValueError(f"{name} must be a non-empty (N, 3) array of finite points")
        if np.abs(cloud).max() > MAX_COORDINATE_M:
            raise ValueError(f"{name} has coordinates beyond {MAX_COORDINATE_M:g} m")
    T_init = rigid_pose("T_init", T_init)
    for name, value, most in (("radius_m", radius_m, MAX_RADIUS_M), ("yaw_radius_rad", yaw_radius_rad, np.pi)):
        if isinstance(value, bool) or not (
            isinstance(value, (int, float, np.integer, np.floating)) and 0 <= value <= most
        ):
            raise ValueError(f"{name} must be a number in [0, {most:g}], got {value!r}")
    res = config.resolution_m
    moved = source @ T_init[:3, :3].T + T_init[:3, 3]
    pivot = moved.mean(axis=0)
    shift_cells = int(np.ceil(radius_m / res))
    reach = np.linalg.norm(moved[:, :2] - pivot[:2], axis=1).max() * yaw_radius_rad
    # One grid holds the source at every yaw and the part of the target it can reach, padded by
    # the search radius so circular correlation never wraps a real overlap.
    margin = res * (shift_cells + 2) + reach
    lo, hi = moved.min(axis=0) - margin, moved.max(axis=0) + margin
    target = target[np.all((target[:, :2] >= lo[:2] + res) & (target[:, :2] <= hi[:2] - res), axis=1)]
    if len(target) == 0:
        return CorrelativeMatch(T_init.copy(), 0.0, 0.0)
    lo[2] = min(target[:, 2].min(), moved[:, 2].min()) - res
    hi[2] = max(target[:, 2].max(), moved[:, 2].max()) + res
    extent = np.ceil((hi - lo) / res) + 1  # in floats: a cast first could overflow
    yaw_steps = 2 * np.floor(yaw_radius_rad / config.yaw_step_rad) + 1
    cells = float(np.prod(extent))
    if cells > MAX_GRID_CELLS or cells * yaw_steps > MAX_SEARCH_WORK:
        raise ValueError(
            f"radius_m ({radius_m:g} m) and yaw_radius_rad ({yaw_radius_rad:g}) ask for a search grid of "
            f"{cells:.3g} cells x {yaw_steps:.0f} yaw steps at {res:g} m; at most {MAX_GRID_CELLS:.0e} "
            f"cells and {MAX_SEARCH_WORK:.0e} cells x yaw steps (a coarser resolution_m or a smaller "
            "radius)"
        )
    shape = extent.astype(int)
    steps = int(yaw_steps) // 2
    # Only the layers the source occupies enter the sum over z (a yaw keeps every z; one more
    # layer either side, as rotating about the pivot can round a z across a face).
    z_lo = max(int(np.floor((moved[:, 2].min() - lo[2]) / res)) - 1, 0)
    z_hi = min(int(np.floor((moved[:, 2].max() - lo[2]) / res)) + 2, int(shape[2]))
    field = _target_field(np.floor((target - lo) / res).astype(int), shape, z_lo, z_hi, config.blur_voxels)
    return _Plan(
        T_init, moved, pivot, lo, z_lo, res, shift_cells, field, config.yaw_step_rad * np.arange(-steps, steps + 1)
    )


# What a host search costs, measured on the 2-core CPU over the sonar and LiDAR runs' searches:
# a direct lookup (a source cell at an offset); an FFT pass, per cell of the grid, for the
# target's transform (once a search) and for each yaw (its yaws shared by the launch pool's
# threads where the grid is large)
DIRECT_S_PER_LOOKUP = 4e-9
FFT_S_PER_CELL = 5e-9
FFT_S_PER_CELL_YAW = 10e-9
DIRECT_CHUNK_LOOKUPS = 1 << 22
# A search's yaws are scored on several threads from this many cells of the padded grid
THREADED_GRID_CELLS = 1 << 18


def _fft_windows(plan: _Plan):
    """Each yaw's scores over the offsets, by FFT: score(d) = sum_x counts(x) field(x + d) for
    every x-y offset d at once. The transforms run on x-y sizes FFTs are fast at: the padding
    only adds zeros beyond a grid whose margins already keep every window offset from wrapping.
    One thread per transform: on grids of these sizes more threads cost more than they save (the
    bits are the same); the yaws share the launch pool's threads (`parallel.ordered_map`), in
    order."""
    layer_shape = plan.field.shape
    fft_shape = _fft_shape(plan)
    field_spectrum = fft.rfft2(plan.field, s=fft_shape, axes=(0, 1))
    # the source's counts laid out on the padded grid at once: the same zeros the FFT would pad
    counts_shape = (*fft_shape, layer_shape[2])

    def window(n: int) -> np.ndarray:
        cells = plan.cells(n)
        counts = np.bincount(np.ravel_multi_index(cells.T, counts_shape), minlength=int(np.prod(counts_shape)))
        counts = counts.reshape(counts_shape).astype(np.float32)
        spectrum = (np.conj(fft.rfft2(counts, axes=(0, 1))) * field_spectrum).sum(axis=2)
        return _window(fft.irfft2(spectrum, s=fft_shape), plan.shift_cells)

    return parallel.ordered_map(window, range(len(plan.yaws)), threaded=_fft_threaded(plan))


def _fft_shape(plan: _Plan) -> tuple[int, int]:
    """The x-y sizes a search's FFTs run on: the grid's, padded to sizes FFTs are fast at."""
    return fft.next_fast_len(plan.field.shape[0]), fft.next_fast_len(plan.field.shape[1], real=True)


def _fft_threaded(plan: _Plan) -> bool:
    """Whether a search's yaws share the launch pool's threads (THREADED_GRID_CELLS)."""
    return float(np.prod(_fft_shape(plan))) * plan.field.shape[2] >= THREADED_GRID_CELLS


def _direct_is_cheaper(plan: _Plan) -> bool:
    """Whether correlating directly costs less than the FFTs, by the costs measured above (a
    lookup counted per source point: about one a cell at the default 0.1 m voxels and grid). On
    two threads that sends a sonar swath's single yaw direct up to 3.75 lookups a grid cell
    and a LiDAR search's seven yaws on a large grid only below 1.4: replaying the warehouse
    run's searches, by FFT they took 2.2-2.3 s and directly 3.2-3.3 s."""
    yaws = len(plan.yaws)
    lookups = float(len(plan.moved)) * (2 * plan.shift_cells + 1) ** 2 * yaws
    threads = min(parallel.CPU_THREADS, yaws) if _fft_threaded(plan) else 1
    fft_s = plan.field.size * (FFT_S_PER_CELL + FFT_S_PER_CELL_YAW * yaws / threads)
    return lookups * DIRECT_S_PER_LOOKUP <= fft_s


def _direct_windows(plan: _Plan):
    """Each yaw's scores over the offsets, as `_fft_windows` gives them, by direct correlation:
    for each distinct cell of the source, its count times the field at every x-y offset,
    summed in float64 (no transform's round-off: an offset whose points all miss the target
    scores exactly 0). The grid's margins keep every shifted cell inside it. At most
    DIRECT_CHUNK_LOOKUPS lookups are held at once (cells and offsets both split). One thread:
    the lookups hold the GIL."""
    field = plan.field.ravel()
    ny, nz = plan.field.shape[1:]
    index = np.arange(-plan.shift_cells, plan.shift_cells + 1)
    offsets = (index[:, None] * (ny * nz) + index[None, :] * nz).ravel()
    span = min(len(offsets), DIRECT_CHUNK_LOOKUPS)  # offsets per chunk
    rows = DIRECT_CHUNK_LOOKUPS // span  # source cells per chunk
    for n in range(len(plan.yaws)):
        cells, counts = np.unique(np.ravel_multi_index(plan.cells(n).T, plan.field.shape), return_counts=True)
        weights = counts.astype(np.float64)
        scores = np.zeros(len(offsets))
        for start in range(0, len(offsets), span):
            shifts = offsets[start : start + span]
            for first in range(0, len(cells), rows):
                part = slice(first, first + rows)
                scores[start : start + span] += weights[part] @ field[cells[part, None] + shifts[None, :]]
        yield scores.reshape(len(index), len(index))


def _device_windows(plans: list[_Plan], device):
    """(plan, yaw, window) for every plan and yaw, in that order, the windows as `_fft_windows`
    gives them, by direct correlation on `device`. The slots go in as few launches as the
    budgets allow: a launch's target fields within MAX_FIELD_FLOATS, its source cells within
    MAX_LAUNCH_CELLS and its scores within MAX_LAUNCH_SCORES (a launch takes at least one)."""
    launch, fields, field_floats, cells, scores = [], set(), 0, 0, 0
    for p, plan in enumerate(plans):
        more_cells, more_scores = len(plan.moved), (2 * plan.shift_cells + 1) ** 2
        for n in range(len(plan.yaws)):
            more_floats = 0 if p in fields else plan.field.size
            if launch and (
                field_floats + more_floats > MAX_FIELD_FLOATS
                or cells + more_cells > MAX_LAUNCH_CELLS
                or scores + more_scores > MAX_LAUNCH_SCORES
            ):
                yield from _correlate_on_device(plans, launch, device)
                launch, fields, field_floats, cells, scores = [], set(), 0, 0, 0
                more_floats = plan.field.size
            launch.append((p, n))
            fields.add(p)
            field_floats, cells, scores = field_floats + more_floats, cells + more_cells, scores + more_scores
    if launch:
        yield from _correlate_on_device(plans, launch, device)


def _correlate_on_device(plans: list[_Plan], slots: list, device) -> list:
    """(plan, yaw, window) of `slots` ((plan, yaw) pairs) from one launch, a thread per score."""
    used = sorted({p for p, _ in slots})
    field_index = {p: k for k, p in enumerate(used)}
    field_sizes = np.array([plans[p].field.size for p in used])
    widths = np.array([2 * plans[p].shift_cells + 1 for p, _ in slots])
    counts = np.array([len(plans[p].moved) for p, _ in slots])
    window_start = np.concatenate([[0], np.cumsum(widths**2)]).astype(np.int32)
    with wp.ScopedDevice(device):
        field = wp.array(np.concatenate([plans[p].field.ravel() for p in used]), dtype=wp.float32)
        field_start = wp.array(np.concatenate([[0], np.cumsum(field_sizes)[:-1]]).astype(np.int32), dtype=wp.int32)
        field_dims = wp.array(np.array([plans[p].field.shape for p in used], np.int32), dtype=wp.vec3i)
        shift = wp.array(np.array([plans[p].shift_cells for p in used], np.int32), dtype=wp.int32)
        slot_field = wp.array(np.array([field_index[p] for p, _ in slots], np.int32), dtype=wp.int32)
        cell_start = wp.array(np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int32), dtype=wp.int32)
        cell_count = wp.array(counts.astype(np.int32), dtype=wp.int32)
        cells = wp.array(np.concatenate([plans[p].cells(n) for p, n in slots]).astype(np.int32), dtype=wp.vec3i)
        windows = wp.empty(int(window_start[-1]), dtype=wp.float64)
        wp.launch(
            registration.correlate_shifted_cells,
            dim=int(window_start[-1]),
            inputs=[
                field,
                field_start,
                field_dims,
                shift,
                slot_field,
                cell_start,
                cell_count,
                wp.array(window_start, dtype=wp.int32),
                cells,
            ],
            outputs=[windows],
        )
        flat = windows.numpy()
    return [
        (p, n, flat[first : first + width * width].reshape(width, width))
        for (p, n), width, first in zip(slots, widths, window_start)
    ]


class _Peak:
    """The best score over a search's yaws so far (the first yaw wins a tie), with its window."""

    def __init__(self):
        self.score, self.yaw, self.index, self.window = -np.inf, None, None, None

    def offer(self, yaw: float, window: np.ndarray) -> None:
        index = np.unravel_index(np.argmax(window), window.shape)
        if window[index] > self.score:
            self.score, self.yaw, self.index, self.window = float(window[index]), yaw, index, window

    def match(self, plan: _Plan, config: CorrelativeConfig) -> CorrelativeMatch:
        """The peak's pose and its runner-up: the best score at least exclusion_m away. A peak
        of 0 (no source point over any target cell) finds nothing: T_init, not the window's
        first corner."""
        if not self.score > 0.0:
            return CorrelativeMatch(np.array(plan.T_init, dtype=np.float64), 0.0, 0.0)
        res, window, peak = plan.resolution_m, self.window, self.index
        offsets = (np.array(peak) - plan.shift_cells) * res
        ii, jj = np.meshgrid(np.arange(window.shape[0]), np.arange(window.shape[1]), indexing="ij")
        far = np.hypot(ii - peak[0], jj - peak[1]) * res >= config.exclusion_m
        runner_up = float(window[far].max()) if far.any() else 0.0
        correction = np.eye(4)
        correction[:3, :3] = rotation_from_ypr(self.yaw)
        correction[:3, 3] = plan.pivot - correction[:3, :3] @ plan.pivot + np.array([offsets[0], offsets[1], 0.0])
        return CorrelativeMatch(correction @ plan.T_init, self.score, runner_up)


def _target_field(cells: np.ndarray, shape: np.ndarray, z_lo: int, z_hi: int, blur_voxels: float) -> np.ndarray:
    """Layers [z_lo, z_hi) of the target's occupancy on the grid (1 in each cell holding a point),
    blurred by a Gaussian of blur_voxels (ndimage's, reflecting at the grid's faces) and scaled
    to a maximum of 1. The blur runs on the box around the target only: each pass spreads a
    cell's value at most `reach` cells along its axis, so past the reach of every point the
    blurred field is exactly zero, and a box more than a reach from the points at every face it
    does not share with the grid reflects only zeros back in: every value is the whole grid's,
    bit for bit."""
    reach = int(4.0 * blur_voxels + 0.5) if blur_voxels > 0 else 0  # gaussian_filter's truncate=4
    box_lo = np.maximum(cells.min(axis=0) - (reach + 1), 0)
    box_hi = np.minimum(cells.max(axis=0) + (reach + 1) + 1, shape)
    box = np.zeros(box_hi - box_lo, np.float32)
    inside = cells - box_lo
    box[inside[:, 0], inside[:, 1], inside[:, 2]] = 1.0
    if blur_voxels > 0:
        box = ndimage.gaussian_filter(box, blur_voxels)
        box /= max(float(box.max()), 1e-12)
    field = np.zeros((int(shape[0]), int(shape[1]), z_hi - z_lo), np.float32)
    z0, z1 = max(z_lo, int(box_lo[2])), min(z_hi, int(box_hi[2]))
    if z1 > z0:
        field[box_lo[0] : box_hi[0], box_lo[1] : box_hi[1], z0 - z_lo : z1 - z_lo] = box[
            :, :, z0 - box_lo[2] : z1 - box_lo[2]
        ]
    return field


def _window(scores: np.ndarray, cells: int) -> np.ndarray:
    """Scores of offsets -cells..cells in x and y (circular indices), offset 0 at the centre."""
    index = np.arange(-cells, cells + 1)
    return scores[np.ix_(index % scores.shape[0], index % scores.shape[1])]
