"""A stand-in for a spinning lidar's bag: a 16-ring lidar on a vehicle circling inside a room.

The lidar turns once per 0.1 s and writes its clouds as Velodyne's driver does: fields x, y, z,
intensity, ring and time (float32 seconds relative to the header stamp, which marks the end of
the sweep). Each column fires at its own time, from where the sensor is at that moment, so the
clouds are motion-distorted as a real lidar's are. The room is a box of 24 x 18 x 5 m: every
point's true place is on its walls. Odometry of base_link in odom (the true path) on /odom, the
lidar's mount in /tf_static. Written as ROS 2 MCAP with rosbags; no ROS installation needed.
"""

from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

ROOM_LOW, ROOM_HIGH = np.array([-12.0, -9.0, -1.5]), np.array([12.0, 9.0, 3.5])
SPEED, YAW_RATE, RADIUS = 3.0, 1.0, 3.0  # m/s, rad/s (a circle of 3 m), m
SWEEP_S, RINGS = 0.1, 16
T_BASE_LIDAR = np.eye(4)
T_BASE_LIDAR[:3, 3] = [0.2, 0.0, 0.8]
store = get_typestore(Stores.ROS2_HUMBLE)
msg = store.types
T0_NS = 1_700_000_000 * 10**9


def T_odom_base(t_s: np.ndarray) -> np.ndarray:
    """(N,4,4) poses of the vehicle at times t_s: a circle, yaw along the path."""
    yaw = YAW_RATE * np.asarray(t_s)
    T = np.tile(np.eye(4), (len(yaw), 1, 1))
    T[:, :3, :3] = Rotation.from_euler("z", yaw[:, None]).as_matrix()
    T[:, 0, 3], T[:, 1, 3] = RADIUS * np.sin(yaw), -RADIUS * np.cos(yaw)
    return T


def room_ranges(origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Range from points inside the room to its walls along unit directions (N,3)."""
    with np.errstate(divide="ignore"):
        bound = np.where(directions > 0, ROOM_HIGH, ROOM_LOW)
        return np.min(np.where(directions != 0, (bound - origins) / directions, np.inf), axis=1)


def header(stamp_ns: int, frame: str):
    stamp = msg["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return msg["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def odometry(stamp_ns: int, T: np.ndarray):
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    pose = msg["geometry_msgs/msg/Pose"](
        position=msg["geometry_msgs/msg/Point"](*T[:3, 3]), orientation=msg["geometry_msgs/msg/Quaternion"](x, y, z, w)
    )
    zero = msg["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)
    return msg["nav_msgs/msg/Odometry"](
        header=header(stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=msg["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
        twist=msg["geometry_msgs/msg/TwistWithCovariance"](
            twist=msg["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        ),
    )


# Velodyne's point layout: x, y, z, intensity (float32), ring (uint16), time (float32), 2 bytes padding
POINT = np.dtype({"names": ["x", "y", "z", "intensity", "ring", "time"],
                  "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
                  "offsets": [0, 4, 8, 12, 16, 18], "itemsize": 24})  # fmt: skip


def cloud(stamp_ns: int, rows: np.ndarray):
    Field = msg["sensor_msgs/msg/PointField"]
    types = {"x": 7, "y": 7, "z": 7, "intensity": 7, "ring": 4, "time": 7}  # FLOAT32, UINT16
    return msg["sensor_msgs/msg/PointCloud2"](
        header=header(stamp_ns, "velodyne"),
        height=1,
        width=len(rows),
        fields=[Field(name=n, offset=POINT.fields[n][1], datatype=t, count=1) for n, t in types.items()],
        is_bigendian=False,
        point_step=POINT.itemsize,
        row_step=POINT.itemsize * len(rows),
        data=np.frombuffer(rows.tobytes(), dtype=np.uint8),
        is_dense=True,
    )


def write_lidar_bag(path, scans: int = 40, columns: int = 360, seed: int = 0) -> None:
    """Write the bag: `scans` sweeps of RINGS x `columns` points, odometry at 50 Hz."""
    rng = np.random.default_rng(seed)
    elevation = np.deg2rad(np.linspace(-15.0, 15.0, RINGS))
    column, ring = np.repeat(np.arange(columns), RINGS), np.tile(np.arange(RINGS), columns)
    azimuth = 2 * np.pi * column / columns
    beams = np.stack([np.cos(elevation[ring]) * np.cos(azimuth), np.cos(elevation[ring]) * np.sin(azimuth),
                      np.sin(elevation[ring])], axis=1)  # fmt: skip
    with Writer(Path(path), version=9, storage_plugin=StoragePlugin.MCAP) as bag:
        topics = {
            name: bag.add_connection(name, kind, typestore=store)
            for name, kind in (
                ("/tf_static", "tf2_msgs/msg/TFMessage"),
                ("/odom", "nav_msgs/msg/Odometry"),
                ("/velodyne_points", "sensor_msgs/msg/PointCloud2"),
            )
        }
        transform = msg["geometry_msgs/msg/Transform"](
            translation=msg["geometry_msgs/msg/Vector3"](*T_BASE_LIDAR[:3, 3]),
            rotation=msg["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
        )
        stamped = msg["geometry_msgs/msg/TransformStamped"](
            header=header(T0_NS, "base_link"), child_frame_id="velodyne", transform=transform
        )
        tf = msg["tf2_msgs/msg/TFMessage"](transforms=[stamped])
        bag.write(topics["/tf_static"], T0_NS, store.serialize_cdr(tf, "tf2_msgs/msg/TFMessage"))
        odometry_s = np.arange(-0.04, (scans + 1) * SWEEP_S + 1e-9, 0.02)  # from before the first sweep
        events = [(t, "/odom") for t in odometry_s] + [((k + 1) * SWEEP_S, "/velodyne_points") for k in range(scans)]
        for t_s, topic in sorted(events):
            stamp = T0_NS + int(round(t_s * 1e9))
            if topic == "/odom":
                data = store.serialize_cdr(odometry(stamp, T_odom_base([t_s])[0]), "nav_msgs/msg/Odometry")
                bag.write(topics[topic], stamp, data)
                continue
            # the stamp marks the sweep's end: column c fires at (c / columns - 1) * SWEEP_S
            offsets = (column / columns - 1.0) * SWEEP_S + ring * 2.3e-6
            T_odom_lidar = T_odom_base(t_s + offsets) @ T_BASE_LIDAR
            origins, directions = T_odom_lidar[:, :3, 3], np.einsum("nij,nj->ni", T_odom_lidar[:, :3, :3], beams)
            ranges = room_ranges(origins, directions) + rng.normal(0.0, 0.005, len(beams))
            rows = np.zeros(len(beams), POINT)
            rows["x"], rows["y"], rows["z"] = (beams * ranges[:, None]).T
            floor = (origins + directions * ranges[:, None])[:, 2] < ROOM_LOW[2] + 0.01
            rows["intensity"] = np.where(floor, 12.0, 60.0) + rng.uniform(0, 20, len(beams))  # a dark floor
            rows["ring"], rows["time"] = ring, offsets
            bag.write(topics[topic], stamp, store.serialize_cdr(cloud(stamp, rows), "sensor_msgs/msg/PointCloud2"))


write_lidar_bag("lidar_bag")
print("wrote lidar_bag/ (ROS 2, MCAP): /velodyne_points (16 rings x 360 columns), /odom, /tf_static")
