"""Collision checks of edges: the vehicle's box swept along each edge, against the map.

OCCUPIED and UNKNOWN voxels are unsafe (Bircher et al., Ho), except in the box at the vehicle's
own position (it is there: that is water, whatever a drifted map says), and for unknown voxels
two more exceptions, both forced by what a profiling sonar at the bow can see:
- those within `clearance_m` of it: the sonar sees nothing within its blind distance of itself
  nor behind its fan, so the water right around the vehicle stays unknown (with `layer_only`,
  only those within the height of the vehicle's box: the water above and below it is as unseen,
  and a climb into it would be blind);
- on an edge that moves in x-y, those whose column is FREE at the height of the edge's centre
  line (with `layer_only`, or there lies in the vehicle's box: it is water): the fan spans
  -24.5 to +4.5 degrees, so the top slab of the box (0.25 m above the centre) is seen only from
  3 m away and more, while the layer the vehicle travels in is seen all along. An obstacle
  lying wholly inside the box's top or bottom slab, never seen, is what this lets through (an
  overhang at the vehicle's top); occupied voxels are always unsafe.

OCCUPIED voxels are also kept `obstacle_margin_m` farther off (a larger box swept for them
alone): the vehicle's estimate drifts from where an obstacle was mapped, while unknown water
is no nearer for it; an occupied voxel the larger box already holds at the vehicle's position
does not block (the vehicle may leave a wall it came close to, not approach it).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax.kernels import hashing
from vogjax.kernels import planner_collision as kernels
from vogjax.maps import parallel
from vogjax.planner.source import MapLike, Source, opened
from vogjax.validation import float_array, within_key_range

# Voxels one edge's swept box may cover, at most (a 1 m box along 2 m at 0.1 m: about 15,000).
MAX_SWEPT_VOXELS = 1 << 26


def edges_clear(
    map_: MapLike,
    starts: npt.ArrayLike,
    ends: npt.ArrayLike,
    box_m: npt.ArrayLike,
    vehicle: npt.ArrayLike,
    clearance_m: float = 0.0,
    layer_only: bool = False,
    obstacle_margin_m: float | npt.ArrayLike = 0.0,
) -> npt.NDArray[np.bool_]:
    """Whether a box swept along each edge is free.

    Parameters
    ----------
    map_ : vj.VoxelMap, vj.GlobalMap, vj.VogMap or vogjax.planner.Overlay
    starts, ends : array_like, (E, 3) float
        The edges' end points.
    box_m : array_like, (3,) float
        The box's extents (world-aligned, centred on the path).
    vehicle : array_like, (3,) float
        Where the vehicle is now (the box there is water).
    clearance_m : float
        Unknown voxels within this distance of the vehicle count as free.
    layer_only : bool
        ... and only those within the height of the box at the vehicle; on an edge that
        moves, an unknown voxel counts as free when its column's voxel at the height of the
        edge's centre line is FREE (a climb enters only layers seen free).
    obstacle_margin_m : float or array_like (3,)
        OCCUPIED voxels are kept this much farther off (the box grown by it on each side, per
        axis), except those the grown box already holds at the vehicle's position.

    Returns
    -------
    numpy.ndarray, (E,) bool
        Whether each edge is clear.

    Raises
    ------
    ValueError
        If an argument is malformed, box_m not positive, clearance_m or obstacle_margin_m
        negative, or the box would leave the map's key range.
    """
    starts = float_array("starts", starts, (-1, 3), np.float64)
    ends = float_array("ends", ends, (starts.shape[0], 3), np.float64)
    box_m = float_array("box_m", box_m, (3,), np.float64)
    vehicle = float_array("vehicle", vehicle, (3,), np.float64)
    if np.any(box_m <= 0):
        raise ValueError("box_m must be positive")
    if not (np.isfinite(clearance_m) and clearance_m >= 0):
        raise ValueError(f"clearance_m must be a non-negative number, got {clearance_m!r}")
    obstacle = float_array("obstacle_margin_m", np.broadcast_to(obstacle_margin_m, 3), (3,), np.float64)
    if np.any(obstacle < 0):
        raise ValueError("obstacle_margin_m must be non-negative")
    with opened(map_) as source:
        return clear_edges(source, starts, ends, box_m, vehicle, clearance_m, bool(layer_only), obstacle)


def clear_edges(
    source: Source,
    starts: np.ndarray,
    ends: np.ndarray,
    box_m: np.ndarray,
    vehicle: np.ndarray,
    clearance_m: float,
    layer_only: bool = False,
    obstacle_margin_m=0.0,
) -> np.ndarray:
    """`edges_clear` on an opened map."""
    count, device = len(starts), source.device
    if count == 0:
        return np.zeros(0, bool)
    s = source.config.voxel_size
    half = box_m / 2
    half_obstacle = half + np.broadcast_to(np.asarray(obstacle_margin_m, np.float64), 3)
    lo = np.minimum(starts, ends) - half_obstacle
    hi = np.maximum(starts, ends) + half_obstacle
    within_key_range("starts", np.abs(np.r_[lo, hi]), s, hashing.VOXEL_KEY_LIMIT)
    # every voxel whose cube may touch the swept box (a voxel of margin: touching counts)
    first = np.floor(lo / s).astype(np.int64) - 1
    sizes = np.floor(hi / s).astype(np.int64) + 2 - first
    swept = sizes.prod(axis=1)
    if swept.max() > MAX_SWEPT_VOXELS:
        i = int(np.argmax(swept))
        raise ValueError(
            f"ends: edge {i} sweeps its box through {swept[i]} voxels; at most {MAX_SWEPT_VOXELS} "
            "an edge (split long edges)"
        )
    offsets, candidates = source.candidates(lo, hi)
    unsafe = wp.zeros(count, dtype=wp.int32, device=device)
    inputs = [
        wp.array(starts, dtype=wp.vec3d, device=device),
        wp.array(ends, dtype=wp.vec3d, device=device),
        wp.vec3d(*half),
        wp.vec3d(*half_obstacle),
        wp.array(first.astype(np.int32), dtype=wp.vec3i, device=device),
        wp.array(sizes.astype(np.int32), dtype=wp.vec3i, device=device),
        source.access,
        offsets,
        candidates,
        wp.vec3d(*vehicle),
        np.float64(clearance_m),
        int(layer_only),
    ]
    columns = int((sizes[:, 0] * sizes[:, 1]).max())
    # launches of at most 2^31 threads (edges x the widest edge's columns)
    parts = max(parallel.num_parts(device, count * columns // 64), -(-count * columns // (1 << 30)))
    parallel.split_launch(
        lambda part, lo_, hi_: wp.launch(
            kernels.count_unsafe_voxels,
            dim=(hi_ - lo_, columns),
            inputs=[lo_, *inputs],
            outputs=[unsafe],
            device=device,
        ),
        count,
        min(parts, count),
    )
    return unsafe.numpy() == 0
