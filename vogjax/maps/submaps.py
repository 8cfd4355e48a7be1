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
    line_arguments,
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

    Scans go in in the submap's frame: points in world coordinates moved by the inverse of its
    base pose ``T_world_submap``. `VogMap.add_submap` makes one, or takes one built beforehand.

    Parameters
    ----------
    config : MapConfig
        The settings (those of the VogMap it is to join).
    device : str or warp.Device or None
        Warp device (that of the VogMap); None picks CUDA when available, else the CPU.

    Attributes
    ----------
    uid : int
        Tells this submap from any other (a snapshot keeps it), so a global map can refuse to
        undo a contribution of a different submap that happens to sit at the same id.
    config : MapConfig
        The submap's settings.
    device : warp.Device
        Where the submap lives.
    revision : int
        Counts integrations: a global map refuses to undo a submap written since it added it.

    Raises
    ------
    ValueError
        If `config` is not a MapConfig or `device` is not available.
    """

    def __init__(self, config: MapConfig, device: str | wp.Device | None):
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

    def bounds(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None:
        """The box of the submap's observed voxels.

        Returns
        -------
        tuple of two (3,) ndarray of float64, or None
            (lo, hi), metres, in the submap's frame (the voxels' outer faces); None if it has
            observed nothing.
        """
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

    def occupied_points(self) -> npt.NDArray[np.float64]:
        """The centres of the submap's OCCUPIED voxels: the cloud ICP aligns.

        Returns
        -------
        (K, 3) ndarray of float64
            Voxel centres, metres, in the submap's frame, sorted by voxel key (kept until the
            next integration: do not write to it).
        """
        self._refresh_derived()
        return self._occupied


class VogMap:
    """The virtual occupancy grid map: submaps at their poses, queried as their sum.

    The value at a world point is the clamped sum, over the submaps whose box holds it, of the
    log-odds of each submap's voxel containing the point (a fixed-point sum, as in GlobalMap).
    `set_poses` only moves submaps, which is what makes loop closures free for this map.
    Submap ids are 0, 1, ... in the order `add_submap` added them; a pose is the submap's base
    pose ``T_world_submap``, (4, 4), mapping submap coordinates to world coordinates.

    Coarse levels (`level` k >= 1 in the queries) hold, per voxel of voxel_size * 2^k, the
    largest of the virtual values at the centres of its voxels: no sum over submaps gives that,
    so they come from a GlobalMap this map keeps beside its submaps, made on the first coarse
    query and brought to the current poses on each one after (submaps that moved undone and
    redone, as `GlobalMap.update_poses` does; a submap written since forces a full merge). It
    equals `GlobalMap.merge(vog)` bit for bit, and at voxel centres the virtual map. (So a coarse
    point query is conservative against the values at world voxel centres, not against a
    level-0 point query elsewhere in the voxel: the submaps' voxels there may differ.)

    Parameters
    ----------
    config : MapConfig or None, optional
        Settings of every submap (default: ``MapConfig()``).
    device : str or warp.Device or None, optional
        Warp device of every submap; None picks CUDA when available, else the CPU.

    Attributes
    ----------
    config : MapConfig
        The submaps' settings.
    device : warp.Device
        Where the submaps live.

    Raises
    ------
    ValueError
        If `config` is not a MapConfig or `device` is not available.
    """

    def __init__(self, config: MapConfig | None = None, device: str | wp.Device | None = None):
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
        """How many submaps the map holds (their ids are 0 to num_submaps - 1)."""
        return len(self._submaps)

    def add_submap(self, pose: npt.ArrayLike, submap: Submap | None = None) -> int:
        """Add a submap at a base pose.

        Parameters
        ----------
        pose : (4, 4) array_like of float
            Its base pose ``T_world_submap``, a rigid transform.
        submap : Submap or None, optional
            A Submap built beforehand (of this map's config and device, in no VogMap yet), e.g.
            integrated on another thread; None: a new empty one.

        Returns
        -------
        int
            The new submap's id (the number of submaps before it).

        Raises
        ------
        ValueError
            Before anything changes: `pose` is not a rigid (4, 4) transform, or `submap` is no
            Submap, has another config or device, or is in this VogMap already.
        """
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

    def submap(self, i: int) -> Submap:
        """One submap, the object itself (no copy).

        Parameters
        ----------
        i : int
            Its id.

        Returns
        -------
        Submap
            The submap; write to it through its own methods (a global map refuses to undo a
            submap written since it was added).

        Raises
        ------
        ValueError
            If `i` is not one of this map's submap ids.
        """
        return self._submaps[self.check_ids("i", [i])[0]]

    def submaps(self, ids: npt.ArrayLike) -> list[Submap]:
        """Some submaps, the objects themselves, the ids checked once (as `poses(ids)` checks them).

        Parameters
        ----------
        ids : (n,) array_like of int
            Submap ids.

        Returns
        -------
        list of Submap
            The submaps, in the order of `ids`.

        Raises
        ------
        ValueError
            If `ids` are not integers or hold ids this map does not have.
        """
        return [self._submaps[i] for i in self.check_ids("ids", ids).tolist()]

    def pose(self, i: int) -> npt.NDArray[np.float64]:
        """One submap's base pose.

        Parameters
        ----------
        i : int
            Its id.

        Returns
        -------
        (4, 4) ndarray of float64
            ``T_world_submap``, a copy.

        Raises
        ------
        ValueError
            If `i` is not one of this map's submap ids.
        """
        return self._poses[self.check_ids("i", [i])[0]].copy()

    def poses(self, ids: npt.ArrayLike | None = None) -> npt.NDArray[np.float64]:
        """Base poses of some submaps.

        Parameters
        ----------
        ids : (n,) array_like of int or None, optional
            Submap ids; None: all submaps.

        Returns
        -------
        (n, 4, 4) ndarray of float64
            Their ``T_world_submap``, copies, in the order of `ids`.

        Raises
        ------
        ValueError
            If `ids` are not integers or hold ids this map does not have.
        """
        if ids is None:
            return self._poses.copy()
        return self._poses[self.check_ids("ids", ids)].copy()

    def set_poses(self, ids: npt.ArrayLike, poses: npt.ArrayLike) -> None:
        """Move submaps to new base poses; their contents stay as they are.

        What a loop closure costs this map: the next query sums the submaps at their new poses.
        A GlobalMap built from this map follows only when `GlobalMap.update_poses` is called.

        Parameters
        ----------
        ids : (n,) array_like of int
            Submap ids.
        poses : (n, 4, 4) array_like of float
            Their new ``T_world_submap``, rigid transforms, one per id.

        Raises
        ------
        ValueError
            Before anything changes: bad or repeated ids, or `poses` not n rigid (4, 4)
            transforms.
        """
        ids = self.check_ids("ids", ids)
        if len(np.unique(ids)) != len(ids):  # which of two poses would win is NumPy's choice
            raise ValueError(f"ids must not repeat a submap, got {ids.tolist()[:10]}")
        poses = rigid_poses("poses", poses, count=len(ids))
        with self._lock.writing():
            self._poses[ids] = poses

    def view(self, ids: npt.ArrayLike | None = None, poses: npt.ArrayLike | None = None) -> VogMap:
        """A VogMap over the same submap objects (no copies), at poses of its own.

        Handy for "the map without loop closures": the view's poses move independently of this
        map's, while writes to a submap show in both.

        Parameters
        ----------
        ids : (n,) array_like of int or None, optional
            The submaps it holds, each at most once (None: all); they get the ids 0 to n - 1 in
            the view.
        poses : (n, 4, 4) array_like of float or None, optional
            Their ``T_world_submap`` in the view (None: their current ones here).

        Returns
        -------
        VogMap
            The view, of this map's config and device.

        Raises
        ------
        ValueError
            On bad or repeated ids, or `poses` that are not n rigid (4, 4) transforms.
        """
        ids = np.arange(self.num_submaps) if ids is None else self.check_ids("ids", ids)
        if len(np.unique(ids)) != len(ids):  # a submap in a view twice would count twice in every sum
            raise ValueError(f"ids must not repeat a submap, got {ids.tolist()}")
        poses = self._poses[ids] if poses is None else rigid_poses("poses", poses, count=len(ids))
        other = VogMap(self.config, self.device)
        other._submaps = [self._submaps[i] for i in ids]
        other._poses = poses.copy()
        return other

    def check_ids(self, name: str, ids: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """Check submap ids.

        Parameters
        ----------
        name : str
            The argument's name, for error messages.
        ids : int or (n,) array_like of int
            Submap ids.

        Returns
        -------
        (n,) ndarray of int64
            The ids (a single id as an array of one).

        Raises
        ------
        ValueError
            Naming `name`: not integers (or a ragged list), or ids this map does not have.
        """
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

    def log_odds(self, points: npt.ArrayLike, level: int = 0) -> npt.NDArray[np.float32]:
        """Virtual log-odds at `points`.

        Parameters
        ----------
        points : (M, 3) array_like of float
            World points, metres.
        level : int, optional
            0: the submaps' sum at each point; k in [1, 15]: the largest value of the voxels of
            edge voxel_size * 2^k holding each point (see the class docstring).

        Returns
        -------
        (M,) ndarray of float32
            The clamped sums; 0.0 where no submap observed them.

        Raises
        ------
        ValueError
            If `points` is not (M, 3), holds NaN or infinite values, or `level` is no integer
            in [0, 15].
        """
        points = float_array("points", points, (-1, 3))  # checked before any merge
        if check_level(level):
            return self.coarse_map().log_odds(points, level)
        return np.nan_to_num(self._values_at(points.astype(np.float64)), nan=0.0)

    def probability(self, points: npt.ArrayLike, level: int = 0) -> npt.NDArray[np.float32]:
        """Occupancy probability at `points`.

        Parameters
        ----------
        points : (M, 3) array_like of float
            World points, metres.
        level : int, optional
            As for `log_odds`.

        Returns
        -------
        (M,) ndarray of float32
            Probabilities in [0, 1]; 0.5 where unknown.

        Raises
        ------
        ValueError
            As for `log_odds`.
        """
        return probability_from_log_odds(self.log_odds(points, level))

    def state(self, points: npt.ArrayLike, level: int = 0) -> npt.NDArray[np.int8]:
        """States at `points`.

        Parameters
        ----------
        points : (M, 3) array_like of float
            World points, metres.
        level : int, optional
            As for `log_odds`.

        Returns
        -------
        (M,) ndarray of int8
            UNKNOWN (no submap observed the point, or between the thresholds), FREE or
            OCCUPIED.

        Raises
        ------
        ValueError
            As for `log_odds`.
        """
        points = float_array("points", points, (-1, 3))  # checked before any merge
        if check_level(level):
            return self.coarse_map().state(points, level)
        return classify(self._values_at(points.astype(np.float64)), self.config)

    def raycast(
        self, origins: npt.ArrayLike, directions: npt.ArrayLike, max_range: float | npt.ArrayLike, level: int = 0
    ) -> RaycastResult:
        """First OCCUPIED voxel along each ray, as `VoxelMap.raycast`.

        On the world voxel grid, each voxel valued at its centre (long stretches before and
        after the submaps' boxes are counted, not walked, likewise); rays as NumPy arrays only.

        Parameters
        ----------
        origins : (R, 3) array_like of float
            Ray origins, metres, world frame, inside the key range.
        directions : (R, 3) array_like of float
            Directions of any nonzero length.
        max_range : float or (R,) array_like of float
            One range for every ray, or one per ray, metres, positive.
        level : int, optional
            0: the virtual map; k in [1, 15]: `GlobalMap.raycast` of `coarse_map()` at level k.

        Returns
        -------
        RaycastResult
            NumPy arrays: hit (R,) bool, distance (R,) float32, num_unknown and num_free (R,)
            int32.

        Raises
        ------
        ValueError
            Naming the argument: arrays of the wrong shape, NaN, infinite or out-of-range
            origins, zero directions, ranges that are not positive, a bad level; Warp arrays
            at a coarse level.
        """
        if check_level(level):
            if any(isinstance(a, wp.array) for a in (origins, directions, max_range)):
                raise ValueError("origins, directions and max_range must be NumPy arrays or numbers for a VogMap")
            checked = ray_arguments(origins, directions, max_range, normalise=False)  # before any merge
            check_extent(self.config, origins=checked[0])
            return self.coarse_map().raycast(*checked[:2], max_range, level)
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

    def line_query(
        self, starts: npt.ArrayLike, ends: npt.ArrayLike, level: int = 0
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int32]]:
        """Virtual log-odds at the centres of the voxels on each line, as `VoxelMap.line_query`.

        Parameters
        ----------
        starts, ends : (R, 3) array_like of float
            World points, metres.
        level : int, optional
            0: the virtual map; k in [1, 15]: `GlobalMap.line_query` of `coarse_map()` at
            level k.

        Returns
        -------
        values : (R, S) ndarray of float32
            Log-odds along each line, S its longest; 0.0 where unknown, NaN past each line's end.
        lengths : (R,) ndarray of int32
            The number of voxels of each line.

        Raises
        ------
        ValueError
            As for `VoxelMap.line_query`.
        """
        if check_level(level):
            starts, ends = line_arguments(self.config, starts, ends, level)  # before any merge
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
