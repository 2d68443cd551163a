#!/usr/bin/env python3
"""Reads a ROS 1 bag with an independent reader (the Python `rosbags` package) and prints what it
holds as JSON, after checking each connection against what `rosbags` itself writes:

- the type's md5sum equals the one `rosbags` computes for that type (ROS 1 Noetic messages),
- the connection's message_definition parses (rosbags' msg parser) to the same fields as the
  type `rosbags` knows, nested types included,
- the md5sum computed from the connection's own definition text is its md5sum,
- every message deserializes with that type and uses all its bytes.

    /work/venv-rosbags/bin/python scripts/check_rosbag1.py BAG > out.json

The JSON: {"connections": [{"topic", "type", "md5sum"}], "messages": {topic: [message...]}}
with floats as their IEEE 754 bits (integers, exact) and byte arrays as hex. Messages per type:
- sensor_msgs/Imu: {"t", "stamp", "seq", "frame_id", "gyro", "accel", "orientation", "ocov0"}
- sensor_msgs/Image: {"t", "stamp", "width", "height", "encoding", "step", "data"}
- sensor_msgs/CompressedImage: {"t", "stamp", "format", "data"}
- sensor_msgs/PointCloud2: {"t", "stamp", "fields": [[name, offset, datatype, count]],
  "points": [[x, y, z, intensity, t]]} (x y z intensity float32, t uint32 at their offsets)
Other types: {"t"} (and "stamp" when they have a header). Exit status 1 with a message on stderr when a check fails. `povins`' test
`rosbag1::write::tests::python_rosbags_reads_our_bags` runs it on bags our writer makes.
"""

import json
import struct
import sys
from pathlib import Path

from rosbags.rosbag1 import Reader
from rosbags.typesys import Stores, get_typestore, get_types_from_msg


def fail(msg: str) -> None:
    print(f"check_rosbag1: {msg}", file=sys.stderr)
    sys.exit(1)


def stamp_ns(h) -> int:
    return h.stamp.sec * 10**9 + h.stamp.nanosec


def fx(v: float) -> int:
    """The IEEE 754 bits of a double (compared exactly with Rust's `f64::to_bits`)."""
    return struct.unpack("<Q", struct.pack("<d", float(v)))[0]


def check_connection(ts, conn) -> None:
    ros2_name = conn.msgtype  # rosbags names types pkg/msg/Name
    _, md5 = ts.generate_msgdef(ros2_name)
    if conn.digest != md5:
        fail(f"{conn.topic}: md5sum {conn.digest} but rosbags computes {md5} for {ros2_name}")
    parsed = get_types_from_msg(conn.msgdef.data, ros2_name)
    for name, (consts, fields) in parsed.items():
        want = ts.fielddefs.get(name)
        if want is None:
            fail(f"{conn.topic}: definition names unknown type {name}")
        if list(fields) != list(want[1]):
            fail(f"{conn.topic}: {name} fields {fields} differ from rosbags' {want[1]}")
        if sorted(consts) != sorted(want[0]):
            fail(f"{conn.topic}: {name} constants {consts} differ from rosbags' {want[0]}")
    own = get_typestore(Stores.EMPTY)
    own.register(parsed)
    _, own_md5 = own.generate_msgdef(ros2_name)
    if own_md5 != conn.digest:
        fail(f"{conn.topic}: the definition in the bag hashes to {own_md5}, not {conn.digest}")


def message(ty: str, t: int, m) -> dict:
    out = {"t": t}
    if hasattr(m, "header"):
        out["stamp"] = stamp_ns(m.header)
    if ty == "sensor_msgs/msg/Imu":
        w, a, q = m.angular_velocity, m.linear_acceleration, m.orientation
        out.update(seq=m.header.seq, frame_id=m.header.frame_id,
                   gyro=[fx(w.x), fx(w.y), fx(w.z)], accel=[fx(a.x), fx(a.y), fx(a.z)],
                   orientation=[fx(q.x), fx(q.y), fx(q.z), fx(q.w)],
                   ocov0=fx(m.orientation_covariance[0]))
    elif ty == "sensor_msgs/msg/Image":
        out.update(width=m.width, height=m.height, encoding=m.encoding, step=m.step,
                   data=bytes(m.data).hex())
    elif ty == "sensor_msgs/msg/CompressedImage":
        out.update(format=m.format, data=bytes(m.data).hex())
    elif ty == "sensor_msgs/msg/PointCloud2":
        fields = [[f.name, f.offset, f.datatype, f.count] for f in m.fields]
        off = {f.name: f.offset for f in m.fields}
        data = bytes(m.data)
        points = []
        for i in range(m.width * m.height):
            base = i * m.point_step
            xyzi = [fx(struct.unpack_from("<f", data, base + off[k])[0])
                    for k in ("x", "y", "z", "intensity")]
            points.append(xyzi + [struct.unpack_from("<I", data, base + off["t"])[0]])
        out.update(fields=fields, points=points)
    return out


def main() -> None:
    if len(sys.argv) != 2:
        fail("usage: check_rosbag1.py BAG")
    ts = get_typestore(Stores.ROS1_NOETIC)
    result = {"connections": [], "messages": {}}
    with Reader(Path(sys.argv[1])) as rd:
        for c in rd.connections:
            check_connection(ts, c)
            result["connections"].append(
                {"topic": c.topic, "type": c.msgtype, "md5sum": c.digest})
        for conn, t, raw in rd.messages():
            m = ts.deserialize_ros1(raw, conn.msgtype)
            if ts.serialize_ros1(m, conn.msgtype) != bytes(raw):
                fail(f"{conn.topic} at {t}: the message does not re-serialize to its bytes")
            result["messages"].setdefault(conn.topic, []).append(message(conn.msgtype, t, m))
    json.dump(result, sys.stdout)


if __name__ == "__main__":
    main()
