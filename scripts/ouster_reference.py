#!/usr/bin/env python3
"""Decodes an Ouster pcap capture with the Ouster SDK (Python package `ouster-sdk`), the
independent reference for povins' decoder (platform/tests/ouster_sdk.rs).

Usage: ouster_reference.py CAPTURE.pcap METADATA.json OUT_DIR

Writes to OUT_DIR:
- sweeps.csv: per sweep `frame_id,valid_columns,points,first_valid_t_ns`;
- points.bin: per point, in sweep order, then measurement id, then row (staggered, as the
  columns fired), of the valid columns' pixels with range > 0: little-endian
  `i64 frame_id, i64 t_ns (the column timestamp), f64 x, y, z (m, sensor frame: the SDK's
  XYZLut)`;
- imu.csv: per IMU packet `sys_ts,accel_ts,gyro_ts,ax,ay,az,gx,gy,gz` (g and deg/s as sent).
"""
import sys
from pathlib import Path

import numpy as np
from ouster.sdk import core, pcap


def main() -> None:
    capture, meta, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    out.mkdir(parents=True, exist_ok=True)
    scans = pcap.PcapFrameSetSource(capture, meta=[meta])
    info = scans.sensor_info[0]
    xyzlut = core.XYZLut(info)
    with open(out / "sweeps.csv", "w") as sweeps, open(out / "points.bin", "wb") as points:
        for item in scans:
            scan = item[0]  # a FrameSet: one frame per sensor
            if scan is None:
                continue
            valid = (scan.status & 1).astype(bool)
            rng = scan.field(core.ChanField.RANGE)
            xyz = xyzlut(scan)  # H x W x 3, m
            cols = np.flatnonzero(valid)
            recs = []
            for c in cols:
                rows = np.flatnonzero(rng[:, c] > 0)
                rec = np.zeros(len(rows), dtype=[("f", "<i8"), ("t", "<i8"), ("p", "<f8", 3)])
                rec["f"] = scan.frame_id
                rec["t"] = int(scan.timestamp[c])
                rec["p"] = xyz[rows, c, :]
                recs.append(rec)
            allrec = np.concatenate(recs) if recs else np.zeros(0)
            points.write(allrec.tobytes())
            first = int(scan.timestamp[cols[0]]) if len(cols) else -1
            sweeps.write(f"{scan.frame_id},{len(cols)},{len(allrec)},{first}\n")
    packets = pcap.PcapPacketSource(capture, meta=[meta])
    with open(out / "imu.csv", "w") as imu:
        for _, p in packets:
            if isinstance(p, core.ImuPacket):
                a, g = p.accel(), p.gyro()
                vals = [p.sys_ts(), p.accel_ts(), p.gyro_ts()]
                vals += [repr(float(np.ravel(a)[k])) for k in range(3)]
                vals += [repr(float(np.ravel(g)[k])) for k in range(3)]
                imu.write(",".join(str(int(v)) if isinstance(v, (int, np.integer)) else str(v)
                                   for v in vals) + "\n")


if __name__ == "__main__":
    main()
