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

from vogjax.geometry import rigid_poses, rotation_from_ypr
from vogjax.kernels import hashing
from vogjax.planner.seen import group_counts
from vogjax.planner.source import Source, opened
from vogjax.sensors import RangeSensor, as_sensor
from vogjax.validation import float_array, positive_number, within_key_range

# Views sampled along one edge, at most: beyond, a tiny step_m would cast rays for minutes.
MAX_EDGE_VIEWS = 1 << 16


@dataclasses.dataclass(frozen=True)
class ViewGain:
    """Per view (or per group of views): voxels first seen that are unknown, free and
    occupied (N,) int64; unknown_m3 (N,) float64 their unknown volume; voxel_m3 the volume of
    one voxel; rays, the rays cast; frontier (N,) int64, the unknown ones with a FREE face
    neighbour (counted when asked for, else zeros)."""

    unknown: np.ndarray
    free: np.ndarray
    occupied: np.ndarray
    unknown_m3: np.ndarray
    voxel_m3: float
    rays: int
    frontier: np.ndarray | None = None

    def weighted_m3(self, unknown: float = 1.0, free: float = 0.0, occupied: float = 0.0) -> np.ndarray:
        """(N,) gain in m^3: each state's voxels times its weight, in voxel volumes."""
        return (unknown * self.unknown + free * self.free + occupied * self.occupied) * self.voxel_m3


def gain_of(counts: np.ndarray, voxel_size: float, rays: int) -> ViewGain:
    voxel_m3 = float(voxel_size) ** 3
    return ViewGain(
        counts[:, 0], counts[:, 1], counts[:, 2], counts[:, 0] * voxel_m3, voxel_m3, int(rays), counts[:, 3]
    )


def view_gain(
    map_, T_world_sensor, sensor, max_range_m: float | None = None, region=None, frontier: bool = False
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
        One launch for all views on a GPU; split across cores on the CPU.
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
    starts: np.ndarray, ends: np.ndarray, T_vehicle_sensor: np.ndarray, step_m: float, range_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Sensor poses sampled along edges from vehicle states `starts` to `ends` (E,4: x, y, z,
    yaw; level vehicle), and the edge of each: (V,4,4), (V,) int64.

    Position moves linearly and yaw along the shorter turn; an edge gets n views at fractions
    1/n..1 (its start belongs to the edge before), n such that consecutive views are at most
    step_m apart and the fan turns at most step_m at range_m (thesis 4.5.4); at most
    MAX_EDGE_VIEWS views an edge."""
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
    return T @ T_vehicle_sensor, edge


def edge_gain(
    map_, starts, ends, sensor, step_m: float, max_range_m: float | None = None, region=None, frontier: bool = False
) -> ViewGain:
    """Gain along E edges between vehicle states (E,4: x, y, z, yaw): every voxel the sensor
    would see from the views sampled on an edge (`edge_views`), counted once per edge; the
    other arguments as `view_gain`'s."""
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
) -> tuple[np.ndarray, int]:
    """`edge_gain` on an opened map: counts (E,4) unknown, free, occupied, frontier (0 unless
    `frontier`), and the rays cast."""
    poses, edge = edge_views(starts, ends, sensor.T_vehicle_sensor, step_m, max_range)
    return group_counts(source, poses, edge, len(starts), sensor, max_range, region, frontier)


def discounted(gain, distance_m, discount: float) -> np.ndarray:
    """Gain seen at path length distance_m from the vehicle, worth gain * exp(-discount * d)
    (nbvplanner's degressive coefficient, lambda in Ho's Table 4.2)."""
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
