#!/usr/bin/env python3
"""Writes a ROS 1 bag from an EuRoC folder with an independent writer (the Python `rosbags`
package), streaming: /imu0 sensor_msgs/Imu (every row) and /cam0/image_raw sensor_msgs/Image
mono8 (every image, full size), stamps from the EuRoC rows and file names, receipt times equal
to the stamps. For the reading-speed and memory figures of BENCHMARKS.md (issue 30, bar 3):

    povins simulate --scenario flight --duration 600 --images --format euroc --out /tmp/f600
    /work/venv-rosbags/bin/pip install rosbags numpy pillow
    python scripts/make_long_bag.py /tmp/f600 /tmp/f600.bag [--seconds S]

`--seconds S` keeps the first S seconds only (the memory figure compares a run on the whole
bag with one on its first minute).
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore


def main() -> None:
    src, out = Path(sys.argv[1]), Path(sys.argv[2])
    seconds = float(sys.argv[sys.argv.index("--seconds") + 1]) if "--seconds" in sys.argv else None
    ts = get_typestore(Stores.ROS1_NOETIC)
    Imu, ImageMsg = ts.types["sensor_msgs/msg/Imu"], ts.types["sensor_msgs/msg/Image"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    Quat, Vec3 = ts.types["geometry_msgs/msg/Quaternion"], ts.types["geometry_msgs/msg/Vector3"]
    mav0 = src / "mav0"
    imu_rows = []
    for line in (mav0 / "imu0" / "data.csv").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        v = line.split(",")
        imu_rows.append((int(v[0]), [float(x) for x in v[1:7]]))
    cams = []
    for line in (mav0 / "cam0" / "data.csv").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        t, name = line.split(",")[:2]
        cams.append((int(t), mav0 / "cam0" / "data" / name.strip()))
    t0 = imu_rows[0][0]
    end = t0 + int(seconds * 1e9) if seconds else None
    zero9 = np.zeros(9)

    def header(t: int, frame: str):
        return Header(seq=0, stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id=frame)

    if out.exists():
        out.unlink()
    with Writer(out) as w:
        w.chunk_threshold = 4 * 1024 * 1024
        ci = w.add_connection("/imu0", Imu.__msgtype__, typestore=ts)
        cc = w.add_connection("/cam0/image_raw", ImageMsg.__msgtype__, typestore=ts)
        events = [(t, 0, r) for t, r in imu_rows] + [(t, 1, p) for t, p in cams]
        events.sort(key=lambda e: (e[0], e[1]))
        for t, kind, payload in events:
            if end is not None and t > end:
                break
            if kind == 0:
                g, a = payload[:3], payload[3:]
                m = Imu(header=header(t, "imu"), orientation=Quat(x=0, y=0, z=0, w=1),
                        orientation_covariance=zero9,
                        angular_velocity=Vec3(x=g[0], y=g[1], z=g[2]),
                        angular_velocity_covariance=zero9,
                        linear_acceleration=Vec3(x=a[0], y=a[1], z=a[2]),
                        linear_acceleration_covariance=zero9)
                w.write(ci, t, ts.serialize_ros1(m, Imu.__msgtype__))
            else:
                px = np.asarray(Image.open(payload).convert("L"), dtype=np.uint8)
                h, wd = px.shape
                m = ImageMsg(header=header(t, "cam0"), height=h, width=wd, encoding="mono8",
                             is_bigendian=0, step=wd, data=px.reshape(-1))
                w.write(cc, t, ts.serialize_ros1(m, ImageMsg.__msgtype__))


if __name__ == "__main__":
    main()
