"""ROS bags (ROS 1 .bag, ROS 2 folders with sqlite3 or MCAP storage, bare .mcap/.db3 files) into
vogjax run files, read with `rosbags` (pure Python; no ROS installation needed).

    summary = import_bag("drive.bag", "drive.h5", points_topic="/velodyne_points",
                         odometry_topic="/odom", frame="velodyne")

Scans: sensor_msgs/PointCloud2 (fields x, y, z as float32 or float64, in the sensor frame) or
sensor_msgs/LaserScan. Poses: nav_msgs/Odometry, T_world_vehicle with world = its
header.frame_id and vehicle = its child_frame_id, interpolated to each scan's header stamp
(linear in position, slerp in rotation). Without `frame` the points must be in the vehicle frame
(a scan header naming another frame is an error); with `frame` (the sensor frame) its fixed
pose in the vehicle frame is chained from /tf_static (or /tf, where it must not move).

Each scan becomes one row of the run: origin and unit beam directions in the vehicle frame,
ranges, no_return. Beams: a PointCloud2 point is a return (non-finite or zero-length points are
invalid); a LaserScan range is a return in [range_min, range_max], no return above range_max or
+inf (free space is cleared along it up to the map's max range, as OctoMap does), invalid when
NaN or below range_min (-inf included). Invalid beams are dropped and counted. A run holds B
beams per scan (B: the most valid beams of any scan); a scan with fewer is padded with copies of
one of its own beams (a return where it has one), which change no voxel (within one scan a voxel
is updated once), so padding never alters a map.

Scans are dropped, and counted by reason in the run's metadata (`import.dropped`), when they lie
outside the odometry's time span (no extrapolation), have no valid beam, or are not later than
the scan before them. A bag in which no scan survives is an error.

Metadata of the run (documented keys): `sensor` = "point_cloud", `sensor_config` (a
PointCloudConfig: message, beams, rate_hz, min_range_m, max_range_m), `T_vehicle_sensor`,
`source` (bag, storage, topics, message types, frames, where the mount came from) and `import`
(counts). `sensor_config.max_range_m` is the sensor's reach for the mapper: LaserScan's largest
range_max, or for a point cloud the farthest return unless `max_range_m` is given.
"""

from __future__ import annotations

import dataclasses
import functools
from collections import defaultdict
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vogjax.config.point_cloud import PointCloudConfig
from vogjax.config.sensing import MAX_BEAMS
from vogjax.geometry import interpolate_poses, inverse, rigid_pose
from vogjax.io.atomic import check_writable
from vogjax.io.dataset import MAX_RANGE_M, DatasetWriter
from vogjax.sensors.point_cloud import PointCloudSensor

POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
TF_TOPICS = {"/tf_static": True, "tf_static": True, "/tf": False, "tf": False}  # topic -> static
BATCH_SCANS = 256
# Scans are interpolated between odometry poses at most this many median intervals apart (and
# at least this many seconds); scans in longer gaps are dropped, counted as in_odometry_gap.
ODOMETRY_GAP_FACTOR = 10.0
MIN_ODOMETRY_GAP_S = 1.0
BATCH_BEAMS = 1 << 22  # scans x beams per batch written: about 70 MB with padding
_MIN_RANGE = 1e-6  # a point closer than this has no direction
_MOUNT_TOLERANCE = 1e-6  # a /tf mount that moves more than this (m, rad) is not fixed
_FLOAT_TYPES = {7: "f4", 8: "f8"}  # sensor_msgs/PointField FLOAT32, FLOAT64


@dataclasses.dataclass(frozen=True)
class ImportSummary:
    """What `import_bag` wrote: the run's path, scans written and read, beams per scan, scans
    dropped by reason, beams dropped as invalid and copies added as padding, and the metadata."""

    path: Path
    scans: int
    scans_read: int
    beams: int
    dropped: dict
    invalid_beams: int
    padded_beams: int
    metadata: dict


@dataclasses.dataclass(frozen=True)
class Scan:
    """One scan's valid beams in the sensor frame: directions (n,3) unit, ranges (n,) (NaN
    where no return), no_return (n,); stamp_ns its header stamp; frame its header frame."""

    stamp_ns: int
    frame: str
    directions: np.ndarray
    ranges: np.ndarray
    no_return: np.ndarray
    invalid: int
    range_min: float | None = None  # LaserScan's
    range_max: float | None = None


def import_bag(
    bag,
    out,
    points_topic: str,
    odometry_topic: str,
    frame: str | None = None,
    max_range_m: float | None = None,
    progress: bool = True,
) -> ImportSummary:
    """Convert a bag into a run file at `out` (published whole, or not at all)."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    bag, out = Path(bag), Path(out)
    if max_range_m is not None and (
        isinstance(max_range_m, bool) or not isinstance(max_range_m, (int, float)) or not 0 < max_range_m <= MAX_RANGE_M
    ):
        raise ValueError(f"max_range_m must be a number in (0, {MAX_RANGE_M:g}], got {max_range_m!r}")
    if not bag.exists():
        raise ValueError(f"bag {str(bag)!r} does not exist")
    check_writable(out)  # before reading the whole bag
    if not out.parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: folder {str(out.parent)!r} does not exist")
    try:
        with AnyReader([bag], default_typestore=get_typestore(Stores.LATEST)) as reader:
            return _import(reader, bag, out, points_topic, odometry_topic, frame, max_range_m, progress)
    except (
        AnyReaderError,
        FileNotFoundError,
        NotADirectoryError,
        IsADirectoryError,
        PermissionError,
        UnicodeError,
    ) as error:
        # rosbags reads a folder without metadata.yaml as a ROS 2 bag and fails opening it; a
        # damaged MCAP summary can hold undecodable text
        raise ValueError(f"bag {str(bag)!r} cannot be read as a ROS 1, ROS 2 or MCAP bag: {error}") from None
    except _Damaged as damage:
        raise ValueError(f"bag {str(bag)!r} is damaged: {damage}") from None


class _Damaged(Exception):
    """The bag reader failed on a record or a message (what it raises varies: its own errors,
    assertions, decoding errors): the bag, not the caller, is at fault."""


def _messages(reader, connections):
    """(connection, message) of `connections` in the bag's order, read errors as _Damaged."""
    records = reader.messages(connections=connections)
    while True:
        try:
            connection, _, raw = next(records)
            message = reader.deserialize(raw, connection.msgtype)
        except StopIteration:
            return
        except Exception as error:  # anything the reader raises means an unreadable record
            detail = str(error).strip().splitlines()
            raise _Damaged(type(error).__name__ + (f": {detail[0]}" if detail else "")) from None
        yield connection, message


def _import(reader, bag: Path, out: Path, points_topic, odometry_topic, frame, max_range_m, progress):
    from tqdm import tqdm

    scan_connections, message = _topic(reader, points_topic, "--points", {POINT_CLOUD, LASER_SCAN})
    odometry = read_odometry(reader, _topic(reader, odometry_topic, "--odometry", {ODOMETRY})[0], odometry_topic)
    world_frame, vehicle_frame = odometry.frames
    # pass 1: which scans survive, and how many beams the largest holds
    dropped = defaultdict(int)
    kept, stamps, frames, counts, invalid = [], [], set(), [], 0  # kept: ordinals in the topic
    range_min, range_max, longest = np.inf, 0.0, 0.0
    scans_read = 0
    for ordinal, scan in enumerate(_scans(reader, scan_connections, message, points_topic)):
        scans_read += 1
        frames.add(scan.frame)
        if not odometry.covers(scan.stamp_ns):
            dropped["outside_odometry"] += 1
        elif not odometry.bridges(scan.stamp_ns):
            dropped["in_odometry_gap"] += 1
        elif len(scan.ranges) == 0:
            dropped["no_valid_beams"] += 1
        elif stamps and scan.stamp_ns * 1e-9 <= stamps[-1] * 1e-9:  # as the run stores times
            dropped["stamp_not_increasing"] += 1
        else:
            kept.append(ordinal)
            invalid += scan.invalid  # of the scans written: a dropped scan's beams are not counted twice
            stamps.append(scan.stamp_ns)
            counts.append(len(scan.ranges))
            if scan.range_max is not None:
                range_min, range_max = min(range_min, scan.range_min), max(range_max, scan.range_max)
            returned = scan.ranges[~scan.no_return]
            if len(returned):
                longest = max(longest, float(returned.max()))
    if scans_read == 0:
        raise ValueError(f"--points topic {points_topic!r} holds no messages")
    declared = sum(int(getattr(c, "msgcount", 0) or 0) for c in scan_connections)
    if scans_read < declared:  # the reader skipped records it could not read
        raise _Damaged(f"topic {points_topic!r} declares {declared} messages, {scans_read} could be read")
    if not kept:
        raise ValueError(f"no scan on {points_topic!r} can be imported: {_reasons(dropped)}")
    sensor_frame = _check_frames(frames - {""}, None if frame is None else _frame(frame), vehicle_frame, points_topic)
    T_vehicle_sensor, mount = (
        (np.eye(4), "identity: points in the vehicle frame")
        if sensor_frame == vehicle_frame
        else read_mount(reader, vehicle_frame, sensor_frame)
    )
    # the sensor's reach: what the caller says, LaserScan's range_max, or the farthest return (cm up)
    reach = float(
        max_range_m or min(range_max if message == "LaserScan" else np.ceil(longest * 100 + 1) / 100, MAX_RANGE_M)
    )
    beams = int(max(counts))
    if beams > MAX_BEAMS:
        raise ValueError(
            f"--points topic {points_topic!r}: a scan holds {beams} valid beams, more than the "
            f"{MAX_BEAMS} a run file takes"
        )
    duration_s = (stamps[-1] - stamps[0]) * 1e-9
    config = PointCloudConfig(
        message=message,
        beams=beams,
        rate_hz=float((len(kept) - 1) / duration_s) if duration_s > 0 else 10.0,
        min_range_m=float(range_min) if message == "LaserScan" and range_min < reach else 0.0,
        max_range_m=reach,
    )
    sensor = PointCloudSensor(config, T_vehicle_sensor)
    metadata = {
        **sensor.metadata(),
        "source": {
            "bag": str(bag),
            "storage": "ros2" if reader.is2 else "ros1",
            "points_topic": points_topic,
            "points_type": f"sensor_msgs/{message}",
            "odometry_topic": odometry_topic,
            "frames": {"world": world_frame, "vehicle": vehicle_frame, "sensor": sensor_frame},
            "mount": mount,
        },
        "import": {
            "scans_read": scans_read,
            "scans_written": len(kept),
            "dropped": dict(dropped),
            "invalid_beams": invalid,
            "padded_beams": int(beams * len(kept) - sum(counts)),
            "odometry_messages": len(odometry.stamps_ns),
            "odometry_span_s": [odometry.stamps_ns[0] * 1e-9, odometry.stamps_ns[-1] * 1e-9],
        },
    }
    # pass 2: the kept scans, padded, at their interpolated poses
    wanted = set(kept)
    rotation, origin = T_vehicle_sensor[:3, :3], T_vehicle_sensor[:3, 3]
    # every scan is padded to the largest: batches of at most BATCH_BEAMS beams bound the memory
    batch_scans = max(1, min(BATCH_SCANS, BATCH_BEAMS // beams))
    written = 0
    with (
        DatasetWriter(out, beams, metadata, truth=False) as writer,
        tqdm(total=len(kept), unit="scan", desc="importing", disable=not progress) as bar,
    ):
        rows = []
        for ordinal, scan in enumerate(_scans(reader, scan_connections, message, points_topic)):
            if ordinal not in wanted:
                continue
            written += 1
            rows.append(_padded(scan, beams, rotation))
            if len(rows) == batch_scans or written == len(kept):
                batch_ns = np.array([r[0] for r in rows], dtype=np.int64)
                writer.append(
                    time_s=batch_ns * 1e-9,
                    pose_nav=odometry.at(batch_ns),
                    sonar_origin=np.tile(origin, (len(rows), 1)).astype(np.float32),
                    sonar_directions=np.stack([r[1] for r in rows]),
                    ranges=np.stack([r[2] for r in rows]),
                    no_return=np.stack([r[3] for r in rows]),
                    # the bag's own rule: beams below range_min were dropped above, none is stored invalid
                    invalid=np.zeros((len(rows), beams), np.bool_),
                )
                bar.update(len(rows))
                rows = []
    return ImportSummary(
        out, len(kept), scans_read, beams, dict(dropped), invalid, metadata["import"]["padded_beams"], metadata
    )


def _padded(scan: Scan, beams: int, rotation: np.ndarray):
    """(stamp, directions (B,3) in the vehicle frame, ranges (B,), no_return (B,)): the scan's
    beams, then copies of its first return (or first beam) up to B."""
    count = len(scan.ranges)
    returns = np.flatnonzero(~scan.no_return)
    copy = returns[0] if len(returns) else 0
    index = np.r_[np.arange(count), np.full(beams - count, copy)]
    directions = (scan.directions[index] @ rotation.T).astype(np.float32)
    return scan.stamp_ns, directions, scan.ranges[index].astype(np.float32), scan.no_return[index]


def _reasons(dropped: dict) -> str:
    return ", ".join(f"{count} {reason.replace('_', ' ')}" for reason, count in dropped.items())


# ------------------------------------------------------------------ topics and messages
def _topic(reader, topic: str, argument: str, types: set) -> tuple[list, str]:
    """The connections of `topic` and its message name; ValueError naming `argument` when the
    bag lacks the topic or it carries another type."""
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        available = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
        raise ValueError(f"{argument}: the bag has no topic {topic!r} (topics: {available})")
    found = {c.msgtype for c in connections}
    if not found <= types:
        raise ValueError(
            f"{argument}: topic {topic!r} carries {', '.join(sorted(found))}, not {' or '.join(sorted(types))}"
        )
    if len(found) > 1:
        raise ValueError(f"{argument}: topic {topic!r} carries several message types: {', '.join(sorted(found))}")
    return connections, found.pop().rsplit("/", 1)[-1]


def _frame(name: str) -> str:
    return name.lstrip("/")  # ROS 1 frames may carry a leading slash


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _scans(reader, connections, message: str, topic: str):
    parse = cloud_beams if message == "PointCloud2" else laser_beams
    for _, msg in _messages(reader, connections):
        yield parse(msg, topic)


def cloud_beams(msg, topic: str = "") -> Scan:
    """The valid beams of a sensor_msgs/PointCloud2 (ranges from the sensor origin)."""
    points = cloud_points(msg, topic)
    ranges = np.linalg.norm(points, axis=1)
    valid = np.isfinite(ranges) & (ranges >= _MIN_RANGE) & (ranges <= MAX_RANGE_M)
    points, ranges = points[valid], ranges[valid]
    return Scan(
        _stamp_ns(msg.header),
        _frame(msg.header.frame_id),
        points / ranges[:, None],
        ranges,
        np.zeros(len(ranges), dtype=bool),
        int(np.count_nonzero(~valid)),
    )


def cloud_points(msg, topic: str = "") -> np.ndarray:
    """(N,3) float64 x, y, z of every point of a PointCloud2 (NaN ones included)."""
    where = f"--points topic {topic!r}: PointCloud2"
    names = [f.name for f in msg.fields]
    repeated = sorted(n for n in "xyz" if names.count(n) > 1)
    if repeated:
        raise ValueError(f"{where} has field {repeated[0]} twice")
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in "xyz" if n not in fields]
    if missing:
        raise ValueError(f"{where} has no field {', '.join(missing)} (fields: {', '.join(fields) or 'none'})")
    formats, offsets = [], []
    order = ">" if msg.is_bigendian else "<"
    for name in "xyz":
        field = fields[name]
        if field.datatype not in _FLOAT_TYPES or field.count not in (0, 1):
            raise ValueError(
                f"{where} field {name} must be one float32 or float64, got datatype {field.datatype} x {field.count}"
            )
        formats.append(order + _FLOAT_TYPES[field.datatype])
        offsets.append(int(field.offset))
    step, width, height, row_step = int(msg.point_step), int(msg.width), int(msg.height), int(msg.row_step)
    if width * height > MAX_BEAMS:  # a run holds no more beams per scan; refused before converting
        raise ValueError(f"{where} holds {height} x {width} points, more than the {MAX_BEAMS} beams a scan may have")
    data = np.asarray(msg.data, dtype=np.uint8)
    if (
        step <= 0
        or any(o < 0 or o + np.dtype(f).itemsize > step for o, f in zip(offsets, formats))
        or row_step < width * step
        or len(data) < height * row_step
    ):
        raise ValueError(
            f"{where} is malformed: {height} x {width} points of {step} bytes, rows of {row_step} "
            f"bytes, fields x, y, z at bytes {offsets}, {len(data)} bytes of data"
        )
    dtype = np.dtype({"names": list("xyz"), "formats": formats, "offsets": offsets, "itemsize": step})
    rows = data[: height * row_step].reshape(height, row_step)[:, : width * step]
    points = np.ascontiguousarray(rows).view(dtype).reshape(-1)
    return np.stack([points[n].astype(np.float64) for n in "xyz"], axis=1)


def laser_beams(msg, topic: str = "") -> Scan:
    """The valid beams of a sensor_msgs/LaserScan (directions in its x-y plane)."""
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    angles = float(msg.angle_min) + np.arange(len(ranges)) * float(msg.angle_increment)
    directions = np.stack([np.cos(angles), np.sin(angles), np.zeros(len(ranges))], axis=1)
    low, high = float(msg.range_min), float(msg.range_max)
    if not (
        np.isfinite(low)
        and np.isfinite(high)
        and 0 <= low < high
        and np.isfinite(msg.angle_min)
        and np.isfinite(msg.angle_increment)
    ):
        raise ValueError(
            f"--points topic {topic!r}: LaserScan has range_min {low}, range_max {high}, "
            f"angle_min {msg.angle_min}, angle_increment {msg.angle_increment}"
        )
    with np.errstate(invalid="ignore"):
        no_return = ranges > high
        # a return farther than any range sensor reaches is damage, as in a cloud
        invalid = np.isnan(ranges) | (ranges < low) | (~no_return & (ranges > MAX_RANGE_M))
    keep = ~invalid
    return Scan(
        _stamp_ns(msg.header),
        _frame(msg.header.frame_id),
        directions[keep],
        np.where(no_return, np.nan, ranges)[keep],
        no_return[keep],
        int(np.count_nonzero(invalid)),
        low,
        high,
    )


# ------------------------------------------------------------------ poses
@dataclasses.dataclass(frozen=True)
class Odometry:
    """Odometry poses T_world_vehicle (N,4,4) at strictly increasing stamps (N,) ns; frames
    (world, vehicle)."""

    stamps_ns: np.ndarray
    poses: np.ndarray
    frames: tuple

    def covers(self, stamp_ns: int) -> bool:
        return bool(self.stamps_ns[0] <= stamp_ns <= self.stamps_ns[-1])

    @functools.cached_property
    def max_gap_ns(self) -> float:
        """The longest gap between two poses that a scan is interpolated across: ten times the
        odometry's median interval, and at least MIN_ODOMETRY_GAP_S. Across a longer one (a
        dropout, or a message stamped 0) the vehicle's path is unknown."""
        intervals = np.diff(self.stamps_ns)
        median = float(np.median(intervals)) if len(intervals) else 0.0
        return max(ODOMETRY_GAP_FACTOR * median, MIN_ODOMETRY_GAP_S * 1e9)

    def bridges(self, stamp_ns: int) -> bool:
        """Whether a covered stamp lies on a pose or between two no more than max_gap_ns apart."""
        i = int(np.searchsorted(self.stamps_ns, stamp_ns))
        if i < len(self.stamps_ns) and self.stamps_ns[i] == stamp_ns:
            return True
        return bool(self.stamps_ns[i] - self.stamps_ns[i - 1] <= self.max_gap_ns)

    def at(self, stamps_ns: np.ndarray) -> np.ndarray:
        """(M,4,4) poses at stamps within the span: positions linear, rotations slerped."""
        # relative nanoseconds to seconds: stamps since 1970 would lose microseconds as floats
        start = self.stamps_ns[0]
        return interpolate_poses(
            (self.stamps_ns - start) * 1e-9, self.poses, (np.asarray(stamps_ns, dtype=np.int64) - start) * 1e-9
        )


def read_odometry(reader, connections, topic: str) -> Odometry:
    stamps, poses, frames = [], [], set()
    for _, msg in _messages(reader, connections):
        stamps.append(_stamp_ns(msg.header))
        p, o = msg.pose.pose.position, msg.pose.pose.orientation
        poses.append([p.x, p.y, p.z, o.x, o.y, o.z, o.w])
        frames.add((_frame(msg.header.frame_id), _frame(msg.child_frame_id)))
    if not stamps:
        raise ValueError(f"--odometry topic {topic!r} holds no messages")
    if len(frames) > 1:
        raise ValueError(f"--odometry topic {topic!r} changes frames: {sorted(frames)}")
    values = np.array(poses, dtype=np.float64)
    norms = np.linalg.norm(values[:, 3:], axis=1)
    if not np.all(np.isfinite(values)) or np.any(np.abs(norms - 1.0) > 1e-3):
        raise ValueError(f"--odometry topic {topic!r} holds non-finite positions or non-unit orientations")
    stamps = np.array(stamps, dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    stamps, values = stamps[order], values[order]
    first = np.r_[True, np.diff(stamps) > 0]  # one pose per stamp: repeats must agree
    repeat = np.flatnonzero(~first)
    if len(repeat) and np.any(values[repeat] != values[repeat - 1]):
        stamp = int(stamps[repeat[np.argmax(np.any(values[repeat] != values[repeat - 1], axis=1))]])
        raise ValueError(f"--odometry topic {topic!r} holds two different poses stamped {stamp} ns")
    stamps, values = stamps[first], values[first]
    T = np.tile(np.eye(4), (len(stamps), 1, 1))
    T[:, :3, :3] = Rotation.from_quat(values[:, 3:]).as_matrix()
    T[:, :3, 3] = values[:, :3]
    return Odometry(stamps, T, frames.pop())


def _check_frames(frames: set, frame: str | None, vehicle: str, topic: str) -> str:
    """The sensor frame the points are in."""
    if frame is None:
        others = sorted(frames - {vehicle})
        if others:
            raise ValueError(
                f"--points topic {topic!r} is in frame {others[0]!r}, the odometry's child frame is "
                f"{vehicle!r}: pass --frame {others[0]} to place the sensor with TF"
            )
        return vehicle
    others = sorted(frames - {frame})
    if others:
        raise ValueError(f"--frame {frame!r}: the scans on {topic!r} are in frame {others[0]!r}")
    return frame


def read_mount(reader, vehicle: str, sensor: str) -> tuple[np.ndarray, str]:
    """T_vehicle_sensor chained from /tf_static and /tf (a /tf link must not move), and where
    it came from. ValueError naming --frame when TF does not connect the two frames."""
    links = {}  # (parent, child) -> (static, [T_parent_child, ...])
    for connection in reader.connections:
        if connection.topic not in TF_TOPICS or connection.msgtype != TF_MESSAGE:
            continue
        static = TF_TOPICS[connection.topic]
        for _, msg in _messages(reader, [connection]):
            for transform in msg.transforms:
                key = (_frame(transform.header.frame_id), _frame(transform.child_frame_id))
                t, r = transform.transform.translation, transform.transform.rotation
                T = np.full((4, 4), np.nan)  # a link that is no rigid transform: refused if on the path
                values = np.array([t.x, t.y, t.z, r.x, r.y, r.z, r.w], dtype=np.float64)
                if np.all(np.isfinite(values)) and abs(np.linalg.norm(values[3:]) - 1.0) <= 1e-3:
                    T = np.eye(4)
                    T[:3, :3] = Rotation.from_quat(values[3:]).as_matrix()
                    T[:3, 3] = values[:3]
                if key not in links or (static and not links[key][0]):
                    links[key] = (static, [])
                if links[key][0] == static:
                    links[key][1].append(T)
    path = _tf_path(links, vehicle, sensor)
    if path is None:
        known = sorted({f for key in links for f in key})
        raise ValueError(
            f"--frame {sensor!r}: TF (/tf_static, /tf) does not connect it to the odometry's child "
            f"frame {vehicle!r} (frames in TF: {', '.join(known) or 'none'})"
        )
    T_vehicle_sensor = np.eye(4)
    sources = set()
    for parent, child, forward in path:
        static, samples = links[(parent, child)]
        sources.add("/tf_static" if static else "/tf")
        if any(not np.all(np.isfinite(T)) for T in samples):
            raise ValueError(
                f"--frame {sensor!r}: the TF link {parent} -> {child} holds non-finite values or a "
                "quaternion that is not of unit length"
            )
        if (child, parent) in links:
            raise ValueError(
                f"--frame {sensor!r}: TF links {parent} -> {child} and {child} -> {parent} both exist; "
                "which one holds is ambiguous"
            )
        first = samples[0]
        for T in samples[1:]:
            moved = inverse(first) @ T
            if (
                np.abs(moved[:3, 3]).max() > _MOUNT_TOLERANCE
                or np.linalg.norm(Rotation.from_matrix(moved[:3, :3]).as_rotvec()) > _MOUNT_TOLERANCE
            ):
                raise ValueError(
                    f"--frame {sensor!r}: the TF link {parent} -> {child} moves during the bag; only a "
                    "fixed sensor mount is supported"
                )
        T_vehicle_sensor = T_vehicle_sensor @ (first if forward else inverse(first))
    T_vehicle_sensor = rigid_pose("T_vehicle_sensor", _orthonormal(T_vehicle_sensor))
    return T_vehicle_sensor, " + ".join(sorted(sources))


def _tf_path(links: dict, start: str, goal: str):
    """[(parent, child, forward)] from frame `start` to `goal` over TF links (either way)."""
    neighbours = defaultdict(list)
    for parent, child in links:
        neighbours[parent].append((child, (parent, child, True)))
        neighbours[child].append((parent, (parent, child, False)))
    previous = {start: None}
    queue = [start]
    while queue:
        frame = queue.pop(0)
        if frame == goal:
            path = []
            while previous[frame] is not None:
                frame, step = previous[frame]
                path.append(step)
            return path[::-1]
        for other, step in neighbours[frame]:
            if other not in previous:
                previous[other] = (frame, step)
                queue.append(other)
    return None


def _orthonormal(T: np.ndarray) -> np.ndarray:
    """T with its rotation re-orthonormalised (chained float products drift by ulps)."""
    out = T.copy()
    out[:3, :3] = Rotation.from_matrix(T[:3, :3]).as_matrix()
    return out
