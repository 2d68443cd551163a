#!/usr/bin/env python3
"""Writes tests/data/rosbag1-sim/sim.bag: a small ROS 1 bag made by an independent writer (the
Python `rosbags` package) from a simulated EuRoC sequence, for the rosbag1 reader's tests.

    povins simulate --scenario flight --duration 2 --format euroc --images --out /tmp/simrb
    python3 -m venv /work/venv-rosbags && /work/venv-rosbags/bin/pip install rosbags numpy
    /work/venv-rosbags/bin/python scripts/make_rosbag1_fixture.py /tmp/simrb tests/data/rosbag1-sim/sim.bag

Contents (stamps from the EuRoC file names / rows; receipt times equal the stamps):
- /imu0 sensor_msgs/Imu: every IMU row (gyro rad/s, accel m/s^2).
- /cam0/image_raw sensor_msgs/Image: every 3rd camera image, 64x48, cycling through the
  encodings in ENCODINGS, rows padded to a step of row bytes + 3. The gray source is made of
  uniform 2x2 cells and colour channels are equal, so every encoding's documented gray (see
  platform/src/image_raw.rs) is exactly the source.
- /cam0/gray_png sensor_msgs/CompressedImage: the same gray source as PNG, same stamps: the
  reference the tests compare /cam0/image_raw against.
- /chatter std_msgs/String: a topic the reader must skip.
Chunks are uncompressed and small (16 kB), so the bag has many chunks.

With a third argument `--full`: every image at full size in mono8 on /cam0/image_raw, with
/imu0 only, 1 MB chunks (for `povins run BAG --calib EUROC_FOLDER` against the folder itself).
"""

import struct
import sys
import zlib
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_typestore

ENCODINGS = ["mono8", "rgb8", "bgr8", "rgba8", "bgra8", "mono16", "bayer_rggb8",
             "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8", "yuv422", "yuv422_yuy2"]
W, H = 64, 48


def read_png_gray(path: Path) -> np.ndarray:
    """8-bit grayscale non-interlaced PNG (what povins simulate writes) to an array."""
    data = path.read_bytes()
    pos, idat, w, h = 8, b"", 0, 0
    while pos < len(data):
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and colour == 0, (depth, colour)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    out = np.zeros((h, w), np.uint8)
    prev = np.zeros(w, np.int32)
    for r in range(h):
        f = raw[r * (w + 1)]
        line = np.frombuffer(raw, np.uint8, w, r * (w + 1) + 1).astype(np.int32)
        cur = np.zeros(w, np.int32)
        for c in range(w):
            a = cur[c - 1] if c else 0
            b = prev[c]
            cc = prev[c - 1] if c else 0
            if f == 0:
                p = 0
            elif f == 1:
                p = a
            elif f == 2:
                p = b
            elif f == 3:
                p = (a + b) // 2
            else:
                pa, pb, pc = abs(b - cc), abs(a - cc), abs(a + b - 2 * cc)
                p = a if pa <= pb and pa <= pc else (b if pb <= pc else cc)
            cur[c] = (line[c] + p) & 0xFF
        out[r] = cur
        prev = cur
    return out


def png_gray(img: np.ndarray) -> bytes:
    h, w = img.shape
    raw = b"".join(b"\0" + img[r].tobytes() for r in range(h))

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def encode(enc: str, g: np.ndarray) -> tuple[int, bytes]:
    """(bytes per pixel, pixel bytes per row) of gray `g` in `enc`."""
    if enc == "mono8":
        return 1, g
    if enc in ("rgb8", "bgr8"):
        return 3, np.repeat(g[:, :, None], 3, axis=2)
    if enc in ("rgba8", "bgra8"):
        return 4, np.concatenate([np.repeat(g[:, :, None], 3, axis=2),
                                  np.full(g.shape + (1,), 255, np.uint8)], axis=2)
    if enc == "mono16":  # little-endian: low byte noise, high byte the gray
        lo = (np.arange(g.size).reshape(g.shape) * 37 % 256).astype(np.uint8)
        return 2, np.stack([lo, g], axis=2)
    if enc.startswith("bayer"):  # uniform cells: every pixel of a cell the same value
        return 1, g
    chroma = (np.arange(g.size).reshape(g.shape) * 11 % 256).astype(np.uint8)
    if enc == "yuv422":  # U Y V Y
        return 2, np.stack([chroma, g], axis=2)
    return 2, np.stack([g, chroma], axis=2)  # yuv422_yuy2: Y U Y V


def main() -> None:
    src, out = Path(sys.argv[1]), Path(sys.argv[2])
    ts = get_typestore(Stores.ROS1_NOETIC)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Vector3, Quaternion = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    Imu, Image = T["sensor_msgs/msg/Imu"], T["sensor_msgs/msg/Image"]
    CompressedImage, String = T["sensor_msgs/msg/CompressedImage"], T["std_msgs/msg/String"]

    def header(t_ns, seq, frame):
        return Header(seq=seq, stamp=Time(sec=t_ns // 10**9, nanosec=t_ns % 10**9), frame_id=frame)

    msgs = []  # (t_ns, topic, msgtype, message)
    rows = (src / "mav0/imu0/data.csv").read_text().splitlines()[1:]
    for i, row in enumerate(rows):
        v = row.split(",")
        t = int(v[0])
        w = Vector3(x=float(v[1]), y=float(v[2]), z=float(v[3]))
        a = Vector3(x=float(v[4]), y=float(v[5]), z=float(v[6]))
        cov = np.zeros(9, np.float64)
        m = Imu(header=header(t, i, "imu0"), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.array([-1.0] + [0.0] * 8), angular_velocity=w,
                angular_velocity_covariance=cov, linear_acceleration=a,
                linear_acceleration_covariance=cov)
        msgs.append((t, "/imu0", "sensor_msgs/msg/Imu", m))
    full_size = sys.argv[3:] == ["--full"]
    images = sorted((src / "mav0/cam0/data").glob("*.png"), key=lambda p: int(p.stem))
    images = images if full_size else images[::3]
    for k, path in enumerate(images):
        t = int(path.stem)
        full = read_png_gray(path)
        if full_size:
            h, w = full.shape
            im = Image(header=header(t, k, "cam0"), height=h, width=w, encoding="mono8",
                       is_bigendian=0, step=w, data=full.reshape(-1))
            msgs.append((t, "/cam0/image_raw", "sensor_msgs/msg/Image", im))
            continue
        ys = (np.arange(H // 2) * full.shape[0] // (H // 2))
        xs = (np.arange(W // 2) * full.shape[1] // (W // 2))
        g = np.repeat(np.repeat(full[np.ix_(ys, xs)], 2, axis=0), 2, axis=1)
        enc = ENCODINGS[k % len(ENCODINGS)]
        bpp, px = encode(enc, g)
        step = W * bpp + 3
        rows_b = np.asarray(px, np.uint8).reshape(H, W * bpp)
        data = np.concatenate([rows_b, np.full((H, 3), 0xEE, np.uint8)], axis=1).reshape(-1)
        im = Image(header=header(t, k, "cam0"), height=H, width=W, encoding=enc, is_bigendian=0,
                   step=step, data=data)
        msgs.append((t, "/cam0/image_raw", "sensor_msgs/msg/Image", im))
        png = CompressedImage(header=header(t, k, "cam0"), format="png",
                              data=np.frombuffer(png_gray(g), np.uint8))
        msgs.append((t, "/cam0/gray_png", "sensor_msgs/msg/CompressedImage", png))
        msgs.append((t, "/chatter", "std_msgs/msg/String", String(data=f"frame {k} {enc}")))

    out.parent.mkdir(parents=True, exist_ok=True)
    if out.exists():
        out.unlink()
    with Writer(out) as wr:
        wr.chunk_threshold = (1 << 20) if full_size else 16 * 1024
        conns = {}
        for t, topic, ty, m in sorted(msgs, key=lambda x: (x[0], x[1])):
            if topic not in conns:
                conns[topic] = wr.add_connection(topic, ty, typestore=ts)
            wr.write(conns[topic], t, ts.serialize_ros1(m, ty))
    print(f"wrote {out}: {len(rows)} IMU samples, {len(images)} images, {out.stat().st_size} bytes")


if __name__ == "__main__":
    main()
