"""Motion compensation, intensity and ring on `vogjax import`: a spinning lidar on a vehicle that
moves and turns, each point fired at a known time and written in the layout of a real driver
(Velodyne, Ouster, Livox, Hesai). The reference is the analytic motion itself: a screw motion
(constant velocity, constant rate about a fixed axis) that the odometry samples, so linear-slerp
interpolation reproduces it exactly and every deskewed point must land on its true world point."""

from fractions import Fraction

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vogjax import cli
from vogjax.io.dataset import Dataset, DatasetWriter, ScanBatch
from vogjax.io.deskew import MAX_SWEEP_S, deskew_points, point_offsets
from vogjax.io.rosbag import import_bag

pytest.importorskip("rosbags")
from tests.test_import import T0_NS, Messages, axis_angle, quat_matrix, write_bag  # noqa: E402

ODOM_HZ, SCAN_HZ, SWEEP_S = 20.0, 10.0, 0.1
RINGS, COLUMNS = 16, 120
VELOCITY = np.array([4.0, 1.5, 0.3])  # m/s
AXIS = np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0])
RATE = 1.2  # rad/s about AXIS
P0 = np.array([10.0, -5.0, 2.0])
R0 = quat_matrix(axis_angle([0.3, -0.2, 1.0], 0.7))
SIZES = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}
NUMPY = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


# ------------------------------------------------------------------ the analytic motion (independent of vogjax)
def rodrigues(axis, angle):
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def T_world_base(t_s: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R0 @ rodrigues(AXIS, RATE * t_s)
    T[:3, 3] = P0 + VELOCITY * t_s
    return T


def T_base_lidar() -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quat_matrix(axis_angle([0.0, 0.3, 1.0], 0.5))
    T[:3, 3] = [0.4, 0.1, 0.8]
    return T


def seconds(stamp_ns) -> float:
    """Seconds since T0 of an exact stamp (an int or a Fraction of nanoseconds)."""
    return float(Fraction(stamp_ns) - T0_NS) * 1e-9


# ------------------------------------------------------------------ drivers' layouts
# name: (time field, PointField type, stamp at the sweep's start or end, extra fields)
DRIVERS = {
    "velodyne": ("time", 7, "end", [("intensity", 7), ("ring", 4)]),
    "ouster": ("t", 6, "start", [("intensity", 7), ("reflectivity", 4), ("ring", 4), ("ambient", 4), ("range", 6)]),
    "livox": ("timestamp", 8, "start", [("intensity", 7), ("tag", 2), ("line", 2)]),
    "hesai": ("timestamp", 8, "end", [("intensity", 7), ("ring", 4)]),
}
ABSOLUTE_NS = {"livox"}  # float64 nanoseconds since 1970; hesai: float64 seconds


def encoded_times(driver, offsets_s, stamp_ns):
    """The time field as the driver writes it, and each point's firing time as an exact ns Fraction."""
    field, kind, _, _ = DRIVERS[driver]
    if kind == 7:
        values = offsets_s.astype(np.float32)
        fired = [stamp_ns + Fraction(float(v)) * 10**9 for v in values]
    elif kind == 6:
        values = np.round(offsets_s * 1e9).astype(np.uint32)
        fired = [stamp_ns + int(v) for v in values]
    elif driver in ABSOLUTE_NS:
        values = np.array([float(stamp_ns) + o * 1e9 for o in offsets_s])
        fired = [Fraction(float(v)) for v in values]
    else:
        values = np.array([stamp_ns / 1e9 + o for o in offsets_s])
        fired = [Fraction(float(v)) * 10**9 for v in values]
    return values, fired


def cloud_message(m, stamp_ns, frame, columns, bigendian=False):
    """A PointCloud2 of `columns` [(name, datatype, values)], packed in order at natural alignment."""
    names, formats, offsets, at = [], [], [], 0
    order = ">" if bigendian else "<"
    for name, kind, _ in columns:
        size = SIZES[kind]
        at = -(-at // size) * size
        names.append(name)
        formats.append(order + NUMPY[kind])
        offsets.append(at)
        at += size
    step = -(-at // 8) * 8 + 4  # trailing padding, as drivers leave
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    count = len(columns[0][2])
    rows = np.zeros(count, dtype=dtype)
    for name, _, values in columns:
        rows[name] = values
    Field = m.t["sensor_msgs/msg/PointField"]
    return m.t["sensor_msgs/msg/PointCloud2"](
        header=m.header(stamp_ns, frame),
        height=1,
        width=count,
        fields=[Field(name=n, offset=o, datatype=k, count=1) for n, o, (_, k, _) in zip(names, offsets, columns)],
        is_bigendian=bigendian,
        point_step=step,
        row_step=step * count,
        data=np.frombuffer(rows.tobytes(), dtype=np.uint8),
        is_dense=False,
    )


def lidar_bag(path, kind, driver, scans=6, seed=0, bigendian=False):
    """A bag of a spinning lidar on the screw motion: odometry of base_link sampled from the truth,
    the mount in /tf_static, and clouds whose points fired over each sweep. Returns the bag and per
    cloud (stamp, true world points (N,3) of the valid points, intensity, ring, validity)."""
    rng = np.random.default_rng(seed)
    m = Messages(kind == "ros1")
    field, time_kind, stamp_at, extras = DRIVERS[driver]
    duration_s = (scans + 2) / SCAN_HZ
    o_stamps = [T0_NS + int(round(k * 1e9 / ODOM_HZ)) for k in range(int(duration_s * ODOM_HZ) + 1)]
    messages = [("/tf_static", "tf2_msgs/msg/TFMessage", T0_NS, m.tf(T0_NS, "base_link", "lidar", T_base_lidar()))]
    for s in o_stamps:
        T = T_world_base(seconds(s))
        q = Rotation.from_matrix(T[:3, :3]).as_quat()
        messages.append(("/odom", "nav_msgs/msg/Odometry", s, m.odometry(s, T[:3, 3], q)))
    elevation = np.deg2rad(np.linspace(-15, 15, RINGS))
    truth = []
    # the first cloud's sweep starts before the odometry: dropped, counted as sweep_outside_odometry
    stamps = [T0_NS + (20_000_000 if stamp_at == "end" else 0) + int(k * 1e9 / SCAN_HZ) for k in range(scans)]
    if stamp_at == "start":
        stamps[0] = T0_NS  # its sweep lies within the odometry; make the last one run past it
        stamps[-1] = o_stamps[-1] - 30_000_000
    for stamp in stamps:
        column = np.repeat(np.arange(COLUMNS), RINGS)
        ring = np.tile(np.arange(RINGS), COLUMNS)
        # each column fires at its own time over the sweep (and each laser a few microseconds apart)
        fraction = (column + ring * 1e-3) / COLUMNS
        offsets = fraction * SWEEP_S - (SWEEP_S if stamp_at == "end" else 0.0)
        azimuth = 2 * np.pi * column / COLUMNS
        directions = np.stack(
            [
                np.cos(elevation[ring]) * np.cos(azimuth),
                np.cos(elevation[ring]) * np.sin(azimuth),
                np.sin(elevation[ring]),
            ],
            axis=1,
        )
        ranges = rng.uniform(2.0, 30.0, len(column))
        points = directions * ranges[:, None]
        valid = rng.random(len(column)) > 0.05
        points[~valid] = np.nan  # no echo: the driver writes NaN
        values, fired = encoded_times(driver, offsets, stamp)
        world = np.full_like(points, np.nan)
        for i in np.flatnonzero(valid):
            T = T_world_base(seconds(fired[i])) @ T_base_lidar()
            world[i] = T[:3, :3] @ points[i] + T[:3, 3]
        intensity = rng.uniform(0.0, 255.0, len(column)).astype(np.float32)
        columns = [("x", 7, points[:, 0]), ("y", 7, points[:, 1]), ("z", 7, points[:, 2])]
        for name, datatype in extras:
            value = {"intensity": intensity, "ring": ring, "line": ring}.get(name, rng.integers(0, 100, len(column)))
            columns.append((name, datatype, value))
        columns.insert(4 if driver != "ouster" else 5, (field, time_kind, values))
        message = cloud_message(m, stamp, "lidar", columns, bigendian)
        messages.append(("/points", "sensor_msgs/msg/PointCloud2", stamp, message))
        truth.append((stamp, world, intensity, ring, valid))
    write_bag(path, kind, sorted(messages, key=lambda e: (e[2], e[0])))
    return path, truth


def run_rows(path):
    with Dataset(path) as ds:
        batch = ScanBatch.concatenate(list(ds.batches(100)))
        origins, ends = batch.world(batch.pose_nav, 100.0)
        return batch, ends, ds.metadata, ds.optional


@pytest.mark.parametrize(
    "driver, kind, bigendian",
    [("velodyne", "ros1", False), ("ouster", "mcap", False), ("livox", "sqlite3", False), ("hesai", "mcap", True)],
)
def test_deskewed_points_land_where_they_were_when_they_fired(tmp_path, driver, kind, bigendian):
    bag, truth = lidar_bag(tmp_path / ("l.bag" if kind == "ros1" else "l"), kind, driver, bigendian=bigendian)
    summary = import_bag(bag, tmp_path / "run.h5", "/points", "/odom", frame="lidar", progress=False)
    assert summary.dropped == {"sweep_outside_odometry": 1}
    batch, ends, metadata, optional = run_rows(tmp_path / "run.h5")
    written = truth[1:] if DRIVERS[driver][2] == "end" else truth[:-1]
    assert len(batch) == len(written) == summary.scans
    errors = []
    for s, (_, world, intensity, ring, valid) in enumerate(written):
        n = int(valid.sum())
        np.testing.assert_allclose(ends[s, :n], world[valid], atol=2e-5, rtol=0)
        errors.append(np.abs(ends[s, :n] - world[valid]).max())
        np.testing.assert_array_equal(batch.intensity[s, :n], intensity[valid])
        if "ring" in optional:
            np.testing.assert_array_equal(batch.ring[s, :n], ring[valid])
    assert max(errors) < 2e-5  # float32 storage of directions and ranges at 30 m
    time = metadata["import"]["point_time"]
    layout = {"velodyne": "relative_s", "ouster": "relative_ns", "livox": "absolute_ns", "hesai": "absolute_s"}
    assert time["deskewed"] and time["layout"] == layout[driver] and time["field"] == DRIVERS[driver][0]
    low, high = time["offsets_s"]
    expected = (-SWEEP_S, 0.0) if DRIVERS[driver][2] == "end" else (0.0, SWEEP_S)
    assert expected[0] - 1e-6 <= low < expected[0] + 0.01 and expected[1] - 0.01 < high <= expected[1] + 1e-6
    fields = metadata["import"]["fields"]
    extras = [name for name, _ in DRIVERS[driver][3]]
    assert set(fields) == {"x", "y", "z", DRIVERS[driver][0], *extras} and len(fields) == 4 + len(extras)
    assert fields["x"]["use"] == "position" and fields[DRIVERS[driver][0]]["use"] == "point time"
    assert fields["intensity"]["use"] == "intensity"
    for name in set(extras) - {"intensity", "ring"}:
        assert fields[name]["use"] == "ignored"
    assert optional == (("intensity", "ring") if "ring" in extras else ("intensity",))
    assert metadata["import"]["optional_fields"] == list(optional)


def test_without_deskewing_the_points_smear_by_the_motion(tmp_path):
    bag, truth = lidar_bag(tmp_path / "v.bag", "ros1", "velodyne")
    import_bag(bag, tmp_path / "raw.h5", "/points", "/odom", frame="lidar", progress=False, deskew=False)
    batch, ends, metadata, _ = run_rows(tmp_path / "raw.h5")
    # without per-point times the first cloud's sweep is not checked: it lies at its stamp, inside the odometry
    errors = np.concatenate(
        [
            np.linalg.norm(ends[s, : v.sum()] - w[v], axis=1)
            for s, (_, w, _, _, v) in enumerate(truth[len(truth) - len(batch) :])
        ]
    )
    assert np.median(errors) > 0.2 and errors.max() > 2.0  # 0.4 m of travel and 0.12 rad of turn per sweep
    time = metadata["import"]["point_time"]
    assert not time["deskewed"] and "--no-deskew" in time["reason"]
    assert metadata["import"]["fields"]["time"]["use"] == "ignored (deskewing off)"


def test_a_cloud_without_point_times_is_taken_at_its_stamp_and_says_so(tmp_path):
    from tests.test_import import cloud_bag

    bag, _, _ = cloud_bag(tmp_path / "run.bag", "ros1", scans=5)
    summary = import_bag(bag, tmp_path / "run.h5", "/points", "/odom", frame="lidar", progress=False)
    time = summary.metadata["import"]["point_time"]
    assert not time["deskewed"] and "no per-point time field" in time["reason"]


# ------------------------------------------------------------------ time layouts
STAMP_NS = 1_700_000_123_456_789_012


@pytest.mark.parametrize(
    "values, datatype, layout",
    [
        (np.float32([-0.1, -0.05, 0.0]), 7, "relative_s"),
        (np.uint32([0, 50_000_000, 99_999_999]), 6, "relative_ns"),
        (np.int32([-5, 0, 5]), 5, "relative_ns"),
        (np.float64([0.0, 0.01, 0.099]), 8, "relative_s"),
        (np.float64([STAMP_NS / 1e9, STAMP_NS / 1e9 + 0.05]), 8, "absolute_s"),
        (np.float64([float(STAMP_NS), float(STAMP_NS) + 5e7]), 8, "absolute_ns"),
    ],
)
def test_time_layouts_are_told_apart_by_type_and_value(values, datatype, layout):
    offsets, found = point_offsets(values, datatype, STAMP_NS, "f")
    assert found == layout and np.all(np.abs(offsets) <= MAX_SWEEP_S)
    assert np.all(np.diff(offsets) >= 0) and np.diff(offsets).max() > 0


def test_absolute_times_keep_their_nanoseconds():
    v = float(STAMP_NS) + 1.5e7  # float64 nanoseconds: exact to 256 ns
    offsets, _ = point_offsets(np.float64([v]), 8, STAMP_NS, "f")
    assert offsets[0] == pytest.approx(float(Fraction(v) - STAMP_NS) * 1e-9, abs=1e-15)
    s = STAMP_NS / 1e9 + 0.025  # float64 seconds: exact to 240 ns
    offsets, _ = point_offsets(np.float64([s]), 8, STAMP_NS, "f")
    assert offsets[0] == pytest.approx(float(Fraction(s) - Fraction(STAMP_NS, 10**9)), abs=1e-15)


@pytest.mark.parametrize(
    "values, datatype, match",
    [
        (np.float32([STAMP_NS / 1e9]), 7, "absolute seconds in float32"),
        (np.float64([12.0, 13.0]), 8, "no known layout"),  # seconds of another clock
        (np.float64([1e6, 5e7]), 8, "no known layout"),  # float64 nanoseconds are read only as absolute
        (np.uint32([0, 2_000_000_000]), 6, "no known layout"),  # a 2 s sweep
        (np.uint16([0, 5]), 4, "datatype 4"),
        (np.float32([0.0, np.nan]), 7, "non-finite"),
    ],
)
def test_times_that_fit_no_layout_are_refused_naming_the_field(values, datatype, match):
    with pytest.raises(ValueError, match=match) as error:
        point_offsets(values, datatype, STAMP_NS, "--points topic '/p': PointCloud2 field time")
    assert "field time" in str(error.value)


def test_a_topic_keeps_the_layout_of_its_first_cloud():
    with pytest.raises(ValueError, match="as the topic's first cloud"):
        point_offsets(np.float64([STAMP_NS / 1e9]), 8, STAMP_NS, "f", layout="relative_s")


def test_deskewing_is_exact_for_motion_the_interpolation_reproduces():
    times = np.arange(5) * 0.05
    poses = np.array([T_world_base(t) for t in times])
    rng = np.random.default_rng(2)
    points = rng.normal(size=(200, 3)) * 10
    offsets = rng.uniform(-0.1, 0.0, 200)
    stamp = 0.15
    moved = deskew_points(points, offsets, stamp, times, poses, T_base_lidar())
    for p, o, q in zip(points, offsets, moved):
        fired = T_world_base(stamp + o) @ T_base_lidar()
        at_stamp = T_world_base(stamp) @ T_base_lidar()
        np.testing.assert_allclose(at_stamp[:3, :3] @ q + at_stamp[:3, 3], fired[:3, :3] @ p + fired[:3, 3], atol=1e-9)
    with pytest.raises(ValueError, match="outside the odometry"):
        deskew_points(points, offsets - 0.2, stamp, times, poses, T_base_lidar())


def test_deskewing_interpolates_as_the_importer_interpolates_the_scans():
    """Against vogjax.geometry.interpolate_poses (scipy's Slerp), per point, on poses that no
    screw motion joins: random rotations 10-50 ms apart."""
    from vogjax.geometry import interpolate_poses

    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.01, 0.05, 40))
    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, :3, :3] = Rotation.random(40, random_state=4).as_matrix()
    poses[:, :3, 3] = rng.normal(size=(40, 3)) * 50
    points = rng.normal(size=(3000, 3)) * 20
    stamp = float(times[15]) + 0.004
    offsets = rng.uniform(-0.12, 0.03, 3000)
    offsets[:2] = [times[12] - stamp, 0.0]  # a firing time on a pose, one at the stamp
    fired = interpolate_poses(times, poses, stamp + offsets) @ T_base_lidar()
    at_stamp = interpolate_poses(times, poses, [stamp])[0] @ T_base_lidar()
    world = np.einsum("nij,nj->ni", fired[:, :3, :3], points) + fired[:, :3, 3]
    expected = (world - at_stamp[:3, 3]) @ at_stamp[:3, :3]
    got = deskew_points(points, offsets, stamp, times, poses, T_base_lidar())
    np.testing.assert_allclose(got, expected, atol=1e-10, rtol=0)


# ------------------------------------------------------------------ intensity, ring, what is reported
def test_min_intensity_drops_and_counts_the_faint_points(tmp_path):
    bag, truth = lidar_bag(tmp_path / "v.bag", "ros1", "velodyne", scans=4)
    summary = import_bag(
        bag, tmp_path / "run.h5", "/points", "/odom", frame="lidar", progress=False, min_intensity=100.0
    )
    batch, ends, metadata, _ = run_rows(tmp_path / "run.h5")
    expected_below = 0
    for s, (_, world, intensity, ring, valid) in enumerate(truth[1:]):
        bright = valid & (intensity >= 100.0)
        expected_below += int((valid & (intensity < 100.0)).sum())
        n = int(bright.sum())
        np.testing.assert_allclose(ends[s, :n], world[bright], atol=2e-5, rtol=0)
        np.testing.assert_array_equal(batch.ring[s, :n], ring[bright])
        assert np.all(batch.intensity[s] >= 100.0)  # padding copies a kept beam
    assert metadata["import"]["below_min_intensity"] == expected_below > 0
    assert metadata["import"]["min_intensity"] == 100.0
    assert summary.invalid_beams == sum(int((~v).sum()) for *_, v in truth[1:])


def test_min_intensity_needs_an_intensity(tmp_path, capsys):
    from tests.test_import import odometry_messages

    m = Messages(False)
    messages, stamps = odometry_messages(m, 10)
    xyz = [("x", 7, np.ones(3)), ("y", 7, np.zeros(3)), ("z", 7, np.zeros(3))]
    messages.append(
        ("/points", "sensor_msgs/msg/PointCloud2", stamps[2], cloud_message(m, stamps[2], "base_link", xyz))
    )
    bag = write_bag(tmp_path / "plain", "mcap", sorted(messages, key=lambda e: e[2]))
    with pytest.raises(
        ValueError, match="--min-intensity: the PointCloud2 messages on '/points' have no field intensity"
    ):
        import_bag(bag, tmp_path / "x.h5", "/points", "/odom", progress=False, min_intensity=1.0)


def test_the_cli_reports_every_field_once_and_refuses_flags_that_do_not_apply(tmp_path, capsys):
    bag, _ = lidar_bag(tmp_path / "o", "mcap", "ouster", scans=4)
    out = tmp_path / "run.h5"
    argv = ["import", str(bag), "--points", "/points", "--odometry", "/odom", "--frame", "lidar", "--out", str(out)]
    assert cli.main(argv) == 0
    captured = capsys.readouterr()
    notes = [line for line in captured.err.splitlines() if line.startswith("fields of /points")]
    assert len(notes) == 1
    note = notes[0]
    assert "x, y, z (float32: position)" in note and "t (uint32: point time)" in note
    assert "kept in the run: intensity, ring" in note and "ignored: reflectivity, ambient, range" in note
    assert "deskewed by field t (uint32, nanoseconds relative to the header stamp" in captured.out
    for extra, flag in (
        (["--stride", "2"], "--stride"),
        (["--camera-info", "/c"], "--camera-info"),
        (["--depth", "/d"], "--depth"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            cli.main([*argv, "--overwrite", "--quiet", *extra])
        assert exit_info.value.code == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and flag in err


def test_a_topic_whose_clouds_change_fields_is_refused(tmp_path, capsys):
    m = Messages(False)
    from tests.test_import import odometry_messages

    messages, stamps = odometry_messages(m, 10)
    xyz = [("x", 7, np.ones(3)), ("y", 7, np.zeros(3)), ("z", 7, np.zeros(3))]
    first = cloud_message(m, stamps[2], "base_link", [*xyz, ("intensity", 7, np.ones(3))])
    second = cloud_message(m, stamps[4], "base_link", xyz)
    for stamp, message in ((stamps[2], first), (stamps[4], second)):
        messages.append(("/points", "sensor_msgs/msg/PointCloud2", stamp, message))
    bag = write_bag(tmp_path / "mixed", "mcap", sorted(messages, key=lambda e: e[2]))
    with pytest.raises(ValueError, match="carries other fields"):
        import_bag(bag, tmp_path / "x.h5", "/points", "/odom", progress=False)
    assert not (tmp_path / "x.h5").exists()


def test_rings_out_of_range_are_refused_naming_the_field(tmp_path):
    m = Messages(False)
    from tests.test_import import odometry_messages

    messages, stamps = odometry_messages(m, 10)
    columns = [("x", 7, np.ones(3)), ("y", 7, np.zeros(3)), ("z", 7, np.zeros(3)), ("ring", 5, np.array([0, -1, 2]))]
    messages.append(
        ("/points", "sensor_msgs/msg/PointCloud2", stamps[2], cloud_message(m, stamps[2], "base_link", columns))
    )
    bag = write_bag(tmp_path / "ring", "mcap", sorted(messages, key=lambda e: e[2]))
    with pytest.raises(ValueError, match="field ring holds -1 to 2"):
        import_bag(bag, tmp_path / "x.h5", "/points", "/odom", progress=False)


# ------------------------------------------------------------------ the run file's optional fields
def test_optional_fields_are_written_read_and_checked(tmp_path):
    rng = np.random.default_rng(0)
    S, B = 5, 4
    fields = {
        "time_s": np.arange(S, dtype=float),
        "pose_nav": np.tile(np.eye(4), (S, 1, 1)),
        "sonar_origin": np.zeros((S, 3), np.float32),
        "sonar_directions": np.tile(np.float32([1, 0, 0]), (S, B, 1)),
        "ranges": rng.uniform(1, 2, (S, B)).astype(np.float32),
        "no_return": np.zeros((S, B), bool),
    }
    intensity = rng.uniform(0, 9, (S, B)).astype(np.float32)
    ring = rng.integers(0, 16, (S, B)).astype(np.uint16)
    with DatasetWriter(tmp_path / "r.h5", B, {}, truth=False, optional=("ring", "intensity")) as writer:
        with pytest.raises(ValueError, match="fields missing: ring"):
            writer.append(**fields, intensity=intensity)
        with pytest.raises(ValueError, match="intensity must be finite"):
            writer.append(**fields, intensity=np.where(ring > 8, np.nan, intensity), ring=ring)
        writer.append(**fields, intensity=intensity, ring=ring)
    with Dataset(tmp_path / "r.h5") as ds:
        assert ds.optional == ("intensity", "ring")
        batches = list(ds.batches(2))
        joined = ScanBatch.concatenate(batches)
        np.testing.assert_array_equal(joined.intensity, intensity)
        np.testing.assert_array_equal(joined.ring, ring)
        np.testing.assert_array_equal(joined.rows(1, 3).ring, ring[1:3])
    with DatasetWriter(tmp_path / "plain.h5", B, {}, truth=False) as writer:
        writer.append(**fields)
    with Dataset(tmp_path / "plain.h5") as ds:
        batch = next(ds.batches())
        assert ds.optional == () and batch.intensity is None and batch.ring is None
    # a ring field of the wrong type, or a missing chunk (its fill value), is damage
    import h5py

    with h5py.File(tmp_path / "r.h5", "r+") as f:
        del f["ring"]
        f.create_dataset("ring", data=np.full((S, B), 65535, np.uint16), maxshape=(None, B))
    with Dataset(tmp_path / "r.h5") as ds, pytest.raises(ValueError, match="ring must be integers in"):
        ds.validate()
    with h5py.File(tmp_path / "r.h5", "r+") as f:
        del f["ring"]
        f.create_dataset("ring", data=ring.astype(np.int32))
    with pytest.raises(ValueError, match="field ring has shape"):
        Dataset(tmp_path / "r.h5")


def test_a_sweep_across_an_odometry_gap_is_dropped_and_counted(tmp_path):
    from tests.test_import import odometry_messages

    m = Messages(False)
    messages, stamps = odometry_messages(m, 60, skip=range(5, 35))  # 1.5 s without odometry at 20 Hz
    columns = [("x", 7, np.ones(3)), ("y", 7, np.zeros(3)), ("z", 7, np.zeros(3))]
    for stamp, fired in ((stamps[36], [-0.9, -0.5, 0.0]), (stamps[50], [-0.09, -0.05, 0.0])):
        times = ("time", 7, np.float32(fired))  # the first sweep began inside the gap
        message = cloud_message(m, stamp, "base_link", [*columns, times])
        messages.append(("/points", "sensor_msgs/msg/PointCloud2", stamp, message))
    bag = write_bag(tmp_path / "gap", "mcap", sorted(messages, key=lambda e: e[2]))
    summary = import_bag(bag, tmp_path / "x.h5", "/points", "/odom", progress=False)
    assert summary.scans == 1 and summary.dropped == {"in_odometry_gap": 1}


def test_laser_scan_intensities_are_kept_and_filtered(tmp_path):
    from tests.test_import import odometry_messages

    m = Messages(True)
    messages, stamps = odometry_messages(m, 10)
    ranges = np.float32([1.0, 2.0, np.inf, 3.0, np.nan, 4.0])
    intensities = np.float32([50, 5, np.nan, 80, 60, 1])  # the no-return beam's intensity means nothing
    scan = m.laser(stamps[3], "base_link", ranges, -0.5, 0.1, 0.1, 9.0)
    scan.intensities = intensities
    messages.append(("/scan", "sensor_msgs/msg/LaserScan", stamps[3], scan))
    bag = write_bag(tmp_path / "s.bag", "ros1", sorted(messages, key=lambda e: e[2]))
    import_bag(bag, tmp_path / "all.h5", "/scan", "/odom", progress=False)
    summary = import_bag(bag, tmp_path / "bright.h5", "/scan", "/odom", progress=False, min_intensity=10.0)
    with Dataset(tmp_path / "all.h5") as ds:
        batch = next(ds.batches())
        np.testing.assert_array_equal(batch.intensity[0], [50, 5, 0, 80, 1])  # NaN range: invalid
        np.testing.assert_array_equal(batch.no_return[0], [False, False, True, False, False])
        assert ds.metadata["import"]["fields"]["intensities"]["use"] == "intensity"
    with Dataset(tmp_path / "bright.h5") as ds:
        batch = next(ds.batches())
        np.testing.assert_array_equal(batch.intensity[0, :3], [50, 0, 80])  # the no-return beam stays
        np.testing.assert_array_equal(batch.ranges[0, :3], [1.0, np.nan, 3.0])
    assert summary.metadata["import"]["below_min_intensity"] == 2
