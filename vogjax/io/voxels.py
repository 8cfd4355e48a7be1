"""What the exporters read of a map: observed voxels, their log-odds and the state thresholds.

Any map kind can be exported once it is a `VoxelSet`: a VoxelMap, GlobalMap or ConfidenceMap
(`VoxelSet.from_map`; a confidence-rich map by its mean occupancy), or anything else that has
voxel centres with log-odds or occupancy probabilities (`VoxelSet.from_log_odds`,
`VoxelSet.from_probabilities`). `load_map` opens a .vog file of whichever kind its header names.
"""

from __future__ import annotations

import dataclasses
from os import PathLike
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from vogjax.config import MapConfig, logodds
from vogjax.io import mapfile
from vogjax.validation import positive_number

if TYPE_CHECKING:
    import warp as wp

    from vogjax.maps import GlobalMap, VoxelMap
    from vogjax.maps.confidence import ConfidenceMap

# how far a centre may sit off its voxel's centre, in voxels (float rounding, not a wrong size)
_CENTRE_TOLERANCE = 0.01


@dataclasses.dataclass(frozen=True)
class VoxelSet:
    """The observed voxels of one map, as the exporters read them.

    Construction converts and checks every field; build one with `from_map`, `from_log_odds`
    or `from_probabilities`.

    Attributes
    ----------
    centres : (K, 3) ndarray of float64
        Voxel centres, metres (voxel k covers ``[k*s, (k+1)*s)``); each voxel once.
    log_odds : (K,) ndarray of float32
        Their occupancy log-odds, finite (unobserved voxels do not belong in a VoxelSet).
    voxel_size : float
        The voxel edge s, metres.
    log_occupied : numpy.float32
        Log-odds at or above which a voxel is occupied.
    log_free : numpy.float32
        Log-odds at or below which a voxel is free (between the two: unknown).
    states : (K,) ndarray of int8 or None
        vj.UNKNOWN (0), vj.FREE (1) or vj.OCCUPIED (2), as the source map classifies its
        voxels. Given as None, they are computed from `log_odds` and the thresholds, as a
        VoxelMap classifies.

    Raises
    ------
    ValueError
        If `centres` is not (K, 3) real numbers, `log_odds` not (K,), either is not finite,
        `voxel_size` is not positive, `log_free` exceeds `log_occupied`, `states` holds other
        values, or a centre is not a voxel centre or names a voxel twice.
    """

    centres: npt.NDArray[np.float64]
    log_odds: npt.NDArray[np.float32]
    voxel_size: float
    log_occupied: np.float32
    log_free: np.float32
    states: npt.NDArray[np.int8] | None = None

    def __post_init__(self):
        centres = np.asarray(self.centres)
        if centres.ndim != 2 or centres.shape[1] != 3 or centres.dtype.kind not in "fi":
            raise ValueError(f"centres must be real numbers of shape (K, 3), got {centres.dtype} {centres.shape}")
        values = np.asarray(self.log_odds)
        if values.shape != (len(centres),) or values.dtype.kind not in "fi":
            raise ValueError(
                f"log_odds must be real numbers of shape ({len(centres)},), got {values.dtype} {values.shape}"
            )
        if not (np.all(np.isfinite(centres)) and np.all(np.isfinite(values))):
            raise ValueError("centres and log_odds must be finite (unobserved voxels do not belong in a VoxelSet)")
        size = positive_number("voxel_size", self.voxel_size)
        if not (np.isfinite(self.log_free) and np.isfinite(self.log_occupied) and self.log_free <= self.log_occupied):
            raise ValueError("log_free must not exceed log_occupied")
        object.__setattr__(self, "centres", np.ascontiguousarray(centres, dtype=np.float64))
        object.__setattr__(self, "log_odds", np.ascontiguousarray(values, dtype=np.float32))
        object.__setattr__(self, "voxel_size", size)
        object.__setattr__(self, "log_occupied", np.float32(self.log_occupied))
        object.__setattr__(self, "log_free", np.float32(self.log_free))
        if self.states is None:
            states = np.zeros(len(centres), dtype=np.int8)  # the order of the maps' classify
            states[self.log_odds >= self.log_occupied] = 2
            states[self.log_odds <= self.log_free] = 1
        else:
            states = np.asarray(self.states)
            if states.shape != (len(centres),) or not np.isin(states, (0, 1, 2)).all():
                raise ValueError(f"states must be ({len(centres)},) values 0 (unknown), 1 (free) or 2 (occupied)")
        object.__setattr__(self, "states", states.astype(np.int8))
        keys = self.keys()
        if len(keys) and len(np.unique(keys, axis=0)) != len(keys):
            raise ValueError("centres must name each voxel once")

    @classmethod
    def from_map(cls, voxel_map: VoxelMap | GlobalMap | ConfidenceMap) -> VoxelSet:
        """The observed voxels of a map.

        Parameters
        ----------
        voxel_map : VoxelMap, GlobalMap or ConfidenceMap
            A log-odds map, or a confidence-rich map (read by its mean occupancy, with the
            states as it classifies them).

        Returns
        -------
        VoxelSet
            Its observed voxels.

        Raises
        ------
        ValueError
            If `voxel_map` is none of these maps.
        """
        config = getattr(voxel_map, "config", None)
        if isinstance(config, MapConfig) and callable(getattr(voxel_map, "voxels", None)):
            centres, values = voxel_map.voxels()
            return cls(centres, values, config.voxel_size, config.log_occupied, config.log_free)
        from vogjax.maps.confidence import ConfidenceMap

        if isinstance(voxel_map, ConfidenceMap):
            centres, mean, _ = voxel_map.voxels()
            return cls.from_probabilities(
                centres, mean, config.voxel_size, config.occupied_threshold, config.free_threshold
            )
        raise ValueError(f"map must be a vj.VoxelMap, vj.GlobalMap or vj.ConfidenceMap, got {type(voxel_map).__name__}")

    @classmethod
    def from_log_odds(
        cls,
        centres: npt.ArrayLike,
        log_odds: npt.ArrayLike,
        voxel_size: float,
        occupied_threshold: float = 0.7,
        free_threshold: float = 0.3,
    ) -> VoxelSet:
        """Voxels with occupancy log-odds, classified as a VoxelMap classifies.

        Parameters
        ----------
        centres : (K, 3) array_like of float
            Voxel centres, metres.
        log_odds : (K,) array_like of float
            Their log-odds, finite.
        voxel_size : float
            The voxel edge, metres.
        occupied_threshold : float, optional
            Probability at or above which a voxel is occupied, as in `MapConfig`.
        free_threshold : float, optional
            Probability at or below which a voxel is free, as in `MapConfig`.

        Returns
        -------
        VoxelSet
            The voxels.

        Raises
        ------
        ValueError
            If a threshold is not strictly between 0 and 1, or the voxels are refused as the
            class refuses them.
        """
        return cls(centres, log_odds, voxel_size, *_thresholds(occupied_threshold, free_threshold))

    @classmethod
    def from_probabilities(
        cls,
        centres: npt.ArrayLike,
        probabilities: npt.ArrayLike,
        voxel_size: float,
        occupied_threshold: float = 0.7,
        free_threshold: float = 0.3,
    ) -> VoxelSet:
        """Voxels with occupancy probabilities, such as a confidence-rich map's means.

        The states compare the probabilities themselves with the thresholds.

        Parameters
        ----------
        centres : (K, 3) array_like of float
            Voxel centres, metres.
        probabilities : (K,) array_like of float
            Occupancy probabilities, strictly between 0 and 1.
        voxel_size : float
            The voxel edge, metres.
        occupied_threshold : float, optional
            Probability at or above which a voxel is occupied.
        free_threshold : float, optional
            Probability at or below which a voxel is free.

        Returns
        -------
        VoxelSet
            The voxels, with their log-odds.

        Raises
        ------
        ValueError
            If a probability or threshold is not strictly between 0 and 1, or the voxels are
            refused as the class refuses them.
        """
        given = np.asarray(probabilities)
        p = given.astype(np.float64)
        if given.dtype.kind not in "fi" or not np.all((p > 0) & (p < 1)):
            raise ValueError("probabilities must lie strictly between 0 and 1")
        thresholds = _thresholds(occupied_threshold, free_threshold)
        states = np.zeros(len(p), dtype=np.int8)
        states[given >= occupied_threshold] = 2
        states[given <= free_threshold] = 1
        return cls(centres, np.log(p / (1.0 - p)).astype(np.float32), voxel_size, *thresholds, states)

    def __len__(self) -> int:
        return len(self.centres)

    def keys(self) -> npt.NDArray[np.int64]:
        """Integer voxel indices of the centres.

        Returns
        -------
        (K, 3) ndarray of int64
            ``floor(centre / voxel_size)``.

        Raises
        ------
        ValueError
            If a centre sits more than 0.01 voxel off a voxel centre of this size.
        """
        scaled = self.centres / self.voxel_size
        keys = np.floor(scaled).astype(np.int64)
        if len(keys) and np.abs(scaled - keys - 0.5).max() > _CENTRE_TOLERANCE:
            raise ValueError(f"centres are not centres of voxels of {self.voxel_size} m")
        return keys

    def state(self) -> npt.NDArray[np.int8]:
        """The voxels' states, as the source map classifies them.

        Returns
        -------
        (K,) ndarray of int8
            vj.UNKNOWN (0), vj.FREE (1) or vj.OCCUPIED (2).
        """
        return self.states

    def probability(self) -> npt.NDArray[np.float32]:
        """The voxels' occupancy probabilities.

        Returns
        -------
        (K,) ndarray of float32
            ``1 - 1 / (1 + exp(log_odds))``, computed in float64.
        """
        return (1.0 - 1.0 / (1.0 + np.exp(self.log_odds.astype(np.float64)))).astype(np.float32)


def _thresholds(occupied: float, free: float) -> tuple[np.float32, np.float32]:
    for name, value in (("occupied_threshold", occupied), ("free_threshold", free)):
        if not (isinstance(value, (int, float, np.floating)) and 0 < value < 1):
            raise ValueError(f"{name} must lie strictly between 0 and 1, got {value!r}")
    return logodds(occupied), logodds(free)


def load_map(path: str | PathLike, device: str | wp.Device | None = None) -> VoxelMap | GlobalMap | ConfidenceMap:
    """Load a .vog map file as the class its header names.

    Parameters
    ----------
    path : str or os.PathLike
        A map file holding a VoxelMap, GlobalMap or ConfidenceMap.
    device : str or warp.Device or None, optional
        Warp device for the map (None: CUDA when available, else the CPU).

    Returns
    -------
    VoxelMap, GlobalMap or ConfidenceMap
        The map.

    Raises
    ------
    ValueError
        If the file is no map file, holds another kind of map, or is damaged.
    """
    from vogjax.maps import GlobalMap, VoxelMap
    from vogjax.maps.confidence import ConfidenceMap

    kinds = {"VoxelMap": VoxelMap, "GlobalMap": GlobalMap, "ConfidenceMap": ConfidenceMap}
    kind = mapfile.map_kind(path)
    if kind not in kinds:
        raise ValueError(f"path {str(path)!r} holds a {kind!r}; this command reads {', '.join(kinds)}")
    return kinds[kind].load(path, device)
