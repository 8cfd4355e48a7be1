"""Submaps at poses, packed for the kernels: one `SubmapView` per (submap, pose), built
column-wise in NumPy (a Warp struct per submap costs about 50 us of Python each)."""

from __future__ import annotations

import numpy as np
import warp as wp

from vogjax.kernels.submap_view import SubmapView

_DTYPE = None  # SubmapView's NumPy dtype, parsed once (NumPy parses a dtype spec per use)


def submap_views(submaps: list, poses: np.ndarray, device) -> wp.array:
    """Device array of SubmapViews of `submaps` (Submap objects, held read-locked by the caller)
    at `poses` (n,4,4). A view's box is its submap's observed box widened by a voxel (empty
    where the submap observed nothing)."""
    global _DTYPE
    if _DTYPE is None:
        _DTYPE = np.dtype(SubmapView.numpy_dtype())
    views = np.zeros(len(submaps), dtype=_DTYPE)
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
    # the boxes widened by a voxel, in two array operations rather than two per submap
    boxes = [submap.bounds() for submap in submaps]
    empty = ((np.inf,) * 3, (-np.inf,) * 3)
    lo = np.array([empty[0] if box is None else box[0] for box in boxes], dtype=np.float64)
    hi = np.array([empty[1] if box is None else box[1] for box in boxes], dtype=np.float64)
    margin = np.array([submap.config.voxel_size for submap in submaps], dtype=np.float64)[:, None]
    views["box_lo"], views["box_hi"] = lo - margin, hi + margin
    return wp.array(views, dtype=SubmapView, device=device)
