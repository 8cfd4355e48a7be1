"""VoxelMap: a log-odds occupancy map of hashed voxel blocks, integrated and queried in Warp."""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import warp as wp

from vogjax.config import MapConfig
from vogjax.config.maps import MAX_RANGE_VOXELS
from vogjax.io import read_map_file, write_map_file
from vogjax.kernels import octree
from vogjax.maps import integrator, parallel
from vogjax.maps.blockmap import BlockMap, check_extent
from vogjax.maps.blocks import BLOCK_VOXELS, BlockStore, check_block_keys, pack_blocks
from vogjax.validation import float_array, index_array

if TYPE_CHECKING:
    from vogjax.io.octomap_read import OctreeLeaves

# Scans integrated per pass: each voxel a pass touches carries two bits per scan. A GPU takes
# more per pass: its time goes to the host work of each pass (launches, block allocation,
# read-backs), and it has memory to spare (`bench_profile.py --pass-sweep`).
# On 2 CPU cores passes of 128 scans took 19 % longer, of 512 46 % (pass_sweep_cpu.json); 256 is
# the most apply_marks_few_words replays.
SCANS_PER_PASS = 256
SCANS_PER_PASS_CUDA = 2048
# Bound on the per-pass mark scratch; a pass above it is split in two. Passes of 2048 of the
# pier benchmark's scans took a 148 MiB scratch (64 words, 256 KiB, per block touched). The
# scratch grows by doubling and is pooled per device, so it may keep up to twice the budget;
# on a GPU the budget is also at most a 32nd of its memory (512 MiB kept on a 16 GiB card).
MARK_BUDGET_BYTES = 256 << 20
MARK_BUDGET_BYTES_CUDA = 1 << 30
# Voxel slots (512 a block) an OctoMap tree may expand to when read: 1 GiB of log-odds.
OCTOMAP_MAX_VOXELS = 1 << 28


class VoxelMap(BlockMap):
    """Occupancy map with OctoMap's update rule on dense 8x8x8 blocks in a hash table.

    A scan updates each voxel it reaches once (OctoMap's ``insertPointCloud``): the voxels its
    beams cross become freer, their end voxels more occupied (occupied wins where both), with
    the log-odds clamped after every update; the map equals OctoMap's voxel by voxel. Voxel k
    covers ``[k*s, (k+1)*s)`` on each axis (s: `MapConfig.voxel_size`).

    Queries may run from several threads; integration waits for them and holds them off.

    Parameters
    ----------
    config : MapConfig or None, optional
        Voxel size, sensor model, thresholds, clamping and max range (default: ``MapConfig()``).
    device : str or warp.Device or None, optional
        Warp device; None picks CUDA when available, else the CPU.

    Attributes
    ----------
    config : MapConfig
        The map's settings.
    device : warp.Device
        Where the map lives.
    revision : int
        Counts integrations, so derived data (bounds, clouds) knows it is stale.

    Raises
    ------
    ValueError
        If `config` is not a MapConfig or `device` is not available.

    Examples
    --------
    >>> import vogjax as vj
    >>> vmap = vj.VoxelMap(vj.MapConfig(voxel_size=0.1), device="cpu")
    >>> vmap.integrate_scan([0.0, 0.0, 0.0], [[2.05, 0.05, 0.05]])
    >>> vmap.state([[2.05, 0.05, 0.05], [1.05, 0.05, 0.05]]).tolist() == [vj.OCCUPIED, vj.FREE]
    True
    """

    def __init__(self, config: MapConfig | None = None, device: str | wp.Device | None = None):
        super().__init__(config, device, layers={})
        self.revision = 0  # counts integrations, so derived data (bounds, clouds) knows it is stale

    # ---------------------------------------------------------------- integration
    def integrate_scan(self, origin: npt.ArrayLike, points: npt.ArrayLike) -> None:
        """Integrate one scan.

        Parameters
        ----------
        origin : (3,) array_like of float
            Sensor position, metres, world frame.
        points : (N, 3) array_like of float
            Beam endpoints, metres, world frame; a beam longer than `MapConfig.max_range`
            gives free space up to it and no hit.

        Raises
        ------
        ValueError
            Naming the argument, before anything changes: an array of the wrong shape, of
            values that are not real numbers, NaN or infinite, or beyond the key range.
        """
        origin = float_array("origin", origin, (3,))
        points = float_array("points", points, (-1, 3))
        check_extent(self.config, origin=origin[None], points=points)
        self._integrate(origin[None], points, np.zeros(points.shape[0], dtype=np.int32))

    def integrate_scans(self, origins: npt.ArrayLike, points: npt.ArrayLike, scan_index: npt.ArrayLike) -> None:
        """Integrate a batch of scans: the same map, bit for bit, as `integrate_scan` in order.

        Parameters
        ----------
        origins : (S, 3) array_like of float
            Sensor position per scan, metres, world frame.
        points : (N, 3) array_like of float
            Beam endpoints, metres, world frame.
        scan_index : (N,) array_like of int
            The scan each point belongs to, in [0, S) (in any order: scans are integrated in
            the order of their index).

        Raises
        ------
        ValueError
            Naming the argument, before anything changes: as for `integrate_scan`, or
            `scan_index` not integers in [0, S), one per point.
        """
        origins = float_array("origins", origins, (-1, 3))
        points = float_array("points", points, (-1, 3))
        scan_index = index_array("scan_index", scan_index, points.shape[0], origins.shape[0])
        self._check_extent(origins, points)
        if np.any(np.diff(scan_index) < 0):
            order = np.argsort(scan_index, kind="stable")
            points, scan_index = points[order], scan_index[order]
        self._integrate(origins, points, scan_index)

    def _integrate(self, origins: np.ndarray, points: np.ndarray, scan_index: np.ndarray) -> None:
        batch = integrator.beams(self.device, origins, points, scan_index)
        cuda = self.device.is_cuda
        with self._lock.writing():
            touched = [] if self._levels.count else None  # the written blocks, for the coarse levels
            integrator.integrate(
                self._store,
                self.config,
                batch,
                SCANS_PER_PASS_CUDA if cuda else SCANS_PER_PASS,
                min(MARK_BUDGET_BYTES_CUDA, self.device.total_memory // 32) if cuda else MARK_BUDGET_BYTES,
                touched,
            )
            self.revision += 1
            if not touched:  # no levels kept, or nothing written
                self._values_changed(np.zeros(0, np.int64))
            elif len(touched) == 1:  # one pass: its blocks are distinct
                self._values_changed(*touched[0], distinct=True)
            else:
                keys, cells = zip(*touched)
                self._values_changed(np.concatenate(keys), np.concatenate(cells))

    # ---------------------------------------------------------------- files
    def save(self, path: str | os.PathLike) -> None:
        """Write the map, settings included, to one map file, atomically.

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
        write_map_file(
            path, "VoxelMap", {"config": self.config.to_dict()}, {"block_keys": keys, "log_odds": layers["log_odds"]}
        )

    @classmethod
    def load(cls, path: str | os.PathLike, device: str | wp.Device | None = None) -> VoxelMap:
        """Read a map written by `save`, checking the whole file and its contents.

        Parameters
        ----------
        path : str or os.PathLike
            The .vog file.
        device : str or warp.Device or None, optional
            Warp device for the map (None: CUDA when available, else the CPU).

        Returns
        -------
        VoxelMap
            The map, the same bit for bit as the one saved.

        Raises
        ------
        ValueError
            Naming the path if the file is not a valid VoxelMap file (damaged, another kind of
            map, block keys that are not valid, log-odds of the wrong type or shape, or outside
            the clamping range of its settings).
        """
        metadata, arrays = read_map_file(path, "VoxelMap")
        try:
            config = MapConfig.from_dict(metadata["config"])
            keys, values = arrays["block_keys"], arrays["log_odds"]
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"path {str(path)!r} has invalid map contents: {error}") from None
        where = f"path {str(path)!r}"
        check_block_keys(keys, where)
        if values.dtype != np.float32 or values.shape != (keys.shape[0], BLOCK_VOXELS):
            raise ValueError(
                f"{where} has invalid map contents (log-odds of type {values.dtype}, shape {values.shape})"
            )
        observed = values[~np.isnan(values)]
        if observed.size and (
            observed.min() < config.log_clamp_min
            or observed.max() > config.log_clamp_max
            or not np.all(np.isfinite(observed))
        ):
            raise ValueError(f"{where} holds log-odds outside its clamping range")
        vmap = cls(config, device)
        vmap._store = BlockStore.from_host(vmap.device, vmap._store.layer_specs, keys, {"log_odds": values})
        return vmap

    # ---------------------------------------------------------------- OctoMap
    @classmethod
    def from_octomap(
        cls,
        path: str | os.PathLike,
        config: MapConfig | None = None,
        device: str | wp.Device | None = None,
        max_voxels: int = OCTOMAP_MAX_VOXELS,
    ) -> VoxelMap:
        """A map holding the voxels of an OctoMap file (.bt or .ot, told by its first line).

        The tree's resolution becomes the voxel size; a pruned node stands for all its voxels.
        A .bt (binary) tree holds occupied and free voxels: they get the clamping bounds
        `config.log_clamp_max` and `log_clamp_min`, as OctoMap reads them. A .ot (full) tree of
        type OcTree gives every voxel its stored float log-odds.

        Parameters
        ----------
        path : str or os.PathLike
            The OctoMap file.
        config : MapConfig or None, optional
            Thresholds, clamping and sensor model of the map; its voxel_size must equal the
            file's resolution. None: `MapConfig(voxel_size=<the file's resolution>)`.
        device : str or warp.Device or None, optional
            Where the map lives (None: CUDA if available, else the CPU).
        max_voxels : int, optional
            Budget of voxel slots (512 per 8x8x8 block) the tree may expand to; a larger tree is
            refused before anything is allocated (default 2^28: 1 GiB of log-odds).

        Returns
        -------
        VoxelMap
            The tree's voxels as a map of `config`'s settings.

        Raises
        ------
        ValueError
            One line naming the file: it cannot be read, is no OctoMap OcTree, is malformed
            (truncated, wrong header, inconsistent child bits, NaN log-odds, a resolution
            outside [1e-4, 1e3] m), expands past `max_voxels`, or does not fit `config`.
        """
        from vogjax.io.octomap_read import read_octree

        tree = read_octree(path)
        return cls.from_octree(tree, config, device, max_voxels, where=f"path {str(path)!r}")

    @classmethod
    def from_octree(
        cls,
        tree: OctreeLeaves,
        config: MapConfig | None = None,
        device: str | wp.Device | None = None,
        max_voxels: int = OCTOMAP_MAX_VOXELS,
        where: str = "tree",
    ) -> VoxelMap:
        """A map of a decoded OctoMap tree, as `from_octomap` builds it.

        Parameters
        ----------
        tree : vogjax.io.octomap_read.OctreeLeaves
            From `read_octree` (a file) or `vogjax.io.octomap_bag.read_octomap_message`.
        config : MapConfig or None, optional
            As for `from_octomap`.
        device : str or warp.Device or None, optional
            As for `from_octomap`.
        max_voxels : int, optional
            As for `from_octomap`.
        where : str, optional
            The tree's source, for error messages.

        Returns
        -------
        VoxelMap
            The tree's voxels, as `from_octomap` gives them.

        Raises
        ------
        ValueError
            Naming `where`: the tree expands past `max_voxels`, or does not fit `config`
            (another voxel size, log-odds outside its clamping, a binary tree with infinite
            clamping bounds or bounds its thresholds do not call occupied and free).
        """
        from vogjax.io.octomap_read import leaf_blocks

        if isinstance(max_voxels, bool) or not isinstance(max_voxels, (int, np.integer)) or max_voxels < 0:
            raise ValueError(f"max_voxels must be a non-negative integer, got {max_voxels!r}")
        if config is None:  # the defaults, the range cut to what integration takes at this voxel size
            reach = min(MapConfig.max_range, MAX_RANGE_VOXELS * tree.resolution)
            config = MapConfig(voxel_size=tree.resolution, max_range=reach)
        elif not isinstance(config, MapConfig):
            raise ValueError(f"config must be a vj.MapConfig, got {type(config).__name__}")
        elif config.voxel_size != tree.resolution:
            raise ValueError(
                f"{where} has resolution {tree.resolution!r} m; config.voxel_size is {config.voxel_size!r} m"
            )
        low, high = config.log_clamp_min, config.log_clamp_max
        if tree.binary:
            if not (np.isfinite(low) and np.isfinite(high)):
                raise ValueError(
                    f"{where} is a binary tree (occupied or free only), read as the clamping bounds; "
                    "config clamps nothing (clamp_min 0 or clamp_max 1): give one with clamp_min > 0 and clamp_max < 1"
                )
            if high < config.log_occupied or low > config.log_free:
                raise ValueError(
                    f"{where} is a binary tree, read as the clamping bounds, which config's thresholds "
                    "do not call occupied and free: give a config with clamp_max >= occupied_threshold and "
                    "clamp_min <= free_threshold"
                )
            values = np.where(tree.occupied, high, low).astype(np.float32)
        else:
            values = tree.values
            if len(values) and (values.min() < low or values.max() > high):
                raise ValueError(
                    f"{where} holds log-odds in [{values.min():g}, {values.max():g}], outside config's clamping "
                    f"range [{low:g}, {high:g}]: give a config with wider clamping (clamp_min, clamp_max)"
                )
        blocks = leaf_blocks(tree, int(max_voxels), where)
        vmap = cls(config, device)
        device = vmap.device
        store = BlockStore.from_host(device, vmap._store.layer_specs, pack_blocks(blocks), {})
        copy = device.is_cuda  # on the CPU, Warp arrays over the host arrays
        arrays = [
            wp.array(np.ascontiguousarray(a), dtype=t, device=device, copy=copy)
            for a, t in ((tree.codes, wp.int64), (tree.depths, wp.int8), (tree.rows, wp.int32), (values, wp.float32))
        ]
        parallel.split_launch(
            lambda part, lo, hi: wp.launch(
                octree.fill_leaf_voxels,
                dim=hi - lo,
                inputs=[a[lo:hi] for a in arrays],
                outputs=[store.layers["log_odds"]],
                device=device,
            ),
            len(tree),
            parallel.num_parts(device, len(tree)),
        )
        vmap._store = store
        return vmap
