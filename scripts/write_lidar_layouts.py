#!/usr/bin/env python3
"""Writes the LiDAR sweeps of an EuRoC folder (povins' `mav0/lidar0/data.csv`) as the LiDAR
drivers publish them, with an independent writer (Python `rosbags`, numpy; none of povins' code),
for `host-tools/tests/lidar_layouts.rs`:

    python3 scripts/write_lidar_layouts.py SRC_EUROC OUT_DIR

- OUT_DIR/layouts.bag: ROS 1 bag, `/imu0` (sensor_msgs/Imu) and one LiDAR topic per layout;
- OUT_DIR/layouts2/: ROS 2 bag (sqlite3), the same topics but `livox_ros_driver` (ROS 1 only).

Layouts, from the drivers' point types (offsets as their PCL structs lay them out):
- /ouster/points    ouster-ros: x y z (pad) intensity@16 f32, t@20 u32 ns after the stamp,
                    reflectivity@24 u16, ring@26 u16, ambient@28 u16, range@32 u32 mm; 48 bytes
- /velodyne_points  velodyne_pointcloud XYZIRT: x y z intensity f32, ring@16 u16, time@18 f32
                    s after the stamp; 22 bytes
- /hesai/pandar     Hesai: x y z (pad) intensity@16 f32, timestamp@24 f64 s since the epoch,
                    ring@32 u16; 48 bytes
- /rslidar_points   rslidar_sdk XYZIRT: x y z (pad) intensity@16 f32, ring@20 u16,
                    timestamp@24 f64 s since the epoch; 32 bytes
- /livox/lidar_pc2  livox_ros_driver2 PointCloud2: x y z intensity f32, tag@16 u8, line@17 u8,
                    timestamp@18 f64 ns since the epoch; 26 bytes
- /livox/lidar      livox_ros_driver/CustomMsg (ROS 1 bag only)
- /livox2/lidar     livox_ros_driver2/CustomMsg
Header stamps are the sweep stamps of the CSV, except CustomMsg's: the first point's time
(`timebase`), as the Livox drivers stamp them. Log times equal the stamps.
"""

import sys
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Bag1Writer
from rosbags.rosbag2 import Writer as Bag2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

F32, F64, U8, U16, U32 = 7, 8, 2, 4, 6
NP = {F32: "<f4", F64: "<f8", U8: "u1", U16: "<u2", U32: "<u4"}

LAYOUTS = {
    "/ouster/points": (48, [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 16, F32),
                            ("t", 20, U32), ("reflectivity", 24, U16), ("ring", 26, U16),
                            ("ambient", 28, U16), ("range", 32, U32)]),
    "/velodyne_points": (22, [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 12, F32),
                              ("ring", 16, U16), ("time", 18, F32)]),
    "/hesai/pandar": (48, [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 16, F32),
                           ("timestamp", 24, F64), ("ring", 32, U16)]),
    "/rslidar_points": (32, [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 16, F32),
                             ("ring", 20, U16), ("timestamp", 24, F64)]),
    "/livox/lidar_pc2": (26, [("x", 0, F32), ("y", 4, F32), ("z", 8, F32), ("intensity", 12, F32),
                              ("tag", 16, U8), ("line", 17, U8), ("timestamp", 18, F64)]),
}

CUSTOM_POINT = """uint32 offset_time
float32 x
float32 y
float32 z
uint8 reflectivity
uint8 tag
uint8 line
"""


def custom_msg(pkg):
    return f"""std_msgs/Header header
uint64 timebase
uint32 point_num
uint8 lidar_id
uint8[3] rsvd
{pkg}/CustomPoint[] points
"""


def register_livox(ts, pkgs):
    types = {}
    for pkg in pkgs:
        types.update(get_types_from_msg(CUSTOM_POINT, f"{pkg}/msg/CustomPoint"))
        types.update(get_types_from_msg(custom_msg(pkg), f"{pkg}/msg/CustomMsg"))
    ts.register(types)


def read_sweeps(src):
    """[(sweep_t_ns, points (n x 5: t_ns, x, y, z, intensity))] of lidar0/data.csv."""
    rows = (src / "mav0/lidar0/data.csv").read_text().splitlines()
    sweeps = {}
    for r in rows:
        if r.startswith("#") or not r.strip():
            continue
        v = r.split(",")
        sweeps.setdefault(int(v[0]), []).append((int(v[1]), float(v[2]), float(v[3]),
                                                  float(v[4]), float(v[5])))
    return sorted(sweeps.items())


def read_imu(src):
    out = []
    for r in (src / "mav0/imu0/data.csv").read_text().splitlines():
        if r.startswith("#") or not r.strip():
            continue
        v = r.split(",")
        out.append((int(v[0]), [float(x) for x in v[1:7]]))
    return out


def epoch_s(t_ns):
    """Seconds since the epoch as float64, the fraction kept to the nanosecond float64 allows."""
    return float(t_ns // 10**9) + (t_ns % 10**9) * 1e-9


def cloud_data(stamp, pts, step, fields):
    names = [f[0] for f in fields]
    dt = np.dtype({"names": names, "formats": [NP[f[2]] for f in fields],
                   "offsets": [f[1] for f in fields], "itemsize": step})
    a = np.zeros(len(pts), dtype=dt)
    t = np.array([p[0] for p in pts], dtype=np.int64)
    xyz = np.array([[p[1], p[2], p[3]] for p in pts], dtype=np.float32)
    a["x"], a["y"], a["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    a["intensity"] = np.array([p[4] for p in pts], dtype=np.float32)
    if "t" in names:
        a["t"] = (t - stamp).astype(np.uint32)
    if "time" in names:
        a["time"] = ((t - stamp) * 1e-9).astype(np.float32)
    if "range" in names:
        a["range"] = np.round(np.linalg.norm(xyz.astype(np.float64), axis=1) * 1e3)
    if "timestamp" in names:
        if names[-1] == "timestamp" and step == 26:  # livox2: ns since the epoch
            a["timestamp"] = t.astype(np.float64)
        else:
            a["timestamp"] = np.array([epoch_s(int(x)) for x in t])
    return np.frombuffer(a.tobytes(), dtype=np.uint8)


def messages(ts, ros1, sweeps, imu):
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vector3, Quaternion = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    Imu, PC2, PF = T["sensor_msgs/msg/Imu"], T["sensor_msgs/msg/PointCloud2"], T["sensor_msgs/msg/PointField"]

    def header(t_ns, seq, frame):
        stamp = Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        return Header(seq=seq, stamp=stamp, frame_id=frame) if ros1 else Header(stamp=stamp, frame_id=frame)

    out = []
    for i, (t, v) in enumerate(imu):
        m = Imu(header=header(t, i, "imu"), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.array([-1.0] + [0.0] * 8),
                angular_velocity=Vector3(x=v[0], y=v[1], z=v[2]),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=Vector3(x=v[3], y=v[4], z=v[5]),
                linear_acceleration_covariance=np.zeros(9))
        out.append((t, "/imu0", "sensor_msgs/msg/Imu", m))
    pkgs = ["livox_ros_driver", "livox_ros_driver2"] if ros1 else ["livox_ros_driver2"]
    for k, (stamp, pts) in enumerate(sweeps):
        for topic, (step, fields) in LAYOUTS.items():
            data = cloud_data(stamp, pts, step, fields)
            m = PC2(header=header(stamp, k, "lidar"), height=1, width=len(pts),
                    fields=[PF(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
                    is_bigendian=False, point_step=step, row_step=step * len(pts), data=data,
                    is_dense=True)
            out.append((stamp, topic, "sensor_msgs/msg/PointCloud2", m))
        base = min(p[0] for p in pts)
        for pkg in pkgs:
            CM, CP = T[f"{pkg}/msg/CustomMsg"], T[f"{pkg}/msg/CustomPoint"]
            cps = [CP(offset_time=p[0] - base, x=p[1], y=p[2], z=p[3],
                      reflectivity=int(min(max(p[4], 0), 255)), tag=0, line=0) for p in pts]
            m = CM(header=header(base, k, "livox_frame"), timebase=base, point_num=len(cps),
                   lidar_id=0, rsvd=np.zeros(3, dtype=np.uint8), points=cps)
            topic = "/livox/lidar" if pkg == "livox_ros_driver" else "/livox2/lidar"
            out.append((base, topic, f"{pkg}/msg/CustomMsg", m))
    out.sort(key=lambda x: (x[0], x[1]))
    return out


def main():
    src, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    sweeps, imu = read_sweeps(src), read_imu(src)
    ts1 = get_typestore(Stores.ROS1_NOETIC)
    register_livox(ts1, ["livox_ros_driver", "livox_ros_driver2"])
    with Bag1Writer(out / "layouts.bag") as wr:
        conns = {}
        for t, topic, ty, m in messages(ts1, True, sweeps, imu):
            if topic not in conns:
                conns[topic] = wr.add_connection(topic, ty, typestore=ts1)
            wr.write(conns[topic], t, ts1.serialize_ros1(m, ty))
    ts2 = get_typestore(Stores.ROS2_HUMBLE)
    register_livox(ts2, ["livox_ros_driver2"])
    with Bag2Writer(out / "layouts2", version=9) as wr:
        conns = {}
        for t, topic, ty, m in messages(ts2, False, sweeps, imu):
            if topic not in conns:
                conns[topic] = wr.add_connection(topic, ty, typestore=ts2)
            wr.write(conns[topic], t, ts2.serialize_cdr(m, ty))
    print(f"{len(sweeps)} sweeps, {sum(len(p) for _, p in sweeps)} points, {len(imu)} IMU samples")


if __name__ == "__main__":
    main()
