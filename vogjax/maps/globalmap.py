"""GlobalMap: one map for planners, kept consistent with loop closures by undo/redo of submaps.

Each voxel stores the exact fixed-point sum of the log-odds its submaps contribute and how many
contribute. Clamping and the occupancy state come at query time, so removing a submap's
contribution (at the pose it was applied at) and adding it back at its new pose leaves exactly
what a full merge at the new poses would build (Sodhi et al., Algorithm 1, with the
p_min = 0, p_max = 1 restriction lifted).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from os import PathLike

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax.config import MapConfig, PipelineConfig
from vogjax.config.schema import check_setting
from vogjax.geometry import confidence_volume, pose_deltas, rigid_pose
from vogjax.io import read_map_file, write_map_file
from vogjax.kernels import accumulation, hashing
from vogjax.maps import parallel
from vogjax.maps.blockmap import BlockMap
from vogjax.maps.blocks import BLOCK_VOXELS, BlockStore, check_block_keys, voxel_keys
from vogjax.maps.submaps import VogMap
from vogjax.maps.views import submap_views
from vogjax.validation import real_array

LAYERS = {"sum": (wp.int64, 0), "count": (wp.int32, 0)}
# Submaps (the newest) whose copies `_follow` keeps, to undo them once they were written to.
FOLLOW_SNAPSHOTS = 2
# Marginals that fail these checks are not covariances: asymmetry and negative eigenvalues
# relative to each matrix's own largest entry (round-off is about 1e-16 of it; a scale over the
# whole batch let one large marginal hide a variance of -1 in another)
_SYMMETRY_TOLERANCE = _PSD_TOLERANCE = 1e-11


@dataclasses.dataclass(frozen=True)
class Applied:
    """A submap as the global map holds it: the pose it was added at, its revision then, the
    95% x-y-yaw confidence volume of that pose (inf: not known) and the submap's uid (None when
    loaded from a file: the submap objects are not)."""

    pose: np.ndarray
    revision: int
    volume: float = math.inf
    uid: int | None = None


@dataclasses.dataclass(frozen=True)
class UpdateReport:
    """What `GlobalMap.update_poses` did (Sodhi et al., Algorithm 1).

    Attributes
    ----------
    reapplied : tuple of int
        Ids undone at their applied pose and redone at their current one (in S1 and S2).
    moved : tuple of int
        Ids whose pose moved by more than eps_rot or eps_trans (and, with eps_move_m > 0, moved
        a corner of their box by more than it): S1.
    uncertain : tuple of int or None
        Ids whose x-y-yaw confidence volume exceeds eps_cov now or did when they were last
        applied: S2; None: all of them, there were no marginals.
    eps_cov : float or None
        The volume threshold used ("auto" resolved to its value); None without marginals.
    voxels_touched : int
        Global voxel updates made (each undo and each redo counts its voxels).
    seconds : float
        Wall time of the update, seconds.
    """

    reapplied: tuple[int, ...]
    moved: tuple[int, ...]
    uncertain: tuple[int, ...] | None
    eps_cov: float | None
    voxels_touched: int
    seconds: float


class GlobalMap(BlockMap):
    """The online global map of Sodhi et al. over the submaps of a VogMap.

    Each voxel holds the exact fixed-point sum of the log-odds its submaps contribute (at the
    poses they were applied at) and how many contribute; clamping and the state come at query
    time. So `update_poses`, which undoes a moved submap's contribution and redoes it at its
    new pose, leaves exactly what `merge` at the new poses builds, bit for bit (Algorithm 1,
    with the p_min = 0, p_max = 1 restriction lifted).

    Queries (those of VoxelMap) read the map under a shared lock; `merge`, `add` and
    `update_poses` hold it exclusively for their whole run, so a planner querying from another
    thread sees the map before an update or after it, never in between.

    Parameters
    ----------
    config : MapConfig or None, optional
        Settings; they must be the VogMap's (default: ``MapConfig()``).
    device : str or warp.Device or None, optional
        Warp device; None picks CUDA when available, else the CPU.

    Attributes
    ----------
    config : MapConfig
        The map's settings.
    device : warp.Device
        Where the map lives.

    Raises
    ------
    ValueError
        If `config` is not a MapConfig or `device` is not available.
    """

    def __init__(self, config: MapConfig | None = None, device: str | wp.Device | None = None):
        super().__init__(config, device, layers=LAYERS)
        self._applied: dict[int, Applied] = {}
        self._snapshots: dict = {}  # id -> Submap copy as applied, kept by `_follow` (a VogMap's coarse map)

    @property
    def applied_ids(self) -> tuple[int, ...]:
        """Ids of the submaps whose contribution the map holds, ascending."""
        return tuple(sorted(self._applied))

    def applied_pose(self, i: int) -> npt.NDArray[np.float64]:
        """The pose at which a submap's contribution stands in the map.

        Parameters
        ----------
        i : int
            A submap id in `applied_ids`.

        Returns
        -------
        (4, 4) ndarray of float64
            Its ``T_world_submap`` when it was last applied, a copy.

        Raises
        ------
        ValueError
            If `i` is not an integer or not in `applied_ids`.
        """
        if isinstance(i, (bool, np.bool_)) or not isinstance(i, (int, np.integer)):
            raise ValueError(f"i must be a submap id (an integer), got {i!r}")
        i = int(i)
        if i not in self._applied:
            raise ValueError(f"i: submap {i!r} has not been added to this global map")
        return self._applied[i].pose.copy()

    # ---------------------------------------------------------------- building
    def merge(self, vog: VogMap, marginals: npt.ArrayLike | None = None) -> int:
        """Rebuild from scratch with every submap at its current pose (the "full merge").

        Parameters
        ----------
        vog : VogMap
            The submaps, of this map's config.
        marginals : (N, 6, 6) array_like of float or None, optional
            Covariances of all N submaps' poses, as for `update_poses` (None: not known).

        Returns
        -------
        int
            The number of global voxel updates made.

        Raises
        ------
        ValueError
            Before anything changes: `vog` is no VogMap of this map's config, `marginals` is
            not valid (see `update_poses`), or a submap at its pose reaches beyond the voxel
            keys the map can pack.
        """
        self._check_vog(vog)
        volumes = self._volumes(vog, marginals)
        self._check_key_range(vog, range(vog.num_submaps))
        with self._lock.writing():
            self._store = BlockStore(self.device, self._store.layer_specs)
            self._applied, self._snapshots = {}, {}
            touched = []
            pulls = self._apply(vog, range(vog.num_submaps), touched, volumes)
            self._refresh(touched, rebuilt=True)
        return pulls

    def add(self, vog: VogMap, ids: npt.ArrayLike, marginals: npt.ArrayLike | None = None) -> int:
        """Add submaps not yet in the map at their current poses (the cached merge).

        Add a submap once it is complete: one written to after it was added cannot be
        re-applied (`update_poses` refuses it).

        Parameters
        ----------
        vog : VogMap
            The submaps, of this map's config.
        ids : (n,) array_like of int
            Ids of submaps of `vog` not in the map yet, none repeated.
        marginals : (N, 6, 6) array_like of float or None, optional
            Covariances of all N submaps' poses (rows of `ids` are read), as for
            `update_poses`; None: not known, so these submaps count as uncertain until
            re-applied.

        Returns
        -------
        int
            The number of global voxel updates made.

        Raises
        ------
        ValueError
            Before anything changes: as for `merge`, or bad ids, ids already in the map, or
            repeated ones (moved submaps are re-applied by `update_poses`).
        """
        self._check_vog(vog)
        volumes = self._volumes(vog, marginals)
        ids = [int(i) for i in vog.check_ids("ids", ids)]
        already = [i for i in ids if i in self._applied]
        if already:
            raise ValueError(
                f"ids: submaps {already[:10]} are already in the global map; moved submaps are "
                "re-applied by update_poses"
            )
        if len(set(ids)) != len(ids):
            raise ValueError(f"ids must not repeat a submap, got {ids[:10]}")
        self._check_key_range(vog, ids)
        with self._lock.writing():
            touched = []
            pulls = self._apply(vog, ids, touched, volumes)
            self._refresh(touched)
        return pulls

    def update_poses(
        self,
        vog: VogMap,
        marginals: npt.ArrayLike | None = None,
        eps_rot: float = PipelineConfig.eps_rot,
        eps_trans: float = PipelineConfig.eps_trans,
        eps_cov: float | str = PipelineConfig.eps_cov,
        eps_move_m: float = 0.0,
    ) -> UpdateReport:
        """Sodhi et al. Algorithm 1: re-apply the submaps that moved and are uncertain.

        S1: applied submaps whose current pose differs from the applied one by a rotation angle
        above `eps_rot` (rad) or a translation above `eps_trans` (m), both from the SE(3) log of
        the relative pose, and (when `eps_move_m` > 0) that move some corner of their observed
        box by more than `eps_move_m` (m): what moves a submap's voxels, rotation included,
        measured where they are. S2: submaps whose marginal covariance (`marginals`, (N,6,6) for all
        N submaps, GTSAM tangent order: rotation then translation) has a 95% x-y-yaw confidence
        ellipsoid larger than `eps_cov` now, or had when the submap was last applied; "auto"
        takes the largest current volume among submaps 0-9, as the paper does. A row of NaN
        means "not computed" and counts as uncertain (never pass zeros for unknown: zero
        reads as perfectly certain). `marginals=None` puts every submap in S2.

        Why "or when last applied": a loop closure that moves an uncertain submap usually also
        makes it certain. Judged by the new marginal alone, it would be left in the map at its
        old, wrong pose, and the online map would stop agreeing with a full merge.

        Parameters
        ----------
        vog : VogMap
            The VogMap the map was merged or added from, its submaps at their current poses.
        marginals : (N, 6, 6) array_like of float or None, optional
            Marginal covariances of all N submaps' poses (`PoseGraph.marginals`), GTSAM tangent
            order; rows of NaN: not computed (uncertain). None: every submap uncertain.
        eps_rot : float, optional
            S1's rotation threshold, radians (default `PipelineConfig.eps_rot`, 1e-2).
        eps_trans : float, optional
            S1's translation threshold, metres (default `PipelineConfig.eps_trans`, 2e-3).
        eps_cov : float or "auto", optional
            S2's threshold on the 95% x-y-yaw confidence volume (default "auto": the largest
            current volume among submaps 0-9).
        eps_move_m : float, optional
            S1's threshold on how far a corner of a submap's observed box moves, metres; 0:
            not applied.

        Returns
        -------
        UpdateReport
            The submaps re-applied, those in S1 and S2, the threshold used, the voxel updates
            made and the time taken.

        Raises
        ------
        ValueError
            Before anything changes: `vog` is no VogMap of this map's config or holds other
            submaps than the map was built from, a threshold is out of its range (see
            `PipelineConfig`), `marginals` has the wrong shape, infinite values, NaN in rows
            that are not all NaN, or is not symmetric positive semi-definite, a submap to
            re-apply was written since it was added, or one at its new pose reaches beyond the
            voxel keys the map can pack.
        """
        start = time.perf_counter()
        self._check_vog(vog)
        for name, value in (
            ("eps_rot", eps_rot),
            ("eps_trans", eps_trans),
            ("eps_cov", eps_cov),
            ("eps_move_m", eps_move_m),
        ):
            check_setting(PipelineConfig, name, value)
        others = [
            i for i in self.applied_ids if i >= vog.num_submaps or self._applied[i].uid not in (None, vog.submap(i).uid)
        ]
        if others:
            raise ValueError(
                f"vog holds other submaps than this global map was built from (ids {others[:5]}): "
                "update a global map with the VogMap it was merged or added from"
            )
        volumes = self._volumes(vog, marginals)
        threshold = self._threshold(volumes, eps_cov)
        uncertain = None if volumes is None else set()
        if threshold is not None:
            was = np.array([self._applied[i].volume if i in self._applied else 0.0 for i in range(vog.num_submaps)])
            uncertain = set(np.flatnonzero(np.maximum(volumes, was) > threshold).tolist())
        moved = self._moved(vog, eps_rot, eps_trans, eps_move_m)
        reapply = [i for i in moved if uncertain is None or i in uncertain]
        with contextlib.ExitStack() as stack:
            # read-locked from the revision check to the redo: a scan written in between would
            # be undone without ever having been added
            for i in reapply:
                stack.enter_context(vog.submap(i).reading())
            stale = [i for i in reapply if vog.submap(i).revision != self._applied[i].revision]
            if stale:
                raise ValueError(
                    f"vog: submaps {stale} changed since they were added; their old "
                    "contribution cannot be undone (add submaps once they are complete)"
                )
            self._check_key_range(vog, reapply)
            with self._lock.writing():
                touched = []
                # integer sums commute: every undo first, then every redo, gives the same bits
                pulls = self._contribute([(vog.submap(i), self._applied[i].pose) for i in reapply], -1, touched)
                pulls += self._apply(vog, reapply, touched, volumes)
                self._refresh(touched, release=True)
        return UpdateReport(
            tuple(reapply),
            moved,
            None if uncertain is None else tuple(sorted(uncertain)),
            threshold,
            pulls,
            time.perf_counter() - start,
        )

    def _follow(self, vog: VogMap) -> None:
        """Make the map equal `merge(vog)` at vog's current poses, bit for bit, doing as little
        as it can: submaps whose pose changed at all are undone and redone, new ones added. A
        submap written since it was applied is undone from the copy kept of it then (kept of
        the last FOLLOW_SNAPSHOTS submaps: the one being filled); any other forces a merge.
        (How a VogMap answers coarse queries: from a global map it keeps beside its submaps.)"""
        self._check_vog(vog)
        count = vog.num_submaps
        submaps = vog.submaps(range(count))
        with contextlib.ExitStack() as stack:
            # every submap read-locked from judging its revision to recording it: a scan written
            # in between would be undone without ever having been added, or added unrecorded
            for submap in submaps:
                stack.enter_context(submap.reading())
            self._follow_locked(vog, submaps)

    def _follow_locked(self, vog: VogMap, submaps: list) -> None:
        count = len(submaps)
        snapshots = self._snapshots
        stale = not self._applied or any(
            i >= count
            or a.uid != submaps[i].uid
            or (a.revision != submaps[i].revision and (i not in snapshots or snapshots[i].revision != a.revision))
            for i, a in self._applied.items()
        )
        if stale:
            self.merge(vog)
            self._snapshots = {i: submaps[i].snapshot() for i in range(max(0, count - FOLLOW_SNAPSHOTS), count)}
            return
        written = {i for i, a in self._applied.items() if a.revision != submaps[i].revision}
        poses = vog.poses()
        moved = [i for i, a in sorted(self._applied.items()) if i in written or np.any(a.pose != poses[i])]
        new = [i for i in range(count) if i not in self._applied]
        if not moved and not new:
            return
        self._check_key_range(vog, moved + new)
        with self._lock.writing():
            touched = []
            undone = [(snapshots[i] if i in written else submaps[i], self._applied[i].pose) for i in moved]
            self._contribute(undone, -1, touched)
            self._apply(vog, moved + new, touched, None)
            self._refresh(touched, release=True)
        recent = range(max(0, count - FOLLOW_SNAPSHOTS), count)
        self._snapshots = {
            i: snapshots[i] if i in snapshots and i not in moved + new else submaps[i].snapshot() for i in recent
        }

    def moved_submaps(
        self,
        vog: VogMap,
        eps_rot: float = PipelineConfig.eps_rot,
        eps_trans: float = PipelineConfig.eps_trans,
        eps_move_m: float = 0.0,
    ) -> tuple[int, ...]:
        """Algorithm 1's S1 as `update_poses` judges it with the same thresholds.

        These are the only submaps whose marginals `update_poses` reads (besides submaps 0-9
        for eps_cov = "auto"), so a caller may compute just those and pass NaN for the rest.

        Parameters
        ----------
        vog : VogMap
            The submaps at their current poses.
        eps_rot : float, optional
            S1's rotation threshold, radians, as for `update_poses`.
        eps_trans : float, optional
            S1's translation threshold, metres, as for `update_poses`.
        eps_move_m : float, optional
            S1's threshold on how far a corner of a submap's box moves, metres (0: not
            applied), as for `update_poses`.

        Returns
        -------
        tuple of int
            Ids of the applied submaps that moved, ascending.

        Raises
        ------
        ValueError
            If `vog` is no VogMap of this map's config or a threshold is out of its range.
        """
        self._check_vog(vog)
        for name, value in (("eps_rot", eps_rot), ("eps_trans", eps_trans), ("eps_move_m", eps_move_m)):
            check_setting(PipelineConfig, name, value)
        return self._moved(vog, eps_rot, eps_trans, eps_move_m)

    def _moved(self, vog: VogMap, eps_rot: float, eps_trans: float, eps_move_m: float) -> tuple:
        ids = np.array(self.applied_ids, dtype=np.int64)
        if not len(ids):
            return ()
        old = np.stack([self._applied[i].pose for i in ids.tolist()])
        new = vog.poses(ids)
        angle, shift = pose_deltas(old, new)
        # An unchanged pose never moves, whatever round-off the SE(3) log leaves.
        moved = np.any(old != new, axis=(1, 2)) & ((angle > eps_rot) | (shift > eps_trans))
        if eps_move_m > 0:  # the box corners only of those the cheap tests left in
            left = np.flatnonzero(moved)
            for k, submap in zip(left.tolist(), vog.submaps(ids[left].tolist())):
                moved[k] = _largest_displacement(submap.bounds(), old[k], new[k]) > eps_move_m
        return tuple(ids[moved].tolist())

    def _volumes(self, vog: VogMap, marginals) -> np.ndarray | None:
        """(N,) 95% x-y-yaw confidence volumes of checked marginals; None without marginals."""
        if marginals is None:
            return None
        marginals = real_array("marginals", marginals)
        if marginals.shape != (vog.num_submaps, 6, 6):
            raise ValueError(f"marginals must have shape ({vog.num_submaps}, 6, 6), got {marginals.shape}")
        unknown = np.all(np.isnan(marginals), axis=(1, 2))  # "not computed": counts as uncertain
        known = marginals[~unknown]
        if not np.all(np.isfinite(known)):
            raise ValueError(
                "marginals contains infinite values, or NaN in rows that are not all NaN "
                "(a row of NaN means: not computed)"
            )
        scale = np.abs(known).max(axis=(1, 2), initial=0.0)
        if np.any(np.abs(known - known.transpose(0, 2, 1)).max(axis=(1, 2), initial=0.0) > _SYMMETRY_TOLERANCE * scale):
            raise ValueError("marginals must be symmetric")
        if len(known) and np.any(np.linalg.eigvalsh(known).min(axis=1) < -_PSD_TOLERANCE * scale):
            raise ValueError("marginals must be positive semi-definite")
        volumes = np.full(len(marginals), np.inf)
        volumes[~unknown] = confidence_volume(known)
        return volumes

    @staticmethod
    def _threshold(volumes: np.ndarray | None, eps_cov) -> float | None:
        if eps_cov == "auto":
            if volumes is None or len(volumes) == 0:
                return None
            known = volumes[:10][np.isfinite(volumes[:10])]
            return float(known.max()) if len(known) else 0.0
        return None if volumes is None else float(eps_cov)

    def _check_vog(self, vog) -> None:
        if not isinstance(vog, VogMap):
            raise ValueError(f"vog must be a vj.VogMap, got {type(vog).__name__}")
        if vog.config != self.config:
            raise ValueError("vog has another MapConfig than this global map")

    def _check_key_range(self, vog: VogMap, ids) -> None:
        """Every block of submaps `ids`, at its current pose, must land on voxel keys the global
        map can pack: beyond them the packed keys would wrap around and write elsewhere."""
        ids = [int(i) for i in ids]
        boxes = []
        for submap in vog.submaps(ids):
            with submap.reading():
                boxes.append(submap.store.block_box())
        kept = [k for k, box in enumerate(boxes) if box is not None]
        if not kept:
            return
        size = self.config.voxel_size
        block_m = hashing.BLOCK_EDGE * size
        lo_m = np.array([boxes[k][0] for k in kept]) * block_m  # (n,3) the boxes' corners, metres
        hi_m = (np.array([boxes[k][1] for k in kept]) + 1) * block_m
        poses = vog.poses([ids[k] for k in kept])
        corners = np.where(_CORNER_HIGH, hi_m[:, None], lo_m[:, None])  # (n,8,3)
        world = np.einsum("nij,nkj->nki", poses[:, :3, :3], corners) + poses[:, None, :3, 3]
        reach = np.abs(world).max(axis=(1, 2))
        limit_m = (hashing.VOXEL_KEY_LIMIT - _KEY_MARGIN_VOXELS) * size
        if not np.all(reach < limit_m):
            k = int(np.argmax(~(reach < limit_m)))
            raise ValueError(
                f"poses: submap {ids[kept[k]]} at its pose reaches {reach[k]:.6g} m from the origin; the "
                f"global map's voxel keys reach {limit_m:.0f} m per axis at voxel size {size} m"
            )

    # ---------------------------------------------------------------- contributions
    def _apply(self, vog: VogMap, ids, touched: list, volumes: np.ndarray | None) -> int:
        """Add submaps `ids` at their current poses and record them as applied (each revision
        read under the lock its contents were read under)."""
        ids = [int(i) for i in ids]
        submaps, poses = vog.submaps(ids), vog.poses(ids)
        with contextlib.ExitStack() as stack:
            for submap in {id(submap): submap for submap in submaps}.values():
                stack.enter_context(submap.reading())
            pulls = self._contribute(list(zip(submaps, poses)), +1, touched)
            for i, submap, pose in zip(ids, submaps, poses):
                volume = math.inf if volumes is None else float(volumes[i])
                self._applied[i] = Applied(pose.copy(), submap.revision, uid=submap.uid, volume=volume)
        return pulls

    def _contribute(self, items: list, sign: int, touched: list) -> int:
        """Add (sign +1) or remove (-1) the pulled values of (submap, pose) items; returns the
        voxels updated. Each step is one launch over every item's blocks (rows); on the CPU it
        is split across threads, the sums by rows whose global blocks no other thread touches
        (integer sums: the same bits whatever the order)."""
        items = [(submap, pose) for submap, pose in items if submap.num_blocks]
        if not items:
            return 0
        cfg, device, span = self.config, self.device, accumulation.COLUMN_SPAN
        with contextlib.ExitStack() as stack:
            # each lock once: a second read acquire of one submap could queue behind a waiting writer
            for submap in {id(submap): submap for submap, _ in items}.values():
                stack.enter_context(submap.reading())
            counts = np.array([submap.store.num_blocks for submap, _ in items])
            offsets = np.concatenate([[0], np.cumsum(counts)])
            rows = int(offsets[-1])
            views = submap_views([submap for submap, _ in items], np.stack([pose for _, pose in items]), device)
            row_source = np.repeat(np.arange(len(items), dtype=np.int32), counts)
            row_slot = (np.arange(rows) - np.repeat(offsets[:-1], counts)).astype(np.int32)
            scales = [np.float64(cfg.voxel_size), np.float64(1.0 / cfg.voxel_size)]
            parts = parallel.num_parts(device, rows * span)
            phases = [[(0, rows)]]
            if parts > 1:
                # CPU threads have no atomics between them: order the rows so that each thread
                # of a phase writes to global blocks no other one touches
                spans = wp.empty(rows, dtype=wp.vec4i, device=device)
                wp.launch(
                    accumulation.row_spans,
                    dim=rows,
                    inputs=[
                        views,
                        *(wp.array(a, dtype=wp.int32, device=device) for a in (row_source, row_slot)),
                        scales[0],
                    ],
                    outputs=[spans],
                    device=device,
                )
                order, phases = parallel.disjoint_order(spans.numpy().reshape(rows, 2, 2), parts)
                row_source, row_slot = row_source[order], row_slot[order]
            common = [
                views,
                wp.array(row_source, dtype=wp.int32, device=device),
                wp.array(row_slot, dtype=wp.int32, device=device),
            ]

            def launch_rows(launch):
                parallel.split_launch(lambda part, lo, hi: launch(part, lo, hi - lo), rows, parts)

            # 1. the global blocks each row's block pulls into (created when adding): a mask of
            # its 64 candidates per row, then their keys listed compactly
            row_masks = wp.zeros(rows, dtype=wp.uint64, device=device)
            launch_rows(
                lambda part, first, n: wp.launch(
                    accumulation.collect_pull_blocks,
                    dim=(n, span),
                    inputs=[*common, first, *scales],
                    outputs=[row_masks],
                    device=device,
                )
            )
            per_row = np.bitwise_count(row_masks.numpy()).astype(np.int64)
            row_start = np.zeros(rows, np.int32)
            np.cumsum(per_row[:-1], out=row_start[1:])
            d_row_start = wp.array(row_start, dtype=wp.int32, device=device)
            keys = wp.empty(int(per_row.sum()), dtype=wp.int64, device=device)
            wp.launch(
                accumulation.list_pull_blocks,
                dim=rows,
                inputs=[*common, scales[0], row_masks, d_row_start],
                outputs=[keys],
                device=device,
            )
            store = self._store
            if sign > 0:
                store.ensure_blocks(keys)
            slots = store.find(keys)
            # 2. add or subtract the pulled values, phase after phase
            pulls = wp.zeros(max(len(phase) for phase in phases), dtype=wp.int32, device=device)
            for phase in phases:
                parallel.launch_ranges(
                    lambda part, lo, hi: wp.launch(
                        accumulation.accumulate_pulls,
                        dim=(hi - lo, span),
                        inputs=[*common, lo, *scales, sign, row_masks, d_row_start, slots, part],
                        outputs=[store.layers["sum"], store.layers["count"], pulls],
                        device=device,
                    ),
                    phase,
                )
            # 3. which global blocks were touched, flagged on the device (not millions of keys read back)
            flags = wp.zeros(store.block_capacity, dtype=wp.int32, device=device)
            wp.launch(accumulation.flag_slots, dim=slots.shape[0], inputs=[slots], outputs=[flags], device=device)
            touched.append(np.flatnonzero(flags.numpy()).astype(np.int32))
        return int(pulls.numpy().sum())

    def _refresh(self, touched: list, release: bool = False, rebuilt: bool = False) -> None:
        """Recompute the queryable log-odds of touched blocks; release those no submap uses;
        then the coarse levels above them (all of them when the store was `rebuilt`)."""
        slots = np.unique(np.concatenate(touched)).astype(np.int32) if touched else np.zeros(0, np.int32)
        if len(slots) == 0:
            self._values_changed(None if rebuilt else np.zeros(0, np.int64))
            return
        store, device = self._store, self.device
        keys = store.slot_keys.numpy()[slots]  # before any is released
        d_slots = wp.array(slots, dtype=wp.int32, device=device)
        voxels = len(slots) * BLOCK_VOXELS
        parallel.split_launch(
            lambda part, lo, hi: wp.launch(
                accumulation.refresh_log_odds,
                dim=(hi - lo) * BLOCK_VOXELS,
                inputs=[
                    d_slots[lo:hi],
                    store.layers["sum"],
                    store.layers["count"],
                    self.config.log_clamp_min,
                    self.config.log_clamp_max,
                ],
                outputs=[store.layers["log_odds"]],
                device=device,
            ),
            len(slots),
            parallel.num_parts(device, voxels // 64),
        )
        if release:
            unused = wp.empty(len(slots), dtype=wp.int32, device=device)
            wp.launch(
                accumulation.flag_unused_blocks,
                dim=len(slots),
                inputs=[d_slots, store.layers["count"]],
                outputs=[unused],
                device=device,
            )
            store.release(slots[unused.numpy() == 1])
        self._values_changed(None if rebuilt else keys)

    # ---------------------------------------------------------------- contents and files
    def sums(self) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int32]]:
        """The voxels with contributions, as stored: what makes the map exact.

        Returns
        -------
        keys : (K, 3) ndarray of int64
            Voxel keys (voxel k covers ``[k*s, (k+1)*s)`` per axis), sorted.
        sums : (K,) ndarray of int64
            Fixed-point sums of the submaps' log-odds, in units of 2^-24 log-odds.
        counts : (K,) ndarray of int32
            How many submaps contribute to each voxel.
        """
        with self._lock.reading():
            keys, layers = self._store.host_blocks()
        block_index, local = np.nonzero(layers["count"] != 0)
        return (
            voxel_keys(keys, block_index, local),
            layers["sum"][block_index, local],
            layers["count"][block_index, local],
        )

    def save(self, path: str | PathLike) -> None:
        """Write the map to one map file, atomically: config, applied poses and revisions, sums
        and counts.

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
            keys, layers = self._store.host_blocks()
            applied = {
                str(i): {
                    "pose": a.pose.tolist(),
                    "revision": a.revision,
                    "volume": None if math.isinf(a.volume) else a.volume,
                }
                for i, a in self._applied.items()
            }
        write_map_file(
            path,
            "GlobalMap",
            {"config": self.config.to_dict(), "applied": applied},
            {"block_keys": keys, "sum": layers["sum"], "count": layers["count"]},
        )

    @classmethod
    def load(cls, path: str | PathLike, device: str | wp.Device | None = None) -> GlobalMap:
        """Read a map written by `save`, checking the whole file and its contents.

        The submap objects are not in the file: the map answers queries as saved, and
        `update_poses` takes a VogMap with the submaps it was built from.

        Parameters
        ----------
        path : str or os.PathLike
            The .vog file.
        device : str or warp.Device or None, optional
            Warp device for the map (None: CUDA when available, else the CPU).

        Returns
        -------
        GlobalMap
            The map, with the sums, counts and applied poses saved.

        Raises
        ------
        ValueError
            Naming the path if the file is not a valid GlobalMap file (damaged, another kind of
            map, applied submaps that are not valid records, block keys that are not valid,
            sums or counts of the wrong type or shape, or counts no applied submaps give).
        """
        metadata, arrays = read_map_file(path, "GlobalMap")
        where = f"path {str(path)!r}"
        try:
            config = MapConfig.from_dict(metadata["config"])
            applied = {
                _applied_id(i): _applied_record(a, f"{where}: applied submap {i}")
                for i, a in metadata["applied"].items()
            }
            keys, sums, counts = arrays["block_keys"], arrays["sum"], arrays["count"]
        except (KeyError, TypeError, ValueError, AttributeError) as error:
            raise ValueError(f"{where} has invalid map contents: {error}") from None
        check_block_keys(keys, where)
        shape = (keys.shape[0], BLOCK_VOXELS)
        if sums.dtype != np.int64 or counts.dtype != np.int32 or sums.shape != shape or counts.shape != shape:
            raise ValueError(f"{where} has invalid map contents (sums or counts of the wrong type or shape)")
        if counts.size and (counts.min() < 0 or counts.max() > len(applied) or np.any(sums[counts == 0] != 0)):
            raise ValueError(f"{where} holds contribution counts that no applied submaps give")
        gmap = cls(config, device)
        gmap._store = BlockStore.from_host(gmap.device, gmap._store.layer_specs, keys, {"sum": sums, "count": counts})
        gmap._applied = applied
        gmap._refresh([np.arange(keys.shape[0], dtype=np.int32)])
        return gmap


# corner m of a box takes hi on axis a when bit a of m is set
_CORNER_HIGH = ((np.arange(8)[:, None] >> np.arange(3)) & 1).astype(bool)
# A rotated submap block pulls world voxels up to a voxel or so beyond its corners: two blocks' room.
_KEY_MARGIN_VOXELS = 2 * hashing.BLOCK_EDGE


def _largest_displacement(box, T_old: np.ndarray, T_new: np.ndarray) -> float:
    """How far the farthest corner of a submap-frame box moves from T_old to T_new (0 for None)."""
    if box is None:
        return 0.0
    corners = np.where(_CORNER_HIGH, box[1], box[0])
    moved = corners @ (T_new[:3, :3] - T_old[:3, :3]).T + (T_new[:3, 3] - T_old[:3, 3])
    return float(np.linalg.norm(moved, axis=1).max())


def _applied_id(key) -> int:
    i = int(key)
    if i < 0 or str(i) != str(key):
        raise ValueError(f"applied submap id {key!r} is no non-negative integer")
    return i


def _applied_record(record: dict, where: str) -> Applied:
    """An applied submap read back from a file: a rigid pose, a revision, a volume (or None)."""
    pose = rigid_pose(f"{where}: pose", np.array(record["pose"], dtype=np.float64))
    revision = record["revision"]
    if isinstance(revision, bool) or not isinstance(revision, int) or revision < 0:
        raise ValueError(f"{where}: revision {revision!r} is no non-negative integer")
    volume = record.get("volume")
    if volume is not None and (
        isinstance(volume, bool) or not isinstance(volume, (int, float)) or not 0 <= volume < math.inf
    ):
        raise ValueError(f"{where}: volume {volume!r} is no finite number >= 0")
    return Applied(pose, revision, math.inf if volume is None else float(volume))
