"""A stand-in for your own bag: a ROS 2 (MCAP) bag of point clouds and odometry.

A simulated survey of the `boxes` scene is written as a robot would record it: the sonar's
returns as `sensor_msgs/PointCloud2` in the `sonar` frame on /points, the vehicle's
(drifting) navigation as `nav_msgs/Odometry` of `base_link` in `odom` on /odom, and the
sonar's mount in /tf_static. Written with rosbags; no ROS installation needed.
"""

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from vogjax.io.dataset import Dataset
from vogjax.sim import simulate_run

simulate_run("boxes", "boxes.h5", laps=2, progress=False, overwrite=True)
store = get_typestore(Stores.ROS2_HUMBLE)
msg = store.types
T0_NS = 1_700_000_000 * 10**9  # bags carry wall-clock stamps


def header(stamp_ns: int, frame: str):
    stamp = msg["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    return msg["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def pose(T: np.ndarray):
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return msg["geometry_msgs/msg/Pose"](
        position=msg["geometry_msgs/msg/Point"](*T[:3, 3]), orientation=msg["geometry_msgs/msg/Quaternion"](x, y, z, w)
    )


def odometry(stamp_ns: int, T_odom_base: np.ndarray):
    zero = msg["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)
    return msg["nav_msgs/msg/Odometry"](
        header=header(stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=msg["geometry_msgs/msg/PoseWithCovariance"](pose=pose(T_odom_base), covariance=np.zeros(36)),
        twist=msg["geometry_msgs/msg/TwistWithCovariance"](
            twist=msg["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
        ),
    )


def cloud(stamp_ns: int, points: np.ndarray):
    Field = msg["sensor_msgs/msg/PointField"]
    data = np.ascontiguousarray(points, dtype="<f4")
    return msg["sensor_msgs/msg/PointCloud2"](
        header=header(stamp_ns, "sonar"),
        height=1,
        width=len(points),
        fields=[Field(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")],  # 7: FLOAT32
        is_bigendian=False,
        point_step=12,
        row_step=12 * len(points),
        data=data.view(np.uint8).ravel(),
        is_dense=True,
    )


def mount(T_base_sonar: np.ndarray):
    q = Rotation.from_matrix(T_base_sonar[:3, :3]).as_quat()
    transform = msg["geometry_msgs/msg/Transform"](
        translation=msg["geometry_msgs/msg/Vector3"](*T_base_sonar[:3, 3]),
        rotation=msg["geometry_msgs/msg/Quaternion"](*q),
    )
    stamped = msg["geometry_msgs/msg/TransformStamped"](
        header=header(T0_NS, "base_link"), child_frame_id="sonar", transform=transform
    )
    return msg["tf2_msgs/msg/TFMessage"](transforms=[stamped])


with Dataset("boxes.h5") as run:
    T_base_sonar = np.asarray(run.metadata["T_vehicle_sensor"])
    with Writer("survey_bag", version=9, storage_plugin=StoragePlugin.MCAP) as bag:
        topics = {
            "/tf_static": bag.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=store),
            "/odom": bag.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=store),
            "/points": bag.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=store),
        }
        bag.write(topics["/tf_static"], T0_NS, store.serialize_cdr(mount(T_base_sonar), "tf2_msgs/msg/TFMessage"))
        T_sonar_base = np.linalg.inv(T_base_sonar)
        for batch in run.batches(200):
            for s in range(len(batch)):
                stamp = T0_NS + int(round(batch.time_s[s] * 1e9))
                odom = odometry(stamp, batch.pose_nav[s])
                bag.write(topics["/odom"], stamp, store.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
                hit = ~batch.no_return[s]
                ends = batch.sonar_origin[s] + batch.sonar_directions[s][hit] * batch.ranges[s][hit, None]
                points = ends @ T_sonar_base[:3, :3].T + T_sonar_base[:3, 3]  # vehicle frame -> sonar frame
                if len(points):
                    bag.write(
                        topics["/points"],
                        stamp,
                        store.serialize_cdr(cloud(stamp, points), "sensor_msgs/msg/PointCloud2"),
                    )
print("wrote survey_bag/ (ROS 2, MCAP): /points, /odom, /tf_static")
