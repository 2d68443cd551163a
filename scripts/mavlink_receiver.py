#!/usr/bin/env python3
"""An autopilot's side of povins' MAVLink output, written with pymavlink (not povins' code).

Listens on udpin:ADDR:PORT, records every ODOMETRY and VISION_POSITION_ESTIMATE, sends TIMESYNC requests (tc1 = 0, ts1 = its
own monotonic clock in ns) to the sender at 10 Hz once it has spoken, records the answers, and
stops SECONDS after the last message (or at a time limit). Writes OUT.json:
  {"odometry": [[time_usec, x, y, z, qw, qx, qy, qz, vx, vy, vz, reset_counter, quality,
                 frame_id, child_frame_id, estimator_type, recv_ns, srcsys, srccomp,
                 covariance_known, velocity_covariance[0 1 2 6 7 11] (vx vy vz upper triangle),
                 pose_covariance[0 6 11 15 18 20] (x y z roll pitch yaw variances); null for NaN], ...],
   "vision": [[usec, x, y, z, roll, pitch, yaw, reset_counter], ...],  (VISION_POSITION_ESTIMATE)
   "timesync": [[tc1, ts1, recv_ns], ...], "timesync_sent_ns": [ts1 of every request sent, ...],
   "heartbeats": N, "other": {type: count}}
Usage: mavlink_receiver.py udpin:127.0.0.1:PORT OUT.json [IDLE_S] [LIMIT_S]
       mavlink_receiver.py pty OUT.json [IDLE_S] [LIMIT_S]
With `pty` it opens a pseudo-terminal pair, prints "ready SLAVE_PATH" (the serial device the
sender opens, as it would an autopilot's UART) and talks over the master side.
"""
import json
import math
import select
import sys
import time

import os

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402


def finite(x):
    """`x`, or None (JSON null) for NaN, which JSON cannot hold."""
    return None if math.isnan(x) else float(x)


class PtyMaster(mavutil.mavfile):
    """pymavlink over the master side of a pseudo-terminal (pymavlink's serial class needs a
    device path; the master has only a file descriptor)."""

    def __init__(self, fd):
        self.fd = fd
        mavutil.mavfile.__init__(self, fd, "pty", source_system=1, source_component=1)

    def recv(self, n=None):
        # Wait for bytes (not a sleep-and-poll, whose delay would skew TIMESYNC's round trip).
        if not select.select([self.fd], [], [], 0.01)[0]:
            return b""
        try:
            return os.read(self.fd, n or 1024)
        except (BlockingIOError, OSError):
            return b""

    def write(self, buf):
        os.write(self.fd, buf)


def main():
    url, out = sys.argv[1], sys.argv[2]
    idle_s = float(sys.argv[3]) if len(sys.argv) > 3 else 3.0
    limit_s = float(sys.argv[4]) if len(sys.argv) > 4 else 600.0
    ready = "ready"
    if url == "pty":
        import pty
        import tty

        master, slave = pty.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        os.set_blocking(master, False)
        ready = f"ready {os.ttyname(slave)}"
        conn = PtyMaster(master)
    else:
        conn = mavutil.mavlink_connection(url, dialect="common", source_system=1,
                                          source_component=1)
    odo, vision, ts, sync_sent, heartbeats, other = [], [], [], [], 0, {}
    start = time.monotonic()
    last_msg = None
    next_sync = 0.0
    print(ready, flush=True)
    while time.monotonic() - start < limit_s:
        now = time.monotonic()
        if last_msg is not None and now - last_msg > idle_s:
            break
        if last_msg is None and now - start > 120:
            break
        if last_msg is not None and now >= next_sync:
            sent_ns = time.monotonic_ns()
            conn.mav.timesync_send(0, sent_ns)
            sync_sent.append(sent_ns)
            next_sync = now + 0.1
        m = conn.recv_match(blocking=True, timeout=0.05)
        if m is None:
            continue
        recv_ns = time.monotonic_ns()
        last_msg = time.monotonic()
        t = m.get_type()
        if t == "ODOMETRY":
            q = list(m.q)
            odo.append([m.time_usec, m.x, m.y, m.z, q[0], q[1], q[2], q[3], m.vx, m.vy, m.vz,
                        m.reset_counter, m.quality, m.frame_id, m.child_frame_id,
                        m.estimator_type, recv_ns, m.get_srcSystem(), m.get_srcComponent(),
                        0 if math.isnan(m.pose_covariance[0]) else 1]
                       + [finite(m.velocity_covariance[i]) for i in (0, 1, 2, 6, 7, 11)]
                       + [finite(m.pose_covariance[i]) for i in (0, 6, 11, 15, 18, 20)])
        elif t == "VISION_POSITION_ESTIMATE":
            vision.append([m.usec, m.x, m.y, m.z, m.roll, m.pitch, m.yaw, m.reset_counter])
        elif t == "TIMESYNC":
            if m.tc1 != 0:
                ts.append([m.tc1, m.ts1, recv_ns])
        elif t == "HEARTBEAT":
            heartbeats += 1
        else:
            other[t] = other.get(t, 0) + 1
    with open(out, "w") as f:
        json.dump({"odometry": odo, "vision": vision, "timesync": ts,
                   "timesync_sent_ns": sync_sent, "heartbeats": heartbeats, "other": other}, f)
    print(f"{len(odo)} ODOMETRY, {len(ts)} TIMESYNC answers, {heartbeats} HEARTBEAT", flush=True)


if __name__ == "__main__":
    main()
