#!/usr/bin/env python3
"""Decodes Ouster packets with the Ouster SDK (Python package `ouster-sdk`), the independent
reference for povins' decoder (platform/tests/ouster_sdk.rs).

Usage: ouster_reference.py CAPTURE.pcap METADATA.json OUT_DIR
       ouster_reference.py --bag RAW_PACKETS.bag OUT_DIR   (ouster_ros PacketMsg topics and the
                                                            metadata topic; needs `rosbags`)

Writes to OUT_DIR:
- sweeps.csv: per sweep `frame_id,valid_columns,points,first_valid_t_ns`;
- points.bin: per point, in sweep order, then measurement id, then row (staggered, as the
  columns fired), of the valid columns' pixels with range > 0: little-endian
  `i64 frame_id, i64 t_ns (the column timestamp), f64 x, y, z (m, sensor frame: the SDK's
  XYZLut)`;
- imu.csv: per IMU packet `sys_ts,accel_ts,gyro_ts,ax,ay,az (m/s^2),gx,gy,gz (rad/s)` as the
  SDK converts them.
"""
import struct
import sys
from pathlib import Path

import numpy as np
from ouster.sdk import core, pcap

POINT = np.dtype([("f", "<i8"), ("t", "<i8"), ("p", "<f8", 3)])


def write_sweeps(scans, info, out: Path) -> None:
    xyzlut = core.XYZLut(info)
    with open(out / "sweeps.csv", "w") as sweeps, open(out / "points.bin", "wb") as points:
        for scan in scans:
            valid = (scan.status & 1).astype(bool)
            rng = scan.field(core.ChanField.RANGE)
            xyz = xyzlut(scan)  # H x W x 3, m
            cols = np.flatnonzero(valid)
            recs = [np.zeros(0, dtype=POINT)]
            for c in cols:
                rows = np.flatnonzero(rng[:, c] > 0)
                rec = np.zeros(len(rows), dtype=POINT)
                rec["f"] = scan.frame_id
                rec["t"] = int(scan.timestamp[c])
                rec["p"] = xyz[rows, c, :]
                recs.append(rec)
            allrec = np.concatenate(recs)
            points.write(allrec.tobytes())
            first = int(scan.timestamp[cols[0]]) if len(cols) else -1
            sweeps.write(f"{scan.frame_id},{len(cols)},{len(allrec)},{first}\n")


def write_imu(packets, out: Path) -> None:
    with open(out / "imu.csv", "w") as imu:
        for p in packets:
            vals = [str(int(p.sys_ts())), str(int(p.accel_ts())), str(int(p.gyro_ts()))]
            vals += [repr(float(v)) for v in np.ravel(p.accel())[:3]]
            vals += [repr(float(v)) for v in np.ravel(p.gyro())[:3]]
            imu.write(",".join(vals) + "\n")


def from_pcap(capture: str, meta: str, out: Path) -> None:
    frames = pcap.PcapFrameSetSource(capture, meta=[meta])
    info = frames.sensor_info[0]
    write_sweeps((fs[0] for fs in frames if fs[0] is not None), info, out)
    packets = pcap.PcapPacketSource(capture, meta=[meta])
    write_imu((p for _, p in packets if isinstance(p, core.ImuPacket)), out)


def from_bag(bag: str, out: Path) -> None:
    from rosbags.rosbag1 import Reader

    def payload(raw: bytes) -> np.ndarray:
        (n,) = struct.unpack_from("<I", raw, 0)
        return np.frombuffer(raw[4 : 4 + n], np.uint8)

    with Reader(bag) as reader:
        msgs = [(c.topic, raw) for c, _, raw in reader.messages()]
    meta = next(raw for t, raw in msgs if t.endswith("metadata"))
    info = core.SensorInfo(payload(meta).tobytes().decode())
    pf = core.PacketFormat(info)
    batcher = core.FrameBatcher(info)
    scans, scan, pending = [], core.LidarFrame(info), False
    imu = []
    for topic, raw in msgs:
        if topic.endswith("lidar_packets"):
            p = core.LidarPacket(pf)
            p.buf[:] = payload(raw)[: pf.lidar_packet_size]
            pending = True
            if batcher.batch(p, scan):
                scans.append(scan)
                scan, pending = core.LidarFrame(info), False
        elif topic.endswith("imu_packets"):
            p = core.ImuPacket(pf)
            p.buf[:] = payload(raw)[: pf.imu_packet_size]
            imu.append(p)
    if pending:
        scans.append(scan)
    write_sweeps(scans, info, out)
    write_imu(imu, out)


def main() -> None:
    if sys.argv[1] == "--bag":
        out = Path(sys.argv[3])
        out.mkdir(parents=True, exist_ok=True)
        from_bag(sys.argv[2], out)
    else:
        out = Path(sys.argv[3])
        out.mkdir(parents=True, exist_ok=True)
        from_pcap(sys.argv[1], sys.argv[2], out)


if __name__ == "__main__":
    main()
