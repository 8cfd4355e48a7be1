"""BlockMap: the read side shared by every map of hashed voxel blocks (queries, contents)."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import threading

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax import devices
from vogjax.config import MapConfig
from vogjax.kernels import hashing, queries
from vogjax.maps import parallel
from vogjax.maps.blocks import BLOCK_VOXELS, GRID_CELLS, BlockGrid, BlockStore, voxel_keys
from vogjax.maps.levels import Levels, check_level, level_scales
from vogjax.maps.locking import ReadWriteLock
from vogjax.validation import float_array, positive_range, within_key_range

UNKNOWN = 0
FREE = 1
OCCUPIED = 2
# Voxels one line of line_query may cross (its output holds a row this long per line): 6.5 km
# along an axis at 0.1 m voxels. Longer lines are refused rather than allocated.
MAX_LINE_VOXELS = 1 << 16


# On a CPU, ray casts read every voxel's state from a dense box over the map's blocks when its
# two bits a voxel take at most this many bytes (524,288 blocks: a box of 52 x 52 x 26 m at 0.1
# m) and the box holds at most 4 times as many blocks as the map (or 4096)
DENSE_STATE_BYTES = 64 << 20


@dataclasses.dataclass(frozen=True)
class RayTables:
    """What ray casts read, for one version of a map's blocks and log-odds, by `kind`; the arrays
    another kind reads are empty.

    "dense" (a CPU, a compact box): columns, uint16 (prod(8 padded_dims) / 8,), every voxel's
        state in the box of the block grid padded by one block each way (queries.fill_dense_states)
    "grid" (a CPU otherwise): bases, int32 (prod(padded_dims),), each cell's first states word
        in that padded grid (queries.fill_ray_bases), and states
    "device" (a GPU, or no block grid): states, uint32 (32 (block_capacity + 1),), the voxel
        states two bits each (queries.classify_blocks), then one block of unknown voxels
    """

    kind: str
    store: BlockStore
    grid: BlockGrid
    padded_dims: tuple
    columns: wp.array
    bases: wp.array
    states: wp.array

    def memory_bytes(self) -> int:
        return self.columns.capacity + self.bases.capacity + self.states.capacity


@dataclasses.dataclass(frozen=True)
class RaycastResult:
    """What a ray cast (`BlockMap.raycast`, `VogMap.raycast`) found along each of R rays.

    NumPy arrays, or Warp arrays on the map's device for rays given on the device.

    Attributes
    ----------
    hit : (R,) ndarray of bool
        An OCCUPIED voxel was met before `max_range`.
    distance : (R,) ndarray of float32
        Where the ray enters that voxel, metres; `max_range` where there was no hit.
    num_unknown : (R,) ndarray of int32
        UNKNOWN voxels the ray passed before that voxel (or within its range).
    num_free : (R,) ndarray of int32
        FREE voxels the ray passed before that voxel (or within its range).
    """

    hit: npt.NDArray[np.bool_] | wp.array
    distance: npt.NDArray[np.float32] | wp.array
    num_unknown: npt.NDArray[np.int32] | wp.array
    num_free: npt.NDArray[np.int32] | wp.array


class BlockMap:
    """The read side shared by every map of hashed 8x8x8 voxel blocks: queries and contents.

    The map's voxel blocks carry a float32 "log_odds" layer (NaN: never observed). `VoxelMap`,
    `Submap` and `GlobalMap` are BlockMaps: make one of those, not a BlockMap itself.

    Queries hold the map's read lock, so they may run from many threads while updates, which
    hold its write lock, wait for them and see no reader mid-way.

    Every query takes `level`: 0 (the default) reads the map's voxels; level k >= 1 reads voxels
    of voxel_size * 2^k aligned as OctoMap's depth 16 - k, each holding the largest log-odds of
    its observed voxels (unknown when none is observed), OctoMap's inner-node value. A level is
    built on its first query and kept current by every write after (`vogjax.maps.levels`).

    Parameters
    ----------
    config : MapConfig or None
        Voxel size, sensor model, thresholds and clamping (None: ``MapConfig()``).
    device : str or warp.Device or None
        Warp device; None picks CUDA when available, else the CPU.
    layers : dict of str to (dtype, value)
        The layers the blocks carry besides "log_odds": name -> (Warp dtype, value of a voxel
        never written).

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

    def __init__(self, config: MapConfig | None, device: str | wp.Device | None, layers: dict[str, tuple]):
        if config is not None and not isinstance(config, MapConfig):
            raise ValueError(f"config must be a vj.MapConfig, got {type(config).__name__}")
        self.config = config or MapConfig()
        self.device = devices.resolve(device)
        self._store = BlockStore(self.device, {"log_odds": (wp.float32, math.nan), **layers})
        self._lock = ReadWriteLock()
        self._values_revision = 0  # counts writes of log-odds, for the ray-cast state cache
        self._ray_tables_cache = None  # (key, RayTables), rebuilt after writes
        self._level_ray_tables: dict = {}  # level >= 1 -> (key, RayTables)
        self._ray_tables_lock = threading.Lock()
        # the coarse levels built so far: a voxel of a map without a "count" layer (a VoxelMap)
        # never goes back to unobserved, so its coarse blocks never empty
        self._levels = Levels(self.device, releases="count" in layers)
        self._levels_lock = threading.Lock()
        # Ray casts on a CPU read a voxel's state at every step without a test for a block change
        # (queries.cast_rays_dense, cast_rays_on_grid: a branch at each block crossing
        # mispredicts there and costs more than a load); on a GPU, where that would be a second
        # dependent read per step, they look a block up on entering it (queries.cast_rays). All
        # give the same bits; tests run each on the CPU.
        self._cpu_casts = not self.device.is_cuda

    @property
    def store(self) -> BlockStore:
        """The block storage, for kernel launchers in vogjax.maps (read it under `reading()`)."""
        return self._store

    def reading(self) -> contextlib.AbstractContextManager[None]:
        """Hold the map's read lock: no update runs while it is held.

        Returns
        -------
        contextlib.AbstractContextManager
            A context manager; other readers may hold the lock at the same time.
        """
        return self._lock.reading()

    def store_at(self, level: int = 0) -> BlockStore:
        """The block storage of a level, built or brought up to date first.

        For kernel launchers (the planner) that read a coarse level's voxels; call it under
        `reading()` and keep the lock while the store is read.

        Parameters
        ----------
        level : int, optional
            0: the map's own store (`store`); k in [1, 15]: the store of level k, whose voxels
            have the edge `vogjax.maps.levels.level_scales(config.voxel_size, k)[0]`.

        Returns
        -------
        BlockStore
            The level's blocks, current with every write so far.

        Raises
        ------
        ValueError
            When `level` is no integer in [0, 15].
        """
        level = check_level(level)
        if level == 0:
            return self._store
        if self._levels.count < level or self._levels.stale:
            # writes only note blocks under the write lock, so no reader is mid-way through a
            # level while another one brings it up to date here; concurrent readers share one
            with self._levels_lock:
                self._levels.extend(self._store, level)
        return self._levels.store(level)

    @property
    def levels_kept(self) -> int:
        """The coarsest level this map keeps current (0: none built yet)."""
        return self._levels.count

    def _values_changed(
        self, keys: np.ndarray | None = None, cells: np.ndarray | None = None, distinct: bool = False
    ) -> None:
        """Call (under the write lock) after writing log-odds: the ray-cast states go stale, and
        the coarse levels above the written blocks (packed keys `keys` (K,) int64; None: the
        store was replaced, every level is rebuilt) are noted for the next coarse query, with
        the cells of each that changed (`Levels.note`; None: any may have)."""
        self._values_revision += 1
        if self._levels.count:
            if keys is None:
                self._levels.rebuild(self._store)
            else:
                self._levels.note(self._store, keys, cells, distinct)

    def _ray_tables(self, level: int = 0) -> RayTables:
        """What ray casts read, rebuilt after the log-odds or the blocks changed; call under the
        read lock (concurrent readers share one build)."""
        store = self.store_at(level)
        key = (self._values_revision, store.version, store.block_capacity, self._cpu_casts)
        with self._ray_tables_lock:
            cached = self._ray_tables_cache if level == 0 else self._level_ray_tables.get(level)
            if cached is None or cached[0] != key or cached[1].store is not store:
                cached = (key, self._build_ray_tables(store))
                if level == 0:
                    self._ray_tables_cache = cached
                else:
                    self._level_ray_tables[level] = cached
            return cached[1]

    def _build_ray_tables(self, store: BlockStore | None = None) -> RayTables:
        store = self._store if store is None else store
        device, cfg = self.device, self.config
        grid = store.grid()
        padded = tuple(d + 2 for d in grid.dims)
        on_cpu = self._cpu_casts and grid.dims[0] > 0
        log_odds, blocks = store.layers["log_odds"], store.num_blocks

        def empty(*dtypes) -> list:
            return [wp.empty(0, dtype=dtype, device=device) for dtype in dtypes]

        parts = parallel.num_parts(device, blocks * 32)
        # the box's zeros cost little beside reading the blocks' log-odds while it is at most a
        # few times their number; beyond that, a map of scattered blocks builds the grid's tables
        dense_blocks = min(DENSE_STATE_BYTES // (BLOCK_VOXELS // 4), max(4 * blocks, 1 << 12))
        if on_cpu and math.prod(padded) <= dense_blocks:
            dims = tuple(8 * d for d in padded)
            columns = wp.zeros(math.prod(dims) // 8, dtype=wp.uint16, device=device)
            corner = wp.vec3i(*((g - 1) * 8 for g in grid.lo))

            def fill(part: int, lo: int, hi: int) -> None:
                wp.launch(
                    queries.fill_dense_states,
                    dim=(hi - lo) * 64,
                    inputs=[
                        log_odds[lo * BLOCK_VOXELS : hi * BLOCK_VOXELS],
                        store.slot_keys[lo:hi],
                        cfg.log_occupied,
                        cfg.log_free,
                        corner,
                        wp.vec3i(*dims),
                    ],
                    outputs=[columns],
                    device=device,
                )

            parallel.split_launch(fill, blocks, parts)
            return RayTables("dense", store, grid, padded, columns, *empty(wp.int32, wp.uint32))
        empty_base = store.block_capacity * 32  # one block of unknown voxels after the others
        states = wp.zeros(empty_base + 32, dtype=wp.uint32, device=device)

        def classify(part: int, lo: int, hi: int) -> None:
            wp.launch(
                queries.classify_blocks,
                dim=hi - lo,
                inputs=[log_odds[lo * 16 : hi * 16], cfg.log_occupied, cfg.log_free],
                outputs=[states[lo:hi]],
                device=device,
            )

        parallel.split_launch(classify, blocks * 32, parts)
        if on_cpu and math.prod(padded) <= 2 * GRID_CELLS:
            bases = wp.empty(math.prod(padded), dtype=wp.int32, device=device)
            wp.launch(
                queries.fill_ray_bases,
                dim=bases.shape[0],
                inputs=[grid.cells, wp.vec3i(*grid.dims), wp.vec3i(*padded), empty_base],
                outputs=[bases],
                device=device,
            )
            return RayTables("grid", store, grid, padded, *empty(wp.uint16), bases, states)
        return RayTables("device", store, grid, padded, *empty(wp.uint16, wp.int32), states)

    def _check_extent(self, origins: np.ndarray, points: np.ndarray) -> None:
        check_extent(self.config, origins=origins, points=points)

    # ---------------------------------------------------------------- point queries
    def _lookup(self, points, level: int = 0) -> np.ndarray:
        """Stored log-odds at each point, NaN where never observed."""
        points = float_array("points", points, (-1, 3))
        level = check_level(level)
        with self._lock.reading():
            return self._lookup_unlocked(points, level)

    def _lookup_unlocked(self, points: np.ndarray, level: int = 0) -> np.ndarray:
        values = wp.empty(points.shape[0], dtype=wp.float32, device=self.device)
        if points.shape[0]:
            store = self.store_at(level)
            wp.launch(
                queries.lookup_log_odds,
                dim=points.shape[0],
                inputs=[
                    wp.array(points, dtype=wp.vec3f, device=self.device),
                    level_scales(self.config.voxel_size, level)[1],
                    store.table_keys,
                    store.table_slots,
                    store.layers["log_odds"],
                ],
                outputs=[values],
                device=self.device,
            )
        return values.numpy()

    def log_odds(self, points: npt.ArrayLike, level: int = 0) -> npt.NDArray[np.float32]:
        """Log-odds of the voxels holding `points`.

        Parameters
        ----------
        points : (M, 3) array_like of float
            World points, metres.
        level : int, optional
            0: the map's voxels; k in [1, 15]: the voxel of edge voxel_size * 2^k holding each
            point (the maximum log-odds of its observed voxels).

        Returns
        -------
        (M,) ndarray of float32
            The log-odds; 0.0 where unknown (never observed).

        Raises
        ------
        ValueError
            If `points` is not (M, 3), holds NaN or infinite values, or `level` is no integer
            in [0, 15].
        """
        return np.nan_to_num(self._lookup(points, level), nan=0.0)

    def probability(self, points: npt.ArrayLike, level: int = 0) -> npt.NDArray[np.float32]:
        """Occupancy probability of the voxels holding `points`.

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
        """States of the voxels holding `points`.

        Parameters
        ----------
        points : (M, 3) array_like of float
            World points, metres.
        level : int, optional
            As for `log_odds`. A coarse voxel is OCCUPIED when any of its voxels is, FREE when
            its most occupied observed voxel is FREE (unobserved ones do not count).

        Returns
        -------
        (M,) ndarray of int8
            UNKNOWN (never observed, or between the thresholds), FREE or OCCUPIED.

        Raises
        ------
        ValueError
            As for `log_odds`.
        """
        return classify(self._lookup(points, level), self.config)

    # ---------------------------------------------------------------- ray queries
    def raycast(
        self,
        origins: npt.ArrayLike | wp.array,
        directions: npt.ArrayLike | wp.array,
        max_range: float | npt.ArrayLike | wp.array,
        level: int = 0,
    ) -> RaycastResult:
        """First OCCUPIED voxel along each ray, within `max_range` metres.

        Parameters
        ----------
        origins : (R, 3) array_like of float or warp.array
            Ray origins, metres, world frame, inside the key range (float64).
        directions : (R, 3) array_like of float or warp.array
            Directions of any nonzero length (normalised in the kernel, as
            `unit_directions` does).
        max_range : float or (R,) array_like of float or warp.array
            One range for every ray, or one per ray (float64), metres, positive.
        level : int, optional
            0: the map's voxels; k in [1, 15]: voxels of edge voxel_size * 2^k (see `state`).

        Returns
        -------
        RaycastResult
            hit (R,) bool, distance (R,) float32, num_unknown and num_free (R,) int32.

        Raises
        ------
        ValueError
            Naming the argument: arrays of the wrong shape, NaN, infinite or out-of-range
            origins, zero directions, ranges that are not positive, a bad level; for rays on
            the device, Warp arrays of another dtype, shape or device, or mixed with NumPy ones.

        Notes
        -----
        Any range is accepted: stretches of unknown
        space outside the map's box are counted without walking them, so a ray costs at most
        about the voxels of the map it crosses; voxels outside the key range
        (`hashing.VOXEL_KEY_LIMIT` voxels from the origin per axis) are not counted.

        Rays already on the map's device stay there: with origins and directions given as Warp
        arrays (float64, (R,3) or (R,) vec3d; `wp.from_jax` wraps a float64 JAX array, x64
        enabled, without a copy) and max_range a number or a float64 Warp array of (R,), the
        checks run in a kernel and the result's fields are Warp arrays on the device, final
        when this returns.

        At `level` k >= 1 the rays walk the voxels of edge voxel_size * 2^k: a ray meets an
        OCCUPIED coarse voxel at or before the level-0 voxel it would hit (one it spends more
        than a millionth of an edge in), and the counts are of coarse voxels.
        """
        level = check_level(level)
        if any(isinstance(a, wp.array) for a in (origins, directions, max_range)):
            return self._raycast_on_device(origins, directions, max_range, level)
        origins, directions, ranges = ray_arguments(origins, directions, max_range, normalise=False)
        check_extent(self.config, origins=origins)
        # one range for every ray: one value for the kernel (cast_rays reads a length-1 array
        # for all rays), not an array of copies to fill and upload
        shared = np.isscalar(max_range) and origins.shape[0] > 1
        device = self.device
        # on the CPU, Warp arrays over the NumPy ones (no copies)
        out = self._cast(
            wp.array(origins, dtype=wp.vec3d, device=device, copy=False),
            wp.array(directions, dtype=wp.vec3d, device=device, copy=False),
            wp.array(ranges[:1] if shared else ranges, dtype=wp.float64, device=device, copy=False),
            level,
        )
        return RaycastResult(**{name: a.numpy() for name, a in out.items()})

    def _raycast_on_device(self, origins, directions, max_range, level: int = 0) -> RaycastResult:
        origins = device_rays("origins", origins, -1, self.device)
        count = origins.shape[0]
        directions = device_rays("directions", directions, count, self.device)
        if isinstance(max_range, wp.array):
            if max_range.device != self.device or max_range.dtype != wp.float64 or max_range.shape != (count,):
                raise ValueError(
                    f"max_range must be a float64 Warp array of shape ({count},) on {self.device}, got "
                    f"{wp.types.type_repr(max_range.dtype)} {max_range.shape} on {max_range.device}"
                )
            ranges = max_range
        elif np.isscalar(max_range):
            ranges = wp.array(positive_range("max_range", max_range, 1), dtype=wp.float64, device=self.device)
        else:
            raise ValueError(
                f"max_range must be a number or a float64 Warp array of ({count},) when the rays are "
                f"Warp arrays, got {type(max_range).__name__}"
            )
        if count == 0:
            return RaycastResult(
                *(wp.empty(0, dtype=t, device=self.device) for t in (wp.bool, wp.float32, wp.int32, wp.int32))
            )
        # the host checks of the NumPy path, in one launch and one read-back of three numbers
        first_bad = wp.full(3, count, dtype=wp.int32, device=self.device)
        voxel_size, key_limit = self.config.voxel_size, hashing.VOXEL_KEY_LIMIT - 2
        wp.launch(
            queries.check_rays,
            dim=count,
            inputs=[origins, directions, ranges, np.float64(voxel_size), np.float64(key_limit)],
            outputs=[first_bad],
            device=self.device,
        )
        bad = first_bad.numpy()
        for fault, (name, what) in enumerate(
            (
                (
                    "origins",
                    f"NaN, infinite or {key_limit} voxels ({key_limit * voxel_size:g} m) or farther from "
                    "the origin on an axis",
                ),
                ("directions", "NaN, infinite or zero"),
                ("max_range", "NaN, infinite or not positive"),
            )
        ):
            if bad[fault] < count:
                raise ValueError(f"{name}: ray {bad[fault]} is {what}")
        out = self._cast(origins, directions, ranges, level)
        if self.device.is_cuda:  # final on return, as the docstring says (later launches queue behind it)
            wp.synchronize_stream(wp.get_stream(self.device))
        return RaycastResult(**out)

    def _cast(self, origins: wp.array, directions: wp.array, ranges: wp.array, level: int = 0) -> dict:
        """cast_rays over checked device rays (ranges: one per ray, or one for all) at `level`:
        the RaycastResult fields as Warp arrays."""
        count, device = origins.shape[0], self.device
        resolution, inv_resolution = level_scales(self.config.voxel_size, level)
        shared = ranges.shape[0] == 1 and count > 1
        out = {
            "hit": wp.empty(count, dtype=wp.bool, device=device),
            "distance": wp.empty(count, dtype=wp.float32, device=device),
            "num_unknown": wp.empty(count, dtype=wp.int32, device=device),
            "num_free": wp.empty(count, dtype=wp.int32, device=device),
        }

        def launch(part: int, lo: int, hi: int) -> None:
            rays = [
                origins[lo:hi],
                directions[lo:hi],
                ranges if shared else ranges[lo:hi],
                resolution,
                inv_resolution,
            ]
            outputs = [a[lo:hi] for a in out.values()]
            if tables.kind != "device":
                kernel = queries.cast_rays_dense if tables.kind == "dense" else queries.cast_rays_on_grid
                wp.launch(
                    kernel,
                    dim=hi - lo,
                    inputs=[
                        *rays,
                        grid_lo,
                        *known,
                        key_limit,
                        wp.vec3i(*tables.padded_dims),
                        tables.columns,
                        tables.bases,
                        tables.states,
                    ],
                    outputs=outputs,
                    device=device,
                )
            else:
                wp.launch(
                    queries.cast_rays,
                    dim=hi - lo,
                    inputs=[
                        *rays,
                        tables.store.table_keys,
                        tables.store.table_slots,
                        grid_lo,
                        *known,
                        key_limit,
                        wp.vec3i(*tables.grid.dims),
                        tables.grid.cells,
                        tables.states,
                    ],
                    outputs=outputs,
                    device=device,
                )

        key_limit = hashing.VOXEL_KEY_LIMIT >> level  # the key range's half-width in this level's voxels
        with self._lock.reading():
            tables = self._ray_tables(level)
            grid_lo = wp.vec3i(*tables.grid.lo)
            known = self._known_box(level, tables.grid)
            parallel.split_launch(launch, count, parallel.num_parts(device, count))
        return out

    def _known_box(self, level: int, grid) -> tuple:
        """The ray casts' box of known voxels at `level` (lo, hi voxel keys as wp.vec3i, then
        the stretch past it worth counting instead of walking): the voxels of the blocks' box
        at level 0; at a coarse level, the level-0 box's voxels shifted (tighter than the
        coarse blocks' box, whose blocks are 2^k times as wide: a coarse voxel is known only
        above a known level-0 voxel)."""
        if level == 0:
            lo, hi = np.array(grid.lo) * 8, np.array(grid.hi) * 8 + 7
            return wp.vec3i(*lo.tolist()), wp.vec3i(*hi.tolist()), queries.SKIP_VOXELS
        box = self._store.block_box()
        if box is None:
            return wp.vec3i(0, 0, 0), wp.vec3i(-1, -1, -1), queries.SKIP_VOXELS_COARSE
        lo, hi = (np.asarray(box[0]) * 8) >> level, (np.asarray(box[1]) * 8 + 7) >> level
        return wp.vec3i(*lo.tolist()), wp.vec3i(*hi.tolist()), queries.SKIP_VOXELS_COARSE

    def line_query(
        self, starts: npt.ArrayLike, ends: npt.ArrayLike, level: int = 0
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.int32]]:
        """Log-odds of every voxel from the voxel of each start to that of its end, inclusive.

        Parameters
        ----------
        starts, ends : (R, 3) array_like of float
            World points, metres.
        level : int, optional
            0: the map's voxels; k in [1, 15]: the voxels of edge voxel_size * 2^k (see
            `state`).

        Returns
        -------
        values : (R, S) ndarray of float32
            Log-odds along each line, S its longest; 0.0 where unknown, NaN past each line's end.
        lengths : (R,) ndarray of int32
            The number of voxels of each line.

        Raises
        ------
        ValueError
            Naming the argument: arrays of the wrong shape, NaN, infinite or out-of-range
            points, a line crossing more than MAX_LINE_VOXELS (65536) voxels, a bad level.
        """
        level = check_level(level)
        starts, ends = line_arguments(self.config, starts, ends, level)
        count, device = starts.shape[0], self.device
        if count == 0:
            return np.zeros((0, 0), np.float32), np.zeros(0, np.int32)
        d_starts, d_ends, lengths = _line_lengths(self.config, device, starts, ends, level)
        values = wp.full((count, int(lengths.max())), math.nan, dtype=wp.float32, device=device)
        with self._lock.reading():
            store = self.store_at(level)
            wp.launch(
                queries.fill_line_values,
                dim=count,
                inputs=[
                    d_starts,
                    d_ends,
                    *level_scales(self.config.voxel_size, level),
                    store.table_keys,
                    store.table_slots,
                    store.layers["log_odds"],
                ],
                outputs=[values],
                device=device,
            )
        return values.numpy(), lengths

    # ---------------------------------------------------------------- contents
    def voxels(self, level: int = 0) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float32]]:
        """The observed voxels of a level.

        Parameters
        ----------
        level : int, optional
            0: the map's voxels; k in [1, 15]: the voxels of edge voxel_size * 2^k holding an
            observed one, with their maximum log-odds.

        Returns
        -------
        centres : (K, 3) ndarray of float64
            Voxel centres, metres, sorted by voxel key.
        log_odds : (K,) ndarray of float32
            Their log-odds.

        Raises
        ------
        ValueError
            When `level` is no integer in [0, 15].
        """
        level = check_level(level)
        with self._lock.reading():
            keys, layers = self.store_at(level).host_blocks()
        values = layers["log_odds"]
        block_index, local = np.nonzero(~np.isnan(values))
        size = level_scales(self.config.voxel_size, level)[0]
        return (voxel_keys(keys, block_index, local) + 0.5) * size, values[block_index, local]

    @property
    def num_blocks(self) -> int:
        """8x8x8 blocks allocated so far (512 voxels each, observed or not); blocks a GlobalMap
        released still count (their slots are reused)."""
        return self._store.num_blocks

    def memory_bytes(self) -> int:
        """Device memory the map holds.

        Returns
        -------
        int
            Bytes of the hash table, the block pool, the per-block scratch, the coarse levels
            and the ray-cast caches.
        """
        cached = [self._ray_tables_cache, *self._level_ray_tables.values()]
        tables = sum(c[1].memory_bytes() for c in cached if c is not None)
        return self._store.memory_bytes() + self._levels.memory_bytes() + tables

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(voxel_size={self.config.voxel_size}, blocks={self.num_blocks}, "
            f"device={self.device}, memory={self.memory_bytes() / 2**20:.1f} MiB)"
        )


def probability_from_log_odds(log_odds: np.ndarray) -> np.ndarray:
    """Occupancy probability of log-odds; unclamped maps (`MapConfig.paper()`) reach log-odds
    whose exp overflows to inf, which gives exactly 1.0 here, so the overflow is no error."""
    with np.errstate(over="ignore"):
        return (1.0 - 1.0 / (1.0 + np.exp(log_odds.astype(np.float64)))).astype(np.float32)


def classify(values: np.ndarray, config: MapConfig) -> np.ndarray:
    """States of stored log-odds values (NaN: never observed)."""
    state = np.full(values.shape, UNKNOWN, dtype=np.int8)
    with np.errstate(invalid="ignore"):
        state[values >= config.log_occupied] = OCCUPIED
        state[values <= config.log_free] = FREE
    return state


def ray_arguments(origins, directions, max_range, normalise: bool = True):
    """Validated rays: origins (R,3), unit directions (R,3) (nonzero ones as given, when not
    `normalise`), ranges (R,), all float64."""
    origins = float_array("origins", origins, (-1, 3), np.float64)
    directions = float_array("directions", directions, (origins.shape[0], 3), np.float64)
    ranges = positive_range("max_range", max_range, origins.shape[0])
    if not normalise:
        if not all_rows_nonzero(directions):
            raise ValueError("directions must be nonzero")
        return origins, directions, ranges
    return origins, unit_directions(directions), ranges


def all_rows_nonzero(array: np.ndarray) -> bool:
    """Whether every row of an (R,3) array has a nonzero component. (`array.any(axis=1)` walks
    rows of three one by one, ten times slower: most arrays hold no zero at all.)"""
    zero = array == 0
    if not zero.any():
        return True
    return not np.any(zero[:, 0] & zero[:, 1] & zero[:, 2])


def unit_directions(directions: np.ndarray) -> np.ndarray:
    """(R,3) finite float64 directions scaled to unit length. Rows whose squared length would
    overflow or underflow (components near 1e+-154 and beyond) are first divided by their
    largest |component|, so neither huge (1e200) nor tiny (1e-320) directions break."""
    squared = np.einsum("ij,ij->i", directions, directions)
    extreme = ~((squared > 1e-300) & (squared < 1e300))
    if np.any(extreme):
        directions = directions.copy()
        scale = np.abs(directions[extreme]).max(axis=1)
        if np.any(scale == 0):
            raise ValueError("directions must be nonzero")
        directions[extreme] /= scale[:, None]
        squared[extreme] = np.einsum("ij,ij->i", directions[extreme], directions[extreme])
    return directions / np.sqrt(squared)[:, None]


def device_rays(name: str, array, count: int, device) -> wp.array:
    """A Warp array of `count` (-1: any) 3-vectors on `device`: float64 (R,3) or vec3d (R,)."""
    if not isinstance(array, wp.array):
        raise ValueError(f"{name} must be a Warp array too when any ray argument is one, got {type(array).__name__}")
    if array.device != device:
        raise ValueError(f"{name} is on {array.device}; the map is on {device}")
    if array.dtype == wp.float64 and array.ndim == 2 and array.shape[1] == 3 and array.is_contiguous:
        array = array.view(wp.vec3d)
    if array.dtype != wp.vec3d or array.ndim != 1 or not array.is_contiguous or count not in (-1, array.shape[0]):
        wanted = "R" if count == -1 else str(count)
        raise ValueError(
            f"{name} must be a contiguous float64 Warp array of shape ({wanted}, 3) or a vec3d one of "
            f"shape ({wanted},), got {wp.types.type_repr(array.dtype)} {array.shape}"
        )
    return array


def check_extent(config: MapConfig, **arrays: np.ndarray) -> None:
    for name, array in arrays.items():
        within_key_range(name, array, config.voxel_size, hashing.VOXEL_KEY_LIMIT)


def line_arguments(config: MapConfig, starts, ends, level: int = 0) -> tuple[np.ndarray, np.ndarray]:
    starts = float_array("starts", starts, (-1, 3))
    ends = float_array("ends", ends, (starts.shape[0], 3))
    check_extent(config, starts=starts, ends=ends)
    # a line visits one voxel per unit of L1 key distance, plus its first
    size, inv = level_scales(config.voxel_size, level)
    span = np.abs(np.floor(ends.astype(np.float64) * inv) - np.floor(starts.astype(np.float64) * inv)).sum(axis=1) + 1
    if starts.shape[0] and span.max() > MAX_LINE_VOXELS:
        i = int(np.argmax(span))
        raise ValueError(
            f"ends: line {i} crosses {int(span[i])} voxels; line_query takes at most "
            f"{MAX_LINE_VOXELS} voxels per line ({MAX_LINE_VOXELS * size:.0f} m "
            "along an axis): split longer lines"
        )
    return starts, ends


def _line_lengths(config: MapConfig, device, starts: np.ndarray, ends: np.ndarray, level: int = 0):
    d_starts = wp.array(starts, dtype=wp.vec3f, device=device)
    d_ends = wp.array(ends, dtype=wp.vec3f, device=device)
    lengths = wp.empty(starts.shape[0], dtype=wp.int32, device=device)
    wp.launch(
        queries.count_line_voxels,
        dim=starts.shape[0],
        inputs=[d_starts, d_ends, *level_scales(config.voxel_size, level)],
        outputs=[lengths],
        device=device,
    )
    return d_starts, d_ends, lengths.numpy()


def line_voxels(config: MapConfig, device, starts, ends, level: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Voxel keys (R,S,3) of `level` on each line, as line queries walk them, and the lengths (R,)."""
    starts, ends = line_arguments(config, starts, ends, level)
    if starts.shape[0] == 0:
        return np.zeros((0, 0, 3), np.int32), np.zeros(0, np.int32)
    d_starts, d_ends, lengths = _line_lengths(config, device, starts, ends, level)
    voxels = wp.zeros((starts.shape[0], int(lengths.max())), dtype=wp.vec3i, device=device)
    wp.launch(
        queries.fill_line_voxels,
        dim=starts.shape[0],
        inputs=[d_starts, d_ends, *level_scales(config.voxel_size, level)],
        outputs=[voxels],
        device=device,
    )
    return voxels.numpy(), lengths
