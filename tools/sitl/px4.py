#!/usr/bin/env python3
"""PX4 SITL (SIH fixed-wing) harness: one measured GNSS-loss flight beside the ianav daemon.

Starts PX4 from a `px4_sitl_default` build with its SIH airplane, flies a take-off and a
rectangular circuit mission in a steady wind, takes GNSS away after a cruise phase
(`SIM_GPS_USED = 0`), and records SIH's ground truth (HIL_STATE_QUATERNION), PX4's estimate
(GLOBAL_POSITION_INT) and the daemon's ODOMETRY. The harness is the MAVLink router between
PX4's onboard link and the daemon, so it sees every frame both ways: it measures what PX4
sends the daemon (rates, stamp latency, SET_MESSAGE_INTERVAL answers) and, in `open` mode,
keeps the daemon's output away from PX4.

Modes: `alone` (no daemon), `open` (daemon runs, its ODOMETRY and origin are not forwarded,
EKF2_EV_CTRL = 0), `closed` (forwarded and fused by EKF2 as external vision).

Writes flight.csv, motion.csv (SIH's and the daemon's heading, attitude and velocity: tells
a heading error from a wind error), summary.toml (with the daemon's wind at its last fix
before the loss, from its debug log line), error.png, the daemon's ianav.toml and ins.toml
(the exact settings it flew with) and logs/ into --out. Needs Python >= 3.11 (tomllib),
pymavlink, numpy, matplotlib.

Wind: SIH's SIH_WIND_N / SIH_WIND_E parameters (PX4-Autopilot main since PR 26467, in the
sense PR 27376 and its follow-up left them: the components of the direction the wind blows
FROM). A PX4 without them (v1.16 and older) flies only with --wind-mps 0: the harness refuses
to fly, or to label, a wind the autopilot did not take, and checks the wind SIH actually
applies against the request from its truth and airspeed during the cruise.
"""

from __future__ import annotations

import argparse
import math
import os
import queue
import re
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import development as mavlink  # noqa: E402

EARTH_RADIUS_M = 6371000.0  # PX4's map projection radius (CONSTANTS_RADIUS_OF_EARTH)
REPO = Path(__file__).resolve().parents[2]

# PX4 SIH's IMU noise as the daemon's INS configuration (see Harness.daemon_config).
SIH_GYRO_VAR_RAD2PS2 = 2.3e-3
SIH_ACCEL_VAR_M2PS4 = 0.42
SIH_Q_VELOCITY_M2PS2 = 7e-5
# The body-rate Q̃ that keeps the paper's Q̃/R ratio (1e-6 / 5.63e-7) with SIH's gyro R: with
# the paper's 1e-6 the body-rate state lags SIH's gyro by 0.48 s (docs/INS.md "Body-rate lag").
SIH_Q_W_NB_RAD2PS2 = SIH_GYRO_VAR_RAD2PS2 * 1e-6 / 5.63e-7
# SIH's magnetometer (PX4 sensor_mag_sim): white noise σ 0.02 / 0.02 / 0.03 gauss per axis;
# the INS's one R per axis takes the largest, (3000 nT)².
SIH_MAG_VAR_NT2 = 9e6
# SIH's gyros do not drift: the paper's gyro-error random walk, not config/ianav.toml's MEMS one.
SIH_Q_E_GYR_RAD2PS2 = 3e-14
# Seconds after TECS's altitude reference meets the aircraft on the ground before arming.
TECS_MARGIN_S = 15.0
# A flight whose aircraft sinks below this fraction of --alt-m after the climb is not labelled.
MIN_HEIGHT_FRACTION = 0.5
# The accuracy of PX4's attitude beside SIH, as the transfer alignment's reference ([alignment]
# in the INS file): EKF2 of PX4 main with SIH lockstep is 0.05–0.15° off in roll, pitch and yaw
# (means per 50 s, motion.csv's px4_*_err_deg of the stock flights in docs/results/px4), so its
# white and slowly varying errors are given 0.2° (0.3° in yaw), about twice that. The INS file's
# 0.5° and 1 / 1 / 1.5° were PX4 v1.16's without lockstep (1.1–1.6° RMS); with them the INS
# leaves an autopilot attitude that is right for its own, whose tilt is ≈ 1° off (docs/INS.md).
SIH_REF_ATTITUDE_SIGMA_DEG = 0.2
SIH_REF_ERROR_SIGMA_DEG = [0.2, 0.2, 0.3]
# The wind SIH applies (from its truth and airspeed) may differ from the request by turbulence-
# free estimation error only: airspeed noise 0.2 m/s, angle of attack and sideslip of a few
# degrees (≤ 0.1 × airspeed along the body axis, averaging out over turns). A sign or unit
# mistake is 2 × the wind speed off.
WIND_CHECK_TOLERANCE_MPS = 1.5

# The SIH airplane's forward thruster as PX4 PR 28362 ("restore and tune the airplane forward
# thruster of sihsim_airplane", merged 2026-08-24) sets it: since the advance-ratio propeller
# model (PR 26720, April 2026) the airframe's SIH_T_MAX no longer reaches the fixed-wing thrust
# and the airplane cannot take off (< 6 m/s at full throttle) on PX4 main between the two.
# APC 8x6" UIUC coefficients (those of 10043_sihsim_standard_vtol) at 13,000 RPM, and a climb
# rate limit that a 30° climb at trim airspeed needs. Set only where the parameters exist.
SIH_AIRPLANE_THRUSTER = {
    "SIH_F_CT0": 0.131, "SIH_F_CT1": 0.004, "SIH_F_CT2": -0.146, "SIH_F_CP0": 0.0777,
    "SIH_F_CP1": 0.0498, "SIH_F_CP2": -0.11, "SIH_F_DIA_INCH": 8, "SIH_F_RPM_MAX": 13000,
    "FW_T_CLMB_MAX": 8.0,
}

# PX4 custom_mode: main mode in bits 16..23, sub mode in 24..31.
PX4_MAIN_MODES = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO", 6: "OFFBOARD",
                  7: "STABILIZED", 8: "RATTITUDE"}
PX4_AUTO_SUB = {1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND",
                8: "FOLLOW", 9: "PRECLAND", 10: "VTOL_TAKEOFF"}

# Messages PX4 stamps with its boot clock, and where the stamp is (field, scale to µs).
STAMPS = {
    "HIGHRES_IMU": ("time_usec", 1), "ATTITUDE": ("time_boot_ms", 1000),
    "ATTITUDE_QUATERNION": ("time_boot_ms", 1000), "GPS_RAW_INT": ("time_usec", 1),
    "GLOBAL_POSITION_INT": ("time_boot_ms", 1000), "SCALED_PRESSURE": ("time_boot_ms", 1000),
    "LOCAL_POSITION_NED": ("time_boot_ms", 1000), "ODOMETRY": ("time_usec", 1),
    "ALTITUDE": ("time_usec", 1), "SYSTEM_TIME": ("time_boot_ms", 1000),
}


def px4_mode_name(custom_mode: int) -> str:
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    name = PX4_MAIN_MODES.get(main, f"MAIN{main}")
    if main == 4:
        name += "." + PX4_AUTO_SUB.get(sub, f"SUB{sub}")
    return name


def reproject(lat0_deg: float, lon0_deg: float, x_n: float, y_e: float) -> tuple[float, float]:
    """Local NED → lat/lon, azimuthal equidistant about the origin (PX4's MapProjection)."""
    lat0 = math.radians(lat0_deg)
    lon0 = math.radians(lon0_deg)
    xr = x_n / EARTH_RADIUS_M
    yr = y_e / EARTH_RADIUS_M
    c = math.hypot(xr, yr)
    if c > 0.0:
        sin_c, cos_c = math.sin(c), math.cos(c)
        lat = math.asin(cos_c * math.sin(lat0) + xr * sin_c * math.cos(lat0) / c)
        lon = lon0 + math.atan2(yr * sin_c, c * math.cos(lat0) * cos_c - xr * math.sin(lat0) * sin_c)
    else:
        lat, lon = lat0, lon0
    return math.degrees(lat), math.degrees(lon)


def horizontal_m(lat1, lon1, lat2, lon2):
    """Horizontal distance (m) for nearby points (local tangent plane; numpy arrays ok)."""
    import numpy as np

    dn = np.radians(np.asarray(lat2) - np.asarray(lat1)) * EARTH_RADIUS_M
    de = (np.radians(np.asarray(lon2) - np.asarray(lon1)) * EARTH_RADIUS_M
          * np.cos(np.radians(np.asarray(lat1))))
    return np.hypot(dn, de)


def offset_latlon(lat_deg: float, lon_deg: float, n_m: float, e_m: float) -> tuple[float, float]:
    return (lat_deg + math.degrees(n_m / EARTH_RADIUS_M),
            lon_deg + math.degrees(e_m / (EARTH_RADIUS_M * math.cos(math.radians(lat_deg)))))


@dataclass
class Ports:
    instance: int

    @property
    def onboard_px4(self) -> int:  # PX4's onboard (API) link, local port
        return 14580 + self.instance

    @property
    def onboard_remote(self) -> int:  # where PX4 sends it: the harness listens here
        return 14540 + self.instance

    @property
    def gcs_px4(self) -> int:
        return 18570 + self.instance

    @property
    def gcs_remote(self) -> int:  # private GCS port (PX4's default 14550 may be in use)
        return 24550 + self.instance

    @property
    def sih_px4(self) -> int:
        return 19450 + self.instance

    @property
    def sih_remote(self) -> int:  # SIH display link: HIL_STATE_QUATERNION 25 Hz
        return 19410 + self.instance

    @property
    def daemon(self) -> int:  # the daemon's udpin port
        return 24640 + self.instance


@dataclass
class Record:
    """Everything the IO thread stores (PX4 µs stamps unless said)."""

    truth: list = field(default_factory=list)  # (t_us, lat, lon, alt_m)
    ap: list = field(default_factory=list)  # (t_us, lat, lon, alt_m)
    odom: list = field(default_factory=list)  # (t_us, x, y, z, var_xx, var_yy, wall)
    # (t_us, qw, qx, qy, qz, v_n, v_e, v_d, tas_mps): SIH's attitude, velocity and airspeed
    truth_motion: list = field(default_factory=list)
    # (t_us, qw, qx, qy, qz, vb_x, vb_y, vb_z, yaw_var_rad2)
    odom_motion: list = field(default_factory=list)
    # (t_us, qw, qx, qy, qz): PX4's own attitude (ATTITUDE_QUATERNION on the onboard link)
    ap_motion: list = field(default_factory=list)
    airspeed: list = field(default_factory=list)  # (t_us, calibrated airspeed m/s) VFR_HUD
    origin: tuple | None = None  # daemon's SET_GPS_GLOBAL_ORIGIN (lat, lon, alt_m)
    gps_fix: list = field(default_factory=list)  # (t_us, fix_type) from the GCS link
    modes: list = field(default_factory=list)  # (t_us, name, armed)
    statustext: list = field(default_factory=list)  # (t_us, link, text)
    # onboard link, PX4 → daemon: name → list of (wall_s, stamp_us or None)
    to_daemon: dict = field(default_factory=dict)
    from_daemon: dict = field(default_factory=dict)  # name → count
    interval_requests: list = field(default_factory=list)  # (wall, who, msg_id, interval_us)
    interval_acks: list = field(default_factory=list)  # (wall, result)
    timesync: list = field(default_factory=list)  # (wall_mid_s, px4_us, rtt_s)
    forwarded_to_px4: int = 0
    dropped_to_px4: int = 0


class Harness:
    def __init__(self, args):
        self.args = args
        self.ports = Ports(args.instance)
        self.rec = Record()
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.gcs_q: queue.Queue = queue.Queue()
        self.latest_t_us = 0  # newest PX4 time seen (truth stamp)
        self.sih_clock_us = 0
        self.latest_truth = None  # (t_us, lat, lon, alt)
        self.home_alt_m = None
        self.mode = ("", False)
        self.mission_seq = -1
        self.gcs_mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.ob_mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        self.parsers = {k: mavlink.MAVLink(None) for k in ("gcs", "sih", "px4ob", "daemon")}
        for p in self.parsers.values():
            p.robust_parsing = True
        self.daemon_addr = None
        self.probe = args.mode == "alone"
        self._thruster = None
        self.px4 = None
        self.daemon = None
        self.ekf_notes: dict = {}
        self.sysid = 1
        # Since 5019b10 the daemon answers TIMESYNC in the clock it stamps ODOMETRY in, so
        # TIMESYNC is forwarded; --drop-timesync leaves PX4 unsynchronised (it then stamps
        # each ODOMETRY at its arrival, as it would a companion without TIMESYNC).
        self.drop_timesync = args.mode == "closed" and args.drop_timesync

    # ---------------------------------------------------------------- sockets and IO thread
    def open_sockets(self):
        def udp(port):
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            s.bind(("127.0.0.1", port))
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
            return s

        self.s_gcs = udp(self.ports.gcs_remote)
        self.s_sih = udp(self.ports.sih_remote)
        self.s_ob = udp(self.ports.onboard_remote)
        self.s_dmn = udp(0)  # the daemon answers whoever sent last: this socket

    def send_gcs(self, msg):
        self.s_gcs.sendto(msg.pack(self.gcs_mav), ("127.0.0.1", self.ports.gcs_px4))

    def send_sih(self, msg):
        self.s_sih.sendto(msg.pack(self.gcs_mav), ("127.0.0.1", self.ports.sih_px4))

    def send_onboard(self, msg):
        self.s_ob.sendto(msg.pack(self.ob_mav), ("127.0.0.1", self.ports.onboard_px4))

    def parse(self, key, data):
        out = []
        try:
            msgs = self.parsers[key].parse_buffer(data)
        except Exception:  # a malformed frame must not stop the recording
            return out
        for m in msgs or []:
            if m.get_type() != "BAD_DATA":
                out.append(m)
        return out

    def io_loop(self):
        socks = [self.s_gcs, self.s_sih, self.s_ob, self.s_dmn]
        while not self.stop.is_set():
            ready, _, _ = select.select(socks, [], [], 0.05)
            for s in ready:
                try:
                    data, addr = s.recvfrom(65536)
                except OSError:
                    continue
                wall = time.monotonic()
                if s is self.s_ob:
                    self.on_px4_onboard(data, wall)
                elif s is self.s_dmn:
                    self.on_daemon(data, wall)
                elif s is self.s_gcs:
                    for m in self.parse("gcs", data):
                        self.on_gcs(m, wall)
                else:
                    for m in self.parse("sih", data):
                        self.on_sih(m)

    def on_px4_onboard(self, data, wall):
        msgs = self.parse("px4ob", data)
        drop = self.drop_timesync and any(m.get_type() == "TIMESYNC" for m in msgs)
        if self.daemon is not None and not drop:
            self.s_dmn.sendto(data, ("127.0.0.1", self.ports.daemon))
        with self.lock:
            for m in msgs:
                name = m.get_type()
                st = STAMPS.get(name)
                stamp = getattr(m, st[0]) * st[1] if st else None
                self.rec.to_daemon.setdefault(name, []).append((wall, stamp))
                if name == "ATTITUDE_QUATERNION":
                    self.rec.ap_motion.append((m.time_boot_ms * 1000, m.q1, m.q2, m.q3, m.q4))
                elif name == "COMMAND_ACK" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                    self.rec.interval_acks.append((wall, int(m.result)))
                elif name == "STATUSTEXT":
                    self.rec.statustext.append((self.latest_t_us, "onboard", m.text))

    def on_daemon(self, data, wall):
        msgs = self.parse("daemon", data)
        output = any(m.get_type() in ("ODOMETRY", "SET_GPS_GLOBAL_ORIGIN") for m in msgs)
        extra_drop = self.args.drop_to_px4
        dropped = any(extra_drop == "all" or m.get_type() in extra_drop.split(",") for m in msgs)
        if self.drop_timesync and any(m.get_type() == "TIMESYNC" for m in msgs):
            return
        with self.lock:
            for m in msgs:
                name = m.get_type()
                self.rec.from_daemon[name] = self.rec.from_daemon.get(name, 0) + 1
                if name == "ODOMETRY":
                    c = m.pose_covariance
                    self.rec.odom.append((m.time_usec, m.x, m.y, m.z, c[0], c[6], wall))
                    self.rec.odom_motion.append((m.time_usec, *m.q, m.vx, m.vy, m.vz, c[20]))
                elif name == "SET_GPS_GLOBAL_ORIGIN":
                    self.rec.origin = (m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3)
                elif name == "COMMAND_LONG" and m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                    self.rec.interval_requests.append((wall, "daemon", int(m.param1), m.param2))
                elif name == "STATUSTEXT":
                    self.rec.statustext.append((self.latest_t_us, "daemon", m.text))
            if (output and self.args.mode == "open") or (extra_drop and dropped):
                # Frames hold one message each (the daemon writes message by message).
                self.rec.dropped_to_px4 += 1
                return
            self.rec.forwarded_to_px4 += 1
        self.s_ob.sendto(data, ("127.0.0.1", self.ports.onboard_px4))

    def on_sih(self, m):
        # PX4 v1.16 sends HIL_STATE_QUATERNION with time_usec = 0; the same link's
        # HIL_ACTUATOR_CONTROLS (200 Hz, sent by the same MAVLink thread) carries the time.
        name = m.get_type()
        if name == "HIL_ACTUATOR_CONTROLS":
            self.sih_clock_us = max(self.sih_clock_us, m.time_usec)
            self.latest_t_us = self.sih_clock_us
            return
        if name != "HIL_STATE_QUATERNION" or self.sih_clock_us == 0:
            return
        row = (self.sih_clock_us, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3)
        motion = (self.sih_clock_us, *m.attitude_quaternion, m.vx * 0.01, m.vy * 0.01,
                  m.vz * 0.01, m.true_airspeed * 0.01)
        with self.lock:
            if self.rec.truth_motion and self.rec.truth_motion[-1][0] == motion[0]:
                self.rec.truth_motion[-1] = motion
            else:
                self.rec.truth_motion.append(motion)
            if self.rec.truth and self.rec.truth[-1][0] == row[0]:
                self.rec.truth[-1] = row  # two in one 5 ms step: keep the newer
            else:
                self.rec.truth.append(row)
            self.latest_truth = row

    def on_gcs(self, m, wall):
        name = m.get_type()
        if name == "GLOBAL_POSITION_INT":
            with self.lock:
                self.rec.ap.append((m.time_boot_ms * 1000, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3))
        elif name == "VFR_HUD":
            if math.isfinite(m.airspeed) and self.latest_t_us:
                with self.lock:
                    self.rec.airspeed.append((self.latest_t_us, m.airspeed))
        elif name == "GPS_RAW_INT":
            with self.lock:
                self.rec.gps_fix.append((m.time_usec, m.fix_type))
        elif name == "HEARTBEAT" and m.autopilot == mavlink.MAV_AUTOPILOT_PX4:
            self.sysid = m.get_srcSystem()  # 1 + instance in SITL
            armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            mode = (px4_mode_name(m.custom_mode), armed)
            if mode != self.mode:
                self.mode = mode
                with self.lock:
                    self.rec.modes.append((self.latest_t_us, mode[0], armed))
                log(f"mode {mode[0]} armed={armed}")
        elif name == "MISSION_CURRENT":
            self.mission_seq = m.seq
        elif name == "HOME_POSITION":
            self.home_alt_m = m.altitude * 1e-3
        elif name == "TIMESYNC" and m.tc1 != 0 and m.ts1 > 0:
            sent = m.ts1 * 1e-9
            with self.lock:
                self.rec.timesync.append(((sent + wall) / 2, m.tc1 / 1000.0, wall - sent))
        elif name == "STATUSTEXT":
            with self.lock:
                self.rec.statustext.append((self.latest_t_us, "gcs", m.text))
            log(f"PX4: {m.text}")
        elif name in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK", "COMMAND_ACK",
                      "PARAM_VALUE"):
            self.gcs_q.put(m)

    # ---------------------------------------------------------------- PX4 and daemon processes
    def px4_params(self) -> dict:
        a = self.args
        p = {
            # Failsafes raised so that every mode flies the whole mission (see README).
            "COM_POS_FS_EPH": 400.0, "COM_POS_LOW_EPH": -1.0, "COM_VEL_FS_EVH": 100.0,
            "NAV_DLL_ACT": 0, "COM_DL_LOSS_T": 300, "NAV_RCL_ACT": 0, "COM_RCL_EXCEPT": 7,
            "COM_RC_IN_MODE": 4, "SDLOG_MODE": 1 if a.ulog else -1, "MIS_TKO_LAND_REQ": 0,
            "EKF2_EV_CTRL": 0,
        }
        p.update(self.thruster_params())
        if a.mode == "closed":
            p.update({"EKF2_EV_CTRL": a.ev_ctrl, "EKF2_EV_NOISE_MD": 0, "EKF2_EVP_NOISE": 0.5,
                      "EKF2_EVV_NOISE": 0.3, "EKF2_EV_QMIN": 1, "EKF2_EV_DELAY": a.ev_delay_ms})
        return p

    def thruster_params(self) -> dict:
        """SIH_AIRPLANE_THRUSTER where this build has the forward-thruster model but its
        airplane airframe does not configure it (PX4 main from PR 26720 to PR 28362). Read
        once: it scans the PX4 binary."""
        if self._thruster is None:
            self._thruster = self._find_thruster_params()
        return self._thruster

    def _find_thruster_params(self) -> dict:
        build = Path(self.args.px4_build).resolve()
        airframe = build / "etc" / "init.d-posix" / "airframes" / "10041_sihsim_airplane"
        try:
            has_model = b"SIH_F_CT0" in (build / "bin" / "px4").read_bytes()
            configured = "SIH_F_CT0" in airframe.read_text()
        except OSError:
            return {}
        return dict(SIH_AIRPLANE_THRUSTER) if has_model and not configured else {}

    def start_px4(self, work: Path, logs: Path):
        build = Path(self.args.px4_build).resolve()
        etc = work / "etc"
        shutil.copytree(build / "etc", etc, symlinks=True)
        # Private GCS port for the harness; the parameters go in before any module starts.
        rc_mav = etc / "init.d-posix" / "px4-rc.mavlink"
        txt = rc_mav.read_text()
        txt = txt.replace("mavlink start -x -u $udp_gcs_port_local -r 4000000 -f\n",
                          f"mavlink start -x -u $udp_gcs_port_local -r 4000000 -f "
                          f"-o {self.ports.gcs_remote}\n")
        rc_mav.write_text(txt)
        rcs = etc / "init.d-posix" / "rcS"
        lines = []
        for k, v in self.px4_params().items():
            lines.append(f"param set {k} {v}")
        txt = rcs.read_text()
        assert "\ndataman start\n" in txt, "unexpected rcS: no 'dataman start'"
        txt = txt.replace("\ndataman start\n", "\n" + "\n".join(lines) + "\ndataman start\n", 1)
        rcs.write_text(txt)
        rootfs = work / "rootfs"
        rootfs.mkdir()
        env = dict(os.environ, PX4_SIM_MODEL="sihsim_airplane",
                   PX4_SIM_SPEED_FACTOR=str(self.args.speed_factor))
        self.px4_log = open(logs / "px4.log", "w")
        self.px4 = subprocess.Popen(
            [str(build / "bin" / "px4"), "-d", "-i", str(self.args.instance), "-w", str(rootfs),
             str(etc)], stdout=self.px4_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env=env, start_new_session=True)
        self.px4_bin = build / "bin"

    def px4_cmd(self, *words) -> str:
        """Run a px4 shell command through the client (`px4-param set ...`)."""
        exe = self.px4_bin / f"px4-{words[0]}"
        r = subprocess.run([str(exe), "--instance", str(self.args.instance), *words[1:]],
                           capture_output=True, text=True, timeout=30)
        out = (r.stdout + r.stderr).strip()
        if words[0] != "listener":
            log(f"px4 {' '.join(words)} -> rc {r.returncode} {out[-200:]}")
        return out

    def px4_ver(self) -> str:
        """PX4's own account of its build: `ver all` (git hash, tag, OS)."""
        out = self.px4_cmd("ver", "all")
        keep = [ln.strip() for ln in out.splitlines()
                if ln.strip().startswith(("FW git-hash", "FW version", "FW git-branch", "PX4GIT"))
                or "git" in ln.lower() and ":" in ln]
        return "; ".join(dict.fromkeys(keep))

    def ekf_snapshot(self, label):
        """EKF2's aiding flags and its EV position fusion state (px4-listener), for the summary."""
        keep = ("cs_gnss_pos", "cs_ev_pos", "cs_ev_vel", "cs_fuse_aspd", "cs_fuse_beta",
                "cs_wind_dead_reckoning", "cs_inertial_dead_reckoning", "fused",
                "innovation_rejected", "test_ratio", "innovation", "observation_variance")
        lines = []
        for topic in ("estimator_status_flags", "estimator_aid_src_ev_pos"):
            out = self.px4_cmd("listener", topic, "-n", "1")
            if "never published" in out:
                lines.append(f"{topic}: never published")
                continue
            for ln in out.splitlines():
                k = ln.strip().split(":")[0]
                if k in keep:
                    lines.append(f"{topic}.{ln.strip()}")
        self.ekf_notes[label] = lines

    def daemon_config(self, path: Path):
        """The daemon's configuration: the given file, with the SITL link keys overridden.

        Written as `path` with its INS file copied beside it (`ins.toml`, referenced relatively),
        so the flight directory holds exactly the settings the daemon flew with."""
        import tomllib

        base = Path(self.args.config).resolve()
        cfg = tomllib.loads(base.read_text())
        cfg.setdefault("mavlink", {}).update({
            "connection": f"udpin:127.0.0.1:{self.ports.daemon}", "autopilot": "px4",
            "clock": "autopilot"})
        cfg.setdefault("output", {}).update({"mode": "odometry"})
        if self.args.daemon_log_level:
            cfg.setdefault("logging", {})["level"] = self.args.daemon_log_level
        nav = cfg.setdefault("navigation", {})
        if nav.get("ins_config"):
            ins_src = (base.parent / nav["ins_config"]).resolve()
            shutil.copyfile(ins_src, path.parent / "ins.toml")
            nav["ins_config"] = "ins.toml"
        # HIGHRES_IMU's field has EKF2's wandering mag-bias estimate subtracted (docs/PX4.md).
        cfg.setdefault("input", {})["magnetometer"] = self.args.magnetometer
        if self.args.q_e_gyr:
            # SIH's gyros do not drift: the paper's gyro model fits them better than the
            # drifting-MEMS random walk of config/ianav.toml.
            cfg.setdefault("ins", {}).setdefault("attitude", {})["q_e_gyr_rad2ps2"] = \
                self.args.q_e_gyr
        if self.args.sih_imu:
            # SIH's IMU is far noisier than the paper's (sih.cpp: per-sample σ 0.5/1.7/1.4 m/s²
            # and 0.14/0.07/0.03 rad/s, 250 Hz sensor_combined in cruise: 0.25/0.85/0.70 m/s²,
            # 0.073/0.036/0.015 rad/s). As for any IMU, its noise goes in the INS's R and Q:
            # the mean per-axis variance in the attitude filter's R, and the accelerometer
            # noise as velocity random walk (0.85² m²/s⁴ × (10 ms)² per step, rounded up), not
            # as position-filter R, which would smooth the specific force and lag it in turns.
            ins = cfg.setdefault("ins", {})
            att = ins.setdefault("attitude", {})
            att.update({"r_gyro_rad2ps2": SIH_GYRO_VAR_RAD2PS2,
                        "gyro_noise_var_rad2ps2": SIH_GYRO_VAR_RAD2PS2,
                        "q_w_nb_rad2ps2": SIH_Q_W_NB_RAD2PS2,
                        "r_accel_white_m2ps4": SIH_ACCEL_VAR_M2PS4,
                        "r_mag_nt2": SIH_MAG_VAR_NT2})
            ins.setdefault("position", {})["q_velocity_m2ps2"] = SIH_Q_VELOCITY_M2PS2
        if self.args.sih_reference:
            cfg.setdefault("ins", {}).setdefault("alignment", {}).update({
                "ref_attitude_sigma_deg": SIH_REF_ATTITUDE_SIGMA_DEG,
                "ref_error_sigma_deg": SIH_REF_ERROR_SIGMA_DEG})
        for item in self.args.ins_set:
            key, sep, value = item.partition("=")
            section, dot, name = key.strip().partition(".")
            if not sep or not dot or not section or not name:
                raise SystemExit(f"--ins-set {item!r}: expected SECTION.KEY=VALUE")
            try:
                parsed = tomllib.loads(f"v = {value.strip()}")["v"]
            except tomllib.TOMLDecodeError as e:
                raise SystemExit(f"--ins-set {item!r}: {e}")
            cfg.setdefault("ins", {}).setdefault(section, {})[name] = parsed
        path.write_text(to_toml(cfg))

    def start_daemon(self, logs: Path):
        cfg = Path(self.args.out) / "ianav.toml"
        self.daemon_config(cfg)
        self.daemon_log = open(logs / "ianav.log", "w")
        record = ["--record", str(logs / "daemon.bin")] if self.args.record else []
        self.daemon = subprocess.Popen(
            [str(Path(self.args.daemon).resolve()), "run", "--config", str(cfg)] + record,
            stdout=self.daemon_log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            start_new_session=True)

    def stop_processes(self):
        for p in (self.daemon, self.px4):
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()

    def min_height_after_climb(self, t_loss_us) -> float | None:
        """The lowest truth height over home after the climb first reached 90 % of --alt-m,
        up to the loss (None before that): a take-off that sinks back is visible."""
        a = self.args
        if not self.rec.truth or self.home_alt_m is None:
            return None
        h = [r[3] - self.home_alt_m for r in self.rec.truth
             if t_loss_us is None or r[0] <= t_loss_us]
        up = next((i for i, v in enumerate(h) if v >= 0.9 * a.alt_m), None)
        return None if up is None else round(min(h[up:]), 1)

    def px4_param(self, name: str) -> float | None:
        """A parameter's value from PX4's shell, None when this build has no such parameter."""
        out = self.px4_cmd("param", "show", name)
        m = re.search(rf"{name}\s*\[[^\]]*\]\s*:\s*([-+0-9.eE]+)", out)
        return float(m.group(1)) if m else None

    def set_wind(self):
        """SIH's steady wind, in the sense of PX4's SIH_WIND_N/E: the components of the direction
        the wind blows from. Refuses a wind this build cannot apply."""
        a = self.args
        n_from = a.wind_mps * math.cos(math.radians(a.wind_from_deg))
        e_from = a.wind_mps * math.sin(math.radians(a.wind_from_deg))
        have = self.px4_param("SIH_WIND_N") is not None and self.px4_param("SIH_WIND_E") is not None
        if not have:
            if a.wind_mps != 0.0:
                raise RuntimeError("this PX4 has no SIH_WIND_N/E (SIH wind needs PX4-Autopilot "
                                   "main with PR 26467 or a release containing it): fly with "
                                   "--wind-mps 0")
            self.sih_wind_params = None
            return
        self.px4_cmd("param", "set", "SIH_WIND_N", f"{n_from:.3f}")
        self.px4_cmd("param", "set", "SIH_WIND_E", f"{e_from:.3f}")
        got = (self.px4_param("SIH_WIND_N"), self.px4_param("SIH_WIND_E"))
        if any(g is None or abs(g - w) > 1e-3 for g, w in zip(got, (n_from, e_from))):
            raise RuntimeError(f"PX4 did not take the wind: SIH_WIND_N/E = {got}, "
                               f"requested {n_from:.3f}, {e_from:.3f}")
        self.sih_wind_params = got

    def measured_wind(self, t0_us):
        """The wind SIH applies, from its truth: ground velocity minus the air velocity along
        the body x axis (VFR_HUD's calibrated airspeed scaled to true airspeed with the ISA
        density at the truth altitude), averaged from t0_us on. Returns the air's velocity
        (north, east, m/s) and the number of samples."""
        import numpy as np

        with self.lock:
            tm = np.array([r for r in self.rec.truth_motion if r[0] >= t0_us], dtype=float)
            tr = np.array([r for r in self.rec.truth if r[0] >= t0_us], dtype=float)
            asp = np.array(self.rec.airspeed, dtype=float)
        if len(tm) < 20 or len(asp) < 20 or len(tr) < 20:
            return None, 0
        cas = np.interp(tm[:, 0], asp[:, 0], asp[:, 1])
        alt = np.interp(tm[:, 0], tr[:, 0], tr[:, 3])
        tas = cas / np.sqrt((1.0 - 2.25577e-5 * alt) ** 4.2559)
        w, x, y, z = tm[:, 1:5].T
        bx_n = 1 - 2 * (y * y + z * z)  # body x axis in NED
        bx_e = 2 * (x * y + w * z)
        wn = np.mean(tm[:, 5] - tas * bx_n)
        we = np.mean(tm[:, 6] - tas * bx_e)
        return (float(wn), float(we)), len(tm)

    def check_wind(self, t_wind_us):
        """The wind SIH applied over the cruise (after 20 s of settling) against the request."""
        a = self.args
        got, n = self.measured_wind(t_wind_us + 20e6)
        self.wind_measured = got
        if got is None:
            raise RuntimeError("no truth or airspeed to measure the wind SIH applies")
        want = (-a.wind_mps * math.cos(math.radians(a.wind_from_deg)),
                -a.wind_mps * math.sin(math.radians(a.wind_from_deg)))
        off = math.hypot(got[0] - want[0], got[1] - want[1])
        log(f"wind measured from SIH truth: {got[0]:.2f} N {got[1]:.2f} E m/s "
            f"(requested {want[0]:.2f}, {want[1]:.2f}; {n} samples)")
        if off > WIND_CHECK_TOLERANCE_MPS:
            raise RuntimeError(f"SIH applies a wind of ({got[0]:.2f}, {got[1]:.2f}) m/s N/E, "
                               f"{off:.1f} m/s away from the requested ({want[0]:.2f}, "
                               f"{want[1]:.2f}): not labelling this flight with it")

    # ---------------------------------------------------------------- MAVLink control
    def wait_t(self, cond, timeout_wall_s, what):
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_wall_s:
            if cond():
                return
            self.check_alive()
            time.sleep(0.05)
        raise RuntimeError(f"timeout waiting for {what}")

    def check_alive(self):
        if self.px4 is not None and self.px4.poll() is not None:
            raise RuntimeError(f"PX4 exited with {self.px4.returncode}")
        if self.daemon is not None and self.daemon.poll() is not None:
            raise RuntimeError(f"ianav exited with {self.daemon.returncode}")

    def sim_sleep(self, dt_s):
        """Sleep dt_s of PX4 time."""
        t_end = self.latest_t_us + dt_s * 1e6
        self.wait_t(lambda: self.latest_t_us >= t_end, dt_s / 0.2 + 60, f"{dt_s} s of sim time")

    def heartbeat_loop(self):
        n = 0
        while not self.stop.is_set():
            hb = mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID,
                                                   0, 0, mavlink.MAV_STATE_ACTIVE, 3)
            self.send_gcs(hb)
            self.send_sih(hb)
            if n % 2 == 0:
                ts = mavlink.MAVLink_timesync_message(0, int(time.monotonic() * 1e9))
                self.send_gcs(ts)
            n += 1
            self.stop.wait(0.5)

    def command(self, cmd, *params, timeout=5.0):
        p = list(params) + [0.0] * (7 - len(params))
        for _ in range(3):
            self.send_gcs(mavlink.MAVLink_command_long_message(self.sysid, 1, cmd, 0, *p))
            t0 = time.monotonic()
            while time.monotonic() - t0 < timeout:
                try:
                    m = self.gcs_q.get(timeout=0.2)
                except queue.Empty:
                    continue
                if m.get_type() == "COMMAND_ACK" and m.command == cmd:
                    return m.result
        raise RuntimeError(f"no COMMAND_ACK for {cmd}")

    def set_interval(self, send, msg_id, rate_hz):
        send(mavlink.MAVLink_command_long_message(
            self.sysid, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, 1e6 / rate_hz, 0, 0, 0, 0, 0))

    def upload_mission(self, items):
        while not self.gcs_q.empty():
            self.gcs_q.get_nowait()
        self.send_gcs(mavlink.MAVLink_mission_count_message(self.sysid, 1, len(items), 0))
        t0 = time.monotonic()
        while time.monotonic() - t0 < 30:
            try:
                m = self.gcs_q.get(timeout=1.0)
            except queue.Empty:
                continue
            t = m.get_type()
            if t in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
                self.send_gcs(items[m.seq])
            elif t == "MISSION_ACK":
                if m.type != mavlink.MAV_MISSION_ACCEPTED:
                    raise RuntimeError(f"mission refused: {m.type}")
                return
        raise RuntimeError("mission upload timed out")

    def mission_items(self, lat0, lon0):
        """Take-off to 100 m, then a 1.6 km x 0.9 km rectangle flown again and again."""
        def item(seq, cmd, lat=0.0, lon=0.0, alt=0.0, p1=0.0, p2=0.0, p3=0.0, p4=0.0,
                 frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
            return mavlink.MAVLink_mission_item_int_message(
                self.sysid, 1, seq, frame, cmd, 0, 1, p1, p2, p3, p4, int(lat * 1e7), int(lon * 1e7), alt, 0)

        alt = self.args.alt_m
        la, lo = offset_latlon(lat0, lon0, 600.0, 0.0)
        items = [item(0, mavlink.MAV_CMD_NAV_TAKEOFF, la, lo, alt, p1=15.0)]
        corners = [(600.0, 700.0), (-300.0, 900.0), (-300.0, -700.0), (600.0, -700.0)]
        for i, (n, e) in enumerate(corners):
            la, lo = offset_latlon(lat0, lon0, n, e)
            items.append(item(i + 1, mavlink.MAV_CMD_NAV_WAYPOINT, la, lo, alt))
        items.append(item(len(items), mavlink.MAV_CMD_DO_JUMP, p1=1, p2=1000,
                          frame=mavlink.MAV_FRAME_MISSION))
        return items

    # ---------------------------------------------------------------- the flight
    def probe_link(self):
        """alone mode: default onboard rates, then what a HIGHRES_IMU request achieves."""
        # No HEARTBEAT here: a companion that goes silent trips PX4's "mission computer lost".
        marks = []
        w0 = time.monotonic()
        self.sim_sleep(10)
        marks.append(("default", w0, time.monotonic()))
        for rate in (100.0, 250.0):
            with self.lock:
                self.rec.interval_requests.append(
                    (time.monotonic(), "harness", mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, 1e6 / rate))
            self.set_interval(self.send_onboard, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, rate)
            self.sim_sleep(2)
            w0 = time.monotonic()
            self.sim_sleep(10)
            marks.append((f"requested_{rate:g}_hz", w0, time.monotonic()))
        self.set_interval(self.send_onboard, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU, 50.0)
        self.probe_marks = marks

    def fly(self):
        a = self.args
        out = Path(a.out)
        logs = out / "logs"
        logs.mkdir(parents=True, exist_ok=True)
        work = Path(tempfile.mkdtemp(prefix="px4sih_"))
        self.open_sockets()
        io = threading.Thread(target=self.io_loop, daemon=True)
        io.start()
        self.probe_marks = []
        self.wind_measured = None
        self.sih_wind_params = None
        self.px4_version = ""
        t_arm = t_wind = t_cmd_loss = None
        try:
            self.start_px4(work, logs)
            hb = threading.Thread(target=self.heartbeat_loop, daemon=True)
            hb.start()
            self.wait_t(lambda: self.latest_truth is not None and self.mode[0] != "", 120,
                        "PX4 heartbeat and SIH truth")
            self.px4_version = self.px4_ver()
            for msg_id, rate in ((mavlink.MAVLINK_MSG_ID_GPS_RAW_INT, 10.0),
                                 (mavlink.MAVLINK_MSG_ID_VFR_HUD, 10.0),
                                 (mavlink.MAVLINK_MSG_ID_HOME_POSITION, 1.0),
                                 (mavlink.MAVLINK_MSG_ID_MISSION_CURRENT, 2.0)):
                self.set_interval(self.send_gcs, msg_id, rate)
            if a.mode != "alone":
                self.start_daemon(logs)
            else:
                self.probe_link()
            # EKF2 needs GNSS and a home position before arming.
            self.wait_t(lambda: self.home_alt_m is not None, 300, "home position")
            _, lat0, lon0, _ = self.latest_truth
            self.upload_mission(self.mission_items(lat0, lon0))
            log("mission uploaded")
            self.sim_sleep(5)
            # The same time on the ground in every mode: EKF2's heading and biases settle
            # while it stands still, and alone mode's link probe used to give it 34 s more.
            # Not before TECS is ready: its altitude reference starts at 0 m MSL at boot and
            # rises at FW_T_CLMB_R_SP until it meets the aircraft (PX4 main 7f8482c655, its
            # tecs_status). Armed earlier, the take-off hands TECS a reference far below the
            # aircraft, which then sinks at FW_T_SINK_MAX into the ground and climbs again.
            clmb = self.px4_param("FW_T_CLMB_R_SP") or 3.0
            self.arm_at_s = max(a.arm_at_s, self.home_alt_m / clmb + TECS_MARGIN_S)
            self.wait_t(lambda: self.latest_t_us >= self.arm_at_s * 1e6,
                        self.arm_at_s / 0.2 + 60, f"PX4 time {self.arm_at_s:.0f} s")
            for attempt in range(30):
                self.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 4)  # AUTO.MISSION
                r = self.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
                if r == mavlink.MAV_RESULT_ACCEPTED:
                    break
                self.sim_sleep(2)
            else:
                raise RuntimeError("PX4 refused to arm")
            t_arm = self.latest_t_us
            log("armed")
            self.wait_t(lambda: self.latest_truth[3] - self.home_alt_m > 0.7 * a.alt_m,
                        600, "climb")
            self.set_wind()
            t_wind = self.latest_t_us
            log(f"wind {a.wind_mps} m/s from {a.wind_from_deg} deg; cruising {a.cruise_s} s")
            self.sim_sleep(a.cruise_s)
            self.check_wind(t_wind)
            self.ekf_snapshot("before_loss")
            self.px4_cmd("param", "set", "SIM_GPS_USED", "0")
            t_cmd_loss = self.latest_t_us
            log(f"GNSS off; denied for {a.denied_s} s")
            first = min(60.0, a.denied_s)
            self.sim_sleep(first)
            self.ekf_snapshot("loss_plus_60s")
            self.sim_sleep(a.denied_s - first)
            self.ekf_snapshot("end")
            self.completed = True
        except (Exception, KeyboardInterrupt) as e:  # keep what was recorded: the summary says so
            log(f"flight aborted: {e}")
            self.completed = False
            self.abort_reason = str(e)
        finally:
            self.stop.set()
            time.sleep(0.3)
            self.stop_processes()
            if a.ulog:  # PX4 writes under its rootfs: log/<date>/<time>.ulg
                for i, f in enumerate(sorted((work / "rootfs").rglob("*.ulg"))):
                    shutil.copy(f, logs / f"px4-{i}.ulg")
            shutil.rmtree(work, ignore_errors=True)
        self.t_arm, self.t_wind, self.t_cmd_loss = t_arm, t_wind, t_cmd_loss
        return self.analyse(out)

    # ---------------------------------------------------------------- analysis and outputs
    def analyse(self, out: Path):
        import numpy as np

        a = self.args
        rec = self.rec
        truth = np.array(rec.truth, dtype=float)
        if len(truth) < 10:
            raise RuntimeError(f"no ground truth recorded ({getattr(self, 'abort_reason', '')})")
        ap = np.array(rec.ap, dtype=float) if rec.ap else np.zeros((0, 4))
        # GNSS loss: first no-fix report at or after the command.
        t_loss = None
        if self.t_cmd_loss is not None:
            for t, fix in rec.gps_fix:
                if t >= self.t_cmd_loss - 1e6 and fix < 3:
                    t_loss = t
                    break
            if t_loss is None:
                t_loss = self.t_cmd_loss
        t_ref = t_loss if t_loss is not None else truth[-1, 0]
        odom = None
        if rec.odom and rec.origin is not None:
            o = np.array(rec.odom, dtype=float)
            order = np.argsort(o[:, 0], kind="stable")
            o = o[order]
            ll = np.array([reproject(rec.origin[0], rec.origin[1], x, y) for x, y in o[:, 1:3]])
            hacc = np.sqrt(np.maximum(o[:, 4], o[:, 5]))
            odom = np.column_stack([o[:, 0], ll[:, 0], ll[:, 1], rec.origin[2] - o[:, 3], hacc])

        # 5 Hz grid of PX4 time from arming (or the first truth) to the end.
        t0 = self.t_arm if self.t_arm is not None else truth[0, 0]
        grid = np.arange(t0, truth[-1, 0], 2e5)

        def interp(series, cols, max_gap_us):
            outc = np.full((len(grid), len(cols)), np.nan)
            if series is None or len(series) < 2:
                return outc
            t = series[:, 0]
            keep = np.concatenate([[True], np.diff(t) > 0])
            series, t = series[keep], t[keep]
            idx = np.searchsorted(t, grid)
            ok = (idx > 0) & (idx < len(t))
            gap = np.full(len(grid), np.inf)
            gap[ok] = t[idx[ok]] - t[idx[ok] - 1]
            ok &= gap <= max_gap_us
            for j, c in enumerate(cols):
                v = np.interp(grid, t, series[:, c])
                outc[ok, j] = v[ok]
            return outc

        tr = interp(truth, [1, 2, 3], 0.5e6)
        apg = interp(ap, [1, 2, 3], 0.5e6)
        ia = interp(odom, [1, 2, 3, 4], 0.5e6)
        ap_err = horizontal_m(tr[:, 0], tr[:, 1], apg[:, 0], apg[:, 1])
        ia_err = horizontal_m(tr[:, 0], tr[:, 1], ia[:, 0], ia[:, 1])
        t_s = (grid - t_ref) / 1e6

        with open(out / "flight.csv", "w") as f:
            f.write("t_s,truth_lat_deg,truth_lon_deg,truth_alt_m,ap_lat_deg,ap_lon_deg,ap_alt_m,"
                    "ap_err_h_m,ianav_lat_deg,ianav_lon_deg,ianav_alt_m,ianav_err_h_m,ianav_hacc_m\n")
            step = max(1, int(round(a.csv_period_s / 0.2)))
            for i in range(0, len(grid), step):
                def fmt(v, nd):
                    return "" if not np.isfinite(v) else f"{v:.{nd}f}"
                f.write(",".join([
                    f"{t_s[i]:.1f}", fmt(tr[i, 0], 7), fmt(tr[i, 1], 7), fmt(tr[i, 2], 1),
                    fmt(apg[i, 0], 7), fmt(apg[i, 1], 7), fmt(apg[i, 2], 1), fmt(ap_err[i], 1),
                    fmt(ia[i, 0], 7), fmt(ia[i, 1], 7), fmt(ia[i, 2], 1), fmt(ia_err[i], 1),
                    fmt(ia[i, 3], 1)]) + "\n")

        post = (t_s >= 0) & np.isfinite(tr[:, 0])

        def at(err, minutes):
            k = np.argmin(np.abs(t_s - 60.0 * minutes))
            if t_loss is None or abs(t_s[k] - 60.0 * minutes) > 1.0 or not np.isfinite(err[k]):
                return None
            return round(float(err[k]), 1)

        s = {
            "autopilot": "PX4 SITL, SIH airplane (sihsim_airplane)",
            "px4_version": getattr(self, "px4_version", ""),
            "mode": a.mode,
            "daemon_commit": git_describe() if a.mode != "alone" else "",
            "completed": bool(getattr(self, "completed", False)),
            "abort_reason": getattr(self, "abort_reason", ""),
            "short": bool(a.short),
            "wind_mps": a.wind_mps,
            "wind_from_deg": a.wind_from_deg,
            "sih_wind_params_n_e_from": list(self.sih_wind_params) if getattr(
                self, "sih_wind_params", None) else [],
            "wind_measured_n_e_mps": [round(v, 2) for v in self.wind_measured] if getattr(
                self, "wind_measured", None) else [],
            "seed": 1234,
            "seed_note": "SIH seeds its sensor noise with srand(1234) at start; not settable",
            "speed_factor": a.speed_factor,
            "arm_at_px4_time_s": round(getattr(self, "arm_at_s", a.arm_at_s), 1),
            "min_height_after_climb_m": self.min_height_after_climb(t_loss),
            "armed_px4_time_s": round(self.t_arm / 1e6, 3) if self.t_arm is not None else -1.0,
            "cruise_before_loss_s": a.cruise_s,
            "denied_s": a.denied_s,
            "timesync_dropped_by_router": self.drop_timesync,
            "harness_args": flight_args(a),
            "dropped_from_daemon_by_router": a.drop_to_px4,
            "daemon_ins_for_sih_imu": bool(a.sih_imu),
            "daemon_reference_for_sih": bool(a.sih_reference),
            "daemon_q_e_gyr": a.q_e_gyr,
            "px4_timesync_resets": count_in(Path(a.out) / "logs" / "px4.log",
                                            "time jump detected"),
            "px4_params": {k: v for k, v in self.px4_params().items()},
        }
        low = s["min_height_after_climb_m"]
        if low is not None and low < MIN_HEIGHT_FRACTION * a.alt_m:
            s["completed"] = False
            s["abort_reason"] = (f"sank to {low} m over home after the climb (TECS; "
                                 "see the arm time in fly())")
        if s["min_height_after_climb_m"] is None:
            del s["min_height_after_climb_m"]  # TOML has no null
        if t_loss is not None:
            s["gnss_loss_px4_time_s"] = round(t_loss / 1e6, 3)
            s["denied_recorded_s"] = round(float(t_s[post][-1]) if post.any() else 0.0, 1)
        err = {}
        for name, e in (("ap", ap_err), ("ianav", ia_err)):
            for mnt in (1, 2, 5, 10):
                v = at(e, mnt)
                if v is not None:
                    err[f"{name}_{mnt}min_m"] = v
            pe = e[post & np.isfinite(e)]
            if len(pe):
                err[f"{name}_max_m"] = round(float(pe.max()), 1)
                err[f"{name}_rms_m"] = round(float(np.sqrt(np.mean(pe ** 2))), 1)
        s["horizontal_error_after_loss"] = err
        ok = post & np.isfinite(ia_err) & np.isfinite(ia[:, 3])
        if ok.any():
            e, h = ia_err[ok], ia[ok, 3]
            s["ianav_consistency"] = {
                "samples": int(ok.sum()),
                "fraction_err_le_2p45_hacc": round(float(np.mean(e <= 2.45 * h)), 3),
                "hacc_rms_over_err_rms": round(float(np.sqrt(np.mean(h ** 2)) / max(
                    1e-9, np.sqrt(np.mean(e ** 2)))), 3),
                "hacc_at_end_m": round(float(h[-1]), 1),
            }
            s["ianav_published_after_loss"] = True
        else:
            s["ianav_published_after_loss"] = False
        s["flight_modes"] = [f"{(t - t_ref) / 1e6:.1f}s {n} armed={ar}" for t, n, ar in rec.modes]
        s["statustext"] = [f"{(t - t_ref) / 1e6:.1f}s {lk}: {x}" for t, lk, x in rec.statustext
                           if lk != "gcs" or "GPS" in x or "ailsafe" in x or "osition" in x][-40:]
        s["ekf2"] = self.ekf_notes
        s["link"] = self.link_summary()
        (out / "summary.toml").write_text(to_toml(s))
        wind = self.wind_at_loss(out)
        if wind:
            s["ianav_wind_at_loss"] = wind
        motion = self.write_motion(out, grid, t_ref, post)
        if motion:
            s["ianav_motion_after_loss"] = motion
            (out / "summary.toml").write_text(to_toml(s))
        self.plot(out, t_s, ap_err, ia_err, ia[:, 3], t_loss is not None)
        return s

    def wind_at_loss(self, out):
        """The daemon's wind estimate at its last fix before the loss (its debug line), against
        SIH's wind (SIH_WIND_N/E, constant)."""
        last = None
        try:
            text = (Path(out) / "logs" / "ianav.log").read_text(errors="replace")
        except OSError:
            return None
        for line in re.sub(r"\x1b\[[0-9;]*m", "", text).splitlines():
            if "GNSS fix processed" in line and "denied=false" in line:
                last = line
        if last is None:
            return None
        got = dict(re.findall(r"(\w+)=([-0-9.e]+)", last))
        try:
            wn, we = float(got["wind_n_mps"]), float(got["wind_e_mps"])
        except (KeyError, ValueError):
            return None
        a = self.args
        tn = -a.wind_mps * math.cos(math.radians(a.wind_from_deg))
        te = -a.wind_mps * math.sin(math.radians(a.wind_from_deg))
        return {"ianav_n_mps": round(wn, 2), "ianav_e_mps": round(we, 2),
                "sih_n_mps": round(tn, 2), "sih_e_mps": round(te, 2),
                "error_n_mps": round(wn - tn, 2), "error_e_mps": round(we - te, 2)}

    def write_motion(self, out, grid, t_ref, post):
        """motion.csv: SIH's and the daemon's heading, attitude and NED velocity on the 5 Hz
        grid, to tell a heading error from a wind or airspeed error after the loss. Returns
        per-minute means of the daemon's heading and velocity errors after the loss."""
        import numpy as np

        rec = self.rec
        if len(rec.truth_motion) < 10 or len(rec.odom_motion) < 10:
            return None
        tm = np.array(rec.truth_motion, dtype=float)
        om = np.array(rec.odom_motion, dtype=float)
        om = om[np.argsort(om[:, 0], kind="stable")]

        def euler_deg(q):
            w, x, y, z = q.T
            roll = np.degrees(np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)))
            pitch = np.degrees(np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)))
            yaw = np.degrees(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))
            return roll, pitch, yaw

        def body_to_ned(q, v):
            w, x, y, z = q.T
            r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                          [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                          [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
            return np.einsum("ijk,kj->ki", r, v)

        def on_grid(t, cols):
            keep = np.concatenate([[True], np.diff(t) > 0])
            t = t[keep]
            idx = np.clip(np.searchsorted(t, grid), 1, len(t) - 1)
            ok = (grid >= t[0]) & (grid <= t[-1]) & (t[idx] - t[idx - 1] <= 0.5e6)
            res = []
            for c in cols:
                v = np.interp(grid, t, c[keep])
                v[~ok] = np.nan
                res.append(v)
            return res

        tr_r, tr_p, tr_y = euler_deg(tm[:, 1:5])
        ia_r, ia_p, ia_y = euler_deg(om[:, 1:5])
        ia_v = body_to_ned(om[:, 1:5], om[:, 5:8])
        # Angles are interpolated as unwrapped series, then wrapped again.
        g_tr = on_grid(tm[:, 0], [np.unwrap(np.radians(tr_y)), tr_r, tr_p, tm[:, 5], tm[:, 6],
                                  tm[:, 8]])
        g_ia = on_grid(om[:, 0], [np.unwrap(np.radians(ia_y)), ia_r, ia_p, ia_v[:, 0],
                                  ia_v[:, 1], np.degrees(np.sqrt(np.maximum(om[:, 8], 0)))])
        yaw_err = np.degrees(np.angle(np.exp(1j * (g_ia[0] - g_tr[0]))))
        # PX4's own attitude: the daemon aligns to it while GNSS is available.
        nan = np.full(len(grid), np.nan)
        px4_yaw_err, px4_roll_err, px4_pitch_err = nan, nan, nan
        if len(rec.ap_motion) >= 10:
            am = np.array(rec.ap_motion, dtype=float)
            am = am[np.argsort(am[:, 0], kind="stable")]
            ap_r, ap_p, ap_y = euler_deg(am[:, 1:5])
            g_ap = on_grid(am[:, 0], [np.unwrap(np.radians(ap_y)), ap_r, ap_p])
            px4_yaw_err = np.degrees(np.angle(np.exp(1j * (g_ap[0] - g_tr[0]))))
            px4_roll_err, px4_pitch_err = g_ap[1] - g_tr[1], g_ap[2] - g_tr[2]
        t_s = (grid - t_ref) / 1e6
        cols = {
            "truth_yaw_deg": np.degrees(np.angle(np.exp(1j * g_tr[0]))) % 360,
            "truth_roll_deg": g_tr[1], "truth_pitch_deg": g_tr[2],
            "ianav_yaw_err_deg": yaw_err, "ianav_roll_err_deg": g_ia[1] - g_tr[1],
            "ianav_pitch_err_deg": g_ia[2] - g_tr[2], "ianav_yaw_sigma_deg": g_ia[5],
            "truth_v_n_mps": g_tr[3], "truth_v_e_mps": g_tr[4],
            "ianav_v_n_err_mps": g_ia[3] - g_tr[3], "ianav_v_e_err_mps": g_ia[4] - g_tr[4],
            "truth_tas_mps": g_tr[5],
            "px4_yaw_err_deg": px4_yaw_err, "px4_roll_err_deg": px4_roll_err,
            "px4_pitch_err_deg": px4_pitch_err,
        }
        with open(out / "motion.csv", "w") as f:
            f.write("t_s," + ",".join(cols) + "\n")
            for i in range(len(grid)):
                f.write(f"{t_s[i]:.1f}," + ",".join(
                    "" if not np.isfinite(c[i]) else f"{c[i]:.3f}" for c in cols.values()) + "\n")
        minutes = {}
        for k in range(int(np.nanmax(t_s[post]) // 60) if post.any() else 0):
            m = post & (t_s >= 60 * k) & (t_s < 60 * (k + 1)) & np.isfinite(yaw_err)
            if m.sum() < 10:
                continue
            minutes[f"min{k}"] = {
                "yaw_err_mean_deg": round(float(np.mean(yaw_err[m])), 2),
                "yaw_err_rms_deg": round(float(np.sqrt(np.mean(yaw_err[m] ** 2))), 2),
                "yaw_sigma_mean_deg": round(float(np.nanmean(g_ia[5][m])), 2),
                "v_n_err_mean_mps": round(float(np.mean(cols["ianav_v_n_err_mps"][m])), 2),
                "v_e_err_mean_mps": round(float(np.mean(cols["ianav_v_e_err_mps"][m])), 2),
            }
        return minutes

    def px4_time_at(self, wall):
        """PX4 µs at a wall time, from the harness's TIMESYNC exchanges (nearest, local slope)."""
        import numpy as np

        ts = np.array(self.rec.timesync) if self.rec.timesync else None
        if ts is None or len(ts) < 3:
            return None
        w, p = ts[:, 0], ts[:, 1]
        i = np.clip(np.searchsorted(w, wall), 1, len(w) - 1)
        j0, j1 = np.maximum(i - 10, 0), np.minimum(i + 10, len(w) - 1)
        slope = (p[j1] - p[j0]) / np.maximum(w[j1] - w[j0], 1e-6)
        return p[i] + slope * (wall - w[i]), slope

    def link_summary(self):
        import numpy as np

        rec = self.rec
        out = {}
        ts = np.array(rec.timesync) if rec.timesync else np.zeros((0, 3))
        if len(ts) > 3:
            speed = (ts[-1, 1] - ts[0, 1]) / 1e6 / (ts[-1, 0] - ts[0, 0])
            out["achieved_speed_factor"] = round(float(speed), 2)
            out["timesync_rtt_wall_ms_median"] = round(float(np.median(ts[:, 2]) * 1e3), 2)
        rates = {}
        for name, samples in sorted(rec.to_daemon.items()):
            arr = np.array([w for w, _ in samples])
            d = {"count": len(samples)}
            conv = self.px4_time_at(arr) if len(arr) else None
            if conv is not None and len(arr) > 2:
                px4_t, slope = conv
                span = (px4_t[-1] - px4_t[0]) / 1e6
                if span > 0:
                    d["rate_hz_px4_time"] = round((len(arr) - 1) / span, 2)
                stamps = np.array([s if s is not None else np.nan for _, s in samples], dtype=float)
                lat = (px4_t - stamps) / 1e3
                lat = lat[np.isfinite(lat)]
                if len(lat):
                    d["stamp_age_ms_px4_time_p50"] = round(float(np.median(lat)), 2)
                    d["stamp_age_ms_px4_time_p95"] = round(float(np.percentile(lat, 95)), 2)
            rates[name] = d
        out["px4_to_ianav"] = rates
        out["ianav_to_px4_counts"] = dict(sorted(rec.from_daemon.items()))
        if rec.odom:
            o = np.array(rec.odom)
            conv = self.px4_time_at(o[:, 6])
            if conv is not None:
                px4_t, _ = conv
                span = (px4_t[-1] - px4_t[0]) / 1e6
                age = (px4_t - o[:, 0]) / 1e3
                out["odometry"] = {
                    "rate_hz_px4_time": round((len(o) - 1) / span, 2) if span > 0 else 0.0,
                    "age_at_router_ms_px4_time_p50": round(float(np.median(age)), 2),
                    "age_at_router_ms_px4_time_p95": round(float(np.percentile(age, 95)), 2)}
        out["forwarded_to_px4"] = rec.forwarded_to_px4
        out["dropped_to_px4"] = rec.dropped_to_px4
        out["interval_requests"] = [f"{who} id {mid} interval {iv:g} us"
                                    for _, who, mid, iv in rec.interval_requests]
        names = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED",
                 4: "FAILED"}
        out["interval_acks"] = [names.get(r, str(r)) for _, r in rec.interval_acks]
        if self.probe_marks:
            probe = {}
            for label, w0, w1 in self.probe_marks:
                imu = [w for w, _ in rec.to_daemon.get("HIGHRES_IMU", []) if w0 <= w < w1]
                c0 = self.px4_time_at(np.array([w0, w1]))
                if c0 is not None and len(imu) > 1:
                    span = (c0[0][1] - c0[0][0]) / 1e6
                    probe[label] = round(len(imu) / span, 1)
            out["highres_imu_rate_probe_hz"] = probe
        return out

    def plot(self, out, t_s, ap_err, ia_err, hacc, lost):
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        a = self.args
        fig, ax = plt.subplots(figsize=(9, 4.5))
        ax.plot(t_s, ap_err, label="PX4 EKF2 (GLOBAL_POSITION_INT)")
        if any(map(math.isfinite, ia_err)):
            ax.plot(t_s, ia_err, label="ianav ODOMETRY")
            ax.plot(t_s, 2.45 * hacc, ":", label="ianav 2.45 x hacc")
        if lost:
            ax.axvline(0.0, color="k", lw=0.8, label="GNSS lost")
        ax.set_xlabel("time since GNSS loss [s]")
        ax.set_ylabel("horizontal error [m]")
        ax.set_yscale("symlog", linthresh=10.0)
        ax.set_ylim(bottom=0.0)
        ax.set_title(f"PX4 SIH airplane, mode {a.mode}, wind {a.wind_mps:g} m/s from "
                     f"{a.wind_from_deg:g} deg")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper left", fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "error.png", dpi=90)
        plt.close(fig)


def to_toml(d: dict, prefix: str = "") -> str:
    """Minimal TOML writer for nested dicts of scalars and lists of scalars."""
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int):
            return repr(int(v))
        if isinstance(v, float):
            return repr(float(v)) if math.isfinite(v) else '"nan"'
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        raise TypeError(type(v))

    lines, tables = [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif v is not None:
            lines.append(f"{k} = {val(v)}")
    text = "\n".join(lines) + ("\n" if lines else "")
    for k, v in tables:
        name = f"{prefix}{k}"
        text += f"\n[{name}]\n" + to_toml(v, name + ".")
    return text


def flight_args(a) -> str:
    """The options that define the flight, as px4.py arguments: everything but the machine's
    paths (PX4 build, daemon binary, output); the config relative to the repository."""
    skip = {"px4_build", "daemon", "out"}
    words = []
    for k, v in sorted(vars(a).items()):
        if k in skip or v is None or v is False or v == "":
            continue
        if k == "config":
            try:
                v = Path(v).resolve().relative_to(REPO)
            except ValueError:
                v = Path(v).name
        flag = "--" + k.replace("_", "-")
        if isinstance(v, list):
            words.extend(f"{flag} {item}" for item in v)
        elif v is True:
            words.append(flag)
        else:
            words.append(f"{flag} {v}")
    for k in ("sih_imu", "sih_reference"):
        if not getattr(a, k):
            words.append("--no-" + k.replace("_", "-"))
    return " ".join(words)


def count_in(path: Path, text: str) -> int:
    try:
        return path.read_text(errors="replace").count(text)
    except OSError:
        return -1


def git_describe() -> str:
    r = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"],
                       capture_output=True, text=True)
    return r.stdout.strip()


def log(msg):
    print(f"[px4.py {time.strftime('%H:%M:%S')}] {msg}", flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--px4-build", required=True, help="PX4 build dir (build/px4_sitl_default)")
    ap.add_argument("--daemon", default=str(REPO / "target" / "release" / "ianav"))
    ap.add_argument("--magnetometer", choices=["imu", "scaled_imu"], default="scaled_imu",
                    help="the daemon's input.magnetometer (default scaled_imu: the raw field)")
    ap.add_argument("--config", default=str(REPO / "config" / "ianav.toml"),
                    help="daemon configuration; link, clock and output keys are overridden")
    ap.add_argument("--mode", choices=("alone", "open", "closed"), required=True)
    ap.add_argument("--q-e-gyr", type=float, default=SIH_Q_E_GYR_RAD2PS2,
                    help="daemon [ins.attitude] q_e_gyr_rad2ps2 (default 3e-14: SIH's gyros do "
                         "not drift; 0 keeps the config's)")
    ap.add_argument("--ins-set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="one more daemon INS setting (repeatable), a key of config/ins.toml "
                         "under its section and a TOML value, e.g. "
                         "attitude.r_accel_turn_rel=0.2; applied after the presets above, "
                         "recorded in the flight's ianav.toml and summary")
    ap.add_argument("--sih-imu", action=argparse.BooleanOptionalAction, default=True,
                    help="configure the daemon's INS for SIH's sensor noise: IMU (measured), "
                         "the body-rate Q̃ matched to the gyro R, magnetometer (PX4's "
                         "sensor_mag_sim); see daemon_config; on by default")
    ap.add_argument("--sih-reference", action=argparse.BooleanOptionalAction, default=True,
                    help="give the transfer alignment the accuracy of PX4's attitude beside "
                         "SIH (SIH_REF_*; on by default)")
    ap.add_argument("--out", required=True, help="flight directory to write")
    ap.add_argument("--wind-mps", type=float, default=6.0)
    ap.add_argument("--wind-from-deg", type=float, default=270.0)
    ap.add_argument("--speed-factor", type=float, default=4.0)
    ap.add_argument("--instance", type=int, default=0)
    ap.add_argument("--alt-m", type=float, default=100.0)
    ap.add_argument("--arm-at-s", type=float, default=60.0,
                    help="arm no earlier than this PX4 time since boot, in every mode")
    ap.add_argument("--cruise-s", type=float, default=180.0, help="cruise in wind before the loss")
    ap.add_argument("--denied-s", type=float, default=630.0, help="flight after the loss")
    ap.add_argument("--ev-ctrl", type=int, default=1,
                    help="EKF2_EV_CTRL in closed mode: 1 horizontal position, 5 + velocity")
    ap.add_argument("--drop-timesync", action="store_true",
                    help="closed: drop TIMESYNC between PX4 and the daemon (the behaviour before "
                         "5019b10, when the daemon answered in its own clock)")
    ap.add_argument("--ev-delay-ms", type=float, default=0.0, help="EKF2_EV_DELAY (closed)")
    ap.add_argument("--drop-to-px4", default="",
                    help="comma-separated message names (or 'all') never passed from the daemon "
                         "to PX4, in any mode: isolates what of the daemon's traffic PX4 reacts to")
    ap.add_argument("--ulog", action="store_true",
                    help="PX4 logs from boot (SDLOG_MODE 1); the .ulg files go to OUT/logs/")
    ap.add_argument("--daemon-log-level", default="info,ianav::daemon::nav_thread=debug",
                    help="the daemon's logging.level (the default logs its wind at each fix)")
    ap.add_argument("--csv-period-s", type=float, default=0.2, help="flight.csv row period")
    ap.add_argument("--short", action="store_true", help="quick check: 60 s cruise, 120 s denied")
    ap.add_argument("--record", action="store_true",
                    help="the daemon records what it feeds its navigator (daemon.bin, "
                         "daemon.solutions.csv; `ianav replay`, docs/REPLAY.md)")
    a = ap.parse_args(argv)

    def on_term(signum, _frame):  # stop PX4 and the daemon too (they run in their own sessions)
        raise KeyboardInterrupt(f"signal {signum}")

    signal.signal(signal.SIGTERM, on_term)
    if a.short:
        a.cruise_s, a.denied_s = 60.0, 130.0
    s = Harness(a).fly()
    err = s.get("horizontal_error_after_loss", {})
    log(f"completed={s['completed']} errors={err}")
    return 0 if s["completed"] else 1


if __name__ == "__main__":
    sys.exit(main())
