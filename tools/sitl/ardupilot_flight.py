#!/usr/bin/env python3
"""One measured ArduPlane SITL flight beside the ianav daemon.

Starts ArduPlane SITL (plane model, default parameters plus the ones set in `sitl_params`),
optionally the ianav daemon, and routes MAVLink between the daemon and SITL's SERIAL1 so that
every message either way is seen and timed. SERIAL0 is the harness's own ground-station link:
mission upload, mode, arming, the GNSS loss, and the recording of the truth (SIM_STATE) and
of the autopilot's estimate (GLOBAL_POSITION_INT).

Modes (same flight definition):
  alone   no daemon, GPS2_TYPE 0
  open    daemon runs, GPS2_TYPE 0 and the router drops its GPS_INPUT (open loop)
  closed  daemon's GPS_INPUT reaches ArduPlane as GPS2 (GPS2_TYPE 14)

Output directory: flight.csv, summary.toml, error.png, daemon.log, sitl.log and, unless
`alone`, the daemon's configuration as it flew: ianav.toml and the INS file it names, ins.toml
(a copy of --ins-config, named relative to ianav.toml), so the directory holds its settings.
Times are simulation (vehicle boot) time unless named `wall`.
"""

import argparse
import bisect
import math
import os
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

EARTH_R_M = 6378137.0
HOME = (-35.363261, 149.165230, 584.0, 353.0)  # ArduPilot's usual SITL home (CMAC)
PLANE_MODE_AUTO = 10
CRUISE_ALT_M = 150.0
# Message ids the daemon asks for (docs/DAEMON.md) plus what ArduPlane streams by default.
SENSOR_MSGS = (
    "SCALED_IMU", "RAW_IMU", "SCALED_IMU2", "SCALED_PRESSURE", "SCALED_PRESSURE2",
    "AIRSPEED", "VFR_HUD", "AOA_SSA", "ATTITUDE", "GPS_RAW_INT", "GLOBAL_POSITION_INT",
)
STAMPED = {  # field holding the sample time and its unit in ms
    "SCALED_IMU": ("time_boot_ms", 1.0), "RAW_IMU": ("time_usec", 1e-3),
    "SCALED_IMU2": ("time_boot_ms", 1.0), "SCALED_PRESSURE": ("time_boot_ms", 1.0),
    "SCALED_PRESSURE2": ("time_boot_ms", 1.0), "ATTITUDE": ("time_boot_ms", 1.0),
    "GPS_RAW_INT": ("time_usec", 1e-3), "GLOBAL_POSITION_INT": ("time_boot_ms", 1.0),
    "AOA_SSA": ("time_usec", 1e-3), "SYSTEM_TIME": ("time_boot_ms", 1.0),
}


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def horiz_m(lat1, lon1, lat2, lon2):
    dn = math.radians(lat2 - lat1) * EARTH_R_M
    de = math.radians(lon2 - lon1) * EARTH_R_M * math.cos(math.radians(lat1))
    return math.hypot(dn, de)


def offset(lat, lon, north_m, east_m):
    return (lat + math.degrees(north_m / EARTH_R_M),
            lon + math.degrees(east_m / (EARTH_R_M * math.cos(math.radians(lat)))))


def flight_definition(args):
    """Waypoints and parameters from the options alone: same seed and options, same flight."""
    rng = random.Random(args.seed)
    rot = math.radians(rng.uniform(0.0, 360.0))  # circuit orientation
    centre_dist = 1500.0
    centre = offset(HOME[0], HOME[1], centre_dist * math.cos(rot), centre_dist * math.sin(rot))
    # A 2.4 km x 1.6 km rectangle with a dog-leg: turns of 90 and 45 degrees, about one a minute.
    corners = [(-1200, -800), (1200, -800), (1200, 0), (600, 800), (-1200, 800)]
    wps = []
    for x, y in corners:
        n = x * math.cos(rot) - y * math.sin(rot)
        e = x * math.sin(rot) + y * math.cos(rot)
        wps.append(offset(centre[0], centre[1], n, e))
    return {"circuit_rotation_deg": round(math.degrees(rot), 1), "waypoints": wps}


def sitl_params(args):
    p = {
        "SIM_WIND_SPD": args.wind_speed, "SIM_WIND_DIR": args.wind_dir, "SIM_WIND_TURB": 0,
        "SERIAL1_PROTOCOL": 2, "SERIAL1_BAUD": 921,
        # Closed loop: ianav is GPS2; GPS1 stays primary while it has a 3D fix.
        "GPS2_TYPE": 14 if args.mode == "closed" else 0,
        "GPS_AUTO_SWITCH": 4, "GPS_PRIMARY": 0,
        "AHRS_EKF_TYPE": 3,
        "LOG_BITMASK": 0, "LOG_DISARMED": 0,  # no dataflash: less disk and CPU
        "RTL_AUTOLAND": 0, "FS_GCS_ENABL": 0,
    }
    return p


class Router(threading.Thread):
    """MAVLink between SITL SERIAL1 (TCP) and the daemon (UDP), one message per datagram."""

    def __init__(self, sitl_port, daemon_port, drop_gps_input):
        super().__init__(daemon=True)
        self.tcp = socket.create_connection(("127.0.0.1", sitl_port), timeout=10)
        self.tcp.setblocking(False)
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.bind(("127.0.0.1", 0))
        self.udp.setblocking(False)
        self.daemon_addr = ("127.0.0.1", daemon_port)
        self.drop_gps_input = drop_gps_input
        self.p_ap = mav.MAVLink(None)
        self.p_ap.robust_parsing = True
        self.p_d = mav.MAVLink(None)
        self.p_d.robust_parsing = True
        self.stop = False
        self.lock = threading.Lock()
        self.sim_now_ms = 0.0  # newest vehicle stamp seen on SERIAL1
        self.rx = {}  # type -> list of (sim_now_ms, stamp_ms or None)
        self.imu_wall = []  # (stamp_ms, wall) of SCALED_IMU/RAW_IMU forwarded to the daemon
        self.gps_input = []  # (time_usec, lat, lon, alt, hacc, wall, sim_now_ms)
        self.from_daemon = {}
        self.denials = []
        self.statustext = []

    def run(self):
        import select
        while not self.stop:
            r, _, _ = select.select([self.tcp, self.udp], [], [], 0.2)
            now = time.monotonic()
            if self.tcp in r:
                try:
                    data = self.tcp.recv(65536)
                except BlockingIOError:
                    data = None
                except OSError:
                    break
                if data == b"":
                    break  # SITL closed SERIAL1
                for m in self.p_ap.parse_buffer(data or b"") or []:
                    self._from_ap(m, now)
            if self.udp in r:
                try:
                    data, _ = self.udp.recvfrom(65536)
                except OSError:  # includes ICMP "refused" before the daemon listens
                    data = b""
                for m in self.p_d.parse_buffer(data) or []:
                    self._from_daemon(m, now)

    def _from_ap(self, m, now):
        t = m.get_type()
        if t == "BAD_DATA":
            return
        st = None
        if t in STAMPED:
            f, k = STAMPED[t]
            st = getattr(m, f) * k
            if t != "GPS_RAW_INT":
                self.sim_now_ms = max(self.sim_now_ms, st)
        with self.lock:
            self.rx.setdefault(t, []).append((self.sim_now_ms, st))
            if t in ("SCALED_IMU", "RAW_IMU"):
                self.imu_wall.append((st, now))
            if t == "STATUSTEXT":
                self.statustext.append((self.sim_now_ms, m.text))
            if t == "COMMAND_ACK" and m.result != 0:
                self.denials.append((self.sim_now_ms, m.command, m.result))
        try:
            self.udp.sendto(m.get_msgbuf(), self.daemon_addr)
        except OSError:
            pass  # the daemon is not listening yet

    def _from_daemon(self, m, now):
        t = m.get_type()
        if t == "BAD_DATA":
            return
        with self.lock:
            self.from_daemon[t] = self.from_daemon.get(t, 0) + 1
            if t == "GPS_INPUT":
                self.gps_input.append((m.time_usec, m.lat * 1e-7, m.lon * 1e-7, m.alt,
                                       m.horiz_accuracy, now, self.sim_now_ms))
        if t == "GPS_INPUT" and self.drop_gps_input:
            return
        try:
            self.tcp.sendall(m.get_msgbuf())
        except (BlockingIOError, OSError):
            pass


class Gcs:
    """SERIAL0: control and recording. Sim time = newest GLOBAL_POSITION_INT stamp."""

    def __init__(self, port):
        self.c = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=255,
                                            source_component=190, autoreconnect=False)
        self.t_ms = 0.0
        self.truth = []  # (t_ms, lat, lon, alt_m)
        self.ap = []  # (t_ms, lat, lon, alt_m)
        self.gps_raw = []  # (t_ms, stamp_ms, fix, lat, lon, sats)
        self.gps2_raw = []
        self.mission_seq = 0
        self.armed = False
        self.custom_mode = -1
        self.acks = []
        self.texts = []
        self.params = {}
        self.last_hb = 0.0
        self.watch = []  # processes that must stay alive (SITL, daemon)

    def pump(self, timeout=0.1):
        for p in self.watch:
            if p.poll() is not None:
                raise RuntimeError(f"{os.path.basename(p.args[0])} exited ({p.returncode})")
        m = self.c.recv_match(blocking=True, timeout=timeout)
        while m is not None:
            self._handle(m)
            m = self.c.recv_match(blocking=False)
        if time.monotonic() - self.last_hb > 1.0:
            self.c.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.last_hb = time.monotonic()

    def _handle(self, m):
        t = m.get_type()
        if t == "GLOBAL_POSITION_INT":
            self.t_ms = max(self.t_ms, float(m.time_boot_ms))
            if horiz_m(HOME[0], HOME[1], m.lat * 1e-7, m.lon * 1e-7) > 100e3:
                return  # before the EKF has an origin: a position about (0, 0)
            self.ap.append((float(m.time_boot_ms), m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3))
        elif t == "SIM_STATE":
            lat = m.lat_int * 1e-7 if getattr(m, "lat_int", 0) else m.lat
            lon = m.lon_int * 1e-7 if getattr(m, "lon_int", 0) else m.lon
            # Sent after GLOBAL_POSITION_INT in the same scheduler bucket (lower message
            # enum first): stamped with it, at most one 20 ms loop late.
            if self.t_ms > 0:
                self.truth.append((self.t_ms, lat, lon, m.alt))
        elif t == "GPS_RAW_INT":
            self.gps_raw.append((self.t_ms, m.time_usec * 1e-3, m.fix_type, m.lat * 1e-7,
                                 m.lon * 1e-7, m.satellites_visible))
        elif t == "GPS2_RAW":
            self.gps2_raw.append((self.t_ms, m.time_usec * 1e-3, m.fix_type, m.lat * 1e-7,
                                  m.lon * 1e-7, m.satellites_visible))
        elif t == "MISSION_CURRENT":
            self.mission_seq = m.seq
        elif t == "HEARTBEAT" and m.get_srcComponent() == 1:
            self.armed = bool(m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = m.custom_mode
        elif t == "COMMAND_ACK":
            self.acks.append((m.command, m.result))
        elif t == "STATUSTEXT":
            self.texts.append((self.t_ms, m.text))
        elif t == "PARAM_VALUE":
            self.params[m.param_id] = m.param_value

    def wait(self, cond, wall_timeout_s, what):
        end = time.monotonic() + wall_timeout_s
        while time.monotonic() < end:
            self.pump()
            if cond():
                return
        raise TimeoutError(f"timed out waiting for {what}")

    def interval(self, msg_id, hz):
        self.c.mav.command_long_send(1, 1, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id,
                                     1e6 / hz, 0, 0, 0, 0, 0)

    def set_param(self, name, value, wall_timeout_s=20):
        self.params.pop(name, None)
        end = time.monotonic() + wall_timeout_s
        while time.monotonic() < end:
            self.c.mav.param_set_send(1, 1, name.encode(), float(value),
                                      mav.MAV_PARAM_TYPE_REAL32)
            t_end = time.monotonic() + 2
            while time.monotonic() < t_end:
                self.pump()
                if name in self.params and abs(self.params[name] - value) < 1e-3:
                    return
        raise TimeoutError(f"param {name}")

    def upload_mission(self, items, wall_timeout_s=60):
        self.c.mav.mission_count_send(1, 1, len(items), 0)
        end = time.monotonic() + wall_timeout_s
        while time.monotonic() < end:
            m = self.c.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"],
                                  blocking=True, timeout=0.5)
            if m is None:
                continue
            if m.get_type() == "MISSION_ACK":
                if m.type != 0:
                    raise RuntimeError(f"mission refused: {m.type}")
                return
            self.c.mav.send(items[m.seq])
        raise TimeoutError("mission upload")


def mission_items(defn):
    fr = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items = []

    def item(cmd, lat=0.0, lon=0.0, alt=0.0, p1=0.0, p2=0.0):
        seq = len(items)
        items.append(mav.MAVLink_mission_item_int_message(
            1, 1, seq, fr, cmd, 0, 1, p1, p2, 0, 0, int(lat * 1e7), int(lon * 1e7), alt, 0))

    item(mav.MAV_CMD_NAV_WAYPOINT, HOME[0], HOME[1], 0)  # home, replaced by the autopilot
    item(mav.MAV_CMD_NAV_TAKEOFF, alt=CRUISE_ALT_M, p1=15)
    for lat, lon in defn["waypoints"]:
        item(mav.MAV_CMD_NAV_WAYPOINT, lat, lon, CRUISE_ALT_M)
    item(mav.MAV_CMD_DO_JUMP, p1=2, p2=200)
    return items


def free_udp_port():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    p = s.getsockname()[1]
    s.close()
    return p


def write_daemon_config(path, port, ins_config, args):
    # Keys newer daemons know are written only when asked for, so older builds still run.
    extra = "" if args.gnss_lag_s is None else f"gnss_lag_s = {args.gnss_lag_s}\n"
    # The gyro-error random walk of config/ianav.toml (an autopilot's drifting MEMS gyro).
    ins_over = ("" if not args.q_e_gyr else
                f"[ins.attitude]\nq_e_gyr_rad2ps2 = {args.q_e_gyr}\n")
    with open(path, "w") as f:
        f.write(f"""# Written by tools/sitl/ardupilot_flight.py
[mavlink]
connection = "udpin:127.0.0.1:{port}"
autopilot = "ardupilot"
clock = "autopilot"
[input]
imu_rate_hz = {args.imu_rate_hz}
{extra}[output]
mode = "gps_input"
rate_hz = 5.0
gps_id = 1
satellites_visible = 10
[navigation]
ins_config = "{ins_config}"
[logging]
counters_period_s = 30.0
{ins_over}""")


def interp(series, t):
    """Linear interpolation of (t, lat, lon, alt) rows at t; None outside or across a gap."""
    ts = [r[0] for r in series]
    i = bisect.bisect_left(ts, t)
    if i == 0 or i >= len(series):
        return None
    a, b = series[i - 1], series[i]
    if b[0] - a[0] > 500.0 or b[0] == a[0]:
        return None
    w = (t - a[0]) / (b[0] - a[0])
    return tuple(a[k] + w * (b[k] - a[k]) for k in (1, 2, 3))


def fly(args):
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    work = os.path.join(out, "work")
    shutil.rmtree(work, ignore_errors=True)
    os.makedirs(work)
    defn = flight_definition(args)
    params = sitl_params(args)
    parm_file = os.path.join(work, "harness.parm")
    with open(parm_file, "w") as f:
        for k, v in params.items():
            f.write(f"{k} {v}\n")
    plane_parm = os.path.join(args.ardupilot, "Tools/autotest/models/plane.parm")
    base = 5760 + 10 * args.instance
    cmd = [args.arduplane, "--model", "plane", "--speedup", str(args.speedup), "-w",
           "--home", ",".join(str(x) for x in HOME), "-I", str(args.instance),
           "--defaults", f"{plane_parm},{parm_file}"]
    log(f"SITL: {' '.join(cmd)}")
    procs = []
    sitl_log = open(os.path.join(out, "sitl.log"), "w")
    sitl = subprocess.Popen(cmd, cwd=work, stdout=sitl_log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    procs.append(sitl)
    router = None
    daemon = None
    gcs = None
    t_loss = t_cruise = None
    try:
        time.sleep(1.0)
        for _ in range(60):
            try:
                gcs = Gcs(base)
                break
            except OSError:
                time.sleep(0.5)
        if gcs is None:
            raise RuntimeError("SITL SERIAL0 never accepted a connection")
        gcs.watch.append(sitl)
        gcs.wait(lambda: gcs.c.target_system > 0, 60, "SITL heartbeat")
        for mid, hz in ((33, 10), (108, 10), (24, 5), (124, 5), (42, 2)):
            gcs.interval(mid, hz)
        if args.mode != "alone":
            router = Router(base + 2, args.daemon_port or free_udp_port(),
                            drop_gps_input=(args.mode == "open"))
            # The daemon flies on files in the output directory, kept with the results: the
            # INS file copied beside ianav.toml, which names it relatively (the daemon resolves
            # navigation.ins_config against its config file's directory).
            ins_copy = os.path.join(out, "ins.toml")
            if not (os.path.exists(ins_copy) and os.path.samefile(args.ins_config, ins_copy)):
                shutil.copyfile(args.ins_config, ins_copy)
            dcfg = os.path.join(out, "ianav.toml")
            write_daemon_config(dcfg, router.daemon_addr[1], "ins.toml", args)
            dlog = open(os.path.join(out, "daemon.log"), "w")
            record = (["--record", os.path.join(out, "daemon.bin")] if args.record else [])
            daemon = subprocess.Popen([args.ianav, "run", "--config", dcfg] + record, stdout=dlog,
                                      stderr=subprocess.STDOUT, start_new_session=True)
            procs.append(daemon)
            gcs.watch.append(daemon)
            router.start()
        gcs.wait(lambda: gcs.t_ms > 1000, 60, "GLOBAL_POSITION_INT")
        gcs.upload_mission(mission_items(defn))
        log("mission uploaded")
        # AUTO, confirmed by the HEARTBEAT (a lost command left the plane armed in MANUAL).
        t_mode = time.monotonic() + 60
        while gcs.custom_mode != PLANE_MODE_AUTO:
            if time.monotonic() > t_mode:
                raise TimeoutError("mode AUTO")
            gcs.c.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0,
                                        mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PLANE_MODE_AUTO,
                                        0, 0, 0, 0, 0)
            t_end = time.monotonic() + 1.0
            while time.monotonic() < t_end and gcs.custom_mode != PLANE_MODE_AUTO:
                gcs.pump()
        # Arm once the pre-arm checks pass (EKF and GPS ready); retry every 5 s of sim time.
        t_try = -1e9
        end = time.monotonic() + 300
        while not gcs.armed:
            if time.monotonic() > end:
                raise TimeoutError("arming")
            gcs.pump()
            if gcs.t_ms - t_try > 5000:
                gcs.c.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1,
                                            0, 0, 0, 0, 0, 0)
                t_try = gcs.t_ms
        t_arm = gcs.t_ms
        log(f"armed at {t_arm / 1000:.1f} s")
        def took_off():
            if gcs.t_ms - t_arm > 150e3:
                raise RuntimeError("take-off not complete 150 s after arming")
            return gcs.mission_seq >= 2

        gcs.wait(took_off, 400, "take-off complete")
        t_cruise = gcs.t_ms
        log(f"cruising at {t_cruise / 1000:.1f} s")
        gcs.wait(lambda: gcs.t_ms >= t_cruise + args.cruise_s * 1000, 1200, "cruise")
        gcs.set_param("SIM_GPS1_ENABLE", 0)
        t_loss = gcs.t_ms
        log(f"GNSS 1 disabled at {t_loss / 1000:.1f} s")
        gcs.wait(lambda: gcs.t_ms >= t_loss + args.denied_s * 1000, 3600, "denied phase")
        completed = True
        log("flight complete")
    except (TimeoutError, RuntimeError, OSError) as e:
        log(f"FLIGHT FAILED: {e}")
        completed = False
    finally:
        if router is not None:
            router.stop = True
        for p in reversed(procs):
            if p.poll() is None:
                p.send_signal(signal.SIGINT if p is daemon else signal.SIGTERM)
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        if router is not None:
            router.join(5)
    if not args.keep_work:
        shutil.rmtree(work, ignore_errors=True)
    return analyse(args, out, defn, gcs, router, completed, t_loss, t_cruise)


def rate_stats(router, t0_ms, t1_ms):
    """Per message from SITL SERIAL1: rate in sim Hz over [t0, t1], stamp spacing, lag."""
    res = {}
    for t, rows in sorted(router.rx.items()):
        sel = [r for r in rows if t0_ms <= r[0] <= t1_ms]
        if not sel or t1_ms <= t0_ms:
            continue
        d = {"msg_id": getattr(mav, f"MAVLINK_MSG_ID_{t}", -1),
             "rate_hz": round(len(sel) / ((t1_ms - t0_ms) * 1e-3), 2)}
        stamps = [r[1] for r in sel if r[1] is not None]
        if len(stamps) > 2:
            ds = [b - a for a, b in zip(stamps, stamps[1:]) if b != a]
            if ds:
                d["stamp_step_ms_mean"] = round(statistics.fmean(ds), 2)
                d["stamp_step_ms_min"] = round(min(ds), 2)
                d["stamp_step_ms_max"] = round(max(ds), 2)
            d["repeated_stamps"] = sum(1 for a, b in zip(stamps, stamps[1:]) if b == a)
            # How old the sample is when it leaves the autopilot, against the newest
            # stamp on the link (the autopilot's loop time).
            age = [r[0] - r[1] for r in sel if r[1] is not None]
            d["age_at_send_ms_median"] = round(statistics.median(age), 1)
        res[t] = d
    return res


def gnss_lag_ms(gcs):
    """GPS_RAW_INT stamp minus the truth time of the position it reports (before the loss)."""
    lags = []
    tt = [r[0] for r in gcs.truth]
    for _, st, fix, lat, lon, _ in gcs.gps_raw[::5]:
        if fix < 3 or st <= 0:
            continue
        i = bisect.bisect_left(tt, st)
        best = None
        for j in range(max(0, i - 15), min(len(tt), i + 5)):
            d = horiz_m(lat, lon, gcs.truth[j][1], gcs.truth[j][2])
            if best is None or d < best[0]:
                best = (d, tt[j])
        if best is not None and best[0] < 20:
            lags.append(st - best[1])
    return statistics.median(lags) if lags else float("nan")


def analyse(args, out, defn, gcs, router, completed, t_loss, t_cruise):
    truth = gcs.truth if gcs else []
    rows = []
    ianav = []
    if router is not None:
        ianav = sorted((g[0] * 1e-3, g[1], g[2], g[3], g[4]) for g in router.gps_input)
    ianav_ts = [r[0] for r in ianav]
    ap_by_t = {r[0]: r for r in gcs.ap} if gcs else {}
    t_loss = t_loss if t_loss is not None else float("nan")
    for t_ms, lat, lon, alt in truth:
        row = {"t_s": (t_ms - t_loss) / 1000.0, "truth": (lat, lon, alt)}
        a = ap_by_t.get(t_ms)
        row["ap"] = a[1:] if a else None
        row["ap_err"] = horiz_m(lat, lon, a[1], a[2]) if a else None
        row["ianav"] = row["ianav_err"] = row["hacc"] = None
        if ianav:
            i = bisect.bisect_left(ianav_ts, t_ms)
            if 0 < i < len(ianav) and ianav[i][0] - ianav[i - 1][0] < 500:
                a_, b_ = ianav[i - 1], ianav[i]
                w = (t_ms - a_[0]) / (b_[0] - a_[0]) if b_[0] > a_[0] else 0.0
                p = tuple(a_[k] + w * (b_[k] - a_[k]) for k in (1, 2, 3, 4))
                row["ianav"] = p[:3]
                row["ianav_err"] = horiz_m(lat, lon, p[0], p[1])
                row["hacc"] = p[3]
        rows.append(row)
    # flight.csv at full rate in the output dir, decimated copy if asked.
    def fmt(x, n):
        return "" if x is None else f"{x:.{n}f}"

    def write_csv(path, step_s):
        last = -1e9
        with open(path, "w") as f:
            f.write("t_s,truth_lat_deg,truth_lon_deg,truth_alt_m,ap_lat_deg,ap_lon_deg,ap_alt_m,"
                    "ap_err_h_m,ianav_lat_deg,ianav_lon_deg,ianav_alt_m,ianav_err_h_m,"
                    "ianav_hacc_m\n")
            for r in rows:
                if r["t_s"] - last < step_s - 1e-6:
                    continue
                last = r["t_s"]
                tr, ap, ia = r["truth"], r["ap"] or (None,) * 3, r["ianav"] or (None,) * 3
                f.write(",".join([f"{r['t_s']:.2f}", fmt(tr[0], 7), fmt(tr[1], 7), fmt(tr[2], 2),
                                  fmt(ap[0], 7), fmt(ap[1], 7), fmt(ap[2], 2),
                                  fmt(r["ap_err"], 2), fmt(ia[0], 7), fmt(ia[1], 7),
                                  fmt(ia[2], 2), fmt(r["ianav_err"], 2), fmt(r["hacc"], 2)])
                        + "\n")

    write_csv(os.path.join(out, "flight.csv"), args.csv_step_s)

    def at(key, t_s):
        best = None
        for r in rows:
            if r[key] is not None and abs(r["t_s"] - t_s) <= 1.0:
                if best is None or abs(r["t_s"] - t_s) < abs(best["t_s"] - t_s):
                    best = r
        return None if best is None else best[key]

    post = [r for r in rows if r["t_s"] > 0]
    paired = [r for r in post if r["ianav_err"] is not None and r["hacc"] is not None]
    checkpoints = [60, 120, 300, 600] if not args.short else [30, 60, 120]
    s = {}
    s["completed"] = completed
    s["autopilot"] = "ArduPlane SITL (plane model), " + args.ap_version
    s["mode"] = args.mode
    s["wind_speed_mps"] = args.wind_speed
    s["wind_dir_deg"] = args.wind_dir
    s["seed"] = args.seed
    s["short"] = bool(args.short)
    s["speedup"] = args.speedup
    s["daemon_imu_rate_hz"] = args.imu_rate_hz
    s["daemon_gnss_lag_s"] = args.gnss_lag_s
    s["daemon_q_e_gyr_rad2ps2"] = args.q_e_gyr
    s["daemon_commit"] = args.daemon_commit
    s["harness_commit"] = args.harness_commit
    if args.mode != "alone":
        # The daemon's settings, beside this file (tools/sitl/README.md).
        s["daemon_config"] = "ianav.toml"
        s["ins_config"] = "ins.toml"
    s["circuit_rotation_deg"] = defn["circuit_rotation_deg"]
    s["cruise_before_loss_s"] = args.cruise_s
    s["denied_s"] = round(post[-1]["t_s"], 1) if post else 0.0
    s["post_loss_samples"] = len(post)
    s["ianav_post_loss_samples"] = len(paired)
    s["ianav_published_after_loss"] = bool(router) and any(
        g[0] * 1e-3 > t_loss + 1000 for g in router.gps_input)
    err = {}
    for c in checkpoints:
        e_ap, e_ia, h = at("ap_err", c), at("ianav_err", c), at("hacc", c)
        key = f"t{c}s"
        err[key] = {"ap_err_h_m": e_ap, "ianav_err_h_m": e_ia, "ianav_hacc_m": h}
    if paired:
        s["frac_ianav_err_le_2p45_hacc"] = round(
            sum(1 for r in paired if r["ianav_err"] <= 2.45 * r["hacc"]) / len(paired), 4)
        # hacc is a DRMS; for a circular error the 95 % radius is 1.73 DRMS.
        s["frac_ianav_err_le_1p73_hacc"] = round(
            sum(1 for r in paired if r["ianav_err"] <= 1.73 * r["hacc"]) / len(paired), 4)
        rms_h = math.sqrt(statistics.fmean(r["hacc"] ** 2 for r in paired))
        rms_e = math.sqrt(statistics.fmean(r["ianav_err"] ** 2 for r in paired))
        s["hacc_rms_over_err_rms"] = round(rms_h / rms_e, 3) if rms_e > 0 else None
        s["ianav_err_h_max_m"] = round(max(r["ianav_err"] for r in paired), 1)
    ap_post = [r["ap_err"] for r in post if r["ap_err"] is not None]
    if ap_post:
        s["ap_err_h_max_m"] = round(max(ap_post), 1)
    # Primary switch check: GPS_RAW_INT must only ever carry GPS1 (SITL's receiver).
    raw_after = [g for g in gcs.gps_raw if g[0] > t_loss + 2000] if gcs else []
    s["gps_raw_int_fix3_after_loss"] = sum(1 for g in raw_after if g[2] >= 3)
    s["gps_raw_int_equal_to_ianav_after_loss"] = 0
    if router is not None and raw_after:
        for g in raw_after:
            if g[2] >= 3 and ianav and ianav_ts:
                i = min(bisect.bisect_left(ianav_ts, g[1]), len(ianav) - 1)
                if horiz_m(g[3], g[4], ianav[i][1], ianav[i][2]) < 5.0:
                    s["gps_raw_int_equal_to_ianav_after_loss"] += 1
    s["gps2_raw_fix3_after_loss"] = sum(1 for g in (gcs.gps2_raw if gcs else [])
                                        if g[0] > t_loss + 2000 and g[2] >= 3)
    link = {}
    rates = {}
    if router is not None and gcs is not None and gcs.t_ms > 0:
        # Cruise with GNSS: the link in its normal state (stamps of GPS_RAW_INT freeze after
        # the loss).
        t1 = t_loss if t_loss is not None and not math.isnan(t_loss) else gcs.t_ms
        t0 = t_cruise if t_cruise is not None else t1 - 60000
        rates = rate_stats(router, t0, t1)
        lat_ms = []
        iw = sorted(router.imu_wall)
        iw_t = [x[0] for x in iw]
        for g in router.gps_input:
            i = bisect.bisect_left(iw_t, g[0] * 1e-3)
            if i < len(iw) and abs(iw_t[i] - g[0] * 1e-3) < 0.5:
                lat_ms.append((g[5] - iw[i][1]) * 1e3)
        if lat_ms:
            link["gps_input_wall_latency_ms_median"] = round(statistics.median(lat_ms), 2)
            link["gps_input_wall_latency_ms_p95"] = round(
                sorted(lat_ms)[int(0.95 * (len(lat_ms) - 1))], 2)
        ages = [g[6] - g[0] * 1e-3 for g in router.gps_input if g[6] > 0]
        if ages:
            link["gps_input_age_at_arrival_sim_ms_median"] = round(statistics.median(ages), 1)
        link["from_daemon"] = dict(sorted(router.from_daemon.items()))
        link["command_denials"] = [list(d) for d in router.denials]
        with open(os.path.join(out, "statustext_serial1.txt"), "w") as f:
            f.writelines(f"{t / 1000:.1f} s  {x}\n" for t, x in router.statustext)
    if gcs is not None:
        link["gps_raw_int_stamp_minus_truth_ms"] = round(gnss_lag_ms(gcs), 1)
        with open(os.path.join(out, "statustext.txt"), "w") as f:
            f.writelines(f"{t / 1000:.1f} s  {x}\n" for t, x in gcs.texts)
    write_summary(os.path.join(out, "summary.toml"), s, err, rates, link)
    plot(os.path.join(out, "error.png"), rows, args)
    log(f"summary: {os.path.join(out, 'summary.toml')}")
    for k, v in err.items():
        log(f"  {k}: {v}")
    return s, err


def toml_value(v):
    if v is None:
        return '"n/a"'
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v) or math.isinf(v):
            return '"n/a"'
        t = f"{v:.4g}" if abs(v) < 1e5 else f"{v:.1f}"
        return t if any(c in t for c in ".en") else t + ".0"  # stays a TOML float
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'


def write_summary(path, s, err, rates, link):
    with open(path, "w") as f:
        f.write("# tools/sitl/ardupilot_flight.py; times are simulation time since the GNSS loss\n")
        for k, v in s.items():
            f.write(f"{k} = {toml_value(v)}\n")
        for k, v in err.items():
            f.write(f"\n[error.{k}]\n")
            for kk, vv in v.items():
                f.write(f"{kk} = {toml_value(round(vv, 2) if isinstance(vv, float) else vv)}\n")
        for k, v in rates.items():
            f.write(f"\n[input_rates.{k}]\n")
            for kk, vv in v.items():
                f.write(f"{kk} = {toml_value(vv)}\n")
        f.write("\n[link]\n")
        tables = {}
        for k, v in link.items():
            if isinstance(v, dict):
                tables[k] = v
            else:
                f.write(f"{k} = {toml_value(v)}\n")
        for k, v in tables.items():
            f.write(f"\n[link.{k}]\n")
            for kk, vv in v.items():
                f.write(f"{kk} = {toml_value(vv)}\n")


def plot(path, rows, args):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 4.5), dpi=90)
    t = [r["t_s"] / 60 for r in rows if r["ap_err"] is not None]
    ax.plot(t, [r["ap_err"] for r in rows if r["ap_err"] is not None], label="ArduPlane EKF3")
    ri = [r for r in rows if r["ianav_err"] is not None]
    if ri:
        ax.plot([r["t_s"] / 60 for r in ri], [r["ianav_err"] for r in ri], label="ianav")
        ax.plot([r["t_s"] / 60 for r in ri], [r["hacc"] for r in ri], ":",
                label="ianav horiz_accuracy")
    ax.set_yscale("symlog", linthresh=10)
    ax.set_ylim(bottom=0)
    ax.axvline(0, color="k", lw=0.8)
    ax.text(0, ax.get_ylim()[1] * 0.7, " GNSS lost", va="top")
    ax.set_xlabel("time since GNSS loss [min]")
    ax.set_ylabel("horizontal error [m]")
    ax.set_title(f"ArduPlane SITL, mode {args.mode}, wind {args.wind_speed} m/s from "
                 f"{args.wind_dir}°, seed {args.seed}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--arduplane", required=True, help="path of the arduplane SITL binary")
    ap.add_argument("--ardupilot", help="ArduPilot source tree (default: from --arduplane)")
    ap.add_argument("--ianav", help="ianav daemon binary (needed unless --mode alone)")
    ap.add_argument("--ins-config", default=os.path.join(
        os.path.dirname(os.path.abspath(__file__)), "..", "..", "config", "ins.toml"))
    ap.add_argument("--mode", choices=["alone", "open", "closed"], required=True)
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument("--wind-speed", type=float, default=6.0, help="m/s (SIM_WIND_SPD)")
    ap.add_argument("--wind-dir", type=float, default=180.0, help="deg from (SIM_WIND_DIR)")
    ap.add_argument("--seed", type=int, default=1, help="circuit orientation")
    ap.add_argument("--short", action="store_true", help="60 s cruise, 120 s denied")
    ap.add_argument("--cruise-s", type=float, help="cruise before the loss (default 180)")
    ap.add_argument("--denied-s", type=float, help="time after the loss (default 600)")
    ap.add_argument("--speedup", type=float, default=10.0,
                    help="SITL speed-up (lock-step; the published flights used 10)")
    ap.add_argument("--record", action="store_true",
                    help="the daemon records what it feeds its navigator (daemon.bin, "
                         "daemon.solutions.csv; `ianav replay`, docs/REPLAY.md)")
    ap.add_argument("--instance", type=int, default=3, help="SITL -I (ports 5760 + 10 I)")
    ap.add_argument("--daemon-port", type=int, default=0)
    ap.add_argument("--imu-rate-hz", type=float, default=40.0,
                    help="daemon input.imu_rate_hz (ArduPlane accepts 40 Hz at most)")
    ap.add_argument("--q-e-gyr", type=float, default=1.27e-10,
                    help="daemon [ins.attitude] q_e_gyr_rad2ps2 over --ins-config (0: not written)")
    ap.add_argument("--gnss-lag-s", type=float, default=0.07,
                    help="daemon input.gnss_lag_s (negative: not written, for daemons older "
                         "than the key)")
    ap.add_argument("--csv-step-s", type=float, default=1.0,
                    help="decimate flight.csv (0: every truth sample, 10 Hz)")
    ap.add_argument("--keep-work", action="store_true")
    args = ap.parse_args()
    if args.mode != "alone" and not args.ianav:
        ap.error("--ianav is required with --mode open/closed")
    args.cruise_s = args.cruise_s or (60.0 if args.short else 180.0)
    args.denied_s = args.denied_s or (120.0 if args.short else 600.0)
    if args.ardupilot is None:
        args.ardupilot = os.path.abspath(os.path.join(os.path.dirname(args.arduplane),
                                                      "..", "..", ".."))
    try:
        args.ap_version = subprocess.run(
            ["git", "-C", args.ardupilot, "log", "-1", "--format=%h %cs"],
            capture_output=True, text=True, timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        args.ap_version = "unknown"
    if args.gnss_lag_s is not None and args.gnss_lag_s < 0:
        args.gnss_lag_s = None
    args.daemon_commit = os.environ.get("IANAV_COMMIT", "")
    # The tree the harness (and its default INS file) came from; "-dirty" when modified.
    try:
        args.harness_commit = subprocess.run(
            ["git", "-C", os.path.dirname(os.path.abspath(__file__)), "describe", "--always",
             "--dirty", "--abbrev=7"],
            capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        args.harness_commit = ""
    s, _ = fly(args)
    sys.exit(0 if s["completed"] else 1)


if __name__ == "__main__":
    main()
