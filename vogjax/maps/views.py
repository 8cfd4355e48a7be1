"""Submaps at poses, packed for the kernels: one `SubmapView` per (submap, pose), built
column-wise in NumPy (a Warp struct per submap costs about 50 us of Python each)."""

from __future__ import annotations

import numpy as np
import warp as wp

from vogjax.kernels.submap_view import SubmapView


def submap_views(submaps: list, poses: np.ndarray, device) -> wp.array:
    """Device array of SubmapViews of `submaps` (Submap objects, held read-locked by the caller)
    at `poses` (n,4,4). A view's box is its submap's observed box widened by a voxel (empty
    where the submap observed nothing)."""
    views = np.zeros(len(submaps), dtype=SubmapView.numpy_dtype())
    if len(submaps) == 0:
        return wp.array(views, dtype=SubmapView, device=device)
    stores = [submap.store for submap in submaps]
    views["table_keys"] = [store.table_keys.ptr for store in stores]
    views["table_slots"] = [store.table_slots.ptr for store in stores]
    views["table_capacity"] = [store.table_capacity for store in stores]
    views["slot_keys"] = [store.slot_keys.ptr for store in stores]
    views["log_odds"] = [store.layers["log_odds"].ptr for store in stores]
    views["block_capacity"] = [store.block_capacity for store in stores]
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    views["rotation"] = poses[:, :3, :3]
    views["rotation_t"] = poses[:, :3, :3].transpose(0, 2, 1)
    views["translation"] = poses[:, :3, 3]
    boxes = np.array([_widened_box(submap) for submap in submaps])
    views["box_lo"], views["box_hi"] = boxes[:, 0], boxes[:, 1]
    return wp.array(views, dtype=SubmapView, device=device)


def _widened_box(submap) -> np.ndarray:
    box = submap.bounds()
    if box is None:
        return np.array([[np.inf] * 3, [-np.inf] * 3])
    margin = submap.config.voxel_size
    return np.array([box[0] - margin, box[1] + margin])
