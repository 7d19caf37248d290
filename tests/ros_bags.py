"""ROS 1 and ROS 2 bags of the bundled flight for tests, written by rosbags' own writers (ROS 1
``.bag``; ROS 2 SQLite and MCAP) with its standard message types: never hand-made bytes.

Each bag holds what a drone's ROS stack records: the camera's JPEGs (``CompressedImage``) and
``CameraInfo``, MAVROS' ``NavSatFix`` (ellipsoidal altitude: the flight's altitude plus
``ELLIPSOID_OFFSET_M``) and ``rel_alt`` (the flight's altitude), the gimbal's attitude as a
``QuaternionStamped`` in ROS's ENU/FLU convention and the airframe's ``Imu`` (level, yawing)."""

from __future__ import annotations

import json
from datetime import datetime
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

FLIGHT = Path(__file__).resolve().parents[1] / "harborsight" / "data" / "samples" / "flight"
ELLIPSOID_OFFSET_M = 42.5
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])


def flight_frame(index: int) -> dict:
    return json.loads((FLIGHT / "frames" / f"{index:06d}.json").read_text())


def enu_flu_quaternion(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """(x, y, z, w) of R_ENU<-FLU for a NED ZYX attitude: M^-1 · R_NED<-FRD · F^-1 (both
    M and F are their own inverses)."""
    ned = Rotation.from_euler("ZYX", [yaw_deg, pitch_deg, roll_deg], degrees=True).as_matrix()
    return Rotation.from_matrix(ENU_TO_NED @ ned @ FRD_TO_FLU).as_quat()


def _stamp(types, seconds: float):
    sec = int(np.floor(seconds))
    return types["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((seconds - sec) * 1e9))


def _header(types, ros1: bool, seconds: float, frame_id: str):
    fields = {"stamp": _stamp(types, seconds), "frame_id": frame_id}
    if ros1:
        fields["seq"] = 0
    return types["std_msgs/msg/Header"](**fields)


def flight_messages(types, ros1: bool, indices, *, with_images: bool = True,
                    covariance_m: float = 0.5) -> list[tuple[str, str, float, object]]:
    """(topic, type, time, message) for frames ``indices`` of the bundled flight."""
    out = []
    camera = flight_frame(0)["camera"]
    info_fields = {
        "header": _header(types, ros1, 0.0, "camera"), "height": camera["height"],
        "width": camera["width"], "distortion_model": "plumb_bob",
        "binning_x": 0, "binning_y": 0,
        "roi": types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                         width=0, do_rectify=False)}
    k = [camera["fx"], 0.0, camera["cx"], 0.0, camera["fy"], camera["cy"], 0.0, 0.0, 1.0]
    matrices = {"d": np.zeros(5), "k": np.array(k), "r": np.eye(3).ravel(),
                "p": np.array([*k[:3], 0.0, *k[3:6], 0.0, *k[6:], 0.0])}
    if ros1:
        matrices = {name.upper(): value for name, value in matrices.items()}
    for index in indices:
        frame = flight_frame(index)
        seconds = datetime.fromisoformat(frame["timestamp"].replace("Z", "+00:00")).timestamp()
        uav, attitude = frame["uav"], frame["camera_attitude"]
        header = _header(types, ros1, seconds, "map")
        if with_images:
            data = (FLIGHT / "images" / frame["image"]).read_bytes()
            out.append(("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage", seconds,
                        types["sensor_msgs/msg/CompressedImage"](
                            header=header, format="jpeg", data=np.frombuffer(data, np.uint8))))
            info = types["sensor_msgs/msg/CameraInfo"](**{**info_fields, **matrices,
                                                          "header": header})
            out.append(("/camera/camera_info", "sensor_msgs/msg/CameraInfo", seconds, info))
        status = types["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
        covariance = np.diag([covariance_m ** 2, covariance_m ** 2, 1.0]).ravel()
        out.append(("/mavros/global_position/global", "sensor_msgs/msg/NavSatFix", seconds,
                    types["sensor_msgs/msg/NavSatFix"](
                        header=header, status=status, latitude=uav["lat"], longitude=uav["lon"],
                        altitude=uav["alt_m"] + ELLIPSOID_OFFSET_M,
                        position_covariance=covariance, position_covariance_type=2)))
        out.append(("/mavros/global_position/rel_alt", "std_msgs/msg/Float64", seconds,
                    types["std_msgs/msg/Float64"](data=uav["alt_m"])))
        x, y, z, w = enu_flu_quaternion(attitude["yaw_deg"], attitude["pitch_deg"],
                                        attitude["roll_deg"])
        out.append(("/gimbal/attitude", "geometry_msgs/msg/QuaternionStamped", seconds,
                    types["geometry_msgs/msg/QuaternionStamped"](
                        header=header, quaternion=types["geometry_msgs/msg/Quaternion"](
                            x=x, y=y, z=z, w=w))))
        bx, by, bz, bw = enu_flu_quaternion(attitude["yaw_deg"], 0.0, 0.0)
        zero = types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        out.append(("/mavros/imu/data", "sensor_msgs/msg/Imu", seconds,
                    types["sensor_msgs/msg/Imu"](
                        header=header, orientation=types["geometry_msgs/msg/Quaternion"](
                            x=bx, y=by, z=bz, w=bw),
                        orientation_covariance=np.zeros(9), angular_velocity=zero,
                        angular_velocity_covariance=np.zeros(9), linear_acceleration=zero,
                        linear_acceleration_covariance=np.zeros(9))))
    return out


def write_flight_bag(path: Path, kind: str, indices, *, leave_out=None, **options) -> Path:
    """A bag of the flight's frames ``indices``: ``kind`` is ``ros1`` (``path`` a .bag file),
    ``sqlite3`` or ``mcap`` (``path`` a ROS 2 bag folder); ``leave_out(topic, seconds)``, the
    messages not to write (a dropout). Returns the bag's path."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = kind == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    messages = [m for m in flight_messages(store.types, ros1, indices, **options)
                if leave_out is None or not leave_out(m[0], m[2])]
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        writer.chunk_threshold = 64 * 1024
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    with writer:
        connections = {}
        for topic, msgtype, seconds, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            data = (store.serialize_ros1(message, msgtype) if ros1
                    else store.serialize_cdr(message, msgtype))
            writer.write(connections[topic], round(seconds * 1e9), data)
    return path
