#!/usr/bin/env python3
"""Writes, with the Ouster SDK (Python package `ouster-sdk`), a firmware 3.1 `FUSA`-header
capture of the sweeps of an Ouster pcap: the independent source of the `FUSA` packets that
povins' decoder is tested on (platform/tests/ouster_sdk.rs). No FUSA capture is in
../shared/data; the SDK's packet format writes the header the firmware sends.

Usage: ouster_fusa_capture.py CAPTURE.pcap METADATA.json OUT_DIR

Reads the capture's sweeps with its metadata, gives them frame ids 65535, 65536, ... (past 16
bits, which only the FUSA header's 32-bit frame id carries), and writes to OUT_DIR:
- fusa.json: the metadata with `lidar_data_format.header_type = FUSA`;
- fusa.pcap: the sweeps' lidar packets in that format (the SDK's `frame_to_packets`, the
  metadata's init id and serial number), then the capture's IMU packets unchanged.
"""
import sys
from pathlib import Path

from ouster.sdk import core, pcap

FIRST_FRAME_ID = 65535


def main() -> None:
    capture, meta, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
    out.mkdir(parents=True, exist_ok=True)
    with open(meta) as f:
        info = core.SensorInfo(f.read())
    info.format.header_type = core.HeaderType.FUSA
    fmt = core.PacketFormat(info)
    packets = []
    scans = pcap.PcapScanSource(capture, meta=[meta])
    for k, frames in enumerate(scans):
        scan = frames[0] if isinstance(frames, list) or hasattr(frames, "__getitem__") else frames
        scan.frame_id = FIRST_FRAME_ID + k
        packets += [
            p
            for p in core.frame_to_packets(scan, fmt, info.init_id, int(info.sn))
            if isinstance(p, core.LidarPacket)
        ]
    n_lidar = len(packets)
    for item in pcap.PcapPacketSource(capture, meta=[meta]):
        p = item[1] if isinstance(item, tuple) else item
        if isinstance(p, core.ImuPacket):
            packets.append(p)
    (out / "fusa.json").write_text(info.to_json_string())
    written = pcap.record(packets, str(out / "fusa.pcap"))
    print(f"{n_lidar} lidar + {len(packets) - n_lidar} IMU packets, {written} written")


if __name__ == "__main__":
    main()
