"""Submaps and the virtual map: local VoxelMaps hung off pose-graph nodes, summed on the fly."""

from __future__ import annotations

import contextlib
import itertools
import math
import threading
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax import devices
from vogjax.config import MapConfig
from vogjax.geometry import rigid_pose, rigid_poses
from vogjax.kernels import fixed_point, virtual
from vogjax.maps import parallel
from vogjax.maps.blockmap import (
    RaycastResult,
    check_extent,
    classify,
    line_voxels,
    probability_from_log_odds,
    ray_arguments,
)
from vogjax.maps.levels import check_level
from vogjax.maps.locking import ReadWriteLock
from vogjax.maps.views import submap_views
from vogjax.maps.voxelmap import VoxelMap
from vogjax.validation import float_array

if TYPE_CHECKING:
    from vogjax.maps.globalmap import GlobalMap

_SUBMAP_UIDS = itertools.count(1)


class Submap(VoxelMap):
    """A VoxelMap in the frame of its base pose (the pose lives in the VogMap that owns it).
    `uid` tells this submap from any other, so a global map can refuse to undo a contribution
    of a different submap that happens to sit at the same id."""

    def __init__(self, config: MapConfig, device):
        super().__init__(config, device)
        self.uid = next(_SUBMAP_UIDS)
        self._derived_revision = -1
        self._bounds = None
        self._occupied = None

    def _refresh_derived(self) -> None:
        if self._derived_revision == self.revision:
            return
        centres, log_odds = self.voxels()
        half = self.config.voxel_size / 2
        self._bounds = (centres.min(axis=0) - half, centres.max(axis=0) + half) if len(centres) else None
        self._occupied = centres[log_odds >= self.config.log_occupied]
        self._derived_revision = self.revision

    def bounds(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(lo, hi) metres, the submap-frame box of its observed voxels; None if it has none."""
        self._refresh_derived()
        return self._bounds

    def snapshot(self) -> Submap:
        """A copy of the submap as it is now.

        Returns
        -------
        Submap
            The same uid and revision, blocks of its own: what a global map undoes the
            contribution of once the submap itself has been written to.
        """
        copy = Submap(self.config, self.device)
        copy.uid = self.uid
        with self.reading():
            copy.revision = self.revision
            copy._store = self._store.copy()
        return copy

    def occupied_points(self) -> np.ndarray:
        """(K,3) submap-frame centres of its OCCUPIED voxels (the cloud ICP aligns)."""
        self._refresh_derived()
        return self._occupied


class VogMap:
    """The virtual occupancy grid map: submaps at their poses, queried as their sum.

    The value at a world point is the clamped sum, over the submaps whose box holds it, of the
    log-odds of each submap's voxel containing the point (a fixed-point sum, as in GlobalMap).
    `set_poses` only moves submaps, which is what makes loop closures free for this map.

    Coarse levels (`level` k >= 1 in the queries) hold, per voxel of voxel_size * 2^k, the
    largest of the virtual values at the centres of its voxels: no sum over submaps gives that,
    so they come from a GlobalMap this map keeps beside its submaps, made on the first coarse
    query and brought to the current poses on each one after (submaps that moved undone and
    redone, as `GlobalMap.update_poses` does; a submap written since forces a full merge). It
    equals `GlobalMap.merge(vog)` bit for bit, and at voxel centres the virtual map.
    """

    def __init__(self, config: MapConfig | None = None, device=None):
        if config is not None and not isinstance(config, MapConfig):
            raise ValueError(f"config must be a vj.MapConfig, got {type(config).__name__}")
        self.config = config or MapConfig()
        self.device = devices.resolve(device)
        self._submaps: list[Submap] = []
        self._poses = np.zeros((0, 4, 4))
        self._lock = ReadWriteLock()
        self._coarse = None  # the GlobalMap coarse queries read, made on the first one
        self._coarse_lock = threading.Lock()

    # ---------------------------------------------------------------- submaps and poses
    @property
    def num_submaps(self) -> int:
        return len(self._submaps)

    def add_submap(self, pose, submap: Submap | None = None) -> int:
        """A new submap with base pose `pose` (4,4) T_world_submap; returns its id.

        submap: a Submap built beforehand (of this map's config and device, in no VogMap yet),
        e.g. integrated on another thread; None: a new empty one."""
        pose = rigid_pose("pose", pose)[None]
        if submap is not None:
            if not isinstance(submap, Submap):
                raise ValueError(f"submap must be a Submap, got {type(submap).__name__}")
            if submap.config != self.config or submap.device != self.device:
                raise ValueError("submap must have this VogMap's config and device")
            if any(s is submap for s in self._submaps):
                raise ValueError("submap is already in this VogMap")
        with self._lock.writing():
            self._submaps.append(Submap(self.config, self.device) if submap is None else submap)
            self._poses = np.concatenate([self._poses, pose])
            return len(self._submaps) - 1

    def submap(self, i) -> Submap:
        return self._submaps[self.check_ids("i", [i])[0]]

    def submaps(self, ids) -> list[Submap]:
        """The submaps `ids`, the ids checked once (as `poses(ids)` checks them)."""
        return [self._submaps[i] for i in self.check_ids("ids", ids).tolist()]

    def pose(self, i) -> np.ndarray:
        return self._poses[self.check_ids("i", [i])[0]].copy()

    def poses(self, ids=None) -> np.ndarray:
        """(n,4,4) poses of `ids` (all submaps when None)."""
        if ids is None:
            return self._poses.copy()
        return self._poses[self.check_ids("ids", ids)].copy()

    def set_poses(self, ids, poses) -> None:
        """Move submaps `ids` to `poses` (n,4,4); their contents stay as they are."""
        ids = self.check_ids("ids", ids)
        poses = rigid_poses("poses", poses, count=len(ids))
        with self._lock.writing():
            self._poses[ids] = poses

    def view(self, ids=None, poses=None) -> VogMap:
        """A VogMap over the same submap objects (no copies): `ids` of them (all when None), at
        `poses` (their own when None). Handy for "the map without loop closures"."""
        ids = np.arange(self.num_submaps) if ids is None else self.check_ids("ids", ids)
        if len(np.unique(ids)) != len(ids):  # a submap in a view twice would count twice in every sum
            raise ValueError(f"ids must not repeat a submap, got {ids.tolist()}")
        poses = self._poses[ids] if poses is None else rigid_poses("poses", poses, count=len(ids))
        other = VogMap(self.config, self.device)
        other._submaps = [self._submaps[i] for i in ids]
        other._poses = poses.copy()
        return other

    def check_ids(self, name: str, ids) -> np.ndarray:
        """`ids` as an int64 array of this map's submap ids; ValueError naming `name` otherwise."""
        try:
            array = np.atleast_1d(np.asarray(ids))
        except Exception:  # ragged lists
            raise ValueError(f"{name} must be submap ids (integers), got {ids!r}") from None
        if array.ndim != 1 or (array.size and array.dtype.kind not in "iu"):
            raise ValueError(f"{name} must be submap ids (integers), got {ids!r}")
        if array.size and (array.min() < 0 or array.max() >= self.num_submaps):
            raise ValueError(f"{name} holds unknown submap ids (this map has {self.num_submaps})")
        return array.astype(np.int64)

    # ---------------------------------------------------------------- virtual queries
    @contextlib.contextmanager
    def _views(self):
        """Device array of SubmapViews of the observed submaps at their current poses, with
        every submap read-locked."""
        with contextlib.ExitStack() as stack:
            stack.enter_context(self._lock.reading())
            for submap in self._submaps:
                stack.enter_context(submap.reading())
            observed = [i for i, submap in enumerate(self._submaps) if submap.bounds() is not None]
            yield submap_views([self._submaps[i] for i in observed], self._poses[observed], self.device)

    def _values_at(self, points: np.ndarray) -> np.ndarray:
        """Clamped summed log-odds at world points (M,3) float64; NaN where no submap observed."""
        count = points.shape[0]
        sums = wp.zeros(count, dtype=wp.int64, device=self.device)
        counts = wp.zeros(count, dtype=wp.int32, device=self.device)
        d_points = wp.array(points, dtype=wp.vec3d, device=self.device)
        inv_resolution = np.float64(1.0 / self.config.voxel_size)
        with self._views() as views:
            if views.shape[0]:
                parallel.split_launch(
                    lambda part, lo, hi: wp.launch(
                        virtual.sum_at_points,
                        dim=(hi - lo, views.shape[0]),
                        inputs=[d_points, lo, views, inv_resolution],
                        outputs=[sums, counts],
                        device=self.device,
                    ),
                    count,
                    parallel.num_parts(self.device, count),
                )
        return fixed_point_values(sums.numpy(), counts.numpy(), self.config)

    def coarse_map(self) -> GlobalMap:
        """The global map coarse queries read, made or brought up to date now.

        Returns
        -------
        GlobalMap
            Equal to `GlobalMap.merge(self)` at the current poses, bit for bit; kept by this
            VogMap (do not write to it).
        """
        from vogjax.maps.globalmap import GlobalMap  # globalmap imports this module

        with self._coarse_lock, self._lock.reading():
            if self._coarse is None:
                self._coarse = GlobalMap(self.config, self.device)
            self._coarse._follow(self)
            return self._coarse

    def log_odds(self, points: npt.ArrayLike, level: int = 0) -> np.ndarray:
        """Virtual log-odds at `points`.

        Parameters
        ----------
        points : array_like
            (M,3) world points, metres.
        level : int
            0: the submaps' sum at each point; k >= 1: the largest value of the voxels of edge
            voxel_size * 2^k holding each point (see the class docstring).

        Returns
        -------
        numpy.ndarray
            (M,) float32, 0.0 where no submap observed them.
        """
        if check_level(level):
            return self.coarse_map().log_odds(points, level)
        points = float_array("points", points, (-1, 3), np.float64)
        return np.nan_to_num(self._values_at(points), nan=0.0)

    def probability(self, points: npt.ArrayLike, level: int = 0) -> np.ndarray:
        """Occupancy probability at `points`.

        Parameters
        ----------
        points : array_like
            (M,3) world points, metres.
        level : int
            As for `log_odds`.

        Returns
        -------
        numpy.ndarray
            (M,) float32, 0.5 where unknown.
        """
        return probability_from_log_odds(self.log_odds(points, level))

    def state(self, points: npt.ArrayLike, level: int = 0) -> np.ndarray:
        """States at `points`.

        Parameters
        ----------
        points : array_like
            (M,3) world points, metres.
        level : int
            As for `log_odds`.

        Returns
        -------
        numpy.ndarray
            (M,) int8: UNKNOWN, FREE or OCCUPIED.
        """
        if check_level(level):
            return self.coarse_map().state(points, level)
        points = float_array("points", points, (-1, 3), np.float64)
        return classify(self._values_at(points), self.config)

    def raycast(
        self, origins: npt.ArrayLike, directions: npt.ArrayLike, max_range: float | npt.ArrayLike, level: int = 0
    ) -> RaycastResult:
        """First OCCUPIED voxel along each ray, as `VoxelMap.raycast`.

        On the world voxel grid, each voxel valued at its centre (long stretches before and
        after the submaps' boxes are counted, not walked, likewise); rays as NumPy arrays only.

        Parameters
        ----------
        origins, directions : array_like
            (R,3) float64.
        max_range : float or array_like
            One range, or (R,), metres.
        level : int
            0: the virtual map; k >= 1: `GlobalMap.raycast` of `coarse_map()` at level k.

        Returns
        -------
        RaycastResult
        """
        if check_level(level):
            if any(isinstance(a, wp.array) for a in (origins, directions, max_range)):
                raise ValueError("origins, directions and max_range must be NumPy arrays or numbers for a VogMap")
            return self.coarse_map().raycast(origins, directions, max_range, level)
        origins, directions, ranges = ray_arguments(origins, directions, max_range)
        check_extent(self.config, origins=origins)
        cfg, device, count = self.config, self.device, origins.shape[0]
        rays = [
            wp.array(origins, dtype=wp.vec3d, device=device),
            wp.array(directions, dtype=wp.vec3d, device=device),
            wp.array(ranges, dtype=wp.float64, device=device),
        ]
        out = {
            "hit": wp.zeros(count, dtype=wp.bool, device=device),
            "distance": wp.zeros(count, dtype=wp.float32, device=device),  # every ray writes its own
            "num_unknown": wp.zeros(count, dtype=wp.int32, device=device),
            "num_free": wp.zeros(count, dtype=wp.int32, device=device),
        }
        parts = parallel.num_parts(device, count)
        with self._views() as views:
            n = views.shape[0]
            # 1. per ray, the submaps whose box it crosses, with the crossing interval
            counts = wp.zeros(count, dtype=wp.int32, device=device)
            parallel.split_launch(
                lambda part, lo, hi: wp.launch(
                    virtual.count_ray_candidates,
                    dim=(hi - lo, n),
                    inputs=[*rays, lo, views],
                    outputs=[counts],
                    device=device,
                ),
                count if n else 0,
                parts,
            )
            offsets_host = np.zeros(count + 1, np.int32)
            np.cumsum(counts.numpy(), out=offsets_host[1:])
            offsets = wp.array(offsets_host, dtype=wp.int32, device=device)
            total = int(offsets_host[-1])
            candidates = wp.empty(max(total, 1), dtype=wp.int32, device=device)
            spans = wp.empty(max(total, 1), dtype=wp.vec2d, device=device)
            fill = wp.zeros(count, dtype=wp.int32, device=device)
            parallel.split_launch(
                lambda part, lo, hi: wp.launch(
                    virtual.list_ray_candidates,
                    dim=(hi - lo, n),
                    inputs=[*rays, lo, views, offsets],
                    outputs=[fill, candidates, spans],
                    device=device,
                ),
                count if n else 0,
                parts,
            )
            # 2. walk each ray, summing its candidates at every voxel centre
            parallel.split_launch(
                lambda part, lo, hi: wp.launch(
                    virtual.cast_virtual_rays,
                    dim=hi - lo,
                    inputs=[
                        *rays,
                        lo,
                        views,
                        offsets,
                        candidates,
                        spans,
                        np.float64(cfg.voxel_size),
                        np.float64(1.0 / cfg.voxel_size),
                        cfg.log_clamp_min,
                        cfg.log_clamp_max,
                        cfg.log_occupied,
                        cfg.log_free,
                    ],
                    outputs=list(out.values()),
                    device=device,
                ),
                count,
                parts,
            )
        return RaycastResult(**{name: a.numpy() for name, a in out.items()})

    def line_query(self, starts: npt.ArrayLike, ends: npt.ArrayLike, level: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Virtual log-odds at the centres of the voxels on each line, as `VoxelMap.line_query`.

        Parameters
        ----------
        starts, ends : array_like
            (R,3) world points, metres.
        level : int
            0: the virtual map; k >= 1: `GlobalMap.line_query` of `coarse_map()` at level k.

        Returns
        -------
        values : numpy.ndarray
            (R,S) float32, NaN past each line's end.
        lengths : numpy.ndarray
            (R,) int32.
        """
        if check_level(level):
            return self.coarse_map().line_query(starts, ends, level)
        keys, lengths = line_voxels(self.config, self.device, starts, ends)
        values = np.full(keys.shape[:2], np.nan, np.float32)
        inside = np.arange(keys.shape[1])[None, :] < lengths[:, None]
        centres = (keys[inside].astype(np.float64) + 0.5) * self.config.voxel_size
        values[inside] = np.nan_to_num(self._values_at(centres), nan=0.0)
        return values, lengths


def fixed_point_values(sums: np.ndarray, counts: np.ndarray, config: MapConfig) -> np.ndarray:
    """Host twin of fixed_point.from_fixed_point: clamped log-odds, NaN where count is 0."""
    values = (sums.astype(np.float64) / fixed_point.FIXED_POINT_SCALE).astype(np.float32)
    values = np.clip(values, config.log_clamp_min, config.log_clamp_max)
    values[counts == 0] = math.nan
    return values
