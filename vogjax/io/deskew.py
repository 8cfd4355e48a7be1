"""Motion compensation: a spinning lidar's points, each moved to where the sensor was when it fired.

A spinning lidar fires its columns over the whole sweep (0.1 s at 10 Hz), while its driver
stamps the cloud once. Read as if every point had been measured at the stamp, the cloud of a
vehicle turning at 1 rad/s smears by 2 m at 20 m. Drivers write each point's time in a field;
`point_offsets` reads it in the layouts drivers write, and `deskew_points` carries every point
from the sensor's pose at its own time to the sensor's pose at the stamp, with the vehicle's
odometry interpolated as the importer interpolates it for the scans (linear in position, slerp
in rotation: `vogjax.geometry.interpolate_poses`).

Layouts of the per-point time, told apart by type and by value against the header stamp:

| type | layout | drivers |
| --- | --- | --- |
| float32 | seconds relative to the header stamp | Velodyne (`time`) |
| uint32, int32 | nanoseconds relative to the header stamp | Ouster (`t`) |
| float64, small | seconds relative to the header stamp | |
| float64, near the stamp in s | absolute seconds | Hesai, Robosense (`timestamp`) |
| float64, near the stamp in ns | absolute nanoseconds | Livox (`timestamp`) |

Every point of a cloud must have fired within `MAX_SWEEP_S` of its stamp in the layout found;
a cloud whose times fit none (a driver clock apart from the header's, say) is an error, as is a
float32 time that looks absolute (float32 holds 1.7e9 s only to two minutes).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from vogjax.geometry import interpolate_poses

MAX_SWEEP_S = 1.0  # a point fired farther from its cloud's stamp is damage or another clock
_STAMP_RESOLUTION_S = 1e-9  # stamps are whole nanoseconds: closer than this to the span is on it
LAYOUTS = {
    "relative_s": "seconds relative to the header stamp",
    "relative_ns": "nanoseconds relative to the header stamp",
    "absolute_s": "absolute seconds",
    "absolute_ns": "absolute nanoseconds",
}


def point_offsets(
    values: npt.ArrayLike, datatype: int, stamp_ns: int, where: str, layout: str | None = None
) -> tuple[npt.NDArray[np.float64], str]:
    """Each point's firing time relative to its cloud's stamp, from the time field as stored.

    Parameters
    ----------
    values : (N,) array_like
        The time field of the points to place (finite x, y, z), in its own dtype.
    datatype : int
        Its sensor_msgs/PointField datatype (5: int32, 6: uint32, 7: float32, 8: float64).
    stamp_ns : int
        The cloud's header stamp, nanoseconds.
    where : str
        What an error names (flag, topic and field).
    layout : str or None, optional
        The layout (a key of `LAYOUTS`) the topic's earlier clouds had: this one must fit it too.
        None: found from this cloud.

    Returns
    -------
    offsets_s : (N,) ndarray of float64
        Firing time minus stamp, seconds, each within ``MAX_SWEEP_S``.
    layout : str
        The layout found (or the one given), a key of `LAYOUTS`.

    Raises
    ------
    ValueError
        Naming `where` when the type holds no known layout, a time is not finite, or the
        times fit no layout within ``MAX_SWEEP_S`` of the stamp (or not the one given).
    """
    if datatype not in (5, 6, 7, 8):
        raise ValueError(f"{where} is of PointField datatype {datatype}: no lidar driver's time layout is known for it")
    raw = np.asarray(values)
    if raw.dtype.kind == "f" and not np.all(np.isfinite(raw)):
        raise ValueError(f"{where} holds non-finite times")
    if raw.size == 0:
        return np.zeros(0), layout or ("relative_ns" if datatype in (5, 6) else "relative_s")
    candidates = {
        5: ["relative_ns"],
        6: ["relative_ns"],
        7: ["relative_s"],
        # not float64 nanoseconds relative: 12.0 would read as 12 ns, where seconds of another clock are likelier
        8: ["relative_s", "absolute_s", "absolute_ns"],
    }[datatype]
    if layout is not None:
        candidates = [layout] if layout in candidates else []
    for name in candidates:
        offsets = _offsets(raw, name, stamp_ns)
        if np.abs(offsets).max() <= MAX_SWEEP_S:
            return offsets, name
    low, high = float(raw.min()), float(raw.max())
    if datatype == 7 and abs(high - stamp_ns * 1e-9) <= 1e3:
        raise ValueError(
            f"{where} looks like absolute seconds in float32, which holds them only to minutes: pass --no-deskew"
        )
    expected = f" ({LAYOUTS[layout]}, as the topic's first cloud)" if layout is not None else ""
    raise ValueError(
        f"{where} holds times {low:.9g} to {high:.9g} ({np.dtype(raw.dtype).name}), which lie within "
        f"{MAX_SWEEP_S:g} s of the header stamp {stamp_ns} ns in no known layout{expected}: "
        "pass --no-deskew to import the points at the stamp"
    )


def _offsets(raw: np.ndarray, layout: str, stamp_ns: int) -> np.ndarray:
    if layout == "relative_s":
        return raw.astype(np.float64)
    if layout == "relative_ns":
        return raw.astype(np.float64) * 1e-9
    if layout == "absolute_s":  # the stamp split in whole and fractional seconds keeps its nanoseconds
        return (raw.astype(np.float64) - float(stamp_ns // 10**9)) - (stamp_ns % 10**9) * 1e-9
    # absolute_ns: float64 holds 1.7e18 ns to 256 ns; the stamp's own rounding is taken back exactly
    near = float(stamp_ns)
    return ((raw.astype(np.float64) - near) - (stamp_ns - int(near))) * 1e-9


def deskew_points(
    points: npt.ArrayLike,
    offsets_s: npt.ArrayLike,
    stamp_s: float,
    times_s: npt.ArrayLike,
    poses: npt.NDArray[np.floating],
    T_vehicle_sensor: npt.NDArray[np.floating],
) -> npt.NDArray[np.float64]:
    """Points measured at their own times, in the sensor frame at the cloud's stamp.

    A point p measured at time t lies at ``T_world_sensor(t) p`` in the world; stored in the
    frame the sensor had at the stamp, ``T_world_sensor(stamp)^-1 T_world_sensor(t) p``, it
    lands there again when the mapper carries it with the stamp's pose.

    Parameters
    ----------
    points : (N, 3) array_like of float
        x, y, z in the sensor frame at each point's firing time, metres.
    offsets_s : (N,) array_like of float
        Firing time minus `stamp_s`, seconds.
    stamp_s : float
        The cloud's stamp, seconds on the clock of `times_s`.
    times_s : (M,) array_like of float
        Strictly increasing times of the odometry poses, seconds; they must span
        ``stamp_s + offsets_s`` and `stamp_s`.
    poses : (M, 4, 4) ndarray of float
        T_world_vehicle at `times_s`.
    T_vehicle_sensor : (4, 4) ndarray of float
        The sensor's mount on the vehicle.

    Returns
    -------
    (N, 3) ndarray of float64
        The points in the sensor frame at `stamp_s`, metres.

    Raises
    ------
    ValueError
        If a firing time (or the stamp) lies outside the odometry's span.
    """
    points = np.asarray(points, dtype=np.float64)
    offsets = np.asarray(offsets_s, dtype=np.float64)
    times = np.asarray(times_s, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    if len(points) == 0:
        return points.reshape(0, 3)
    fired = stamp_s + offsets
    low, high = min(stamp_s, float(fired.min())), max(stamp_s, float(fired.max()))
    if low < times[0] - _STAMP_RESOLUTION_S or high > times[-1] + _STAMP_RESOLUTION_S:
        raise ValueError(
            f"firing times {low:.6f} to {high:.6f} s reach outside the odometry's {times[0]:.6f} to {times[-1]:.6f} s"
        )
    # a point fired on the odometry's first or last stamp may sum to a hair outside it
    fired = np.clip(fired, times[0], times[-1])
    mount = np.asarray(T_vehicle_sensor, dtype=np.float64)
    # every step is a product of (N,3) vectors with one matrix, or a rotation of each point about
    # its own axis: no (N,3,3) arrays, nor scipy's slow products of N rotations
    in_vehicle = points @ mount[:3, :3].T + mount[:3, 3]
    world = _slerp_apply(times, poses, fired, in_vehicle)
    # the sensor at the stamp, as the importer places the scan
    T_world_sensor = interpolate_poses(times, poses, [min(max(stamp_s, times[0]), times[-1])])[0] @ mount
    return (world - T_world_sensor[:3, 3]) @ T_world_sensor[:3, :3]


def _slerp_apply(times: np.ndarray, poses: np.ndarray, query: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``T_world_vehicle(query_i) vectors_i``, with T interpolated as `vogjax.geometry.interpolate_poses`
    interpolates it (scipy's Slerp, R_k exp(u log(R_k^T R_k+1)); positions linear), equal to it
    to float rounding. One query applies to every vector when `query` holds one time."""
    if len(times) == 1:
        return vectors @ poses[0, :3, :3].T + poses[0, :3, 3]
    # only the segments around the sweep
    lo = max(int(np.searchsorted(times, query.min(), side="right")) - 1, 0)
    hi = min(int(np.searchsorted(times, query.max(), side="left")), len(times) - 1)
    lo, hi = min(lo, len(times) - 2), max(hi, lo + 1)
    times, poses = times[lo : hi + 1], poses[lo : hi + 1]
    segment = np.clip(np.searchsorted(times, query, side="right") - 1, 0, len(times) - 2)
    u = ((query - times[segment]) / (times[segment + 1] - times[segment]))[:, None]
    rotations = Rotation.from_matrix(poses[:, :3, :3])
    steps = (rotations[:-1].inv() * rotations[1:]).as_rotvec()
    # each query's turn from its segment's start, then the segment's start rotation
    turned = Rotation.from_rotvec(steps[segment] * u).apply(vectors)
    out = np.empty_like(turned)
    matrices = rotations.as_matrix()
    for k in np.unique(segment):
        rows = segment == k
        out[rows] = turned[rows] @ matrices[k].T
    start, end = poses[segment, :3, 3], poses[segment + 1, :3, 3]
    return out + start + (end - start) * u
