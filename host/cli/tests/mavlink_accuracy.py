"""What the autopilot received against the truth (docs/PERFORMANCE.md, "MAVLink bridge").

Usage: mavlink_accuracy.py RECEIVED.jsonl SUMMARY.json TRUTH.csv BOOT_OFFSET_S SPEED
RECEIVED: mavlink_autopilot.py's log; SUMMARY: `--mavlink-summary`; TRUTH: `--truth` (t_s,n_m,e_m,d_m,yaw_rad).
The autopilot's clock is CLOCK_MONOTONIC - BOOT_OFFSET_S, the companion's CLOCK_MONOTONIC; the
stamps are in the summary's stamp_clock; the head's time 0 is at the summary's
head_t0_companion_us; a native run at SPEED maps head time t to companion t0 + t / SPEED.
Prints JSON: counts and rates per message, the horizontal error of VISION_POSITION_ESTIMATE
(RMS, max, fraction with both axes within 3 sigma), the yaw error, the lag arrival - stamp.
"""
import bisect
import csv
import json
import math
import sys

rx, summ, truth_path = sys.argv[1:4]
boot_us = float(sys.argv[4]) * 1e6
speed = float(sys.argv[5])
s = json.load(open(summ))
t0 = s["head_t0_companion_us"]
truth = [tuple(map(float, (r["t_s"], r["n_m"], r["e_m"], r["d_m"], r["yaw_rad"]))) for r in csv.DictReader(open(truth_path))]
ts = [r[0] for r in truth]


def at(t):
    i = min(max(bisect.bisect_left(ts, t), 1), len(ts) - 1)
    a, b = truth[i - 1], truth[i]
    w = (t - a[0]) / (b[0] - a[0])
    yaw = a[4] + w * math.remainder(b[4] - a[4], 2 * math.pi)
    return [a[k] + w * (b[k] - a[k]) for k in (1, 2, 3)], yaw


msgs = [json.loads(l) for l in open(rx)]
counts = {}
for m in msgs:
    counts[m["mavpackettype"]] = counts.get(m["mavpackettype"], 0) + 1
vpe = [m for m in msgs if m["mavpackettype"] == "VISION_POSITION_ESTIMATE"]
span_s = (vpe[-1]["arrival_us"] - vpe[0]["arrival_us"]) * 1e-6 if len(vpe) > 1 else float("nan")
errs, within, yaw_errs, lags = [], 0, [], []
# Stamps in the companion's clock; with --mavlink-stamp-clock autopilot, before TIMESYNC converges
# the bridge stamps in its own clock (and says so): seconds away from the autopilot's. Those are
# counted, not scored.
to_companion = 0.0 if s.get("stamp_clock", "Autopilot") == "Companion" else boot_us
for m in msgs:
    m["arrival_companion_us"] = m["arrival_us"] + boot_us
own_clock = [m for m in vpe if abs(m["arrival_companion_us"] - m["usec"] - to_companion) > 1e6]
vpe = [m for m in vpe if abs(m["arrival_companion_us"] - m["usec"] - to_companion) <= 1e6]
for m in vpe:
    t = (m["usec"] + to_companion - t0) * 1e-6 * speed
    p, yaw = at(t)
    # The autopilot's frame: the head's unless it sent an origin (offsets applied by the caller).
    dn, de = m["x"] - p[0], m["y"] - p[1]
    e = math.hypot(dn, de)
    c = m["covariance"]
    errs.append(e)
    within += abs(dn) <= 3 * math.sqrt(c[0]) and abs(de) <= 3 * math.sqrt(c[6])
    yaw_errs.append(abs(math.remainder(m["yaw"] - yaw, 2 * math.pi)))
    lags.append((m["arrival_companion_us"] - m["usec"] - to_companion) * 1e-3)
lags.sort()
out = {
    "messages": counts,
    "vision_position_rate_hz_wall": len(vpe) / span_s if span_s == span_s else None,
    "stamped_own_clock": len(own_clock),
    "scored": len(vpe),
    "horizontal_rms_m": math.sqrt(sum(e * e for e in errs) / len(errs)),
    "horizontal_max_m": max(errs),
    "within_3_sigma": within / len(errs),
    "yaw_rmse_deg": math.degrees(math.sqrt(sum(e * e for e in yaw_errs) / len(yaw_errs))),
    "arrival_minus_stamp_ms": {"median": lags[len(lags) // 2], "p95": lags[int(0.95 * (len(lags) - 1))], "max": lags[-1]},
}
print(json.dumps(out, indent=1))
