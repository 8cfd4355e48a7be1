"""The maps a planner reads, opened for its kernels (`kernels/planner_maps.py`).

with opened(map) as source:   # a VoxelMap, GlobalMap, VogMap or Overlay, read-locked
    source.access             # the MapAccess struct the kernels take
    source.boxes              # (n,2,3) world boxes of its submap views (the virtual part)
"""

from __future__ import annotations

import contextlib
import dataclasses

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax.config import MapConfig
from vogjax.kernels import planner_maps
from vogjax.maps import GlobalMap, VogMap, VoxelMap
from vogjax.maps.levels import check_level, level_scales
from vogjax.maps.views import submap_views


class Overlay:
    """A global map with submaps on top at their current poses: what the global map will hold
    once they are added.

    The mapper adds a submap only when it is complete, and holds its scans until then, so a
    planner on the online global map reads it through an Overlay of the scans not yet in it
    (`extra`: a VogMap of their own, e.g. one submap of the scans the mapper holds), or it
    would not see the last up to 100 scans. Sums are exact: at voxel centres an Overlay answers
    what `GlobalMap.add` of those submaps would. A submap of `vog` added to base after the
    Overlay was made is read from base alone from then on.

    Parameters
    ----------
    base : vj.GlobalMap
    vog : vj.VogMap
        The map whose submaps `ids` lie on top (not yet in base).
    ids : array_like of int
        Submaps of `vog`, none of them in base.
    extra : vj.VogMap, optional
        Every submap of this map lies on top as well, at its pose (same MapConfig).
    """

    def __init__(self, base: GlobalMap, vog: VogMap, ids: npt.ArrayLike, extra: VogMap | None = None) -> None:
        if not isinstance(base, GlobalMap):
            raise ValueError(f"base must be a vj.GlobalMap, got {type(base).__name__}")
        if not isinstance(vog, VogMap):
            raise ValueError(f"vog must be a vj.VogMap, got {type(vog).__name__}")
        if vog.config != base.config:
            raise ValueError("vog has another MapConfig than base")
        if extra is not None and (not isinstance(extra, VogMap) or extra.config != base.config):
            raise ValueError("extra must be a vj.VogMap with base's MapConfig")
        self.ids = [int(i) for i in vog.check_ids("ids", ids)]
        clash = sorted(set(self.ids) & set(base.applied_ids))
        if clash or len(set(self.ids)) != len(self.ids):
            raise ValueError(f"ids: submaps {clash or self.ids} are already in base (or repeated)")
        self.base, self.vog, self.extra = base, vog, extra
        self.config, self.device = base.config, base.device


# What the planner's queries read: a map, the virtual map or a global map with submaps on top.
MapLike = VoxelMap | GlobalMap | VogMap | Overlay


@dataclasses.dataclass(frozen=True)
class Source:
    """An opened map: `access` (planner_maps.MapAccess), `boxes` (n,2,3) the world-aligned
    boxes (lo, hi) of its n submap views, `config`, `device`."""

    access: planner_maps.MapAccess
    boxes: np.ndarray
    config: MapConfig
    device: object

    def candidates(self, lo: np.ndarray, hi: np.ndarray) -> tuple[wp.array, wp.array]:
        """Per query box (lo, hi (Q,3)), the views whose box meets it: offsets (Q+1,) and
        view indices, as device arrays (the CSR lists the kernels take)."""
        count = len(lo)
        if len(self.boxes) == 0 or count == 0:
            offsets = np.zeros(count + 1, np.int32)
            return (
                wp.array(offsets, dtype=wp.int32, device=self.device),
                wp.zeros(1, dtype=wp.int32, device=self.device),
            )
        meets = np.all((lo[:, None, :] <= self.boxes[None, :, 1]) & (hi[:, None, :] >= self.boxes[None, :, 0]), axis=2)
        query, view = np.nonzero(meets)
        offsets = np.zeros(count + 1, np.int64)
        np.cumsum(np.bincount(query, minlength=count), out=offsets[1:])
        if offsets[-1] >= 2**31:
            raise ValueError("too many (query, submap) pairs for one launch; query fewer views at once")
        return (
            wp.array(offsets.astype(np.int32), dtype=wp.int32, device=self.device),
            wp.array(np.r_[view, 0].astype(np.int32), dtype=wp.int32, device=self.device),
        )


PLANNABLE = "a vj.VoxelMap, vj.GlobalMap, vj.VogMap or vogjax.planner.Overlay"


def check_map(map_) -> None:
    if not isinstance(map_, (VoxelMap, GlobalMap, VogMap, Overlay)):
        raise ValueError(f"map must be {PLANNABLE}, got {type(map_).__name__}")


@contextlib.contextmanager
def opened(map_, level: int = 0):
    """`map_` read-locked (its submaps too) as a Source, for the length of the block; at
    `level` k >= 1 its coarse level k (a VogMap's from `VogMap.coarse_map()`, made before any
    lock is taken), whose Source's config has voxel_size * 2^k."""
    check_map(map_)
    level = check_level(level)
    if level and isinstance(map_, Overlay):
        raise ValueError(
            f"level {level}: an Overlay has no coarse levels (the submaps on top are not in its base's); "
            "plan at level 0, or on the GlobalMap or the VogMap"
        )
    coarse = map_.coarse_map() if level and isinstance(map_, VogMap) else map_
    config, device = map_.config, map_.device
    with contextlib.ExitStack() as stack:
        if level:  # a coarse level: a block store of log-odds of its own, no submaps on top
            stack.enter_context(coarse.reading())
            store, kind = coarse.store_at(level), planner_maps.LOG_ODDS_STORE
            submaps, poses = [], np.zeros((0, 4, 4))
        elif isinstance(map_, VogMap):
            store, kind = None, planner_maps.NO_STORE
            submaps, poses = _observed(stack, map_, range(map_.num_submaps))
        elif isinstance(map_, Overlay):
            stack.enter_context(map_.base.reading())
            store, kind = map_.base.store, planner_maps.SUM_STORE
            # a submap added to base since the Overlay was made is there already: on top too,
            # it would count twice
            applied = set(map_.base.applied_ids)
            submaps, poses = _observed(stack, map_.vog, [i for i in map_.ids if i not in applied])
            if map_.extra is not None:
                more, more_poses = _observed(stack, map_.extra, range(map_.extra.num_submaps))
                submaps, poses = submaps + more, np.concatenate([poses, more_poses])
        else:
            stack.enter_context(map_.reading())
            store, kind = map_.store, planner_maps.LOG_ODDS_STORE
            submaps, poses = [], np.zeros((0, 4, 4))
        access = planner_maps.MapAccess()
        access.kind = int(kind)
        empty_keys = wp.full(1, -1, dtype=wp.int64, device=device)
        access.table_keys = store.table_keys if store is not None else empty_keys
        access.table_slots = store.table_slots if store is not None else wp.full(1, -1, dtype=wp.int32, device=device)
        access.log_odds = (
            store.layers["log_odds"] if store is not None else wp.zeros(1, dtype=wp.float32, device=device)
        )
        has_sums = store is not None and "sum" in store.layers
        access.sums = store.layers["sum"] if has_sums else wp.zeros(1, dtype=wp.int64, device=device)
        access.counts = store.layers["count"] if has_sums else wp.zeros(1, dtype=wp.int32, device=device)
        views = submap_views(submaps, poses, device)
        access.views = views if len(submaps) else wp.zeros(1, dtype=views.dtype, device=device)
        access.resolution, access.inv_resolution = level_scales(config.voxel_size, level)
        access.clamp_min, access.clamp_max = config.log_clamp_min, config.log_clamp_max
        access.log_occupied, access.log_free = config.log_occupied, config.log_free
        boxes = np.array([_world_box(s, p) for s, p in zip(submaps, poses)]).reshape(-1, 2, 3)
        if level:
            try:
                config = dataclasses.replace(config, voxel_size=float(access.resolution))
            except ValueError as error:
                raise ValueError(f"level {level}: voxels of {access.resolution:g} m: {error}") from None
        yield Source(access, boxes, config, device)


def _observed(stack: contextlib.ExitStack, vog: VogMap, ids) -> tuple[list, np.ndarray]:
    """The submaps `ids` of `vog` that observed something, read-locked, and their poses."""
    ids = list(ids)
    poses = vog.poses(ids) if ids else np.zeros((0, 4, 4))
    submaps = [vog.submap(i) for i in ids]
    for submap in submaps:
        stack.enter_context(submap.reading())
    keep = [k for k, submap in enumerate(submaps) if submap.bounds() is not None]
    return [submaps[k] for k in keep], poses[keep]


def _world_box(submap, pose: np.ndarray) -> np.ndarray:
    """World-aligned box (2,3) around a submap's observed box (widened by a voxel, as its view)."""
    lo, hi = submap.bounds()
    margin = submap.config.voxel_size
    centre, half = (lo + hi) / 2, (hi - lo) / 2 + margin
    world_centre = pose[:3, :3] @ centre + pose[:3, 3]
    world_half = np.abs(pose[:3, :3]) @ half
    return np.stack([world_centre - world_half, world_centre + world_half])
