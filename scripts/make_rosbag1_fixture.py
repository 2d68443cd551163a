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

Kalibr files (PyYAML as the independent writer, in Kalibr's own layout: `T_cam_imu` as a block
list of flow rows, `imu0:` nesting with `--nested`):

    make_rosbag1_fixture.py --kalibr EUROC_DIR OUT_PREFIX [--size W H] [--image-topic T] [--nested]

writes OUT_PREFIX-camchain-imucam.yaml and OUT_PREFIX-imu.yaml from EUROC_DIR's
mav0/cam0/sensor.yaml and mav0/imu0/sensor.yaml: `T_cam_imu` is the matrix inverse of
`T_B_imu^-1 T_B_cam` (numpy), `distortion_model` radial-tangential -> radtan, `rate_hz` and
`gravity_magnitude` carried as povins' extension keys. `--size W H` rescales the resolution and
the intrinsics (the fixture bag's 64x48 images: `tests/data/kalibr/sim-*.yaml`).

    /work/venv-rosbags/bin/pip install pyyaml
    make_rosbag1_fixture.py --kalibr tests/data/euroc-v101-30s-features tests/data/kalibr/euroc-v101 --nested
    make_rosbag1_fixture.py --kalibr /tmp/simrb tests/data/kalibr/sim --size 64 48 --image-topic /cam0/gray_png
"""

import re
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


def read_euroc_yaml(path: Path) -> dict:
    import yaml
    text = path.read_text()
    return yaml.safe_load(re.sub(r"^%YAML:1.0", "", text, flags=re.M))


def t_bs(d: dict) -> np.ndarray:
    t = d.get("T_BS")
    return np.eye(4) if t is None else np.array(t["data"], np.float64).reshape(4, 4)


def write_kalibr(args: list[str]) -> None:
    import yaml
    src, prefix = Path(args[0]), args[1]
    cam = read_euroc_yaml(src / "mav0/cam0/sensor.yaml")
    imu = read_euroc_yaml(src / "mav0/imu0/sensor.yaml")
    w, h = cam["resolution"]
    fu, fv, pu, pv = cam["intrinsics"]
    if "--size" in args:
        k = args.index("--size")
        nw, nh = int(args[k + 1]), int(args[k + 2])
        sx, sy = nw / w, nh / h
        fu, fv, pu, pv, w, h = fu * sx, fv * sy, pu * sx, pv * sy, nw, nh
    topic = args[args.index("--image-topic") + 1] if "--image-topic" in args else "/cam0/image_raw"
    model = {"radial-tangential": "radtan", "equidistant": "equidistant"}[cam["distortion_model"]]
    t_cam_imu = np.linalg.inv(np.linalg.inv(t_bs(imu)) @ t_bs(cam))
    t_cam_imu[3] = [0.0, 0.0, 0.0, 1.0]
    cam0 = {
        "camera_model": "pinhole",
        "intrinsics": [float(fu), float(fv), float(pu), float(pv)],
        "distortion_model": model,
        "distortion_coeffs": [float(c) for c in cam["distortion_coefficients"]],
        "T_cam_imu": [[float(v) for v in row] for row in t_cam_imu],
        "timeshift_cam_imu": float(cam.get("timeshift_cam_imu", 0.0)),
        "rostopic": topic,
        "resolution": [int(w), int(h)],
        "rate_hz": float(cam["rate_hz"]),
    }
    noise = {
        "accelerometer_noise_density": float(imu["accelerometer_noise_density"]),
        "accelerometer_random_walk": float(imu["accelerometer_random_walk"]),
        "gyroscope_noise_density": float(imu["gyroscope_noise_density"]),
        "gyroscope_random_walk": float(imu["gyroscope_random_walk"]),
        "rostopic": "/imu0",
        "update_rate": float(imu["rate_hz"]),
    }
    if "gravity_magnitude" in imu:
        noise["gravity_magnitude"] = float(imu["gravity_magnitude"])
    if "--nested" in args:
        noise = {"imu0": dict(noise, model="calibrated", time_offset=0.0)}
    dump = lambda d: yaml.safe_dump(d, default_flow_style=None, sort_keys=False)
    Path(prefix + "-camchain-imucam.yaml").write_text(dump({"cam0": cam0}))
    Path(prefix + "-imu.yaml").write_text(yaml.safe_dump(noise, default_flow_style=False, sort_keys=False))
    print(f"wrote {prefix}-camchain-imucam.yaml and {prefix}-imu.yaml")


def main() -> None:
    if sys.argv[1] == "--kalibr":
        write_kalibr(sys.argv[2:])
        return
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
