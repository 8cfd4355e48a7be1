"""View gain: what a range sensor would newly see from candidate poses (Bircher et al.'s
volumetric gain; Ho, thesis 4.3.1 and 4.5.4; IROS Eq. 7).

    g = planner.view_gain(map, T_world_sensor, sensor)   # N views in one launch
    g.unknown, g.free, g.occupied, g.unknown_m3
    g = planner.view_gain(map, T, sensor, frontier=True)  # g.frontier: unknown voxels beside free water

Rays follow the sensor's angular grid (`beam_directions`, every sub-ray), walk the voxel grid
from the sensor and stop at the first OCCUPIED voxel or at the range. A voxel seen by several
rays of one view counts once (an exact hash set per view), so `unknown_m3` is a volume.
Along an edge (`edge_gain`) the views sampled on it form one group: a voxel seen from several
points of the edge also counts once.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt

from vogjax.config import SonarConfig
from vogjax.geometry import rigid_poses, rotation_from_ypr
from vogjax.kernels import hashing
from vogjax.planner.seen import ALL_STATES, group_counts
from vogjax.planner.source import MapLike, Source, opened
from vogjax.sensors import RangeSensor, as_sensor
from vogjax.validation import float_array, positive_number, within_key_range

# Views sampled along one edge, at most: beyond, a tiny step_m would cast rays for minutes.
MAX_EDGE_VIEWS = 1 << 16


@dataclasses.dataclass(frozen=True)
class ViewGain:
    """What N views (or N groups of views, e.g. the views along an edge) would see, each voxel
    counted once per view or group.

    Attributes
    ----------
    unknown : numpy.ndarray, (N,) int64
        Unknown voxels seen.
    free : numpy.ndarray, (N,) int64
        Free voxels seen.
    occupied : numpy.ndarray, (N,) int64
        Occupied voxels seen (each ray stops at its first).
    unknown_m3 : numpy.ndarray, (N,) float64
        The unknown voxels' volume, m^3.
    voxel_m3 : float
        One voxel's volume, m^3.
    rays : int
        Rays cast.
    frontier : numpy.ndarray, (N,) int64 or None
        The unknown voxels seen that have a FREE face neighbour (counted when asked for, else
        zeros).
    """

    unknown: np.ndarray
    free: np.ndarray
    occupied: np.ndarray
    unknown_m3: np.ndarray
    voxel_m3: float
    rays: int
    frontier: np.ndarray | None = None

    def weighted_m3(self, unknown: float = 1.0, free: float = 0.0, occupied: float = 0.0) -> npt.NDArray[np.float64]:
        """Gain weighted by state (nbvplanner's volumetric gain).

        Parameters
        ----------
        unknown, free, occupied : float, optional
            What one voxel of each state adds, in voxel volumes.

        Returns
        -------
        numpy.ndarray, (N,) float64
            Each view's gain, m^3.
        """
        return (unknown * self.unknown + free * self.free + occupied * self.occupied) * self.voxel_m3


def gain_of(counts: np.ndarray, voxel_size: float, rays: int) -> ViewGain:
    voxel_m3 = float(voxel_size) ** 3
    return ViewGain(
        counts[:, 0], counts[:, 1], counts[:, 2], counts[:, 0] * voxel_m3, voxel_m3, int(rays), counts[:, 3]
    )


def view_gain(
    map_: MapLike,
    T_world_sensor: npt.ArrayLike,
    sensor: RangeSensor | SonarConfig,
    max_range_m: float | None = None,
    region: npt.ArrayLike | None = None,
    frontier: bool = False,
) -> ViewGain:
    """Gain of N views.

    Parameters
    ----------
    map_ : vj.VoxelMap, vj.GlobalMap, vj.VogMap or vogjax.planner.Overlay
        The map, read as its own queries read it (a VogMap summed over its submaps).
    T_world_sensor : array_like, (N, 4, 4) float
        Sensor poses.
    sensor : vogjax.sensors.RangeSensor or vj.SonarConfig
        Whose beams the rays follow.
    max_range_m : float, optional
        The rays' range (default: the sensor's).
    region : array_like, (2, 3) float, optional
        A box (lo, hi): only voxels whose centre lies in it count (None: all).
    frontier : bool
        Also count the unknown voxels that have a FREE face neighbour (`ViewGain.frontier`).

    Returns
    -------
    ViewGain
        One entry per view (one launch for all views on a GPU; split across cores on the CPU).

    Raises
    ------
    ValueError
        If a pose is not rigid, the range is not beyond the sensor's blind distance, the region
        is malformed, or the rays would leave the map's key range.
    """
    poses = rigid_poses("T_world_sensor", T_world_sensor)
    sensor = as_sensor(sensor)
    max_range = gain_range("max_range_m", sensor, sensor.max_range_m if max_range_m is None else max_range_m)
    region = check_region(region)
    with opened(map_) as source:
        counts, rays = group_counts(
            source, poses, np.arange(len(poses)), len(poses), sensor, max_range, region, bool(frontier)
        )
    return gain_of(counts, source.config.voxel_size, rays)


def edge_views(
    starts: npt.ArrayLike, ends: npt.ArrayLike, T_vehicle_sensor: npt.ArrayLike, step_m: float, range_m: float
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """Sensor poses sampled along edges, as the vehicle flies them.

    Position moves linearly and yaw along the shorter turn; an edge gets n views at fractions
    1/n..1 (its start belongs to the edge before), n such that consecutive views are at most
    step_m apart and the fan turns at most step_m at range_m (thesis 4.5.4); at most
    MAX_EDGE_VIEWS views an edge.

    Parameters
    ----------
    starts, ends : array_like, (E, 4) float
        Vehicle states x, y, z (metres), yaw (radians) at each edge's ends (a level vehicle).
    T_vehicle_sensor : array_like, (4, 4) float
        The sensor's mount.
    step_m : float
        Largest spacing of the views, metres (along the path, and of the fan at range_m).
    range_m : float
        The range the fan's motion is measured at, metres.

    Returns
    -------
    T_world_sensor : numpy.ndarray, (V, 4, 4) float64
        The views' sensor poses.
    edge : numpy.ndarray, (V,) int64
        The edge of each view.

    Raises
    ------
    ValueError
        If the states are malformed, step_m or range_m is not positive, or an edge would take
        more than MAX_EDGE_VIEWS views.
    """
    starts = float_array("starts", starts, (-1, 4), np.float64)
    ends = float_array("ends", ends, (starts.shape[0], 4), np.float64)
    step_m, range_m = positive_number("step_m", step_m), positive_number("range_m", range_m)
    turn = (ends[:, 3] - starts[:, 3] + np.pi) % (2 * np.pi) - np.pi
    length = np.linalg.norm(ends[:, :3] - starts[:, :3], axis=1)
    views = np.maximum(length, np.abs(turn) * range_m) / step_m
    if len(views) and not views.max() <= MAX_EDGE_VIEWS:
        i = int(np.argmax(views))
        raise ValueError(
            f"step_m: edge {i} would take {views[i]:.3g} views {step_m:g} m apart; at most "
            f"{MAX_EDGE_VIEWS} an edge (a larger step_m or shorter edges)"
        )
    n = np.maximum(1, np.ceil(views - 1e-9)).astype(np.int64)
    edge = np.repeat(np.arange(len(starts)), n)
    fraction = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 1) / np.repeat(n, n)
    states = starts[edge] + fraction[:, None] * np.c_[ends[:, :3] - starts[:, :3], turn][edge]
    T = np.zeros((len(states), 4, 4))
    T[:, :3, :3] = rotation_from_ypr(states[:, 3]).reshape(-1, 3, 3)
    T[:, :3, 3] = states[:, :3]
    T[:, 3, 3] = 1.0
    return T @ np.asarray(T_vehicle_sensor, np.float64), edge


def edge_gain(
    map_: MapLike,
    starts: npt.ArrayLike,
    ends: npt.ArrayLike,
    sensor: RangeSensor | SonarConfig,
    step_m: float,
    max_range_m: float | None = None,
    region: npt.ArrayLike | None = None,
    frontier: bool = False,
) -> ViewGain:
    """Gain along edges: every voxel the sensor would see from the views sampled on an edge
    (`edge_views`), counted once per edge (thesis 4.5.4, the path-segment gain).

    Parameters
    ----------
    map_ : vj.VoxelMap, vj.GlobalMap, vj.VogMap or vogjax.planner.Overlay
        The map, read as `view_gain` reads it.
    starts, ends : array_like, (E, 4) float
        Vehicle states x, y, z (metres), yaw (radians) at each edge's ends.
    sensor : vogjax.sensors.RangeSensor or vj.SonarConfig
        Whose beams the rays follow.
    step_m : float
        Spacing of the views along an edge, metres (`edge_views`).
    max_range_m : float, optional
        The rays' range (default: the sensor's).
    region : array_like, (2, 3) float, optional
        Only voxels whose centre lies in this box count (None: all).
    frontier : bool
        Also count the unknown voxels with a FREE face neighbour.

    Returns
    -------
    ViewGain
        One entry per edge.

    Raises
    ------
    ValueError
        As `view_gain` and `edge_views` do.
    """
    sensor = as_sensor(sensor)
    starts = float_array("starts", starts, (-1, 4), np.float64)
    ends = float_array("ends", ends, (starts.shape[0], 4), np.float64)
    step_m = positive_number("step_m", step_m)
    max_range = gain_range("max_range_m", sensor, sensor.max_range_m if max_range_m is None else max_range_m)
    region = check_region(region)
    with opened(map_) as source:
        for name, states in (("starts", starts), ("ends", ends)):
            within_key_range(name, np.abs(states[:, :3]) + max_range, source.config.voxel_size, hashing.VOXEL_KEY_LIMIT)
        counts, rays = edge_counts(source, starts, ends, sensor, step_m, max_range, region, bool(frontier))
    return gain_of(counts, source.config.voxel_size, rays)


def edge_counts(
    source: Source,
    starts: np.ndarray,
    ends: np.ndarray,
    sensor: RangeSensor,
    step_m: float,
    max_range: float,
    region,
    frontier: bool = False,
    states: tuple[int, ...] = ALL_STATES,
) -> tuple[np.ndarray, int]:
    """`edge_gain` on an opened map: counts (E,4) unknown, free, occupied, frontier (0 unless
    `frontier`; -1 in the columns of states not in `states`), and the rays cast."""
    poses, edge = edge_views(starts, ends, sensor.T_vehicle_sensor, step_m, max_range)
    return group_counts(source, poses, edge, len(starts), sensor, max_range, region, frontier, states)


def discounted(gain: npt.ArrayLike, distance_m: npt.ArrayLike, discount: float) -> npt.NDArray[np.float64]:
    """Gain seen farther along the path, discounted (nbvplanner's degressive coefficient).

    Parameters
    ----------
    gain : array_like of float
        Gains, m^3.
    distance_m : array_like of float
        Path length from the vehicle to where each gain is seen, metres (broadcast).
    discount : float
        Lambda, per metre (Ho's Table 4.2: 0.5).

    Returns
    -------
    numpy.ndarray of float64
        gain * exp(-discount * distance_m).
    """
    return np.asarray(gain, np.float64) * np.exp(-discount * np.asarray(distance_m, np.float64))


def gain_range(name: str, sensor: RangeSensor, value) -> float:
    """A gain ray's range: positive, finite and beyond the sensor's blind zone (min_range_m),
    where it would see nothing and every view would read as explored."""
    value = positive_number(name, value)
    if not value > sensor.min_range_m:
        raise ValueError(
            f"{name} must exceed the sensor's min_range_m ({sensor.min_range_m:g} m), got {value!r}: "
            "the rays would see nothing"
        )
    return value


def check_region(region) -> np.ndarray | None:
    """A (2,3) box (lo, hi), or None."""
    if region is None:
        return None
    region = float_array("region", region, (2, 3), np.float64)
    if np.any(region[0] > region[1]):
        raise ValueError("region must be (lo, hi) with lo <= hi on every axis")
    return region
