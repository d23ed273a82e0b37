//! Every input message the daemon decodes, nominal (the fake autopilot's level flight north at
//! 30 m/s) and with its fields at their extremes: each integer at its minimum and maximum,
//! each float NaN, ±∞ and ±f32::MAX, one field at a time and all at once; or with fields drawn
//! from seeds (for property tests). Also the checks every decoded event must pass.

#![allow(
    dead_code,
    reason = "compiled into every test binary with `mod common`, most not using it; `expect` would \
              be unfulfilled in link_robustness, which uses all of it"
)]

use ianav::env::atmosphere;
use ianav::io::mavlink_in::{
    MAX_ACCEL_MPS2, MAX_GROUND_SPEED_MPS, MAX_GYRO_RPS, MAX_MAG_NT, MAX_VERTICAL_SPEED_MPS,
    P_RANGE_PA, T_RANGE_K,
};
use ianav::sensors::SensorEvent;
use mavlink::dialects::ardupilotmega as apm;
use nalgebra::Vector3;

use super::fake_autopilot::{GEOID_M, H0_M, SPEED_MPS};

/// A numeric message field.
pub trait Field: Copy + std::fmt::Debug {
    /// Its extreme values.
    fn extremes() -> Vec<Self>;
    /// A value from raw bits (any bit pattern: NaN payloads, subnormals, huge values).
    fn from_bits(bits: u64) -> Self;
}

macro_rules! int_field {
    ($($t:ty),*) => {$(
        impl Field for $t {
            fn extremes() -> Vec<Self> {
                vec![<$t>::MIN, <$t>::MAX]
            }
            fn from_bits(bits: u64) -> Self {
                bits as $t
            }
        }
    )*};
}
int_field!(u8, i16, u16, i32, u32, u64);

impl Field for f32 {
    fn extremes() -> Vec<Self> {
        vec![
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MAX,
            f32::MIN,
        ]
    }
    fn from_bits(bits: u64) -> Self {
        f32::from_bits(bits as u32)
    }
}

fn like<T: Field>(_: &T) -> Vec<T> {
    T::extremes()
}

/// A field from a seed: kept (0), one of its extremes (1), or raw bits (2, 3).
pub fn pick<T: Field>(nominal: T, (how, bits): (u8, u64)) -> T {
    match how % 4 {
        0 => nominal,
        1 => {
            let e = T::extremes();
            e[(bits % e.len() as u64) as usize]
        }
        _ => T::from_bits(bits),
    }
}

/// Calls `$then!(message, variant, [numeric fields], extra args)` for an input message.
macro_rules! with_fields {
    ($msg:expr, $then:ident!($($args:tt)*)) => {{
        use apm::MavMessage as M;
        match $msg {
            M::HIGHRES_IMU(m) => $then!(m, M::HIGHRES_IMU, [time_usec, xacc, yacc, zacc, xgyro,
                ygyro, zgyro, xmag, ymag, zmag, abs_pressure, diff_pressure, pressure_alt,
                temperature, id], $($args)*),
            M::SCALED_IMU(m) => $then!(m, M::SCALED_IMU, [time_boot_ms, xacc, yacc, zacc, xgyro,
                ygyro, zgyro, xmag, ymag, zmag, temperature], $($args)*),
            M::RAW_IMU(m) => $then!(m, M::RAW_IMU, [time_usec, xacc, yacc, zacc, xgyro, ygyro,
                zgyro, xmag, ymag, zmag, id, temperature], $($args)*),
            M::SCALED_PRESSURE(m) => $then!(m, M::SCALED_PRESSURE, [time_boot_ms, press_abs,
                press_diff, temperature, temperature_press_diff], $($args)*),
            M::SCALED_PRESSURE2(m) => $then!(m, M::SCALED_PRESSURE2, [time_boot_ms, press_abs,
                press_diff, temperature, temperature_press_diff], $($args)*),
            M::AIRSPEED(m) => $then!(m, M::AIRSPEED, [airspeed, raw_press, temperature, id],
                $($args)*),
            M::VFR_HUD(m) => $then!(m, M::VFR_HUD, [airspeed, groundspeed, alt, climb, heading,
                throttle], $($args)*),
            M::AOA_SSA(m) => $then!(m, M::AOA_SSA, [time_usec, AOA, SSA], $($args)*),
            M::ATTITUDE(m) => $then!(m, M::ATTITUDE, [time_boot_ms, roll, pitch, yaw, rollspeed,
                pitchspeed, yawspeed], $($args)*),
            M::GLOBAL_POSITION_INT(m) => $then!(m, M::GLOBAL_POSITION_INT, [time_boot_ms, lat,
                lon, alt, relative_alt, vx, vy, vz, hdg], $($args)*),
            M::GPS_RAW_INT(m) => $then!(m, M::GPS_RAW_INT, [time_usec, lat, lon, alt, eph, epv,
                vel, cog, satellites_visible, alt_ellipsoid, h_acc, v_acc, vel_acc, hdg_acc,
                yaw], $($args)*),
            M::SYSTEM_TIME(m) => $then!(m, M::SYSTEM_TIME, [time_unix_usec, time_boot_ms],
                $($args)*),
            other => panic!("not an input message: {other:?}"),
        }
    }};
}

macro_rules! extreme_variants {
    ($m:expr, $wrap:path, [$($f:ident),+], $out:ident) => {{
        let name = mavlink::Message::message_name(&$wrap($m.clone()));
        $(
            for x in like(&$m.$f) {
                let mut v = $m.clone();
                v.$f = x;
                $out.push((format!("{name} {}={x:?}", stringify!($f)), $wrap(v)));
            }
        )+
        for k in 0..5 {
            let mut v = $m.clone();
            $({
                let e = like(&v.$f);
                v.$f = e[k % e.len()];
            })+
            $out.push((format!("{name} all fields, extreme #{k}"), $wrap(v)));
        }
    }};
}

macro_rules! seeded_variant {
    ($m:expr, $wrap:path, [$($f:ident),+], $seeds:ident) => {{
        let mut v = $m.clone();
        let mut it = $seeds.iter().copied().cycle();
        $( v.$f = pick(v.$f, it.next().unwrap_or((0, 0))); )+
        $wrap(v)
    }};
}

/// `nominal` with its fields at their extremes, each variant named.
pub fn extreme_variants(nominal: &apm::MavMessage) -> Vec<(String, apm::MavMessage)> {
    let mut out = Vec::new();
    with_fields!(nominal, extreme_variants!(out));
    out
}

/// `nominal` with its fields drawn from `seeds` (cycled).
pub fn seeded_variant(nominal: &apm::MavMessage, seeds: &[(u8, u64)]) -> apm::MavMessage {
    with_fields!(nominal, seeded_variant!(seeds))
}

/// One nominal message of every input type, stamped `boot_us` after the autopilot's boot, at
/// latitude/longitude `lat_e7`/`lon_e7` (degE7) with the magnetic field `mag_ned_nt`.
pub fn nominal_inputs(
    boot_us: u64,
    lat_e7: i32,
    lon_e7: i32,
    mag_ned_nt: Vector3<f64>,
) -> Vec<apm::MavMessage> {
    use apm::MavMessage as M;
    let ms = (boot_us / 1_000) as u32;
    let p_pa = atmosphere::pressure_pa(H0_M);
    let temp_k = atmosphere::isa_temperature_k(H0_M);
    let eas = SPEED_MPS * (atmosphere::density_kgpm3(p_pa, temp_k) / 1.225).sqrt();
    let g = 9.806;
    vec![
        M::HIGHRES_IMU(apm::HIGHRES_IMU_DATA {
            time_usec: boot_us,
            zacc: -g as f32,
            xmag: (mag_ned_nt.x / 1e5) as f32,
            ymag: (mag_ned_nt.y / 1e5) as f32,
            zmag: (mag_ned_nt.z / 1e5) as f32,
            abs_pressure: (p_pa / 100.0) as f32,
            pressure_alt: H0_M as f32,
            temperature: (temp_k - 273.15) as f32,
            fields_updated: apm::HighresImuUpdatedFlags::from_bits_truncate(0x1fff),
            ..Default::default()
        }),
        M::SCALED_IMU(apm::SCALED_IMU_DATA {
            time_boot_ms: ms,
            zacc: -1000,
            xmag: (mag_ned_nt.x / 100.0) as i16,
            ymag: (mag_ned_nt.y / 100.0) as i16,
            zmag: (mag_ned_nt.z / 100.0) as i16,
            temperature: 2000,
            ..Default::default()
        }),
        M::RAW_IMU(apm::RAW_IMU_DATA {
            time_usec: boot_us,
            zacc: -1000,
            xmag: (mag_ned_nt.x / 100.0) as i16,
            ymag: (mag_ned_nt.y / 100.0) as i16,
            zmag: (mag_ned_nt.z / 100.0) as i16,
            ..Default::default()
        }),
        M::SCALED_PRESSURE(apm::SCALED_PRESSURE_DATA {
            time_boot_ms: ms,
            press_abs: (p_pa / 100.0) as f32,
            temperature: ((temp_k - 273.15) * 100.0) as i16,
            ..Default::default()
        }),
        M::SCALED_PRESSURE2(apm::SCALED_PRESSURE2_DATA {
            time_boot_ms: ms,
            press_abs: (p_pa / 100.0) as f32,
            temperature: ((temp_k - 273.15) * 100.0) as i16,
            ..Default::default()
        }),
        M::AIRSPEED(apm::AIRSPEED_DATA {
            airspeed: eas as f32,
            temperature: ((temp_k - 273.15) * 100.0) as i16,
            flags: apm::AirspeedSensorFlags::AIRSPEED_SENSOR_USING,
            ..Default::default()
        }),
        M::VFR_HUD(apm::VFR_HUD_DATA {
            airspeed: eas as f32,
            groundspeed: SPEED_MPS as f32,
            alt: (H0_M - GEOID_M) as f32,
            throttle: 50,
            ..Default::default()
        }),
        M::AOA_SSA(apm::AOA_SSA_DATA {
            time_usec: boot_us,
            AOA: 2.0,
            SSA: 0.0,
        }),
        M::ATTITUDE(apm::ATTITUDE_DATA {
            time_boot_ms: ms,
            ..Default::default()
        }),
        M::GLOBAL_POSITION_INT(apm::GLOBAL_POSITION_INT_DATA {
            time_boot_ms: ms,
            lat: lat_e7,
            lon: lon_e7,
            alt: ((H0_M - GEOID_M) * 1e3) as i32,
            relative_alt: 100_000,
            vx: (SPEED_MPS * 100.0) as i16,
            ..Default::default()
        }),
        M::GPS_RAW_INT(apm::GPS_RAW_INT_DATA {
            time_usec: boot_us,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
            lat: lat_e7,
            lon: lon_e7,
            alt: ((H0_M - GEOID_M) * 1e3) as i32,
            eph: 100,
            epv: 150,
            vel: (SPEED_MPS * 100.0) as u16,
            cog: 0,
            satellites_visible: 12,
            alt_ellipsoid: (H0_M * 1e3) as i32,
            h_acc: 1_000,
            v_acc: 1_500,
            vel_acc: 200,
            hdg_acc: 0,
            yaw: 0,
        }),
        M::SYSTEM_TIME(apm::SYSTEM_TIME_DATA {
            time_unix_usec: 1_790_000_000_000_000,
            time_boot_ms: ms,
        }),
    ]
}

fn finite(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// What every event the decoder hands to the navigation must satisfy (docs/DAEMON.md
/// "Refused values").
pub fn check_event(e: &SensorEvent) -> Result<(), String> {
    let ok = match e {
        SensorEvent::Imu(s) => {
            finite(&s.accel_mps2)
                && finite(&s.gyro_rps)
                && s.accel_mps2.norm() <= MAX_ACCEL_MPS2
                && s.gyro_rps.norm() <= MAX_GYRO_RPS
        }
        SensorEvent::Mag(s) => finite(&s.mag_b_nt) && s.mag_b_nt.norm() <= MAX_MAG_NT,
        SensorEvent::Air(s) => {
            s.tas_mps.is_finite()
                && s.tas_mps >= 0.0
                && (P_RANGE_PA.0..=P_RANGE_PA.1).contains(&s.p_pa)
                && (T_RANGE_K.0..=T_RANGE_K.1).contains(&s.temp_k)
                && [s.aoa_rad, s.aos_rad]
                    .iter()
                    .flatten()
                    .all(|a| a.abs() <= std::f64::consts::FRAC_PI_2)
        }
        SensorEvent::Gnss(f) => {
            let v = f.v_ned_mps;
            f.pos.lat_rad.abs() < std::f64::consts::FRAC_PI_2
                && f.pos.lon_rad.abs() <= std::f64::consts::PI
                && f.pos.h_m.is_finite()
                && finite(&v)
                && v.xy().norm() <= MAX_GROUND_SPEED_MPS + 1e-9
                && v.z.abs() <= MAX_VERTICAL_SPEED_MPS
                && [f.sigma_hor_m, f.sigma_ver_m, f.sigma_vel_mps]
                    .iter()
                    .all(|s| s.is_finite() && *s > 0.0)
        }
        SensorEvent::RefAttitude(a) => a.q_nb.coords.iter().all(|x| x.is_finite()),
        SensorEvent::Frame(_) => true,
        // The MAVLink decoder never emits one.
        SensorEvent::Alignment(_)
        | SensorEvent::HeightAboveTerrain(_)
        | SensorEvent::VisionApplied(_) => false,
    };
    if ok { Ok(()) } else { Err(format!("{e:?}")) }
}
