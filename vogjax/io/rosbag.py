"""ROS bags (ROS 1 .bag, ROS 2 folders with sqlite3 or MCAP storage, bare .mcap/.db3 files) into
vogjax run files, read with `rosbags` (pure Python; no ROS installation needed).

    summary = import_bag("drive.bag", "drive.h5", points_topic="/velodyne_points",
                         odometry_topic="/odom", frame="velodyne")
    summary = import_bag("rgbd.bag", "rgbd.h5", depth_topic="/camera/depth/image_rect_raw",
                         odometry_topic="/odom", frame="camera_depth_optical_frame", stride=4)

Scans: sensor_msgs/PointCloud2 (fields x, y, z as float32 or float64, in the sensor frame;
per-point time, intensity and ring read where present: `vogjax.io.pointcloud2`),
sensor_msgs/LaserScan, or a depth camera's sensor_msgs/Image with its sensor_msgs/CameraInfo
(`vogjax.io.depth_image`). Poses: nav_msgs/Odometry, T_world_vehicle with world = its
header.frame_id and vehicle = its child_frame_id, interpolated to each scan's header stamp
(linear in position, slerp in rotation). Without `frame` the points must be in the vehicle frame
(a scan header naming another frame is an error); with `frame` (the sensor frame) its fixed
pose in the vehicle frame is chained from /tf_static (or /tf, where it must not move).

Motion compensation: a cloud with a per-point time field (`time`, `t` or `timestamp`, in the
layouts `vogjax.io.deskew` reads) is deskewed: each point is carried from the sensor's pose at
its firing time to the sensor's pose at the cloud's stamp, with the odometry interpolated at
both. The run stores the deskewed points in the scan's frame at its stamp, so the run format
and the mapper are those of any scan, and every end point lands where the point was when it
fired. A scan whose points fired outside the odometry's span is dropped (`sweep_outside_odometry`).
`deskew=False` imports the points at the stamp (as if fired all at once).

Each scan becomes one row of the run: origin and unit beam directions in the vehicle frame,
ranges, no_return, and where the source has them intensity and ring (optional per-beam fields
of the run). Beams: a PointCloud2 point is a return (non-finite or zero-length points, or ones
with a non-finite intensity, are invalid; below `min_intensity` they are dropped and counted
apart); a depth pixel holding a depth is a return (one without is invalid); a LaserScan range
is a return in [range_min, range_max], no return above range_max or +inf (free space is
cleared along it up to the map's max range, as OctoMap does), invalid when NaN or below
range_min (-inf included). Invalid beams are dropped and counted. A run holds B beams per scan
(B: the most valid beams of any scan); a scan with fewer is padded with copies of one of its own
beams (a return where it has one), which change no voxel (within one scan a voxel is updated
once), so padding never alters a map.

Scans are dropped, and counted by reason in the run's metadata (`import.dropped`), when they lie
outside the odometry's time span (no extrapolation), have no valid beam, or are not later than
the scan before them. A bag in which no scan survives is an error.

Metadata of the run (documented keys): `sensor` = "point_cloud", `sensor_config` (a
PointCloudConfig: message, beams, rate_hz, min_range_m, max_range_m), `T_vehicle_sensor`,
`source` (bag, storage, topics, message types, frames, where the mount came from; for a depth
camera its CameraInfo, stride and encoding) and `import` (counts; `fields`: every field of the
scans and what was done with it; `point_time`: the time field, its layout and whether the
scans were deskewed; `optional_fields`: the per-beam fields stored). `sensor_config.max_range_m`
is the sensor's reach for the mapper: LaserScan's largest range_max, or for a point cloud or a
depth image the farthest (deskewed) return unless `max_range_m` is given.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections import defaultdict
from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from vogjax.config.point_cloud import PointCloudConfig
from vogjax.config.sensing import MAX_BEAMS
from vogjax.geometry import interpolate_poses, inverse, rigid_pose
from vogjax.io.atomic import check_writable
from vogjax.io.dataset import MAX_RANGE_M, MAX_RING, DatasetWriter
from vogjax.io.depth_image import Camera, camera_from_info, check_pixels, depth_points
from vogjax.io.deskew import LAYOUTS, deskew_points, point_offsets
from vogjax.io.pointcloud2 import read_cloud
from vogjax.sensors.point_cloud import PointCloudSensor

POINT_CLOUD = "sensor_msgs/msg/PointCloud2"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
IMAGE = "sensor_msgs/msg/Image"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
TF_TOPICS = {"/tf_static": True, "tf_static": True, "/tf": False, "tf": False}  # topic -> static
BATCH_SCANS = 256
# Scans are interpolated between odometry poses at most this many median intervals apart (and
# at least this many seconds); scans in longer gaps are dropped, counted as in_odometry_gap.
ODOMETRY_GAP_FACTOR = 10.0
MIN_ODOMETRY_GAP_S = 1.0
BATCH_BEAMS = 1 << 22  # scans x beams per batch written: about 70 MB with padding
MAX_STRIDE = 1 << 16
_MIN_RANGE = 1e-6  # a point closer than this has no direction
_MOUNT_TOLERANCE = 1e-6  # a /tf mount that moves more than this (m, rad) is not fixed


@dataclasses.dataclass(frozen=True)
class ImportSummary:
    """What `import_bag` wrote.

    Attributes
    ----------
    path : Path
        The run file.
    scans, scans_read : int
        Scans written, and read from the topic.
    beams : int
        Beams per scan of the run.
    dropped : dict of str to int
        Scans dropped, by reason.
    invalid_beams : int
        Invalid beams dropped (of the scans written).
    padded_beams : int
        Copies added as padding.
    metadata : dict
        The run's metadata (`import.fields`, `import.point_time`: what was used and ignored).
    """

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
    """One scan's valid beams in the sensor frame.

    Attributes
    ----------
    stamp_ns : int
        Its header stamp.
    frame : str
        Its header frame.
    directions : (n, 3) ndarray of float64
        Unit beam directions.
    ranges : (n,) ndarray of float64
        Ranges, metres (NaN where no return).
    no_return : (n,) ndarray of bool
        Beams without a return.
    invalid : int
        Beams dropped as invalid.
    range_min, range_max : float or None
        LaserScan's.
    offsets_s : (n,) ndarray of float64 or None
        Each beam's firing time minus the stamp, seconds (a cloud with a per-point time field,
        when deskewing); None: every beam at the stamp.
    intensity : (n,) ndarray of float64 or None
        Each beam's intensity, where the source has one.
    ring : (n,) ndarray of int64 or None
        Each beam's ring, where the source has one.
    below_min_intensity : int
        Beams dropped below the minimum intensity.
    layout : str or None
        The per-point time layout found (a key of `vogjax.io.deskew.LAYOUTS`).
    """

    stamp_ns: int
    frame: str
    directions: np.ndarray
    ranges: np.ndarray
    no_return: np.ndarray
    invalid: int
    range_min: float | None = None  # LaserScan's
    range_max: float | None = None
    offsets_s: np.ndarray | None = None
    intensity: np.ndarray | None = None
    ring: np.ndarray | None = None
    below_min_intensity: int = 0
    layout: str | None = None


@dataclasses.dataclass(frozen=True)
class _Options:
    """What the caller asked for, checked."""

    scans_topic: str
    flag: str  # --points or --depth, as errors name it
    odometry_topic: str
    frame: str | None
    max_range_m: float | None
    progress: bool
    deskew: bool
    min_intensity: float | None
    camera_info_topic: str | None
    stride: int


def import_bag(
    bag: str | PathLike,
    out: str | PathLike,
    points_topic: str | None = None,
    odometry_topic: str | None = None,
    frame: str | None = None,
    max_range_m: float | None = None,
    progress: bool = True,
    *,
    depth_topic: str | None = None,
    camera_info_topic: str | None = None,
    stride: int = 1,
    deskew: bool = True,
    min_intensity: float | None = None,
) -> ImportSummary:
    """Convert a bag's scans and odometry into a run file at `out` (published whole, or not at all).

    Parameters
    ----------
    bag : str or os.PathLike
        A ROS 1 .bag, a ROS 2 bag folder, or an .mcap/.db3 file.
    out : str or os.PathLike
        The run file to write (its folder must exist).
    points_topic : str or None
        Topic of sensor_msgs/PointCloud2 or sensor_msgs/LaserScan (or give `depth_topic`).
    odometry_topic : str
        Topic of nav_msgs/Odometry: the vehicle's poses.
    frame : str or None, optional
        The sensor frame the scans are in; its mount on the odometry's child frame comes from
        /tf_static or /tf (None: the scans are in the child frame).
    max_range_m : float or None, optional
        The sensor's reach, metres (None: LaserScan's range_max, or the farthest return).
    progress : bool, optional
        Whether to show a progress bar.
    depth_topic : str or None, optional
        Topic of a depth camera's sensor_msgs/Image (16UC1 mm or 32FC1 m), instead of
        `points_topic`.
    camera_info_topic : str or None, optional
        Its sensor_msgs/CameraInfo topic (None: ``camera_info`` beside the depth topic).
    stride : int, optional
        Of a depth image, every `stride`-th pixel of every `stride`-th row.
    deskew : bool, optional
        Whether to deskew clouds that carry per-point times (False: points taken at the stamp).
    min_intensity : float or None, optional
        Points (or laser beams) of lower intensity are dropped and counted (None: all kept).

    Returns
    -------
    ImportSummary

    Raises
    ------
    ValueError
        Naming the argument (as its flag: --points, --depth, --camera-info, --stride,
        --min-intensity, --frame, --odometry) or the bag: a missing topic, a topic of the wrong
        type, a malformed message, frames TF does not connect, an unreadable or damaged bag, or
        no scan that can be imported. Nothing is written then.
    """
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    bag, out = Path(bag), Path(out)
    options = _options(
        points_topic,
        odometry_topic,
        frame,
        max_range_m,
        progress,
        depth_topic,
        camera_info_topic,
        stride,
        deskew,
        min_intensity,
    )
    if not bag.exists():
        raise ValueError(f"bag {str(bag)!r} does not exist")
    check_writable(out)  # before reading the whole bag
    if not out.parent.is_dir():
        raise ValueError(f"--out {str(out)!r}: folder {str(out.parent)!r} does not exist")
    try:
        with AnyReader([bag], default_typestore=get_typestore(Stores.LATEST)) as reader:
            return _import(reader, bag, out, options)
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


def _options(
    points_topic, odometry_topic, frame, max_range_m, progress, depth_topic, camera_info_topic, stride, deskew, minimum
) -> _Options:
    if (points_topic is None) == (depth_topic is None):
        raise ValueError("give one of points_topic (--points) and depth_topic (--depth)")
    if odometry_topic is None:
        raise ValueError("odometry_topic (--odometry) is required")
    if max_range_m is not None and (
        isinstance(max_range_m, bool) or not isinstance(max_range_m, (int, float)) or not 0 < max_range_m <= MAX_RANGE_M
    ):
        raise ValueError(f"max_range_m must be a number in (0, {MAX_RANGE_M:g}], got {max_range_m!r}")
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or not 1 <= stride <= MAX_STRIDE:
        raise ValueError(f"--stride must be an integer in [1, {MAX_STRIDE}], got {stride!r}")
    if depth_topic is None and (stride != 1 or camera_info_topic is not None):
        raise ValueError(f"--{'stride' if stride != 1 else 'camera-info'} applies to a depth image (--depth) only")
    if minimum is not None and (
        isinstance(minimum, bool) or not isinstance(minimum, (int, float)) or not math.isfinite(minimum)
    ):
        raise ValueError(f"--min-intensity must be a finite number, got {minimum!r}")
    if depth_topic is not None and minimum is not None:
        raise ValueError("--min-intensity applies to point clouds and laser scans: a depth image has no intensity")
    if not isinstance(deskew, bool):
        raise ValueError(f"deskew must be True or False, got {deskew!r}")
    if depth_topic is not None and camera_info_topic is None:
        camera_info_topic = depth_topic.rsplit("/", 1)[0] + "/camera_info"  # image_transport's convention
    return _Options(
        scans_topic=points_topic if depth_topic is None else depth_topic,
        flag="--points" if depth_topic is None else "--depth",
        odometry_topic=odometry_topic,
        frame=frame,
        max_range_m=None if max_range_m is None else float(max_range_m),
        progress=progress,
        deskew=deskew,
        min_intensity=None if minimum is None else float(minimum),
        camera_info_topic=camera_info_topic,
        stride=int(stride),
    )


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


def _import(reader, bag: Path, out: Path, options: _Options) -> ImportSummary:
    from tqdm import tqdm

    topic, flag = options.scans_topic, options.flag
    types = {IMAGE} if flag == "--depth" else {POINT_CLOUD, LASER_SCAN}
    scan_connections, message = _topic(reader, topic, flag, types)
    odometry_connections = _topic(reader, options.odometry_topic, "--odometry", {ODOMETRY})[0]
    camera = None
    if message == "Image":
        camera = read_camera(reader, options.camera_info_topic)
        check_pixels(camera.width, camera.height, options.stride, f"--depth topic {topic!r}")
    odometry = read_odometry(reader, odometry_connections, options.odometry_topic)
    world_frame, vehicle_frame = odometry.frames
    stream = _ScanStream(reader, scan_connections, message, options, camera)
    # pass 1: which scans survive, and how many beams the largest holds
    dropped = defaultdict(int)
    kept, stamps, frames, counts, invalid, below = [], [], set(), [], 0, 0  # kept: ordinals in the topic
    range_min, range_max, longest = np.inf, 0.0, 0.0
    span_s = [np.inf, -np.inf]  # firing time minus stamp, over the scans written
    scans_read = 0
    for ordinal, scan in enumerate(stream.scans()):
        scans_read += 1
        frames.add(scan.frame)
        fired = (0, 0) if scan.offsets_s is None or not len(scan.offsets_s) else _fired_ns(scan)
        if not odometry.covers(scan.stamp_ns):
            dropped["outside_odometry"] += 1
        elif not odometry.bridges(scan.stamp_ns):
            dropped["in_odometry_gap"] += 1
        elif len(scan.ranges) == 0:
            dropped["no_valid_beams"] += 1
        elif not (odometry.covers(scan.stamp_ns + fired[0]) and odometry.covers(scan.stamp_ns + fired[1])):
            dropped["sweep_outside_odometry"] += 1
        elif not odometry.bridges_span(scan.stamp_ns + fired[0], scan.stamp_ns + fired[1]):
            dropped["in_odometry_gap"] += 1
        elif stamps and scan.stamp_ns * 1e-9 <= stamps[-1] * 1e-9:  # as the run stores times
            dropped["stamp_not_increasing"] += 1
        else:
            kept.append(ordinal)
            invalid += scan.invalid  # of the scans written: a dropped scan's beams are not counted twice
            below += scan.below_min_intensity
            stamps.append(scan.stamp_ns)
            counts.append(len(scan.ranges))
            if scan.range_max is not None:
                range_min, range_max = min(range_min, scan.range_min), max(range_max, scan.range_max)
            returned = scan.ranges[~scan.no_return]
            if len(returned):
                longest = max(longest, float(returned.max()))
            if scan.offsets_s is not None and len(scan.offsets_s):
                span_s = [min(span_s[0], float(scan.offsets_s.min())), max(span_s[1], float(scan.offsets_s.max()))]
    if scans_read == 0:
        raise ValueError(f"{flag} topic {topic!r} holds no messages")
    declared = sum(int(getattr(c, "msgcount", 0) or 0) for c in scan_connections)
    if scans_read < declared:  # the reader skipped records it could not read
        raise _Damaged(f"topic {topic!r} declares {declared} messages, {scans_read} could be read")
    if not kept:
        raise ValueError(f"no scan on {topic!r} can be imported: {_reasons(dropped)}")
    if camera is not None and frames - {"", camera.frame}:
        raise ValueError(
            f"--camera-info topic {options.camera_info_topic!r} is in frame {camera.frame!r}, the images on "
            f"{topic!r} in {sorted(frames - {''})[0]!r}"
        )
    frame = None if options.frame is None else _frame(options.frame)
    if "" in frames:  # a scan with no frame_id: an unknown frame is no vehicle frame
        if camera is not None and camera.frame:  # the images' frame is the camera's
            frames = (frames - {""}) | {camera.frame}
        elif frame is None:
            raise ValueError(
                f"{flag} topic {topic!r} holds scans with no frame_id: pass --frame with the frame "
                f"their points are in (the odometry's child frame {vehicle_frame!r} if they are in it)"
            )
    sensor_frame = _check_frames(frames - {""}, frame, vehicle_frame, topic, flag)
    T_vehicle_sensor, mount = (
        (np.eye(4), "identity: points in the vehicle frame")
        if sensor_frame == vehicle_frame
        else read_mount(reader, vehicle_frame, sensor_frame)
    )
    beams = int(max(counts))
    if beams > MAX_BEAMS:
        raise ValueError(
            f"{flag} topic {topic!r}: a scan holds {beams} valid beams, more than the {MAX_BEAMS} a run file takes"
        )
    duration_s = (stamps[-1] - stamps[0]) * 1e-9
    deskewed = stream.layout is not None and span_s[0] <= span_s[1]

    def describe(longest_m: float) -> dict:
        # the sensor's reach: what the caller says, LaserScan's range_max, or the farthest return (cm up)
        reach = float(
            options.max_range_m
            or min(range_max if message == "LaserScan" else np.ceil(longest_m * 100 + 1) / 100, MAX_RANGE_M)
        )
        config = PointCloudConfig(
            message=message,
            beams=beams,
            rate_hz=float((len(kept) - 1) / duration_s) if duration_s > 0 else 10.0,
            min_range_m=float(range_min) if message == "LaserScan" and range_min < reach else 0.0,
            max_range_m=reach,
        )
        return PointCloudSensor(config, T_vehicle_sensor).metadata()

    source = {
        "bag": str(bag),
        "storage": "ros2" if reader.is2 else "ros1",
        "points_topic": topic,
        "points_type": f"sensor_msgs/{message}",
        "odometry_topic": options.odometry_topic,
        "frames": {"world": world_frame, "vehicle": vehicle_frame, "sensor": sensor_frame},
        "mount": mount,
    }
    if camera is not None:
        source["camera"] = {
            **camera.describe(),
            "camera_info_topic": options.camera_info_topic,
            "stride": options.stride,
            "encoding": sorted(stream.encodings),
        }
    optional = tuple(name for name in ("intensity", "ring") if name in stream.kept_fields)
    report = {
        "scans_read": scans_read,
        "scans_written": len(kept),
        "dropped": dict(dropped),
        "invalid_beams": invalid,
        "padded_beams": int(beams * len(kept) - sum(counts)),
        "odometry_messages": len(odometry.stamps_ns),
        "odometry_span_s": [odometry.stamps_ns[0] * 1e-9, odometry.stamps_ns[-1] * 1e-9],
        "fields": stream.fields,
        "point_time": stream.point_time(deskewed, span_s),
        "optional_fields": list(optional),
    }
    if options.min_intensity is not None:
        report["min_intensity"] = options.min_intensity
        report["below_min_intensity"] = below
    metadata = {**describe(longest), "source": source, "import": report}
    # pass 2: the kept scans (deskewed), padded, at their interpolated poses
    wanted = set(kept)
    rotation, origin = T_vehicle_sensor[:3, :3], T_vehicle_sensor[:3, 3]
    # every scan is padded to the largest: batches of at most BATCH_BEAMS beams bound the memory
    batch_scans = max(1, min(BATCH_SCANS, BATCH_BEAMS // beams))
    written, longest_written, lost = 0, 0.0, 0
    with (
        DatasetWriter(out, beams, metadata, truth=False, optional=optional) as writer,
        tqdm(total=len(kept), unit="scan", desc="importing", disable=not options.progress) as bar,
    ):
        rows = []
        for ordinal, scan in enumerate(stream.scans()):
            if ordinal not in wanted:
                continue
            written += 1
            if scan.offsets_s is not None:
                scan, dropped_here = _deskewed(scan, odometry, T_vehicle_sensor, topic, flag)
                lost += dropped_here
            returned = scan.ranges[~scan.no_return]
            if len(returned):
                longest_written = max(longest_written, float(returned.max()))
            rows.append(_padded(scan, beams, rotation))
            if len(rows) == batch_scans or written == len(kept):
                batch_ns = np.array([r[0] for r in rows], dtype=np.int64)
                extra = {name: np.stack([r[4][name] for r in rows]) for name in optional}
                writer.append(
                    time_s=batch_ns * 1e-9,
                    pose_nav=odometry.at(batch_ns),
                    sonar_origin=np.tile(origin, (len(rows), 1)).astype(np.float32),
                    sonar_directions=np.stack([r[1] for r in rows]),
                    ranges=np.stack([r[2] for r in rows]),
                    no_return=np.stack([r[3] for r in rows]),
                    # the bag's own rule: beams below range_min were dropped above, none is stored invalid
                    invalid=np.zeros((len(rows), beams), np.bool_),
                    **extra,
                )
                bar.update(len(rows))
                rows = []
        if deskewed:  # deskewing moves the returns: the reach and the counts are those written
            report["invalid_beams"] += lost
            report["invalid_after_deskew"] = lost
            report["padded_beams"] += lost
            metadata = {**describe(longest_written), "source": source, "import": report}
            writer.set_metadata(metadata)
    return ImportSummary(
        out,
        len(kept),
        scans_read,
        beams,
        dict(dropped),
        report["invalid_beams"],
        report["padded_beams"],
        metadata,
    )


def _fired_ns(scan: Scan) -> tuple[int, int]:
    """The earliest and latest firing time of a scan's beams, nanoseconds from its stamp (rounded out)."""
    return math.floor(float(scan.offsets_s.min()) * 1e9), math.ceil(float(scan.offsets_s.max()) * 1e9)


def _deskewed(scan: Scan, odometry: Odometry, T_vehicle_sensor: np.ndarray, topic: str, flag: str) -> tuple[Scan, int]:
    """The scan with its beams moved to the sensor's pose at the stamp, and how many beams were
    lost (a point deskewed onto the sensor, or past any sensor's reach)."""
    points = scan.directions * scan.ranges[:, None]
    start = odometry.stamps_ns[0]
    moved = deskew_points(
        points, scan.offsets_s, (scan.stamp_ns - start) * 1e-9, odometry.times_s, odometry.poses, T_vehicle_sensor
    )
    ranges = np.linalg.norm(moved, axis=1)
    valid = (ranges >= _MIN_RANGE) & (ranges <= MAX_RANGE_M)
    if not valid.any():
        raise ValueError(f"{flag} topic {topic!r}: the scan stamped {scan.stamp_ns} ns keeps no beam once deskewed")
    keep = lambda a: None if a is None else a[valid]  # noqa: E731
    moved, ranges = moved[valid], ranges[valid]
    out = dataclasses.replace(
        scan,
        directions=moved / ranges[:, None],
        ranges=ranges,
        no_return=scan.no_return[valid],
        offsets_s=None,
        intensity=keep(scan.intensity),
        ring=keep(scan.ring),
    )
    return out, int(np.count_nonzero(~valid))


def _padded(scan: Scan, beams: int, rotation: np.ndarray):
    """(stamp, directions (B,3) in the vehicle frame, ranges (B,), no_return (B,), optional
    fields {name: (B,)}): the scan's beams, then copies of its first return (or first beam) up to B."""
    count = len(scan.ranges)
    returns = np.flatnonzero(~scan.no_return)
    copy = returns[0] if len(returns) else 0
    index = np.r_[np.arange(count), np.full(beams - count, copy)]
    directions = (scan.directions[index] @ rotation.T).astype(np.float32)
    optional = {}
    if scan.intensity is not None:
        optional["intensity"] = scan.intensity[index].astype(np.float32)
    if scan.ring is not None:
        optional["ring"] = scan.ring[index].astype(np.uint16)
    return scan.stamp_ns, directions, scan.ranges[index].astype(np.float32), scan.no_return[index], optional


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


class _ScanStream:
    """The scans of a topic, parsed alike on every pass, and what its messages must agree on:
    the fields a cloud's points carry and the layout of their times (fixed by the first cloud
    that has a valid point), a depth camera's encodings."""

    def __init__(self, reader, connections: list, message: str, options: _Options, camera: Camera | None):
        self.reader, self.connections, self.message, self.options = reader, connections, message, options
        self.camera = camera
        try:
            self.rays = None if camera is None else camera.rays(options.stride)
        except ValueError as error:  # a distortion that does not invert over the image
            raise ValueError(f"--camera-info topic {options.camera_info_topic!r}: {error}") from None
        self.layout: str | None = None
        self.fields: dict[str, dict[str, str]] = {}
        self.kept_fields: set[str] = set()
        self.encodings: set[str] = set()
        self._signature = None
        self._time: tuple[str, str] | None = None  # (field, type) of the per-point time read

    def scans(self) -> Iterator[Scan]:
        for _, msg in _messages(self.reader, self.connections):
            yield self._parse(msg)

    def _parse(self, msg) -> Scan:
        topic, flag, options = self.options.scans_topic, self.options.flag, self.options
        if self.message == "LaserScan":
            scan = laser_beams(msg, topic, min_intensity=options.min_intensity)
            signature = scan.intensity is not None
            if not self.fields:
                self.fields = {
                    "ranges": {"type": "float32[]", "use": "range"},
                    "intensities": {"type": "float32[]", "use": "intensity" if signature else "ignored (empty)"},
                }
        elif self.message == "Image":
            self.encodings.add(str(msg.encoding))
            where = f"--depth topic {topic!r}"
            points = depth_points(msg, self.camera, self.rays, options.stride, where)
            scan, signature = _point_beams(points, _stamp_ns(msg.header), _frame(msg.header.frame_id)), None
            self.fields = {"data": {"type": ", ".join(sorted(self.encodings)), "use": "depth"}}
        else:
            where = f"{flag} topic {topic!r}"
            cloud = read_cloud(msg, where, use_time=options.deskew)
            scan = _point_beams(
                cloud.points,
                _stamp_ns(msg.header),
                _frame(msg.header.frame_id),
                intensity=cloud.intensity,
                ring=cloud.ring,
                time=cloud.time,
                time_datatype=cloud.time_datatype,
                layout=self.layout,
                min_intensity=options.min_intensity,
                where=f"{where}: PointCloud2 field",
                time_field=cloud.time_field,
            )
            signature = {name: (f["type"], f["use"]) for name, f in cloud.fields.items() if f["use"] != "ignored"}
            for name, field in cloud.fields.items():
                self.fields.setdefault(name, field)
            if cloud.time_field is not None:
                self._time = (cloud.time_field, cloud.fields[cloud.time_field]["type"])
            if self.layout is None and scan.layout is not None:
                self.layout = scan.layout
        if options.min_intensity is not None and scan.intensity is None:
            what = "field intensity" if self.message == "PointCloud2" else "intensities"
            raise ValueError(f"--min-intensity: the {self.message} messages on {topic!r} have no {what}")
        if self._signature is None:
            self._signature = signature
            present = (("intensity", scan.intensity), ("ring", scan.ring))
            self.kept_fields = {name for name, values in present if values is not None}
        elif signature != self._signature:
            raise ValueError(
                f"{flag} topic {topic!r}: the message stamped {scan.stamp_ns} ns carries other fields "
                f"({_used(signature)}) than the topic's first ({_used(self._signature)})"
            )
        return scan

    def point_time(self, deskewed: bool, span_s: list[float]) -> dict[str, Any]:
        """What `import.point_time` records: the time field, its layout, whether scans were deskewed."""
        if self.message != "PointCloud2":
            return {"deskewed": False, "reason": f"a {self.message} has no per-point times"}
        if self._time is None:
            named = [n for n, f in self.fields.items() if f["use"].startswith("ignored (deskewing off")]
            if named:
                return {"field": named[0], "deskewed": False, "reason": "deskewing turned off (--no-deskew)"}
            return {"deskewed": False, "reason": "the clouds have no per-point time field (time, t or timestamp)"}
        field, kind = self._time
        out = {"field": field, "type": kind, "deskewed": deskewed}
        if self.layout is not None:
            out |= {"layout": self.layout, "meaning": LAYOUTS[self.layout]}
        if deskewed:
            out["offsets_s"] = span_s
        return out


def _used(signature) -> str:
    if not isinstance(signature, dict):
        return "intensities" if signature else "no intensities"
    return ", ".join(f"{name} ({kind}: {use})" for name, (kind, use) in signature.items())


def _point_beams(
    points: np.ndarray,
    stamp_ns: int,
    frame: str,
    intensity: np.ndarray | None = None,
    ring: np.ndarray | None = None,
    time: np.ndarray | None = None,
    time_datatype: int | None = None,
    layout: str | None = None,
    min_intensity: float | None = None,
    where: str = "",
    time_field: str | None = None,
) -> Scan:
    """The valid beams of points (N,3) measured from the sensor origin, with their per-point
    fields: non-finite, zero-length or farther than any sensor reaches (or of non-finite
    intensity) is invalid; below `min_intensity`, dropped apart."""
    ranges = np.linalg.norm(points, axis=1)
    valid = np.isfinite(ranges) & (ranges >= _MIN_RANGE) & (ranges <= MAX_RANGE_M)
    if intensity is not None:
        valid &= np.isfinite(intensity)
    invalid = int(np.count_nonzero(~valid))
    below = 0
    if min_intensity is not None and intensity is not None:
        dim = valid & (intensity < min_intensity)
        below = int(np.count_nonzero(dim))
        valid &= ~dim
    points, ranges = points[valid], ranges[valid]
    offsets, found = None, None
    if time is not None:
        offsets, found = point_offsets(time[valid], time_datatype, stamp_ns, f"{where} {time_field}", layout)
        found = found if len(offsets) else None
    if ring is not None:
        ring = ring[valid]
        if len(ring) and (ring.min() < 0 or ring.max() > MAX_RING):
            raise ValueError(f"{where} ring holds {int(ring.min())} to {int(ring.max())}, not rings in [0, {MAX_RING}]")
    return Scan(
        stamp_ns,
        frame,
        points / ranges[:, None],
        ranges,
        np.zeros(len(ranges), dtype=bool),
        invalid,
        offsets_s=offsets,
        intensity=None if intensity is None else intensity[valid],
        ring=ring,
        below_min_intensity=below,
        layout=found,
    )


def cloud_beams(msg: Any, topic: str = "", deskew: bool = True, layout: str | None = None) -> Scan:
    """The valid beams of a sensor_msgs/PointCloud2 (ranges from the sensor origin).

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud2
        The cloud.
    topic : str, optional
        Its topic, for error messages.
    deskew : bool, optional
        Whether to read its per-point times (`Scan.offsets_s`).
    layout : str or None, optional
        The time layout the topic's earlier clouds had (None: found from this cloud).

    Returns
    -------
    Scan
        Its valid points as beams, with their offsets, intensity and ring where present.

    Raises
    ------
    ValueError
        Naming the topic when the cloud is malformed (see `vogjax.io.pointcloud2.read_cloud`)
        or its times fit no known layout (`vogjax.io.deskew.point_offsets`).
    """
    where = f"--points topic {topic!r}"
    cloud = read_cloud(msg, where, use_time=deskew)
    return _point_beams(
        cloud.points,
        _stamp_ns(msg.header),
        _frame(msg.header.frame_id),
        intensity=cloud.intensity,
        ring=cloud.ring,
        time=cloud.time,
        time_datatype=cloud.time_datatype,
        layout=layout,
        where=f"{where}: PointCloud2 field",
        time_field=cloud.time_field,
    )


def cloud_points(msg: Any, topic: str = "") -> npt.NDArray[np.float64]:
    """x, y, z of every point of a PointCloud2.

    Parameters
    ----------
    msg : sensor_msgs/msg/PointCloud2
        The cloud.
    topic : str, optional
        Its topic, for error messages.

    Returns
    -------
    (N, 3) ndarray of float64
        Every point, NaN ones included.

    Raises
    ------
    ValueError
        Naming the topic when the cloud is malformed (`vogjax.io.pointcloud2.read_cloud`).
    """
    return read_cloud(msg, f"--points topic {topic!r}", use_time=False).points


def read_camera(reader, topic: str) -> Camera:
    """The camera of a depth topic: the CameraInfo messages of `topic`, which must agree.

    Parameters
    ----------
    reader : rosbags.highlevel.AnyReader
        The open bag.
    topic : str
        The sensor_msgs/CameraInfo topic.

    Returns
    -------
    Camera

    Raises
    ------
    ValueError
        Naming --camera-info when the topic is missing, of another type, empty, or its messages
        disagree or describe a camera vogjax does not model (`camera_from_info`).
    """
    connections = _topic(reader, topic, "--camera-info", {CAMERA_INFO})[0]
    where = f"--camera-info topic {topic!r}"
    camera = None
    for _, msg in _messages(reader, connections):
        this = camera_from_info(msg, where)
        if camera is None:
            camera = this
        elif this.describe() != camera.describe():
            raise ValueError(
                f"{where}: the camera changes during the bag ({this.describe()}, first {camera.describe()})"
            )
    if camera is None:
        raise ValueError(f"{where} holds no messages")
    return camera


def laser_beams(msg: Any, topic: str = "", min_intensity: float | None = None) -> Scan:
    """The valid beams of a sensor_msgs/LaserScan (directions in its x-y plane).

    Parameters
    ----------
    msg : sensor_msgs/msg/LaserScan
        The scan.
    topic : str, optional
        Its topic, for error messages.
    min_intensity : float or None, optional
        Returns of lower intensity are dropped (`Scan.below_min_intensity`); None: all kept.

    Returns
    -------
    Scan
        Its valid beams, with their intensities where the scan carries one per range.

    Raises
    ------
    ValueError
        Naming the topic when the scan's limits or angles are not finite and ordered, or it
        carries intensities but not one per range.
    """
    ranges = np.asarray(msg.ranges, dtype=np.float64)
    intensities = np.asarray(msg.intensities, dtype=np.float64)
    if len(intensities) not in (0, len(ranges)):
        raise ValueError(
            f"--points topic {topic!r}: LaserScan has {len(ranges)} ranges but {len(intensities)} intensities"
        )
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
        # and a zero (what many drivers write for "no measurement" beside range_min 0) is no
        # return at all: below _MIN_RANGE, as a cloud's point at the sensor
        invalid = np.isnan(ranges) | (ranges < max(low, _MIN_RANGE)) | (~no_return & (ranges > MAX_RANGE_M))
    dim = np.zeros(len(ranges), dtype=bool)
    if len(intensities):
        invalid |= ~no_return & ~np.isfinite(intensities)
        intensities = np.where(np.isfinite(intensities), intensities, 0.0)  # a no-return beam's means nothing
        if min_intensity is not None:  # a return too faint to trust; a "no return" clears free space still
            dim = ~invalid & ~no_return & (intensities < min_intensity)
    keep = ~invalid & ~dim
    return Scan(
        _stamp_ns(msg.header),
        _frame(msg.header.frame_id),
        directions[keep],
        np.where(no_return, np.nan, ranges)[keep],
        no_return[keep],
        int(np.count_nonzero(invalid)),
        low,
        high,
        intensity=intensities[keep] if len(intensities) else None,
        below_min_intensity=int(np.count_nonzero(dim)),
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
        """Whether a stamp (ns) lies within the odometry's span."""
        return bool(self.stamps_ns[0] <= stamp_ns <= self.stamps_ns[-1])

    @functools.cached_property
    def times_s(self) -> np.ndarray:
        """(N,) seconds since the first pose: the clock `at` interpolates on."""
        return (self.stamps_ns - self.stamps_ns[0]) * 1e-9

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

    def bridges_span(self, first_ns: int, last_ns: int) -> bool:
        """Whether every gap between the poses around a covered span is bridged (see `bridges`)."""
        lo = max(int(np.searchsorted(self.stamps_ns, first_ns, side="right")) - 1, 0)
        hi = int(np.searchsorted(self.stamps_ns, last_ns, side="left"))
        return bool(np.all(np.diff(self.stamps_ns[lo : hi + 1]) <= self.max_gap_ns))

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


def _check_frames(frames: set, frame: str | None, vehicle: str, topic: str, flag: str = "--points") -> str:
    """The sensor frame the points are in."""
    if frame is None:
        others = sorted(frames - {vehicle})
        if others:
            raise ValueError(
                f"{flag} topic {topic!r} is in frame {others[0]!r}, the odometry's child frame is "
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
