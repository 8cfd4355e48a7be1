"""Depth cameras on `vogjax import --depth`: synthetic depth images of an analytic scene (a tilted
plane in the world, seen by a moving camera through its own pinhole model), every beam's end point
checked against the plane and against the pixel it came from; distortion, stride, encodings,
byte orders and malformed messages."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vogjax import cli
from vogjax.io.dataset import Dataset, ScanBatch
from vogjax.io.depth_image import camera_from_info, distort, undistort
from vogjax.io.rosbag import import_bag

pytest.importorskip("rosbags")
from tests.test_import import Messages, odometry_samples, pose_at, write_bag  # noqa: E402

DEPTH, INFO = "/camera/depth/image_raw", "/camera/depth/camera_info"
K = np.array([[52.0, 0.4, 31.7], [0.0, 50.0, 23.2], [0.0, 0.0, 1.0]])
WIDTH, HEIGHT = 64, 48


def T_base_camera() -> np.ndarray:
    """An optical frame (z ahead, x right, y down) looking along the vehicle's x, a little down."""
    T = np.eye(4)
    looking = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # columns: optical x, y, z in base
    T[:3, :3] = Rotation.from_euler("y", 0.2).as_matrix() @ looking
    T[:3, 3] = [0.5, 0.0, 0.3]
    return T


def pixel_rays(stride=1, k=K):
    """(x, y, 1) of each strided pixel, row by row, from the pinhole model written out by hand."""
    rows = []
    for v in range(0, HEIGHT, stride):
        for u in range(0, WIDTH, stride):
            y = (v - k[1, 2]) / k[1, 1]
            x = (u - k[0, 2] - k[0, 1] * y) / k[0, 0]
            rows.append((x, y, 1.0))
    return np.array(rows)


def image_message(m, stamp, depth, encoding, bigendian, pad=6):
    sample = {"16UC1": "u2", "32FC1": "f4"}[encoding]
    order = ">" if bigendian else "<"
    rows = np.ascontiguousarray(depth.astype(order + sample)).view(np.uint8).reshape(depth.shape[0], -1)
    step = rows.shape[1] + pad  # rows padded past the pixels, as some drivers do
    data = np.concatenate([rows, np.full((depth.shape[0], pad), 0xAB, np.uint8)], axis=1).ravel()
    return m.t["sensor_msgs/msg/Image"](
        header=m.header(stamp, "camera"),
        height=depth.shape[0],
        width=depth.shape[1],
        encoding=encoding,
        is_bigendian=bigendian,
        step=step,
        data=data,
    )


def info_message(m, stamp, k=K, model="plumb_bob", d=(0.0, 0.0, 0.0, 0.0, 0.0), size=(WIDTH, HEIGHT), frame="camera"):
    names = ("D", "K", "R", "P") if m.ros1 else ("d", "k", "r", "p")
    projection = np.c_[k, np.zeros(3)]
    values = dict(zip(names, (np.array(d, float), k.ravel(), np.eye(3).ravel(), projection.ravel())))
    roi = m.t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return m.t["sensor_msgs/msg/CameraInfo"](
        header=m.header(stamp, frame),
        width=size[0],
        height=size[1],
        distortion_model=model,
        **values,
        binning_x=0,
        binning_y=0,
        roi=roi,
    )


def plane_bag(path, kind, encoding, bigendian=False, images=5, info=None, depth_of=None):
    """Odometry (turning, climbing), the camera's mount in /tf_static, CameraInfo and depth images of
    the world plane n.x = d. Returns the bag, the plane and per image (stamp, depth (H,W) as written)."""
    m = Messages(kind == "ros1")
    o_stamps, positions, quats = odometry_samples(30)
    odom = (o_stamps, positions, quats)
    messages = [("/odom", "nav_msgs/msg/Odometry", s, m.odometry(s, p, q)) for s, p, q in zip(*odom)]
    messages.append(
        ("/tf_static", "tf2_msgs/msg/TFMessage", o_stamps[0], m.tf(o_stamps[0], "base_link", "camera", T_base_camera()))
    )
    # the plane: 3 m ahead of the first image's camera, tilted 25 degrees about its x
    T0 = pose_at(*odom, o_stamps[1]) @ T_base_camera()
    normal_camera = Rotation.from_euler("x", 0.45).apply([0.0, 0.0, 1.0])
    normal = T0[:3, :3] @ normal_camera
    offset = float(normal @ (T0[:3, 3] + 3.0 * T0[:3, 2]))
    rng = np.random.default_rng(1)
    written = []
    for i in range(images):
        stamp = o_stamps[1] + 13_000_000 + i * 100_000_000
        T = pose_at(*odom, stamp) @ T_base_camera()
        rays = pixel_rays()
        depth = (offset - normal @ T[:3, 3]) / (rays @ T[:3, :3].T @ normal)  # z of each pixel's ray on the plane
        assert np.all(depth > 0.5)
        depth = depth.reshape(HEIGHT, WIDTH)
        if depth_of is not None:
            depth = depth_of(T)
        if encoding == "16UC1":
            depth = np.round(depth * 1000.0).astype(np.uint16)
            depth[rng.random(depth.shape) < 0.05] = 0
        else:
            depth = depth.astype(np.float32)
            depth[rng.random(depth.shape) < 0.03] = 0.0
            depth[rng.random(depth.shape) < 0.03] = np.nan
        messages.append(
            (
                "/camera/depth/image_raw",
                "sensor_msgs/msg/Image",
                stamp,
                image_message(m, stamp, depth, encoding, bigendian),
            )
        )
        messages.append((INFO, "sensor_msgs/msg/CameraInfo", stamp, info or info_message(m, stamp)))
        written.append((stamp, depth))
    write_bag(path, kind, sorted(messages, key=lambda e: (e[2], e[0])))
    return path, odom, (normal, offset), written


def metres(depth):
    return depth / 1000.0 if depth.dtype == np.uint16 else depth.astype(np.float64)


@pytest.mark.parametrize(
    "kind, encoding, bigendian, stride",
    [
        ("ros1", "16UC1", False, 1),
        ("mcap", "32FC1", False, 3),
        ("sqlite3", "32FC1", True, 1),
        ("mcap", "16UC1", True, 2),
    ],
)
def test_depth_pixels_land_on_the_plane_the_camera_saw(tmp_path, kind, encoding, bigendian, stride):
    bag, odom, (normal, offset), written = plane_bag(
        tmp_path / ("d.bag" if kind == "ros1" else "d"), kind, encoding, bigendian
    )
    summary = import_bag(
        bag,
        tmp_path / "run.h5",
        depth_topic=DEPTH,
        odometry_topic="/odom",
        frame="camera",
        stride=stride,
        progress=False,
    )
    with Dataset(tmp_path / "run.h5") as ds:
        batch = ScanBatch.concatenate(list(ds.batches()))
        metadata, optional = ds.metadata, ds.optional
    origins, ends = batch.world(batch.pose_nav, 50.0)
    assert len(batch) == len(written) and optional == ()
    rays = pixel_rays(stride)
    invalid = 0
    for s, (stamp, depth) in enumerate(written):
        z = metres(depth[::stride, ::stride]).ravel()
        valid = np.isfinite(z) & (z > 0)
        invalid += int((~valid).sum())
        T = pose_at(*odom, stamp) @ T_base_camera()
        expected = (rays[valid] * z[valid, None]) @ T[:3, :3].T + T[:3, 3]
        n = int(valid.sum())
        np.testing.assert_allclose(ends[s, :n], expected, atol=2e-5, rtol=0)
        on_plane = np.abs(ends[s, :n] @ normal - offset)
        assert on_plane.max() < (2e-5 if encoding == "32FC1" else 1e-3)  # millimetre depths: within half a mm
        np.testing.assert_allclose(origins[s], T[:3, 3], atol=1e-5)
        assert not batch.no_return[s].any()
    assert summary.invalid_beams == invalid > 0
    assert metadata["sensor_config"]["message"] == "Image"
    camera = metadata["source"]["camera"]
    assert camera["stride"] == stride and camera["encoding"] == [encoding] and camera["camera_info_topic"] == INFO
    np.testing.assert_array_equal(camera["K"], K)
    assert not camera["undistorted"] and metadata["import"]["fields"]["data"]["use"] == "depth"
    assert metadata["import"]["point_time"]["deskewed"] is False


def test_plumb_bob_pixels_are_undistorted_and_reproject_onto_their_pixels(tmp_path):
    d = (-0.21, 0.06, 0.0012, -0.0018, 0.011)
    k = np.array([[48.0, 0.0, 32.5], [0.0, 47.0, 23.5], [0.0, 0.0, 1.0]])
    m = Messages(False)
    bag, odom, _, written = plane_bag(
        tmp_path / "pb",
        "mcap",
        "32FC1",
        info=info_message(m, 0, k=k, d=d),
        depth_of=lambda T: np.full((HEIGHT, WIDTH), 2.5),  # a wall square to the camera
    )
    import_bag(bag, tmp_path / "run.h5", depth_topic=DEPTH, odometry_topic="/odom", frame="camera", progress=False)
    with Dataset(tmp_path / "run.h5") as ds:
        batch = ScanBatch.concatenate(list(ds.batches()))
        assert ds.metadata["source"]["camera"]["undistorted"]
    _, ends = batch.world(batch.pose_nav, 50.0)
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH]
    for s, (stamp, depth) in enumerate(written):
        valid = np.isfinite(depth.ravel()) & (depth.ravel() > 0)
        T = pose_at(*odom, stamp) @ T_base_camera()
        local = (ends[s, : valid.sum()] - T[:3, 3]) @ T[:3, :3]  # back in the camera frame
        np.testing.assert_allclose(local[:, 2], 2.5, atol=1e-5)
        x, y = local[:, 0] / local[:, 2], local[:, 1] / local[:, 2]
        # the distortion, written out (OpenCV's plumb_bob), then K
        r2 = x * x + y * y
        radial = 1 + d[0] * r2 + d[1] * r2**2 + d[4] * r2**3
        xd = x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x)
        yd = y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y
        np.testing.assert_allclose(k[0, 0] * xd + k[0, 2], u.ravel()[valid], atol=1e-3)
        np.testing.assert_allclose(k[1, 1] * yd + k[1, 2], v.ravel()[valid], atol=1e-3)


def test_undistort_inverts_distort():
    rng = np.random.default_rng(5)
    d = (-0.3, 0.09, 0.001, 0.002, -0.01)
    xy = rng.uniform(-0.7, 0.7, (500, 2))
    np.testing.assert_allclose(distort(undistort(xy, d), d), xy, atol=1e-11)
    np.testing.assert_allclose(undistort(distort(xy, d), d), xy, atol=1e-9)
    with pytest.raises(ValueError, match="does not invert"):
        undistort(np.array([[3.0, 3.0]]), (-1.0, 0.0, 0.0, 0.0, 0.0))  # folded: the radius maps back inward


def run_cli(capsys, *argv) -> str:
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["import", *map(str, argv), "--quiet"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    return err


def test_malformed_cameras_and_images_are_one_line_errors_naming_the_flag(tmp_path, capsys):
    m = Messages(False)
    out = tmp_path / "x.h5"
    base = ["--odometry", "/odom", "--frame", "camera", "--out", out]
    bag, _, _, _ = plane_bag(tmp_path / "ok", "mcap", "16UC1", images=2)
    assert "--camera-info: the bag has no topic '/nope'" in run_cli(
        capsys, bag, "--depth", DEPTH, "--camera-info", "/nope", *base
    )
    assert "--depth: topic '/odom' carries nav_msgs/msg/Odometry, not sensor_msgs/msg/Image" in run_cli(
        capsys, bag, "--depth", "/odom", *base
    )
    assert "--min-intensity applies to --points" in run_cli(
        capsys, bag, "--depth", DEPTH, "--min-intensity", "3", *base
    )
    assert "give one of --points" in run_cli(capsys, bag, *base)
    cases = {
        "rational": (
            dict(info=info_message(m, 0, model="rational_polynomial", d=(0.1,) + (0.0,) * 7)),
            "distortion model 'rational_polynomial'",
        ),
        "size": (dict(info=info_message(m, 0, size=(WIDTH, HEIGHT + 1))), "but its CameraInfo says 64 x 49"),
        "k": (dict(info=info_message(m, 0, k=np.diag([0.0, 50.0, 1.0]))), "is not a camera matrix"),
        "frame": (dict(info=info_message(m, 0, frame="elsewhere")), "is in frame 'elsewhere'"),
        # past the distortion's fold no pixel maps back: named with the camera's topic
        "fold": (dict(info=info_message(m, 0, d=(-0.9, 0.0, 0.0, 0.0, 0.0))), "does not invert over the image"),
    }
    for name, (kwargs, expected) in cases.items():
        bag, _, _, _ = plane_bag(tmp_path / name, "mcap", "32FC1", images=2, **kwargs)
        message = run_cli(capsys, bag, "--depth", DEPTH, *base)
        assert expected in message and ("--camera-info" in message or "--depth" in message), message
        assert name != "fold" or "--camera-info topic" in message, message
    assert not out.exists()


def test_a_camera_matrix_of_the_wrong_size_and_a_zero_stride_are_refused_by_name():
    m = Messages(False)
    info = info_message(m, 0)
    camera = camera_from_info(info, "--camera-info topic '/info'")
    for stride in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="stride must be a positive whole number"):
            camera.rays(stride)
    assert camera.rays(2).shape == (((HEIGHT + 1) // 2) * ((WIDTH + 1) // 2), 3)
    short = info_message(m, 0)
    short.k = np.asarray(short.k)[:4]
    with pytest.raises(ValueError, match="'/info': CameraInfo's K holds 4 numbers, not the 9"):
        camera_from_info(short, "--camera-info topic '/info'")


def image_bag(tmp_path, name, image, info):
    m = Messages(False)
    o_stamps, positions, quats = odometry_samples(10)
    messages = [
        ("/odom", "nav_msgs/msg/Odometry", s, m.odometry(s, p, q)) for s, p, q in zip(o_stamps, positions, quats)
    ]
    stamp = o_stamps[3]
    image.header = m.header(stamp, "base_link")
    info.header = m.header(stamp, "base_link")
    messages += [(DEPTH, "sensor_msgs/msg/Image", stamp, image), (INFO, "sensor_msgs/msg/CameraInfo", stamp, info)]
    return write_bag(tmp_path / name, "mcap", sorted(messages, key=lambda e: (e[2], e[0])))


def test_images_are_checked_before_their_pixels_are_read(tmp_path, capsys):
    m = Messages(False)
    depth = np.ones((HEIGHT, WIDTH), np.float32)
    good = image_message(m, 0, depth, "32FC1", False)
    Image = m.t["sensor_msgs/msg/Image"]
    fields = ("header", "height", "width", "encoding", "is_bigendian", "step", "data")
    variant = lambda **c: Image(**{f: c.get(f, getattr(good, f)) for f in fields})  # noqa: E731
    huge_info = info_message(m, 0, size=(4096, 2048))
    cases = [
        (variant(encoding="rgb8"), info_message(m, 0), "Image encoding 'rgb8' is no depth encoding"),
        (variant(data=good.data[:-100]), info_message(m, 0), "Image is malformed"),
        (variant(data=np.concatenate([good.data, good.data])), info_message(m, 0), "Image is malformed"),
        (variant(step=10), info_message(m, 0), "Image is malformed"),
        (variant(width=4096, height=2048, data=good.data[:64]), huge_info, "raise --stride"),
    ]
    for i, (image, info, expected) in enumerate(cases):
        bag = image_bag(tmp_path, f"b{i}", image, info)
        message = run_cli(capsys, bag, "--depth", DEPTH, "--odometry", "/odom", "--out", tmp_path / "x.h5")
        assert expected in message and f"--depth topic {DEPTH!r}" in message, message
    # the same huge image at a stride that fits is refused only for its short data
    bag = image_bag(tmp_path, "huge", cases[-1][0], huge_info)
    message = run_cli(capsys, bag, "--depth", DEPTH, "--stride", "4", "--odometry", "/odom", "--out", tmp_path / "x.h5")
    assert "Image is malformed" in message
