//! The valid traffic the mutations start from: a simulated autopilot in steady level flight
//! (north at 25 m/s, 500 m above the ellipsoid) streaming what the daemon requests, at the
//! daemon's rates. It is a pure function of the tick number, so any stretch of it can be
//! generated on its own and continues the stretch that warmed a pipeline up.

use mavlink::dialects::ardupilotmega as apm;

/// One tick of the stream, µs (the 100 Hz IMU).
pub const TICK_US: u64 = 10_000;
/// The autopilot's boot time at tick 0, µs.
pub const BOOT_OFFSET_US: u64 = 30_000_000;
/// The daemon's clock minus the autopilot's, µs.
pub const CLOCK_OFFSET_US: u64 = 7_000_000;
/// Transport latency, µs.
pub const LATENCY_US: u64 = 1_500;
/// Our MAVLink component id (the daemon's default).
pub const OUR_COMPONENT: u8 = 197;
/// The autopilot's system and component ids.
pub const AP_SYS: u8 = 1;
/// See [`AP_SYS`].
pub const AP_COMP: u8 = 1;

const LAT0_DEG: f64 = 45.0;
const LON0_DEG: f64 = 7.0;
const H_M: f64 = 500.0;
const UNDULATION_M: f64 = 48.0;
const SPEED_MPS: f64 = 25.0;
const EARTH_RADIUS_M: f64 = 6_371_000.0;
/// ISA static pressure at 500 m, hPa, and temperature, °C.
const P_HPA: f32 = 954.61;
const T_C: f32 = 11.75;
/// Field in body axes (level, heading north), gauss.
const MAG_G: [f32; 3] = [0.22, 0.005, 0.42];

/// Which autopilot is simulated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Autopilot {
    /// PX4: HIGHRES_IMU, its pressure in Pa.
    Px4,
    /// ArduPilot: SCALED_IMU plus RAW_IMU at 1 Hz, AOA_SSA.
    Ardupilot,
}

/// What the stream carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stream {
    /// The autopilot.
    pub autopilot: Autopilot,
    /// GNSS messages are sent (off: a GNSS outage).
    pub gnss: bool,
}

/// A message of the stream with the times it carries and arrives at.
#[derive(Debug, Clone)]
pub struct Timed {
    /// The autopilot's time of the message, µs since its boot.
    pub ap_us: u64,
    /// Arrival time on the daemon's clock, µs.
    pub rx_us: u64,
    /// The message.
    pub msg: apm::MavMessage,
}

/// The autopilot's time at `tick`, µs.
pub fn ap_us(tick: u64) -> u64 {
    BOOT_OFFSET_US + tick * TICK_US
}

/// The arrival time of a message sent at `tick`, µs on the daemon's clock.
pub fn rx_us(tick: u64) -> u64 {
    ap_us(tick) + CLOCK_OFFSET_US + LATENCY_US
}

fn position(t_s: f64) -> (i32, i32) {
    let lat = LAT0_DEG + (SPEED_MPS * t_s / EARTH_RADIUS_M).to_degrees();
    ((lat * 1e7).round() as i32, (LON0_DEG * 1e7).round() as i32)
}

/// The messages sent at `tick`, in sending order.
pub fn messages(s: Stream, tick: u64) -> Vec<Timed> {
    let ap = ap_us(tick);
    let ms = (ap / 1_000) as u32;
    let t_s = tick as f64 * TICK_US as f64 * 1e-6;
    let mut out = Vec::new();
    let mut push = |msg| {
        out.push(Timed {
            ap_us: ap,
            rx_us: rx_us(tick),
            msg,
        })
    };
    if tick.is_multiple_of(100) {
        push(apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: apm::MavType::MAV_TYPE_FIXED_WING,
            autopilot: match s.autopilot {
                Autopilot::Px4 => apm::MavAutopilot::MAV_AUTOPILOT_PX4,
                Autopilot::Ardupilot => apm::MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            },
            base_mode: apm::MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED,
            system_status: apm::MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        }));
        push(apm::MavMessage::SYSTEM_TIME(apm::SYSTEM_TIME_DATA {
            time_unix_usec: 1_790_000_000_000_000 + ap,
            time_boot_ms: ms,
        }));
    }
    if tick % 100 == 50 {
        // The autopilot's own TIMESYNC request (answered by the daemon).
        push(apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
            tc1: 0,
            ts1: (ap * 1_000) as i64,
            target_system: 0,
            target_component: 0,
        }));
    }
    if tick % 20 == 10 {
        // The answer to a daemon request sent 2 ms before it arrives (a 2 ms round trip).
        let rx_ns = rx_us(tick) * 1_000;
        push(apm::MavMessage::TIMESYNC(apm::TIMESYNC_DATA {
            tc1: ((ap + 1_000 - LATENCY_US) * 1_000) as i64,
            ts1: (rx_ns - 2_000_000) as i64,
            target_system: AP_SYS,
            target_component: OUR_COMPONENT,
        }));
    }
    match s.autopilot {
        Autopilot::Px4 => push(apm::MavMessage::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
            time_usec: ap,
            xacc: 0.0,
            yacc: 0.0,
            zacc: -9.806_65,
            xgyro: 0.0,
            ygyro: 0.0,
            zgyro: 0.0,
            xmag: MAG_G[0],
            ymag: MAG_G[1],
            zmag: MAG_G[2],
            // PX4 v1.16 sends Pa.
            abs_pressure: P_HPA * 100.0,
            diff_pressure: 0.38,
            pressure_alt: H_M as f32,
            temperature: T_C,
            fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(0x1fff),
            id: 0,
        })),
        Autopilot::Ardupilot => {
            let mg = |g: f32| (g * 1_000.0) as i16;
            push(apm::MavMessage::SCALED_IMU(apm::SCALED_IMU_DATA {
                time_boot_ms: ms,
                xacc: 0,
                yacc: 0,
                zacc: -1_000,
                xgyro: 0,
                ygyro: 0,
                zgyro: 0,
                xmag: mg(MAG_G[0]),
                ymag: mg(MAG_G[1]),
                zmag: mg(MAG_G[2]),
                temperature: 3_000,
            }));
            if tick.is_multiple_of(100) {
                push(apm::MavMessage::RAW_IMU(apm::RAW_IMU_DATA {
                    time_usec: ap,
                    zacc: -1_000,
                    xmag: mg(MAG_G[0]),
                    ymag: mg(MAG_G[1]),
                    zmag: mg(MAG_G[2]),
                    ..Default::default()
                }));
            }
        }
    }
    if tick % 4 == 1 {
        push(apm::MavMessage::AIRSPEED(apm::AIRSPEED_DATA {
            airspeed: SPEED_MPS as f32 * 0.975,
            raw_press: 370.0,
            temperature: 1_175,
            id: 0,
            flags: apm::AirspeedSensorFlags::AIRSPEED_SENSOR_USING,
        }));
        push(apm::MavMessage::VFR_HUD(apm::VFR_HUD_DATA {
            airspeed: SPEED_MPS as f32 * 0.975,
            groundspeed: SPEED_MPS as f32,
            heading: 0,
            throttle: 55,
            alt: (H_M - UNDULATION_M) as f32,
            climb: 0.0,
        }));
        if s.autopilot == Autopilot::Ardupilot {
            push(apm::MavMessage::AOA_SSA(apm::AOA_SSA_DATA {
                time_usec: ap,
                AOA: 3.0,
                SSA: 0.2,
            }));
        }
        push(apm::MavMessage::SCALED_PRESSURE(
            apm::SCALED_PRESSURE_DATA {
                time_boot_ms: ms,
                press_abs: P_HPA,
                press_diff: 3.7,
                temperature: (T_C * 100.0) as i16,
                temperature_press_diff: 0,
            },
        ));
    }
    if tick % 40 == 3 {
        push(apm::MavMessage::SCALED_PRESSURE2(
            apm::SCALED_PRESSURE2_DATA {
                time_boot_ms: ms,
                press_abs: P_HPA + 0.4,
                press_diff: 0.0,
                temperature: 1_200,
                temperature_press_diff: 0,
            },
        ));
    }
    if tick % 10 == 2 {
        push(apm::MavMessage::ATTITUDE(apm::ATTITUDE_DATA {
            time_boot_ms: ms,
            roll: 0.0,
            pitch: 0.05,
            yaw: 0.0,
            rollspeed: 0.0,
            pitchspeed: 0.0,
            yawspeed: 0.0,
        }));
    }
    if s.gnss && tick % 20 == 5 {
        let (lat, lon) = position(t_s);
        push(apm::MavMessage::GLOBAL_POSITION_INT(
            apm::GLOBAL_POSITION_INT_DATA {
                time_boot_ms: ms,
                lat,
                lon,
                alt: ((H_M - UNDULATION_M) * 1e3) as i32,
                relative_alt: 400_000,
                vx: (SPEED_MPS * 100.0) as i16,
                vy: 0,
                vz: 0,
                hdg: 0,
            },
        ));
        push(apm::MavMessage::GPS_RAW_INT(apm::GPS_RAW_INT_DATA {
            time_usec: ap,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
            lat,
            lon,
            alt: ((H_M - UNDULATION_M) * 1e3) as i32,
            eph: 80,
            epv: 120,
            vel: (SPEED_MPS * 100.0) as u16,
            cog: 0,
            satellites_visible: 14,
            alt_ellipsoid: (H_M * 1e3) as i32,
            h_acc: 1_500,
            v_acc: 2_500,
            vel_acc: 300,
            hdg_acc: 0,
            yaw: 0,
        }));
    }
    if tick % 100 == 70 {
        push(apm::MavMessage::COMMAND_ACK(apm::COMMAND_ACK_DATA {
            command: apm::MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
            result: apm::MavResult::MAV_RESULT_ACCEPTED,
            progress: 0,
            result_param2: 0,
            target_system: AP_SYS,
            target_component: OUR_COMPONENT,
        }));
    }
    out
}
