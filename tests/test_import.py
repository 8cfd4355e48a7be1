"""`vogjax import`: bags written with rosbags' writers (ROS 1, ROS 2 with MCAP and sqlite3),
point clouds and laser scans; every beam must land where the bag put it."""

import json

import numpy as np
import pytest

import vogjax as vj
from vogjax import cli
from vogjax.config.point_cloud import PointCloudConfig
from vogjax.io.dataset import Dataset
from vogjax.io.rosbag import cloud_points, import_bag
from vogjax.sensors.point_cloud import PointCloudSensor

rosbags = pytest.importorskip("rosbags")
from rosbags.rosbag1 import Writer as Writer1  # noqa: E402
from rosbags.rosbag2 import StoragePlugin  # noqa: E402
from rosbags.rosbag2 import Writer as Writer2  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

T0_NS = 1_700_000_000_000_000_000  # bags carry wall-clock stamps
ODOM_HZ, SCAN_HZ = 20.0, 10.0
MOUNT = np.array([0.3, -0.1, 0.5])  # lidar in base_link, rotated below


# ------------------------------------------------------------------ reference math (independent of vogjax)
def quat_matrix(q):
    """Rotation matrix of (x, y, z, w)."""
    x, y, z, w = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def slerp(q0, q1, u):
    dot = float(np.dot(q0, q1))
    if dot < 0:
        q1, dot = -q1, -dot
    theta = np.arccos(min(dot, 1.0))
    if theta < 1e-12:
        return q0
    return (np.sin((1 - u) * theta) * q0 + np.sin(u * theta) * q1) / np.sin(theta)


def axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[axis * np.sin(angle / 2), np.cos(angle / 2)]


def odometry_samples(count):
    """Stamps (ns) and poses (position, quaternion xyzw) of a vehicle turning and climbing."""
    t = np.arange(count) / ODOM_HZ
    stamps = T0_NS + np.round(t * 1e9).astype(np.int64)
    positions = np.stack([2.0 * np.sin(0.4 * t), 1.5 * t, 0.2 * t**2], axis=1) + [10.0, -5.0, -20.0]
    quats = np.array([axis_angle([0.2, 0.3, 1.0], 0.9 * s + 0.3) for s in t])
    return stamps, positions, quats


def pose_at(stamps, positions, quats, stamp):
    """4x4 T_world_base at `stamp`: linear position, slerp."""
    i = np.searchsorted(stamps, stamp, side="right") - 1
    i = min(i, len(stamps) - 2)
    u = (stamp - stamps[i]) / (stamps[i + 1] - stamps[i])
    T = np.eye(4)
    T[:3, :3] = quat_matrix(slerp(quats[i], quats[i + 1], u))
    T[:3, 3] = positions[i] + u * (positions[i + 1] - positions[i])
    return T


def mount():
    T = np.eye(4)
    T[:3, :3] = quat_matrix(axis_angle([1.0, 0.5, 0.0], 0.4))
    T[:3, 3] = MOUNT
    return T


# ------------------------------------------------------------------ bag writing
class Messages:
    def __init__(self, ros1: bool):
        self.ros1 = ros1
        self.store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        if ros1:  # Noetic's store lacks tf2_msgs
            self.store.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
            )
        self.t = self.store.types

    def header(self, stamp_ns, frame):
        stamp = self.t["builtin_interfaces/msg/Time"](sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9))
        extra = {"seq": 0} if self.ros1 else {}
        return self.t["std_msgs/msg/Header"](**extra, stamp=stamp, frame_id=frame)

    def odometry(self, stamp_ns, position, quat):
        g = self.t
        pose = g["geometry_msgs/msg/Pose"](
            position=g["geometry_msgs/msg/Point"](*position), orientation=g["geometry_msgs/msg/Quaternion"](*quat)
        )
        twist = g["geometry_msgs/msg/Twist"](
            linear=g["geometry_msgs/msg/Vector3"](0, 0, 0), angular=g["geometry_msgs/msg/Vector3"](0, 0, 0)
        )
        return g["nav_msgs/msg/Odometry"](
            header=self.header(stamp_ns, "odom"),
            child_frame_id="base_link",
            pose=g["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=g["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
        )

    def cloud(self, stamp_ns, frame, points, float64=False):
        """x, y, z plus an intensity field and padding, so offsets and point_step matter."""
        kind = "<f8" if float64 else "<f4"
        size = 8 if float64 else 4
        dtype = np.dtype(
            {
                "names": ["intensity", "x", "y", "z"],
                "formats": ["<f4", kind, kind, kind],
                "offsets": [0, 4, 4 + size, 4 + 2 * size],
                "itemsize": 4 + 3 * size + 4,
            }
        )
        rows = np.zeros(len(points), dtype=dtype)
        rows["x"], rows["y"], rows["z"] = points.T
        Field = self.t["sensor_msgs/msg/PointField"]
        code = 8 if float64 else 7
        fields = [Field(name="intensity", offset=0, datatype=7, count=1)] + [
            Field(name=n, offset=4 + i * size, datatype=code, count=1) for i, n in enumerate("xyz")
        ]
        return self.t["sensor_msgs/msg/PointCloud2"](
            header=self.header(stamp_ns, frame),
            height=1,
            width=len(points),
            fields=fields,
            is_bigendian=False,
            point_step=dtype.itemsize,
            row_step=dtype.itemsize * len(points),
            data=np.frombuffer(rows.tobytes(), dtype=np.uint8),
            is_dense=False,
        )

    def laser(self, stamp_ns, frame, ranges, angle_min, increment, range_min, range_max):
        return self.t["sensor_msgs/msg/LaserScan"](
            header=self.header(stamp_ns, frame),
            angle_min=angle_min,
            angle_max=angle_min + increment * (len(ranges) - 1),
            angle_increment=increment,
            time_increment=0.0,
            scan_time=0.1,
            range_min=range_min,
            range_max=range_max,
            ranges=np.asarray(ranges, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )

    def tf(self, stamp_ns, parent, child, T):
        g = self.t
        q = _quat_of(T[:3, :3])
        transform = g["geometry_msgs/msg/Transform"](
            translation=g["geometry_msgs/msg/Vector3"](*T[:3, 3]), rotation=g["geometry_msgs/msg/Quaternion"](*q)
        )
        stamped = g["geometry_msgs/msg/TransformStamped"](
            header=self.header(stamp_ns, parent), child_frame_id=child, transform=transform
        )
        return g["tf2_msgs/msg/TFMessage"](transforms=[stamped])


def _quat_of(R):
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()


def write_bag(path, kind, messages):
    """messages: [(topic, msgtype, stamp_ns, message)]; kind: "ros1", "mcap" or "sqlite3"."""
    m = Messages(kind == "ros1")
    if kind == "ros1":
        writer = Writer1(path)
    else:
        writer = Writer2(
            path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        )
    with writer:
        connections = {}
        for topic, msgtype, stamp, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=m.store)
            data = (
                m.store.serialize_ros1(message, msgtype) if kind == "ros1" else m.store.serialize_cdr(message, msgtype)
            )
            writer.write(connections[topic], int(stamp), data)
    return path


def cloud_bag(path, kind, scans=12, frame="lidar", float64=False, with_tf=True, seed=0, reach=30.0):
    """A bag of point clouds in `frame`, odometry of base_link in odom, the mount in /tf_static.
    Returns the bag and per kept scan (stamp, points in the sensor frame incl. invalid ones)."""
    rng = np.random.default_rng(seed)
    m = Messages(kind == "ros1")
    o_stamps, positions, quats = odometry_samples(int(ODOM_HZ * scans / SCAN_HZ) + 2)
    messages = []
    if with_tf:
        messages.append(("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS, m.tf(T0_NS, "base_link", frame, mount())))
    clouds = []
    # scan stamps: one before the odometry starts (dropped), the rest between odometry samples
    scan_stamps = [T0_NS - 30_000_000] + [T0_NS + 7_000_000 + int(k * 1e9 / SCAN_HZ) for k in range(scans - 1)]
    events = [(s, "odom", i) for i, s in enumerate(o_stamps)] + [(s, "scan", k) for k, s in enumerate(scan_stamps)]
    for stamp, what, index in sorted(events, key=lambda e: (e[0], e[1])):
        if what == "odom":
            message = m.odometry(stamp, positions[index], quats[index])
            messages.append(("/odom", "nav_msgs/msg/Odometry", stamp, message))
            continue
        count = int(rng.integers(20, 60))
        directions = rng.normal(size=(count, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        points = directions * rng.uniform(0.5, reach, (count, 1))
        points[rng.random(count) < 0.1] = np.nan  # invalid points of a non-dense cloud
        if index == 3:
            points[:] = np.nan  # a scan without a valid point
        messages.append(("/points", "sensor_msgs/msg/PointCloud2", stamp, m.cloud(stamp, frame, points, float64)))
        clouds.append((stamp, points))
    write_bag(path, kind, messages)
    return path, (o_stamps, positions, quats), clouds


def beams_of(run_path):
    """Per scan of a run: time, world origin, world endpoints (B,3), no_return (B,)."""
    with Dataset(run_path) as ds:
        out = []
        for batch in ds.batches(100):
            max_range = 50.0
            origins, ends = batch.world(batch.pose_nav, max_range)
            for s in range(len(batch)):
                out.append((batch.time_s[s], origins[s], ends[s], batch.no_return[s], batch.ranges[s]))
        return out, ds.metadata, ds.has_truth


# ------------------------------------------------------------------ tests
@pytest.mark.parametrize("kind, float64", [("ros1", False), ("mcap", True), ("sqlite3", False)])
def test_point_cloud_beams_land_where_the_bag_put_them(tmp_path, kind, float64):
    bag, odom, clouds = cloud_bag(tmp_path / ("run.bag" if kind == "ros1" else "bag2"), kind, float64=float64)
    summary = import_bag(bag, tmp_path / "run.h5", "/points", "/odom", frame="lidar", progress=False)
    scans, metadata, has_truth = beams_of(tmp_path / "run.h5")
    assert not has_truth
    # the scan before the odometry and the empty one are dropped, counted by reason
    assert summary.dropped == {"outside_odometry": 1, "no_valid_beams": 1}
    kept = [(s, p) for s, p in clouds if s >= odom[0][0] and np.isfinite(p).any()]
    assert len(scans) == len(kept) == summary.scans
    beams = max(np.isfinite(p).all(axis=1).sum() for _, p in kept)
    assert summary.beams == beams and all(len(s[2]) == beams for s in scans)
    T_base_lidar = mount()
    for (stamp, points), (time_s, origin, ends, no_return, _) in zip(kept, scans):
        assert time_s == pytest.approx(stamp * 1e-9, abs=1e-6)
        T = pose_at(*odom, stamp) @ T_base_lidar
        valid = points[np.isfinite(points).all(axis=1)]
        expected = valid @ T[:3, :3].T + T[:3, 3]
        n = len(valid)
        np.testing.assert_allclose(ends[:n], expected, atol=2e-5 * (1 + np.abs(expected).max()))
        np.testing.assert_allclose(origin, T[:3, 3], atol=1e-5)
        assert not no_return.any()
        # padding: exact copies of one of the scan's own beams
        for pad in ends[n:]:
            assert np.any(np.all(ends[:n] == pad, axis=1))
    assert metadata["sensor"] == "point_cloud" and metadata["sensor_config"]["beams"] == beams
    assert metadata["source"]["frames"] == {"world": "odom", "vehicle": "base_link", "sensor": "lidar"}
    assert metadata["source"]["mount"] == "/tf_static"
    np.testing.assert_allclose(metadata["T_vehicle_sensor"], T_base_lidar, atol=1e-9)
    farthest = max(np.linalg.norm(p[np.isfinite(p).all(axis=1)], axis=1).max() for _, p in kept)
    assert farthest <= metadata["sensor_config"]["max_range_m"] <= farthest + 0.02
    assert metadata["import"]["dropped"] == summary.dropped and "scene" not in metadata
    # the sensor the metadata describes (what vj.sensors.from_metadata builds once registered)
    sensor = PointCloudSensor(PointCloudConfig.from_dict(metadata["sensor_config"]), metadata["T_vehicle_sensor"])
    assert sensor.kind == metadata["sensor"] and sensor.max_range_m == metadata["sensor_config"]["max_range_m"]


def test_organised_big_endian_clouds_with_padded_rows_are_read_point_for_point():
    m = Messages(False)
    rng = np.random.default_rng(3)
    points = rng.normal(size=(2, 5, 3))
    dtype = np.dtype({"names": list("xyz"), "formats": [">f8"] * 3, "offsets": [16, 0, 8], "itemsize": 28})
    rows = np.zeros((2, 5), dtype=dtype)
    for axis, name in enumerate("xyz"):
        rows[name] = points[..., axis]
    data = np.concatenate([np.r_[np.frombuffer(row.tobytes(), np.uint8), np.zeros(12, np.uint8)] for row in rows])
    Field = m.t["sensor_msgs/msg/PointField"]
    msg = m.t["sensor_msgs/msg/PointCloud2"](
        header=m.header(T0_NS, "lidar"),
        height=2,
        width=5,
        is_bigendian=True,
        point_step=28,
        row_step=5 * 28 + 12,
        fields=[Field(name=n, offset=o, datatype=8, count=1) for n, o in (("x", 16), ("y", 0), ("z", 8))],
        data=data,
        is_dense=True,
    )
    np.testing.assert_array_equal(cloud_points(msg), points.reshape(-1, 3))
    short = m.t["sensor_msgs/msg/PointCloud2"](
        **{
            **{
                f: getattr(msg, f)
                for f in ("header", "height", "width", "fields", "is_bigendian", "point_step", "row_step", "is_dense")
            },
            "data": data[:-20],
        }
    )
    with pytest.raises(ValueError, match="'/p': PointCloud2 is malformed"):
        cloud_points(short, "/p")


def test_padding_never_changes_the_map(tmp_path):
    bag, odom, clouds = cloud_bag(tmp_path / "run.bag", "ros1")
    import_bag(bag, tmp_path / "run.h5", "/points", "/odom", frame="lidar", progress=False)
    scans, metadata, _ = beams_of(tmp_path / "run.h5")
    cfg = vj.MapConfig(voxel_size=0.5, max_range=40.0)
    padded, real = vj.VoxelMap(cfg), vj.VoxelMap(cfg)
    kept = [p for s, p in clouds if s >= odom[0][0] and np.isfinite(p).any()]
    for (_, origin, ends, _, _), points in zip(scans, kept):
        padded.integrate_scan(origin, ends)
        real.integrate_scan(origin, ends[: np.isfinite(points).all(axis=1).sum()])
    (c1, v1), (c2, v2) = padded.voxels(), real.voxels()
    assert len(v1) > 1000
    np.testing.assert_array_equal(c1, c2)
    np.testing.assert_array_equal(v1, v2)


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_laser_scans_keep_returns_and_no_returns_and_drop_invalid_beams(tmp_path, kind):
    m = Messages(kind == "ros1")
    o_stamps, positions, quats = odometry_samples(30)
    messages = [
        ("/odom", "nav_msgs/msg/Odometry", s, m.odometry(s, p, q)) for s, p, q in zip(o_stamps, positions, quats)
    ]
    rng = np.random.default_rng(4)
    scans = []
    for k in range(8):
        stamp = T0_NS + 13_000_000 + k * 150_000_000
        ranges = rng.uniform(0.5, 8.0, 40).astype(np.float32)
        ranges[[1, 7]] = np.inf  # no return
        ranges[5] = 9.5  # beyond range_max: no return
        ranges[[2, 11]] = np.nan  # invalid
        ranges[3] = 0.05  # below range_min: invalid
        ranges[4] = -np.inf  # too close: invalid
        messages.append(
            ("/scan", "sensor_msgs/msg/LaserScan", stamp, m.laser(stamp, "base_link", ranges, -1.2, 0.06, 0.1, 9.0))
        )
        scans.append((stamp, ranges))
    # a second scan with the last one's stamp: not later than it, dropped
    messages.append(
        (
            "/scan",
            "sensor_msgs/msg/LaserScan",
            stamp + 1,
            m.laser(stamp, "base_link", ranges[::-1].copy(), -1.2, 0.06, 0.1, 9.0),
        )
    )
    bag = write_bag(
        tmp_path / ("scan.bag" if kind == "ros1" else "scan_bag"), kind, sorted(messages, key=lambda x: x[2])
    )
    out = tmp_path / "scan.h5"
    assert cli.main(["import", str(bag), "--points", "/scan", "--odometry", "/odom", "--out", str(out), "--quiet"]) == 0
    rows, metadata, _ = beams_of(out)
    assert len(rows) == 8 and metadata["sensor_config"]["max_range_m"] == pytest.approx(9.0)
    assert metadata["sensor_config"]["min_range_m"] == pytest.approx(0.1)
    assert metadata["import"]["dropped"] == {"stamp_not_increasing": 1}
    # the invalid beams of the 8 scans written (the dropped duplicate's are not counted)
    assert metadata["import"]["invalid_beams"] == 8 * 4 and metadata["source"]["mount"].startswith("identity")
    angles = -1.2 + 0.06 * np.arange(40)
    for (stamp, ranges), (_, origin, ends, no_return, stored) in zip(scans, rows):
        keep = ~(np.isnan(ranges) | (ranges < 0.1))
        assert len(stored) == keep.sum()  # every scan has the same valid beams: no padding
        T = pose_at(o_stamps, positions, quats, stamp)
        expected_no_return = ranges[keep] > 9.0
        np.testing.assert_array_equal(no_return, expected_no_return)
        local = np.stack([np.cos(angles), np.sin(angles), np.zeros(40)], axis=1)[keep]
        hits = local[~expected_no_return] * ranges[keep][~expected_no_return, None]
        np.testing.assert_allclose(ends[~no_return], hits @ T[:3, :3].T + T[:3, 3], atol=1e-5)
        # no-return beams head the right way, past the max range
        heading = (ends[no_return] - origin) / np.linalg.norm(ends[no_return] - origin, axis=1, keepdims=True)
        np.testing.assert_allclose(heading, local[expected_no_return] @ T[:3, :3].T, atol=1e-6)


def test_imported_run_maps_and_the_report_skips_ground_truth(tmp_path, capsys):
    bag, _, _ = cloud_bag(tmp_path / "long.bag", "ros1", scans=40, reach=4.0)
    run = tmp_path / "long.h5"
    import_bag(bag, run, "/points", "/odom", frame="lidar", progress=False)
    (tmp_path / "s.toml").write_text(
        "[map]\nvoxel_size = 0.2\nmax_range = 6.0\n[pipeline]\nscans_per_submap = 10\n[timing]\nevery_submaps = 0\n"
    )
    assert (
        cli.main(["map", str(run), "--out", str(tmp_path / "maps"), "--config", str(tmp_path / "s.toml"), "--quiet"])
        == 0
    )
    report = json.loads((tmp_path / "maps" / "long" / "report.json").read_text())
    assert report["scene"] is None and report["scans"] == 38 and report["submaps"] == 4
    assert all(v is None for v in report["auc"].values()) and all(v is None for v in report["rmse_m"].values())
    assert report["trajectory_rmse_m"] == {}  # no true poses
    table = np.genfromtxt(tmp_path / "maps" / "long" / "trajectories.csv", delimiter=",", names=True)
    assert "truth_x" not in table.dtype.names and len(table) == 4
    assert vj.GlobalMap.load(tmp_path / "maps" / "long" / "global_map.vog").voxels()[0].shape[0] > 500


def run_cli(capsys, *args):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["import", *map(str, args), "--quiet"])
    assert exit_info.value.code == 2
    return capsys.readouterr().err


def test_bad_bags_and_arguments_are_clear_errors(tmp_path, capsys):
    bag, _, _ = cloud_bag(tmp_path / "run.bag", "ros1", scans=4)
    out = tmp_path / "out.h5"
    assert "--points: the bag has no topic '/nope'" in run_cli(
        capsys, bag, "--points", "/nope", "--odometry", "/odom", "--out", out, "--frame", "lidar"
    )
    assert "--odometry: topic '/points' carries sensor_msgs/msg/PointCloud2, not nav_msgs/msg/Odometry" in run_cli(
        capsys, bag, "--points", "/points", "--odometry", "/points", "--out", out, "--frame", "lidar"
    )
    assert "--points: topic '/odom' carries nav_msgs/msg/Odometry" in run_cli(
        capsys, bag, "--points", "/odom", "--odometry", "/odom", "--out", out
    )
    assert "pass --frame lidar" in run_cli(capsys, bag, "--points", "/points", "--odometry", "/odom", "--out", out)
    assert "--frame 'camera': the scans on '/points' are in frame 'lidar'" in run_cli(
        capsys, bag, "--points", "/points", "--odometry", "/odom", "--out", out, "--frame", "camera"
    )
    assert "does not exist" in run_cli(
        capsys, tmp_path / "missing.bag", "--points", "/p", "--odometry", "/o", "--out", out
    )
    (tmp_path / "junk.bag").write_bytes(b"junk" * 100)
    assert "cannot be read" in run_cli(
        capsys, tmp_path / "junk.bag", "--points", "/p", "--odometry", "/o", "--out", out
    )
    untied, _, _ = cloud_bag(tmp_path / "untied.bag", "ros1", scans=4, with_tf=False)
    assert "TF (/tf_static, /tf) does not connect it" in run_cli(
        capsys, untied, "--points", "/points", "--odometry", "/odom", "--out", out, "--frame", "lidar"
    )
    assert "folder" in run_cli(
        capsys, bag, "--points", "/points", "--odometry", "/odom", "--out", tmp_path / "no" / "x.h5", "--frame", "lidar"
    )
    assert not out.exists()


def test_a_bag_whose_scans_all_miss_the_odometry_is_an_error(tmp_path, capsys):
    m = Messages(False)
    stamps, positions, quats = odometry_samples(5)
    late = stamps[-1] + 10**9
    messages = [("/odom", "nav_msgs/msg/Odometry", s, m.odometry(s, p, q)) for s, p, q in zip(stamps, positions, quats)]
    messages.append(("/points", "sensor_msgs/msg/PointCloud2", late, m.cloud(late, "base_link", np.ones((5, 3)))))
    bag = write_bag(tmp_path / "late", "mcap", messages)
    message = run_cli(capsys, bag, "--points", "/points", "--odometry", "/odom", "--out", tmp_path / "x.h5")
    assert "no scan on '/points' can be imported: 1 outside odometry" in message


# ------------------------------------------------------------------ hostile bags (a review campaign's findings)
def odometry_messages(m, count, skip=()):
    stamps, positions, quats = odometry_samples(count)
    return [
        ("/odom", "nav_msgs/msg/Odometry", s, m.odometry(s, p, q))
        for k, (s, p, q) in enumerate(zip(stamps, positions, quats))
        if k not in skip
    ], stamps


def test_a_record_the_reader_cannot_read_names_the_bag(tmp_path, capsys):
    bag, _, _ = cloud_bag(tmp_path / "run.bag", "ros1", scans=6)
    data = bytearray(bag.read_bytes())
    # damage inside the last message records (the index after them stays readable)
    for at in range(len(data) // 2, len(data) * 3 // 4, 97):
        data[at] ^= 0xFF
    bag.write_bytes(bytes(data))
    message = run_cli(
        capsys, bag, "--points", "/points", "--odometry", "/odom", "--out", tmp_path / "x.h5", "--frame", "lidar"
    )
    assert str(bag) in message and "\n" not in message.strip()


def test_a_cloud_larger_than_a_run_takes_is_refused_before_converting():
    m = Messages(False)
    Field = m.t["sensor_msgs/msg/PointField"]
    huge = m.t["sensor_msgs/msg/PointCloud2"](
        header=m.header(T0_NS, "lidar"),
        height=2048,
        width=1024,
        is_bigendian=False,
        point_step=12,
        row_step=12 * 1024,
        fields=[Field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
        data=np.zeros(12, np.uint8),
        is_dense=True,
    )
    with pytest.raises(ValueError, match="more than the 1048576 beams"):
        cloud_points(huge, "/p")


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda f: f.__setitem__(2, ("z", 100)), "is malformed"),  # z beyond point_step
        (lambda f: f.__setitem__(2, ("x", 8)), "has field x twice"),
        (lambda f: f.__setitem__(1, ("y", 2)), "fields x and y share bytes"),  # y read from x's bytes
        (lambda f: f.append(("intensity", 8)), "fields intensity and z share bytes"),
    ],
)
def test_cloud_layouts_are_checked_before_numpy_sees_them(change, match):
    m = Messages(False)
    Field = m.t["sensor_msgs/msg/PointField"]
    layout = [("x", 0), ("y", 4), ("z", 8)]
    change(layout)
    msg = m.t["sensor_msgs/msg/PointCloud2"](
        header=m.header(T0_NS, "lidar"),
        height=1,
        width=2,
        is_bigendian=False,
        point_step=12,
        row_step=24,
        fields=[Field(name=n, offset=o, datatype=7, count=1) for n, o in layout],
        data=np.zeros(24, np.uint8),
        is_dense=True,
    )
    with pytest.raises(ValueError, match=match):
        cloud_points(msg, "/p")


def test_cloud_data_must_hold_exactly_its_rows():
    """data longer than height x row_step is refused too: read, its tail would be lost unseen."""
    m = Messages(False)
    Field = m.t["sensor_msgs/msg/PointField"]
    for size, ok in ((24, True), (23, False), (48, False)):
        msg = m.t["sensor_msgs/msg/PointCloud2"](
            header=m.header(T0_NS, "lidar"),
            height=1,
            width=2,
            is_bigendian=False,
            point_step=12,
            row_step=24,
            fields=[Field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],
            data=np.arange(size, dtype=np.uint8),
            is_dense=True,
        )
        if ok:
            assert cloud_points(msg, "/p").shape == (2, 3)
        else:
            with pytest.raises(ValueError, match=f"{size} bytes of data \\(not 1 x 24\\)"):
                cloud_points(msg, "/p")


def test_odometry_that_disagrees_with_itself_is_refused(tmp_path, capsys):
    m = Messages(False)
    messages, stamps = odometry_messages(m, 10)
    messages.append(
        ("/odom", "nav_msgs/msg/Odometry", stamps[4], m.odometry(stamps[4], [100.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]))
    )
    messages.append(
        ("/points", "sensor_msgs/msg/PointCloud2", stamps[5], m.cloud(stamps[5], "base_link", np.ones((5, 3))))
    )
    bag = write_bag(tmp_path / "dup", "mcap", sorted(messages, key=lambda e: e[2]))
    message = run_cli(capsys, bag, "--points", "/points", "--odometry", "/odom", "--out", tmp_path / "x.h5")
    assert f"two different poses stamped {stamps[4]} ns" in message


def test_scans_in_an_odometry_gap_are_dropped_and_counted(tmp_path):
    m = Messages(False)
    messages, stamps = odometry_messages(m, 40, skip=range(5, 35))  # 1.5 s without odometry at 20 Hz
    inside, gap = stamps[2] + 10_000_000, stamps[20]
    for stamp in (inside, gap):
        messages.append(("/points", "sensor_msgs/msg/PointCloud2", stamp, m.cloud(stamp, "base_link", np.ones((5, 3)))))
    bag = write_bag(tmp_path / "gap", "mcap", sorted(messages, key=lambda e: e[2]))
    summary = import_bag(bag, tmp_path / "x.h5", "/points", "/odom", progress=False)
    assert summary.scans == 1 and summary.dropped == {"in_odometry_gap": 1}


def test_a_tf_link_off_the_path_may_be_junk_but_one_on_it_may_not(tmp_path, capsys):
    m = Messages(False)
    messages, stamps = odometry_messages(m, 10)
    messages.append(("/points", "sensor_msgs/msg/PointCloud2", stamps[3], m.cloud(stamps[3], "lidar", np.ones((5, 3)))))
    junk = np.eye(4)
    junk[:3, :3] = 0.0  # a zero quaternion
    good = ("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS, m.tf(T0_NS, "base_link", "lidar", mount()))
    elsewhere = ("/tf", "tf2_msgs/msg/TFMessage", T0_NS, m.tf(T0_NS, "map", "camera", np.eye(4)))
    elsewhere[3].transforms[0].transform.rotation.w = 0.0
    bag = write_bag(tmp_path / "ok", "mcap", sorted(messages + [good, elsewhere], key=lambda e: e[2]))
    assert import_bag(bag, tmp_path / "ok.h5", "/points", "/odom", frame="lidar", progress=False).scans == 1
    bad = ("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS, m.tf(T0_NS, "base_link", "lidar", mount()))
    bad[3].transforms[0].transform.rotation.w = 0.1  # not a unit quaternion
    bag = write_bag(tmp_path / "bad", "mcap", sorted(messages + [bad], key=lambda e: e[2]))
    message = run_cli(
        capsys, bag, "--points", "/points", "--odometry", "/odom", "--out", tmp_path / "x.h5", "--frame", "lidar"
    )
    assert (
        "the TF link base_link -> lidar holds non-finite values or a quaternion that is not of unit length" in message
    )


def test_laser_returns_beyond_any_sensor_are_invalid_beams():
    m = Messages(False)
    msg = m.laser(T0_NS, "lidar", [1.0, 5e4, np.inf, np.nan], 0.0, 0.1, 0.1, 1e30)
    from vogjax.io.rosbag import laser_beams

    scan = laser_beams(msg, "/scan")
    assert scan.invalid == 2  # 50 km and NaN
    assert np.array_equal(scan.no_return, [False, True]) and scan.ranges[0] == 1.0


def test_invalid_beams_are_counted_for_the_scans_written_only(tmp_path):
    m = Messages(False)
    messages, stamps = odometry_messages(m, 10)
    early = stamps[0] - 10**9  # outside the odometry: dropped, its NaN points not counted again
    points = np.ones((5, 3))
    points[:2] = np.nan
    for stamp in (early, stamps[4]):
        messages.append(("/points", "sensor_msgs/msg/PointCloud2", stamp, m.cloud(stamp, "base_link", points)))
    bag = write_bag(tmp_path / "count", "mcap", sorted(messages, key=lambda e: e[2]))
    summary = import_bag(bag, tmp_path / "x.h5", "/points", "/odom", progress=False)
    assert summary.scans == 1 and summary.dropped == {"outside_odometry": 1} and summary.invalid_beams == 2
