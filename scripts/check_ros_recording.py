#!/usr/bin/env python3
"""Reads a ROS 2 bag folder (sqlite3 or MCAP storage) with Python `rosbags`, or an MCAP file of
ROS 1 messages with PyPI `mcap` + `mcap-ros1-support`, independently of povins, and prints what
it holds as JSON.

    python scripts/check_ros_recording.py RECORDING > out.json

Checks, exit status 1 with a message on stderr when one fails:
- ROS 2 bag: each topic's type description hash (`RIHS01_...`) is the one `rosbags` computes for
  the type (ROS 2 Jazzy messages), its stored definition parses to the type's fields, the counts
  of `metadata.yaml` are the messages read, every message deserializes as CDR and re-serializes
  to its bytes.
- MCAP (profile `ros1`): every schema is `ros1msg` and its md5sum, computed by `rosbags` from the
  schema text, is the one `rosbags` computes for the ROS 1 Noetic type; every message decodes
  with `mcap-ros1-support`'s decoder (built from the schema text) and with `rosbags`, which
  re-serializes it to its bytes.

The JSON: {"container", "topics": {topic: {"type", "count", "messages": [message...]}}}, with
per message {"t" (log time), "stamp"} and per type:
- Imu: "gyro", "accel" (IEEE 754 bits as integers, exact), "frame_id", "ocov0"
- Image: "width", "height", "encoding", "step", "sum" (sum of the data bytes)
- CompressedImage: "format", "bytes" (payload length)
- PointCloud2: "points" (width x height)
`povins`' test `simulate_formats::independent_readers_read_our_recordings` runs it.
"""

import json
import struct
import sys
from pathlib import Path

from rosbags.typesys import Stores, get_typestore, get_types_from_msg


def fail(msg: str) -> None:
    print(f"check_ros_recording: {msg}", file=sys.stderr)
    sys.exit(1)


def fx(v: float) -> int:
    """The IEEE 754 bits of a double (compared exactly with Rust's `f64::to_bits`)."""
    return struct.unpack("<Q", struct.pack("<d", float(v)))[0]


def describe(ty: str, t: int, m) -> dict:
    out = {"t": t}
    h = getattr(m, "header", None)
    if h is not None:
        st = h.stamp
        out["stamp"] = st.sec * 10**9 + (st.nanosec if hasattr(st, "nanosec") else st.nsec)
    short = ty.replace("/msg/", "/")
    if short == "sensor_msgs/Imu":
        w, a = m.angular_velocity, m.linear_acceleration
        out.update(frame_id=m.header.frame_id, gyro=[fx(w.x), fx(w.y), fx(w.z)],
                   accel=[fx(a.x), fx(a.y), fx(a.z)], ocov0=fx(m.orientation_covariance[0]))
    elif short == "sensor_msgs/Image":
        out.update(width=m.width, height=m.height, encoding=m.encoding, step=m.step,
                   sum=sum(bytes(m.data)))
    elif short == "sensor_msgs/CompressedImage":
        out.update(format=m.format, bytes=len(bytes(m.data)))
    elif short == "sensor_msgs/PointCloud2":
        out.update(points=m.width * m.height)
    return out


def check_fields(ts, conn_topic: str, ty: str, text: str) -> None:
    parsed = get_types_from_msg(text, ty)
    for name, (_consts, fields) in parsed.items():
        want = ts.fielddefs.get(name)
        if want is None:
            fail(f"{conn_topic}: definition names unknown type {name}")
        if [f[0] for f in fields] != [f[0] for f in want[1]]:
            fail(f"{conn_topic}: {name} fields {fields} differ from rosbags' {want[1]}")


def read_rosbag2(path: Path) -> dict:
    from rosbags.rosbag2 import Reader
    import yaml

    ts = get_typestore(Stores.ROS2_JAZZY)
    meta = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    want_counts = {t["topic_metadata"]["name"]: t["message_count"]
                   for t in meta["topics_with_message_count"]}
    topics: dict = {}
    with Reader(path) as rd:
        for c in rd.connections:
            rihs = ts.hash_rihs01(c.msgtype)
            if c.digest != rihs:
                fail(f"{c.topic}: type hash {c.digest}, rosbags computes {rihs}")
            check_fields(ts, c.topic, c.msgtype, c.msgdef.data)
            topics[c.topic] = {"type": c.msgtype, "count": 0, "messages": []}
        for c, t, raw in rd.messages():
            m = ts.deserialize_cdr(raw, c.msgtype)
            if ts.serialize_cdr(m, c.msgtype) != bytes(raw):
                fail(f"{c.topic} at {t}: the message does not re-serialize to its bytes")
            topics[c.topic]["count"] += 1
            topics[c.topic]["messages"].append(describe(c.msgtype, t, m))
    for name, n in want_counts.items():
        if topics.get(name, {}).get("count") != n:
            fail(f"{name}: metadata.yaml counts {n} messages, read {topics.get(name)}")
    return {"container": f"rosbag2 {meta['storage_identifier']}", "topics": topics}


def read_mcap_ros1(path: Path) -> dict:
    from mcap.reader import make_reader
    from mcap_ros1.decoder import DecoderFactory

    ts = get_typestore(Stores.ROS1_NOETIC)
    topics: dict = {}
    with path.open("rb") as f:
        rd = make_reader(f, decoder_factories=[DecoderFactory()])
        header = rd.get_header()
        if header.profile != "ros1":
            fail(f"profile {header.profile!r}, not ros1")
        summary = rd.get_summary()
        for sch in summary.schemas.values():
            if sch.encoding != "ros1msg":
                fail(f"schema {sch.name}: encoding {sch.encoding}")
            ros2_name = sch.name.replace("/", "/msg/", 1)
            parsed = get_types_from_msg(sch.data.decode(), ros2_name)
            own = get_typestore(Stores.EMPTY)
            own.register(parsed)
            _, own_md5 = own.generate_msgdef(ros2_name)
            _, md5 = ts.generate_msgdef(ros2_name)
            if own_md5 != md5:
                fail(f"schema {sch.name}: its text hashes to {own_md5}, rosbags' type to {md5}")
        for sch, ch, msg, decoded in rd.iter_decoded_messages(log_time_order=True):
            if ch.message_encoding != "ros1":
                fail(f"{ch.topic}: message encoding {ch.message_encoding}")
            ros2_name = sch.name.replace("/", "/msg/", 1)
            m = ts.deserialize_ros1(msg.data, ros2_name)
            if ts.serialize_ros1(m, ros2_name) != bytes(msg.data):
                fail(f"{ch.topic} at {msg.log_time}: the message does not re-serialize")
            if hasattr(decoded, "header") and decoded.header.stamp.to_nsec() != (
                    m.header.stamp.sec * 10**9 + m.header.stamp.nanosec):
                fail(f"{ch.topic} at {msg.log_time}: the two decoders disagree on the stamp")
            t = topics.setdefault(ch.topic, {"type": sch.name, "count": 0, "messages": []})
            t["count"] += 1
            t["messages"].append(describe(sch.name, msg.log_time, m))
        stats = summary.statistics
        if stats is not None:
            for cid, n in stats.channel_message_counts.items():
                topic = summary.channels[cid].topic
                if topics.get(topic, {}).get("count") != n:
                    fail(f"{topic}: statistics count {n} messages")
    return {"container": "mcap ros1", "topics": topics}


def main() -> None:
    if len(sys.argv) != 2:
        fail("usage: check_ros_recording.py RECORDING")
    p = Path(sys.argv[1])
    result = read_rosbag2(p) if p.is_dir() else read_mcap_ros1(p)
    json.dump(result, sys.stdout)


if __name__ == "__main__":
    main()
