#!/usr/bin/env python3
"""Makes a long EuRoC folder at rest from the real at-rest start of EuRoC V1_01
(../shared/data/euroc-v101-images-at-rest: 95 images and their IMU rows while the MAV stands
still), repeated with shifted stamps until `--seconds` (images are symlinks, so a 10-minute
folder takes little disk). The scene and the IMU agree (both at rest), so the estimator runs
on it for the whole length: the input of the reading-speed and memory figures of
BENCHMARKS.md (issue 30, bar 3), with scripts/make_long_bag.py turning it into a bag:

    python3 scripts/make_static_loop.py ../shared/data/euroc-v101-images-at-rest /tmp/rest600 --seconds 600
"""

import shutil
import sys
from pathlib import Path


def rows(path: Path):
    return [l for l in path.read_text().splitlines() if l.strip() and not l.startswith("#")]


def main() -> None:
    src, out = Path(sys.argv[1]) / "mav0", Path(sys.argv[2]) / "mav0"
    seconds = float(sys.argv[sys.argv.index("--seconds") + 1])
    cams = [(int(l.split(",")[0]), l.split(",")[1].strip()) for l in rows(src / "cam0" / "data.csv")]
    t0, t_last = cams[0][0], cams[-1][0]
    period = t_last - t0 + (cams[1][0] - cams[0][0])
    imu = [l.split(",") for l in rows(src / "imu0" / "data.csv")]
    imu = [(int(v[0]), v[1:]) for v in imu if t0 <= int(v[0]) < t0 + period]
    (out / "cam0" / "data").mkdir(parents=True, exist_ok=True)
    (out / "imu0").mkdir(parents=True, exist_ok=True)
    for s in ["cam0", "imu0"]:
        shutil.copy(src / s / "sensor.yaml", out / s / "sensor.yaml")
    end = t0 + int(seconds * 1e9)
    with open(out / "cam0" / "data.csv", "w") as fc, open(out / "imu0" / "data.csv", "w") as fi:
        fc.write("#timestamp [ns],filename\n")
        fi.write("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                 "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n")
        k = 0
        while t0 + k * period < end:
            shift = k * period
            for t, v in imu:
                if t + shift < end:
                    fi.write(f"{t + shift}," + ",".join(v) + "\n")
            for t, name in cams:
                if t + shift < end:
                    link = out / "cam0" / "data" / f"{t + shift}.png"
                    if not link.exists():
                        link.symlink_to((src / "cam0" / "data" / name).resolve())
                    fc.write(f"{t + shift},{t + shift}.png\n")
            k += 1


if __name__ == "__main__":
    main()
