#!/usr/bin/env python3
"""Independent MAVLink peer for the ianav daemon (its acceptance against a MAVLink
implementation not its own), run by tests/daemon_pymavlink.rs.

Plays an ArduPilot-like autopilot over UDP with pymavlink: sends HEARTBEAT (ARDUPILOTMEGA),
SCALED_IMU at 50 Hz, SCALED_PRESSURE, VFR_HUD and ATTITUDE at 10 Hz, GPS_RAW_INT and
GLOBAL_POSITION_INT at 5 Hz (level flight north at 30 m/s, 500 m above the ellipsoid, geoid
48 m), answers TIMESYNC. Decodes everything the daemon sends with pymavlink's own CRC and
field decoding and checks the values. Prints a summary; exit status 0 = all checks passed.
"""

import argparse
import math
import os
import sys
import time

# MAVLink 2 with extension fields (GPS_INPUT.yaw, TIMESYNC targets); must precede the import.
os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav

LAT0, LON0, H0, GEOID, SPEED = 45.0, 7.0, 500.0, 48.0, 30.0
R_MERIDIAN = 6_367_381.8  # WGS84 meridian radius of curvature at 45°, m


def isa(h):
    t = 288.15 - 0.0065 * h
    return 101325.0 * (t / 288.15) ** 5.25588, t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--duration", type=float, default=6.0)
    args = ap.parse_args()

    conn = mavutil.mavlink_connection(
        f"udpout:127.0.0.1:{args.port}",
        source_system=1,
        source_component=1,
        dialect="ardupilotmega",
    )
    m = conn.mav
    boot = time.monotonic()
    failures = []
    seen = {}
    bad = 0
    gps_inputs = []
    texts = []
    intervals = {}
    heartbeats = []
    timesync_requests = 0
    timesync_answers = 0
    p_pa, t_k = isa(H0)
    rho = p_pa / (287.05287 * t_k)
    eas = SPEED * math.sqrt(rho / 1.225)
    k = 0
    next_t = time.monotonic()
    end = next_t + args.duration
    while time.monotonic() < end:
        now = time.monotonic()
        if now >= next_t:
            next_t += 0.02  # 50 Hz tick
            k += 1
            tb = now - boot
            ms = int(tb * 1000)
            if k % 50 == 1:
                m.heartbeat_send(mav.MAV_TYPE_FIXED_WING, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mav.MAV_STATE_ACTIVE)
            # Level, heading north: specific force −1 g on z (mG), no rotation, no magnetometer.
            m.scaled_imu_send(ms, 0, 0, -1000, 0, 0, 0, 0, 0, 0)
            if k % 5 == 0:
                m.scaled_pressure_send(ms, p_pa / 100.0, 0.0, int(round((t_k - 273.15) * 100)))
                m.vfr_hud_send(eas, SPEED, 0, 50, H0 - GEOID, 0.0)
                m.attitude_send(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            if k % 10 == 3:
                lat = LAT0 + math.degrees(SPEED * tb / R_MERIDIAN)
                m.global_position_int_send(ms, int(lat * 1e7), int(LON0 * 1e7), int((H0 - GEOID) * 1000), 0, int(SPEED * 100), 0, 0, 0)
                m.gps_raw_int_send(int(tb * 1e6), 3, int(round(lat * 1e7)), int(LON0 * 1e7), int((H0 - GEOID) * 1000),
                                   100, 150, int(SPEED * 100), 0, 12, int(H0 * 1000), 1000, 1500, 200, 0, 0)
        msg = conn.recv_match(blocking=True, timeout=0.005)
        if msg is None:
            continue
        t = msg.get_type()
        if t == "BAD_DATA":
            bad += 1
            continue
        seen[t] = seen.get(t, 0) + 1
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src != (1, 197):
            failures.append(f"{t} from {src}, expected (1, 197)")
        if t == "HEARTBEAT":
            heartbeats.append(msg)
        elif t == "TIMESYNC":
            if msg.tc1 == 0:
                timesync_requests += 1
                m.timesync_send(int((time.monotonic() - boot) * 1e9), msg.ts1)  # pymavlink 2.4.50: no target fields
            else:
                timesync_answers += 1
        elif t == "COMMAND_LONG" and msg.command == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            intervals[int(msg.param1)] = msg.param2
            m.command_ack_send(msg.command, mav.MAV_RESULT_ACCEPTED, 0, 0, src[0], src[1])
        elif t == "GPS_INPUT":
            gps_inputs.append((time.monotonic() - boot, msg))
        elif t == "STATUSTEXT":
            texts.append(msg.text)
    # Ask the daemon for a TIMESYNC answer too (tc1 = 0 from us).
    m.timesync_send(0, 123456789)
    t_end = time.monotonic() + 1.0
    answered = False
    while time.monotonic() < t_end and not answered:
        msg = conn.recv_match(type="TIMESYNC", blocking=True, timeout=0.1)
        if msg is not None and msg.tc1 != 0 and msg.ts1 == 123456789:
            answered = True

    # Checks.
    if bad:
        failures.append(f"{bad} frames failed pymavlink's decoding (CRC or length)")
    if not heartbeats:
        failures.append("no HEARTBEAT")
    else:
        h = heartbeats[-1]
        if (h.type, h.autopilot) != (mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID):
            failures.append(f"HEARTBEAT type/autopilot {h.type}/{h.autopilot}")
        if not 3 <= len(heartbeats) <= args.duration + 2:
            failures.append(f"{len(heartbeats)} heartbeats in {args.duration} s")
    if intervals.get(mav.MAVLINK_MSG_ID_SCALED_IMU) != 20000.0:
        failures.append(f"SCALED_IMU interval not requested at 50 Hz: {intervals}")
    if mav.MAVLINK_MSG_ID_GPS_RAW_INT not in intervals:
        failures.append(f"GPS_RAW_INT interval not requested: {intervals}")
    if timesync_requests < 5:
        failures.append(f"only {timesync_requests} TIMESYNC requests from the daemon")
    if not answered:
        failures.append("our TIMESYNC request was not answered")
    if any("GNSS" in s for s in texts):
        failures.append(f"GNSS state announced without a loss: {texts}")
    if not any("INS initialised" in s for s in texts):
        failures.append(f"no 'INS initialised' STATUSTEXT: {texts}")
    if len(gps_inputs) < 10:
        failures.append(f"only {len(gps_inputs)} GPS_INPUT")
    else:
        span = gps_inputs[-1][0] - gps_inputs[0][0]
        rate = (len(gps_inputs) - 1) / span
        if not 4.5 <= rate <= 5.5:
            failures.append(f"GPS_INPUT at {rate:.2f} Hz, configured 5")
        tb, g = gps_inputs[-1]
        lat_truth = LAT0 + math.degrees(SPEED * tb / R_MERIDIAN)
        dn = math.radians(g.lat * 1e-7 - lat_truth) * R_MERIDIAN
        de = math.radians(g.lon * 1e-7 - LON0) * R_MERIDIAN * math.cos(math.radians(LAT0))
        checks = [
            (g.gps_id == 1, f"gps_id {g.gps_id}"),
            (g.fix_type == 3, f"fix_type {g.fix_type}"),
            (g.ignore_flags == 0, f"ignore_flags {g.ignore_flags}"),
            (g.time_week > 2300, f"time_week {g.time_week}"),
            (0 <= g.time_week_ms < 604_800_000, f"time_week_ms {g.time_week_ms}"),
            # The INS lags the fix by up to one GNSS period (0.2 s = 6 m) plus transport.
            (abs(dn) < 20.0 and abs(de) < 20.0, f"position error N {dn:.1f} m E {de:.1f} m"),
            (abs(g.alt - (H0 - GEOID)) < 10.0, f"alt {g.alt} (MSL)"),
            (abs(g.vn - SPEED) < 2.0 and abs(g.ve) < 2.0, f"velocity {g.vn} {g.ve} {g.vd}"),
            # DRMS of the INS position covariance a few seconds after start: above the fix's
            # 1 m, below what an unaided INS would claim; the INS's GNSS σ floor is 2.12 m.
            (2.0 < g.horiz_accuracy < 30.0, f"horiz_accuracy {g.horiz_accuracy}"),
            (0.0 < g.vert_accuracy < 30.0, f"vert_accuracy {g.vert_accuracy}"),
            (g.satellites_visible == 10, f"satellites {g.satellites_visible}"),
            (g.yaw == 0, f"yaw {g.yaw}"),
        ]
        failures += [why for ok, why in checks if not ok]
    print(f"pymavlink peer: received {seen}; GPS_INPUT {len(gps_inputs)}; statustext {texts}")
    for f in failures:
        print("FAIL:", f)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
