"""Correlative x-y-yaw search: where two submap clouds overlap best within the navigation's drift.

ICP converges only from within a few voxels of the answer, while navigation drifts metres
between revisits. Depth, pitch and roll are measured absolutely, so the unknowns are x, y and
yaw: for each yaw on a grid, the source cloud is voxelised and cross-correlated with a blurred
occupancy grid of the target over every x-y offset at once (FFT, summed over z layers). The
peak seeds ICP, and the peak's margin over the best clearly different offset tells whether the
match is unambiguous.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import fft, ndimage

from vogjax.config import CorrelativeConfig
from vogjax.geometry import rigid_pose, rotation_from_ypr
from vogjax.validation import real_array

# Bounds on one search: its grid (float32, plus its FFT), and its work, grid cells times yaw
# steps (one FFT pass per step: 1e9 is about a minute on two CPU cores).
MAX_GRID_CELLS = 5e7
MAX_SEARCH_WORK = 1e9
MAX_RADIUS_M = 1000.0
MAX_COORDINATE_M = 1e7  # beyond it float64 keeps no sub-voxel digits of a grid index


@dataclasses.dataclass(frozen=True)
class CorrelativeMatch:
    """T_target_source (4,4) at the peak; score: mean blurred occupancy under the source points
    (1 when every point lands on a target voxel); runner_up: the best score at least
    `exclusion_m` from the peak in x-y; ratio = runner_up / score (small: unambiguous)."""

    T_target_source: np.ndarray
    score: float
    runner_up: float

    @property
    def ratio(self) -> float:
        return self.runner_up / self.score if self.score > 0 else 1.0


def correlative_xyh(source: np.ndarray, target: np.ndarray, T_init: np.ndarray, radius_m: float,
                    yaw_radius_rad: float, config: CorrelativeConfig = CorrelativeConfig()) -> CorrelativeMatch:
    """Best x-y-yaw correction of T_init (source -> target frame) within radius_m and yaw_radius_rad.

    The correction rotates about the source cloud's centroid (in the target frame) and then
    shifts by whole voxels in x and y.
    """
    source, target = real_array("source", source), real_array("target", target)
    for name, cloud in (("source", source), ("target", target)):
        if cloud.ndim != 2 or cloud.shape[1] != 3 or len(cloud) == 0 or not np.all(np.isfinite(cloud)):
            raise ValueError(f"{name} must be a non-empty (N, 3) array of finite points")
        if np.abs(cloud).max() > MAX_COORDINATE_M:
            raise ValueError(f"{name} has coordinates beyond {MAX_COORDINATE_M:g} m")
    T_init = rigid_pose("T_init", T_init)
    for name, value, most in (("radius_m", radius_m, MAX_RADIUS_M), ("yaw_radius_rad", yaw_radius_rad, np.pi)):
        if isinstance(value, bool) or not (isinstance(value, (int, float, np.integer, np.floating)) and 0 <= value <= most):
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
        raise ValueError(f"radius_m ({radius_m:g} m) and yaw_radius_rad ({yaw_radius_rad:g}) ask for a search grid of "
                         f"{cells:.3g} cells x {yaw_steps:.0f} yaw steps at {res:g} m; at most {MAX_GRID_CELLS:.0e} "
                         f"cells and {MAX_SEARCH_WORK:.0e} cells x yaw steps (a coarser resolution_m or a smaller "
                         "radius)")
    shape = extent.astype(int)
    steps = int(yaw_steps) // 2
    # Only the layers the source occupies enter the sum over z (a yaw keeps every z; one more
    # layer either side, as rotating about the pivot can round a z across a face), and the
    # transforms run on x-y sizes FFTs are fast at: the padding only adds zeros beyond a grid
    # whose margins already keep every window offset from wrapping. One thread per transform:
    # on grids of these sizes more threads cost more than they save (the bits are the same).
    z_lo = max(int(np.floor((moved[:, 2].min() - lo[2]) / res)) - 1, 0)
    z_hi = min(int(np.floor((moved[:, 2].max() - lo[2]) / res)) + 2, int(shape[2]))
    field = _target_field(np.floor((target - lo) / res).astype(int), shape, z_lo, z_hi, config.blur_voxels)
    fft_shape = (fft.next_fast_len(int(shape[0])), fft.next_fast_len(int(shape[1]), real=True))
    field_spectrum = fft.rfft2(field, s=fft_shape, axes=(0, 1))
    layer_shape = (int(shape[0]), int(shape[1]), z_hi - z_lo)
    best = (-np.inf, None, None, None)
    for yaw in config.yaw_step_rad * np.arange(-steps, steps + 1):
        rotation = rotation_from_ypr(yaw)
        points = (moved - pivot) @ rotation.T + pivot
        cells = np.floor((points - lo) / res).astype(int)
        cells[:, 2] -= z_lo
        counts = np.bincount(np.ravel_multi_index(cells.T, layer_shape), minlength=int(np.prod(layer_shape)))
        counts = counts.reshape(layer_shape).astype(np.float32)
        # score(d) = sum_x counts(x) field(x + d), for every x-y offset d at once
        spectrum = (np.conj(fft.rfft2(counts, s=fft_shape, axes=(0, 1))) * field_spectrum).sum(axis=2)
        scores = fft.irfft2(spectrum, s=fft_shape)
        window = _window(scores, shift_cells) / len(points)
        peak = np.unravel_index(np.argmax(window), window.shape)
        if window[peak] > best[0]:
            best = (float(window[peak]), yaw, peak, window)
    score, yaw, peak, window = best
    offsets = (np.array(peak) - shift_cells) * res
    ii, jj = np.meshgrid(np.arange(window.shape[0]), np.arange(window.shape[1]), indexing="ij")
    far = np.hypot(ii - peak[0], jj - peak[1]) * res >= config.exclusion_m
    runner_up = float(window[far].max()) if far.any() else 0.0
    correction = np.eye(4)
    correction[:3, :3] = rotation_from_ypr(yaw)
    correction[:3, 3] = pivot - correction[:3, :3] @ pivot + np.array([offsets[0], offsets[1], 0.0])
    return CorrelativeMatch(correction @ T_init, score, runner_up)


def _target_field(cells: np.ndarray, shape: np.ndarray, z_lo: int, z_hi: int, blur_voxels: float) -> np.ndarray:
    """Layers [z_lo, z_hi) of the target's occupancy on the grid (1 in each cell holding a point),
    blurred by a Gaussian of blur_voxels (ndimage's, reflecting at the grid's faces) and scaled
    to a maximum of 1. The blur runs on the box around the target only: past the kernel's reach
    the blurred field is exactly zero, and a box kept a further reach away from any face it does
    not share with the grid reflects only those zeros, so every value is the whole grid's, bit
    for bit."""
    reach = int(4.0 * blur_voxels + 0.5) if blur_voxels > 0 else 0  # gaussian_filter's truncate=4
    box_lo = np.maximum(cells.min(axis=0) - 2 * reach, 0)
    box_hi = np.minimum(cells.max(axis=0) + 2 * reach + 1, shape)
    box = np.zeros(box_hi - box_lo, np.float32)
    inside = cells - box_lo
    box[inside[:, 0], inside[:, 1], inside[:, 2]] = 1.0
    if blur_voxels > 0:
        box = ndimage.gaussian_filter(box, blur_voxels)
        box /= max(float(box.max()), 1e-12)
    field = np.zeros((int(shape[0]), int(shape[1]), z_hi - z_lo), np.float32)
    z0, z1 = max(z_lo, int(box_lo[2])), min(z_hi, int(box_hi[2]))
    if z1 > z0:
        field[box_lo[0]:box_hi[0], box_lo[1]:box_hi[1], z0 - z_lo:z1 - z_lo] = box[:, :, z0 - box_lo[2]:z1 - box_lo[2]]
    return field


def _window(scores: np.ndarray, cells: int) -> np.ndarray:
    """Scores of offsets -cells..cells in x and y (circular indices), offset 0 at the centre."""
    index = np.arange(-cells, cells + 1)
    return scores[np.ix_(index % scores.shape[0], index % scores.shape[1])]
