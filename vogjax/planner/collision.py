"""Collision checks of edges: the vehicle's box swept along each edge, against the map.

OCCUPIED and UNKNOWN voxels are unsafe (Bircher et al., Ho), except in the box at the vehicle's
own position (it is there: that is water, whatever a drifted map says), and for unknown voxels
two more exceptions, both forced by what a profiling sonar at the bow can see:
- those within `clearance_m` of it: the sonar sees nothing within its blind distance of itself
  nor behind its fan, so the water right around the vehicle stays unknown;
- on an edge that moves in x-y, those whose column is FREE at the height of the edge's centre
  line: the fan spans -24.5 to +4.5 degrees, so the top slab of the box (0.25 m above the
  centre) is seen only from 3 m away and more, while the layer the vehicle travels in is seen
  all along. An obstacle lying wholly inside the box's top or bottom slab, never seen, is what
  this lets through (an overhang at the vehicle's top); occupied voxels are always unsafe.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from vogjax.kernels import hashing
from vogjax.kernels import planner_collision as kernels
from vogjax.maps import parallel
from vogjax.planner.source import Source, opened
from vogjax.validation import float_array, within_key_range

# Voxels one edge's swept box may cover, at most (a 1 m box along 2 m at 0.1 m: about 15,000).
MAX_SWEPT_VOXELS = 1 << 26


def edges_clear(map_, starts, ends, box_m, vehicle, clearance_m: float = 0.0) -> np.ndarray:
    """(E,) bool: is the box of extents box_m (3,) (world-aligned, centred on the path) free
    along each edge from starts (E,3) to ends (E,3)? vehicle (3,): where the vehicle is now."""
    starts = float_array("starts", starts, (-1, 3), np.float64)
    ends = float_array("ends", ends, (starts.shape[0], 3), np.float64)
    box_m = float_array("box_m", box_m, (3,), np.float64)
    vehicle = float_array("vehicle", vehicle, (3,), np.float64)
    if np.any(box_m <= 0):
        raise ValueError("box_m must be positive")
    if not (np.isfinite(clearance_m) and clearance_m >= 0):
        raise ValueError(f"clearance_m must be a non-negative number, got {clearance_m!r}")
    with opened(map_) as source:
        return clear_edges(source, starts, ends, box_m, vehicle, clearance_m)


def clear_edges(
    source: Source, starts: np.ndarray, ends: np.ndarray, box_m: np.ndarray, vehicle: np.ndarray, clearance_m: float
) -> np.ndarray:
    """`edges_clear` on an opened map."""
    count, device = len(starts), source.device
    if count == 0:
        return np.zeros(0, bool)
    s = source.config.voxel_size
    half = box_m / 2
    lo = np.minimum(starts, ends) - half
    hi = np.maximum(starts, ends) + half
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
        wp.array(first.astype(np.int32), dtype=wp.vec3i, device=device),
        wp.array(sizes.astype(np.int32), dtype=wp.vec3i, device=device),
        source.access,
        offsets,
        candidates,
        wp.vec3d(*vehicle),
        np.float64(clearance_m),
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
