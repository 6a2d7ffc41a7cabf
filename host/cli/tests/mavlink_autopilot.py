"""A pymavlink peer acting as the autopilot for `subnav mavlink` (test: mavlink_peer.rs).

It listens on UDP, records every message it receives (with its arrival in the autopilot's own
clock) and behaves like ArduSub towards a companion computer:
- HEARTBEAT once a second (system 1, component 1), TIMESYNC answered with its clock, which is
  CLOCK_MONOTONIC minus a boot offset (so the companion's clock is not the autopilot's);
- at the surface (the depth it receives below 0.3 m) a GPS_RAW_INT at 5 Hz, stamped 50 ms before
  it is sent (the receiver's latency), placed GPS_OFFSET_N_M north of the head's origin (so a fix
  that reaches the head shows in what comes back);
- SET_GPS_GLOBAL_ORIGIN (10 m east of the head's origin) once the vision data flows;
- bad input: garbage bytes, a GPS from another system id, a GPS 50 km off, a GPS from the
  future; and a dead link (silent: no heartbeat, no TIMESYNC answer) for DEAD_S seconds.

Usage: mavlink_autopilot.py PORT OUT.jsonl LAT LON BOOT_OFFSET_S DEAD_FROM_S DEAD_S TIMEOUT_S
       [GPS_OFFSET_N_M ORIGIN_OFFSET_E_M BAD_INPUT(0|1)]
Ends TIMEOUT_S after the first message, or 3 s after the last one.
"""

import json
import math
import os
import socket
import sys
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

GPS_OFFSET_N_M = 15.0
ORIGIN_OFFSET_E_M = 10.0


def finite(v):
    """NaN (an unknown in MAVLink) as null: JSON has no NaN."""
    if isinstance(v, float) and math.isnan(v):
        return None
    if isinstance(v, list):
        return [finite(x) for x in v]
    return v


def main():
    port, out_path = int(sys.argv[1]), sys.argv[2]
    lat0, lon0 = float(sys.argv[3]), float(sys.argv[4])
    boot_offset_s, dead_from_s, dead_s, timeout_s = map(float, sys.argv[5:9])
    gps_offset_n_m = float(sys.argv[9]) if len(sys.argv) > 9 else GPS_OFFSET_N_M
    origin_offset_e_m = float(sys.argv[10]) if len(sys.argv) > 10 else ORIGIN_OFFSET_E_M
    bad_input = (sys.argv[11] != "0") if len(sys.argv) > 11 else True
    boot = boot_offset_s  # the autopilot booted this long after the host

    def now_us():
        return int((time.monotonic() - boot) * 1e6)

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.settimeout(0.02)
    m = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    m.robust_parsing = True
    peer = None
    out = open(out_path, "w")
    first = last = None
    next_hb = next_gps = 0.0
    depth = None
    sent_origin = False
    sent_bad = False
    gps_sent = 0
    started = time.monotonic()

    def send(msg, src_system=1):
        if peer is None:
            return
        m.srcSystem = src_system
        sock.sendto(msg.pack(m), peer)
        m.srcSystem = 1

    # 1 deg of latitude / longitude in metres near lat0 (spherical; the test allows for it).
    r = 6371000.0
    dlat = math.degrees(gps_offset_n_m / r)
    dlon_origin = math.degrees(origin_offset_e_m / (r * math.cos(math.radians(lat0))))
    while True:
        t = time.monotonic()
        if first is not None and (t - first > timeout_s or t - last > 3.0):
            break
        if first is None and t - started > timeout_s:
            break
        since = (t - first) if first is not None else 0.0
        dead = first is not None and dead_from_s <= since < dead_from_s + dead_s
        try:
            data, addr = sock.recvfrom(4096)
        except socket.timeout:
            data = b""
        if data:
            peer = addr
            arrival = now_us()
            if first is None:
                first = t
            last = t
            for msg in m.parse_buffer(data) or []:
                name = msg.get_type()
                d = {k: finite(v) for k, v in msg.to_dict().items()}
                d["arrival_us"] = arrival
                d["src_system"] = msg.get_srcSystem()
                d["src_component"] = msg.get_srcComponent()
                d["dead"] = dead
                out.write(json.dumps(d, default=str) + "\n")
                if name == "VISION_POSITION_ESTIMATE":
                    depth = msg.z
                if name == "TIMESYNC" and msg.tc1 == 0 and not dead:
                    send(mav.MAVLink_timesync_message(now_us() * 1000, msg.ts1))
        if peer is None or dead:
            continue
        if t >= next_hb:
            next_hb = t + 1.0
            send(mav.MAVLink_heartbeat_message(mav.MAV_TYPE_SUBMARINE, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mav.MAV_STATE_ACTIVE, 3))
        if depth is not None and not sent_origin:
            sent_origin = True
            send(mav.MAVLink_set_gps_global_origin_message(1, int(lat0 * 1e7), int((lon0 + dlon_origin) * 1e7), 0, now_us()))
        if depth is not None and depth < 0.3 and t >= next_gps:
            next_gps = t + 0.2
            valid = now_us() - 50_000
            send(mav.MAVLink_gps_raw_int_message(valid, 3, int((lat0 + dlat) * 1e7), int(lon0 * 1e7), 0, 80, 120, 0, 0, 12, h_acc=1500, v_acc=3000))
            gps_sent += 1
            if bad_input and not sent_bad and gps_sent == 3:
                sent_bad = True
                sock.sendto(b"\xfd\x09garbage\xfe\x01not a frame" * 3, peer)
                # Another system's GPS, a GPS 50 km off, one from the future.
                send(mav.MAVLink_gps_raw_int_message(valid, 3, int((lat0 + dlat) * 1e7), int(lon0 * 1e7), 0, 80, 120, 0, 0, 12, h_acc=1500), src_system=42)
                send(mav.MAVLink_gps_raw_int_message(valid, 3, int((lat0 + 0.45) * 1e7), int(lon0 * 1e7), 0, 80, 120, 0, 0, 12, h_acc=1500))
                send(mav.MAVLink_gps_raw_int_message(valid + 10_000_000, 3, int((lat0 + dlat) * 1e7), int(lon0 * 1e7), 0, 80, 120, 0, 0, 12, h_acc=1500))
    out.close()
    print(json.dumps({"gps_sent": gps_sent, "boot_offset_s": boot_offset_s, "clock": "CLOCK_MONOTONIC - boot_offset"}))


if __name__ == "__main__":
    main()
