#!/usr/bin/env python3
"""Writes every ROS container fixture of tests/data from one simulated sequence, each with an
independent writer (none of povins' code):

    povins simulate --scenario flight --duration 2 --format euroc --images --out /tmp/simrb
    python3 -m venv /work/venv-rosbags
    /work/venv-rosbags/bin/pip install rosbags numpy mcap pyyaml
    /work/venv-rosbags/bin/python scripts/make_ros_fixtures.py /tmp/simrb tests/data

- rosbag1-sim/sim.bag: ROS 1 bag (Python `rosbags`), see make_rosbag1_fixture.py.
- ros2-sim/sqlite3/: ROS 2 bag, sqlite3 storage (`rosbags.rosbag2.Writer`, version 9), split
  in two files at 2 s (each half written as a bag of its own; metadata.yaml lists both files,
  merged with PyYAML), as `ros2 bag record --max-bag-duration` leaves it.
- ros2-sim/mcap/: ROS 2 bag, MCAP storage (the same writer with the MCAP storage plugin).
- ros2-sim/ros1.mcap: MCAP with `ros1` message encoding and `ros1msg` schemas (the `mcap`
  package's Writer; messages serialized by `rosbags` for ROS 1), zstd chunks of 16 kB.
- ros2-sim/cdr-nosummary.mcap: MCAP with `cdr` encoding and `ros2msg` schemas, lz4 chunks of
  16 kB and no summary section (no statistics, no indexes, no summary offsets: the footer points
  at nothing), as a recorder that cannot write one leaves it.

Every container holds the same topics as sim.bag: /imu0 (sensor_msgs/Imu), /cam0/image_raw
(sensor_msgs/Image, 64x48, every raw encoding in turn, rows padded), /cam0/gray_png
(sensor_msgs/CompressedImage, the same images as PNG) and /chatter (std_msgs/String); log times
equal the header stamps.
"""

import shutil
import sys
from pathlib import Path

import numpy as np
import yaml
from mcap.writer import CompressionType, IndexType, Writer as McapWriter
from rosbags.rosbag2 import StoragePlugin, Writer as Bag2Writer
from rosbags.typesys import Stores, get_typestore

sys.path.insert(0, str(Path(__file__).parent))
import make_rosbag1_fixture as rb1  # noqa: E402

CHUNK = 16 * 1024


def messages(src: Path, ts, ros1: bool):
    """(t_ns, topic, type, message) of the sequence, built with typestore `ts`."""
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vector3, Quaternion = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    Imu, Image = T["sensor_msgs/msg/Imu"], T["sensor_msgs/msg/Image"]
    CompressedImage, String = T["sensor_msgs/msg/CompressedImage"], T["std_msgs/msg/String"]

    def header(t_ns, seq, frame):
        stamp = Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        if ros1:
            return Header(seq=seq, stamp=stamp, frame_id=frame)
        return Header(stamp=stamp, frame_id=frame)

    out = []
    rows = (src / "mav0/imu0/data.csv").read_text().splitlines()[1:]
    for i, row in enumerate(rows):
        v = row.split(",")
        t = int(v[0])
        cov = np.zeros(9, np.float64)
        m = Imu(header=header(t, i, "imu0"), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.array([-1.0] + [0.0] * 8),
                angular_velocity=Vector3(x=float(v[1]), y=float(v[2]), z=float(v[3])),
                angular_velocity_covariance=cov,
                linear_acceleration=Vector3(x=float(v[4]), y=float(v[5]), z=float(v[6])),
                linear_acceleration_covariance=cov)
        out.append((t, "/imu0", "sensor_msgs/msg/Imu", m))
    images = sorted((src / "mav0/cam0/data").glob("*.png"), key=lambda p: int(p.stem))[::3]
    W, H = rb1.W, rb1.H
    for k, path in enumerate(images):
        t = int(path.stem)
        full = rb1.read_png_gray(path)
        ys = (np.arange(H // 2) * full.shape[0] // (H // 2))
        xs = (np.arange(W // 2) * full.shape[1] // (W // 2))
        g = np.repeat(np.repeat(full[np.ix_(ys, xs)], 2, axis=0), 2, axis=1)
        enc = rb1.ENCODINGS[k % len(rb1.ENCODINGS)]
        bpp, px = rb1.encode(enc, g)
        rows_b = np.asarray(px, np.uint8).reshape(H, W * bpp)
        data = np.concatenate([rows_b, np.full((H, 3), 0xEE, np.uint8)], axis=1).reshape(-1)
        out.append((t, "/cam0/image_raw", "sensor_msgs/msg/Image",
                    Image(header=header(t, k, "cam0"), height=H, width=W, encoding=enc,
                          is_bigendian=0, step=W * bpp + 3, data=data)))
        out.append((t, "/cam0/gray_png", "sensor_msgs/msg/CompressedImage",
                    CompressedImage(header=header(t, k, "cam0"), format="png",
                                    data=np.frombuffer(rb1.png_gray(g), np.uint8))))
        out.append((t, "/chatter", "std_msgs/msg/String", String(data=f"frame {k} {enc}")))
    return sorted(out, key=lambda x: (x[0], x[1]))


def write_rosbag2(src: Path, out: Path, plugin, keep=lambda t: True) -> None:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    if out.exists():
        shutil.rmtree(out)
    with Bag2Writer(out, version=9, storage_plugin=plugin) as wr:
        conns = {}
        for t, topic, ty, m in messages(src, ts, ros1=False):
            if topic not in conns:
                conns[topic] = wr.add_connection(topic, ty, typestore=ts)
            if keep(t):
                wr.write(conns[topic], t, ts.serialize_cdr(m, ty))


def write_split_sqlite3(src: Path, out: Path, split_ns: int) -> None:
    """A sqlite3 bag split in two files at `split_ns`."""
    tmp = out.parent / (out.name + ".parts")
    shutil.rmtree(tmp, ignore_errors=True)
    write_rosbag2(src, tmp / "a", StoragePlugin.SQLITE3, lambda t: t < split_ns)
    write_rosbag2(src, tmp / "b", StoragePlugin.SQLITE3, lambda t: t >= split_ns)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir()
    metas = []
    for k, part in enumerate(["a", "b"]):
        shutil.copy(tmp / part / f"{part}.db3", out / f"sqlite3_{k}.db3")
        metas.append(yaml.safe_load((tmp / part / "metadata.yaml").read_text()))
    a, b = (m["rosbag2_bagfile_information"] for m in metas)
    a["relative_file_paths"] = ["sqlite3_0.db3", "sqlite3_1.db3"]
    for k, f in enumerate(a["files"] + b["files"]):
        f["path"] = f"sqlite3_{k}.db3"
    a["files"] = a["files"] + b["files"]
    a["message_count"] += b["message_count"]
    end = b["starting_time"]["nanoseconds_since_epoch"] + b["duration"]["nanoseconds"]
    a["duration"]["nanoseconds"] = end - a["starting_time"]["nanoseconds_since_epoch"]
    for ta, tb in zip(a["topics_with_message_count"], b["topics_with_message_count"]):
        assert ta["topic_metadata"]["name"] == tb["topic_metadata"]["name"]
        ta["message_count"] += tb["message_count"]
    (out / "metadata.yaml").write_text(yaml.safe_dump(metas[0], sort_keys=False))
    shutil.rmtree(tmp)


def write_mcap(src: Path, out: Path, ros1: bool) -> None:
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    with open(out, "wb") as f:
        if ros1:
            w = McapWriter(f, chunk_size=CHUNK, compression=CompressionType.ZSTD)
        else:
            w = McapWriter(f, chunk_size=CHUNK, compression=CompressionType.LZ4,
                           index_types=IndexType.NONE, repeat_channels=False,
                           repeat_schemas=False, use_statistics=False,
                           use_summary_offsets=False)
        w.start(profile="ros1" if ros1 else "ros2", library="mcap python + rosbags")
        chans = {}
        for seq, (t, topic, ty, m) in enumerate(messages(src, ts, ros1)):
            if topic not in chans:
                ros_ty = ty.replace("/msg/", "/") if ros1 else ty
                msgdef, _ = ts.generate_msgdef(ty, ros_version=1 if ros1 else 2)
                sid = w.register_schema(name=ros_ty, encoding="ros1msg" if ros1 else "ros2msg",
                                        data=msgdef.encode())
                chans[topic] = w.register_channel(topic=topic, message_encoding="ros1" if ros1
                                                  else "cdr", schema_id=sid)
            data = ts.serialize_ros1(m, ty) if ros1 else ts.serialize_cdr(m, ty)
            w.add_message(channel_id=chans[topic], log_time=t, publish_time=t, sequence=seq,
                          data=bytes(data))
        w.finish()


def main() -> None:
    src, data = Path(sys.argv[1]), Path(sys.argv[2])
    sys.argv = [sys.argv[0], str(src), str(data / "rosbag1-sim/sim.bag")]
    rb1.main()
    d = data / "ros2-sim"
    d.mkdir(parents=True, exist_ok=True)
    write_split_sqlite3(src, d / "sqlite3", 2 * 10**9)
    write_rosbag2(src, d / "mcap", StoragePlugin.MCAP)
    write_mcap(src, d / "ros1.mcap", ros1=True)
    write_mcap(src, d / "cdr-nosummary.mcap", ros1=False)
    for p in sorted(d.rglob("*")):
        if p.is_file():
            print(f"wrote {p}: {p.stat().st_size} bytes")


if __name__ == "__main__":
    main()
