//! SI ↔ MAVLink unit conversions of the SITL vehicle (MAVLink `common.xml` field definitions;
//! docs/REFERENCES.md M3.1 for the vehicle's messages, M2.1 for the companion's). Written
//! independently of the daemon's decoder so that the two implementations of the spec meet
//! only on the wire.
//!
//! Conventions: body axes are FRD (the simulator's `B` frame), accelerations are specific
//! force (≈ −9.81 m/s² on z in level flight), angles are radians unless the field is in
//! degrees. The simulated world has no geoid model: mean sea level is the WGS84 ellipsoid
//! (undulation 0), so `alt` (MSL) and `alt_ellipsoid` carry the same height.

use ianav::env::atmosphere::{self, G0_MPS2, KAPPA, P0_PA, T0_K};
use ianav::math::map_projection::MapProjection;
use ianav::math::wgs84::Geodetic;
use mavlink::dialects::ardupilotmega as apm;

/// 1 gauss in nT.
pub const NT_PER_GAUSS: f64 = 1e5;
/// 1 Pa in hPa.
pub const HPA_PER_PA: f64 = 0.01;
/// 0 °C in kelvin.
pub const CELSIUS_ZERO_K: f64 = 273.15;

/// Round and saturate to `i16` (MAVLink int16 fields: values out of range are clamped).
pub fn sat_i16(x: f64) -> i16 {
    if x.is_nan() {
        return 0;
    }
    x.round().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}

/// Truncate toward zero and saturate to `i16`, as a C cast of a float to `int16_t` does in
/// ArduPilot's int16 IMU and temperature fields (a 0.9 mrad/s rate becomes 0, −0.9 becomes 0).
pub fn trunc_i16(x: f64) -> i16 {
    if x.is_nan() {
        return 0;
    }
    x.trunc().clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
}

/// Round and saturate to `i32`.
pub fn sat_i32(x: f64) -> i32 {
    if x.is_nan() {
        return 0;
    }
    x.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
}

/// Round and saturate to `u16` below `u16::MAX` (which means "unknown" in many fields).
pub fn sat_u16_known(x: f64) -> u16 {
    if x.is_nan() {
        return u16::MAX;
    }
    x.round().clamp(0.0, f64::from(u16::MAX - 1)) as u16
}

/// Round and saturate to `u32`.
pub fn sat_u32(x: f64) -> u32 {
    if x.is_nan() {
        return u32::MAX;
    }
    x.round().clamp(0.0, f64::from(u32::MAX)) as u32
}

/// Angle, rad → degE7 (1e-7 degree, ≈ 1.1 cm of latitude).
pub fn deg_e7(rad: f64) -> i32 {
    sat_i32(rad.to_degrees() * 1e7)
}

/// degE7 → angle, rad.
pub fn rad_from_deg_e7(v: i32) -> f64 {
    (f64::from(v) * 1e-7).to_radians()
}

/// Length, m → mm.
pub fn mm(m: f64) -> i32 {
    sat_i32(m * 1e3)
}

/// Heading or course, rad → centidegrees in `0..=35999`.
pub fn cdeg_0_36000(rad: f64) -> u16 {
    let c = (rad.to_degrees() * 100.0).round().rem_euclid(36_000.0);
    // rem_euclid of a value just below 36000 after rounding can give 36000.0 exactly.
    if c >= 36_000.0 { 0 } else { c as u16 }
}

/// Temperature, K → centidegrees Celsius.
pub fn cdeg_c(temp_k: f64) -> i16 {
    sat_i16((temp_k - CELSIUS_ZERO_K) * 100.0)
}

/// Specific force, m/s² → milli-g (g = 9.80665 m/s², MAVLink "mG").
pub fn milli_g(a_mps2: f64) -> i16 {
    sat_i16(a_mps2 / G0_MPS2 * 1e3)
}

/// Angular rate, rad/s → mrad/s.
pub fn mrad_s(w_rps: f64) -> i16 {
    sat_i16(w_rps * 1e3)
}

/// Magnetic field, nT → milligauss (1 mG = 100 nT).
pub fn milli_gauss(b_nt: f64) -> i16 {
    sat_i16(b_nt / NT_PER_GAUSS * 1e3)
}

/// Pitot impact pressure `qc` of a true airspeed, Pa (isentropic compressible flow,
/// subsonic): `qc = p·[(1 + (κ−1)/2·M²)^(κ/(κ−1)) − 1]`, `M = TAS / a(T)`.
pub fn impact_pressure_pa(tas_mps: f64, p_pa: f64, temp_k: f64) -> f64 {
    let mach = tas_mps / atmosphere::speed_of_sound_mps(temp_k);
    p_pa * ((1.0 + 0.5 * (KAPPA - 1.0) * mach * mach).powf(KAPPA / (KAPPA - 1.0)) - 1.0)
}

/// Calibrated airspeed of an impact pressure, m/s: the speed that gives `qc` at sea level
/// in the ISA, `CAS = a₀·√{2/(κ−1)·[(qc/p₀ + 1)^((κ−1)/κ) − 1]}`. The simulated Pitot has no
/// position or instrument error, so indicated airspeed = CAS.
pub fn cas_mps(qc_pa: f64) -> f64 {
    let a0 = atmosphere::speed_of_sound_mps(T0_K);
    let x = (qc_pa / P0_PA + 1.0).powf((KAPPA - 1.0) / KAPPA) - 1.0;
    a0 * (2.0 / (KAPPA - 1.0) * x.max(0.0)).sqrt()
}

/// True airspeed of an impact pressure at static pressure `p_pa` and temperature `temp_k`,
/// m/s (inverse of [`impact_pressure_pa`]; used by the tests as an independent check).
pub fn tas_from_impact_pressure_mps(qc_pa: f64, p_pa: f64, temp_k: f64) -> f64 {
    let x = (qc_pa / p_pa + 1.0).powf((KAPPA - 1.0) / KAPPA) - 1.0;
    atmosphere::speed_of_sound_mps(temp_k) * (2.0 / (KAPPA - 1.0) * x.max(0.0)).sqrt()
}

/// Horizontal position carried by a companion's message, with how it was obtained.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExternalFix {
    /// Position (height above the ellipsoid).
    pub pos: Geodetic,
    /// The sender's timestamp field, µs (`time_usec` or `usec`).
    pub stamp_us: u64,
}

/// Why a companion message carries no usable position.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ExternalFixError {
    /// Local position without a known origin.
    #[error("no local origin")]
    NoOrigin,
    /// A frame the vehicle does not take a position from.
    #[error("unsupported frame")]
    Frame,
    /// NaN/∞ or out-of-range fields.
    #[error("invalid values")]
    Invalid,
    /// GPS_INPUT without a 3D fix.
    #[error("no 3D fix")]
    NoFix,
}

fn local_to_geodetic(
    ned_m: [f32; 3],
    origin: Option<&MapProjection>,
) -> Result<Geodetic, ExternalFixError> {
    let proj = origin.ok_or(ExternalFixError::NoOrigin)?;
    let ned = ned_m.map(f64::from);
    // ±1000 km covers any flight; beyond that the message is nonsense.
    if !ned.iter().all(|v| v.is_finite() && v.abs() < 1e6) {
        return Err(ExternalFixError::Invalid);
    }
    Ok(proj.reproject(&ned))
}

/// Position of an `ODOMETRY` in `MAV_FRAME_LOCAL_NED` (or `LOCAL_FRD`, taken as north-aligned
/// as a north-aligned INS sends it) about `origin` (the autopilots' azimuthal equidistant
/// local frame, `ianav::math::map_projection`).
pub fn odometry_fix(
    m: &apm::ODOMETRY_DATA,
    origin: Option<&MapProjection>,
) -> Result<ExternalFix, ExternalFixError> {
    match m.frame_id {
        apm::MavFrame::MAV_FRAME_LOCAL_NED | apm::MavFrame::MAV_FRAME_LOCAL_FRD => {}
        _ => return Err(ExternalFixError::Frame),
    }
    Ok(ExternalFix {
        pos: local_to_geodetic([m.x, m.y, m.z], origin)?,
        stamp_us: m.time_usec,
    })
}

/// Position of a `VISION_POSITION_ESTIMATE` (local NED about `origin`, as PX4 reads it).
pub fn vision_fix(
    m: &apm::VISION_POSITION_ESTIMATE_DATA,
    origin: Option<&MapProjection>,
) -> Result<ExternalFix, ExternalFixError> {
    Ok(ExternalFix {
        pos: local_to_geodetic([m.x, m.y, m.z], origin)?,
        stamp_us: m.usec,
    })
}

/// Position of a `GPS_INPUT` with at least a 3D fix (alt is MSL = ellipsoid here).
pub fn gps_input_fix(m: &apm::GPS_INPUT_DATA) -> Result<ExternalFix, ExternalFixError> {
    if (m.fix_type as u32) < (apm::GpsFixType::GPS_FIX_TYPE_3D_FIX as u32) {
        return Err(ExternalFixError::NoFix);
    }
    let (lat, lon) = (rad_from_deg_e7(m.lat), rad_from_deg_e7(m.lon));
    let h_m = f64::from(m.alt);
    if lat.abs() > std::f64::consts::FRAC_PI_2
        || lon.abs() > std::f64::consts::PI
        || !h_m.is_finite()
    {
        return Err(ExternalFixError::Invalid);
    }
    Ok(ExternalFix {
        pos: Geodetic {
            lat_rad: lat,
            lon_rad: lon,
            h_m,
        },
        stamp_us: m.time_usec,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integer_fields_round_and_saturate() {
        assert_eq!(sat_i16(1e9), i16::MAX);
        assert_eq!(sat_i16(-1e9), i16::MIN);
        assert_eq!(sat_i16(f64::NAN), 0);
        assert_eq!(sat_i16(2.5), 3);
        assert_eq!(sat_u16_known(1e9), u16::MAX - 1);
        assert_eq!(sat_u16_known(f64::NAN), u16::MAX);
    }

    #[test]
    fn unit_factors_follow_the_spec() {
        // 1 g of specific force is 1000 mG; 1 rad/s is 1000 mrad/s; 0.5 G is 500 mgauss.
        assert_eq!(milli_g(-G0_MPS2), -1000);
        assert_eq!(mrad_s(0.0125), 13);
        assert_eq!(milli_gauss(50_000.0), 500);
        assert_eq!(cdeg_c(288.15), 1500);
        assert_eq!(mm(-1.2344), -1234);
        // degE7: 45° exactly, and a 1.1 cm step of latitude is one unit.
        assert_eq!(deg_e7(45_f64.to_radians()), 450_000_000);
        let one_unit_m = rad_from_deg_e7(1) * 6_371_000.0;
        assert!((one_unit_m - 0.0111).abs() < 0.0002, "{one_unit_m}");
    }

    #[test]
    fn headings_wrap_into_0_to_35999_centidegrees() {
        assert_eq!(cdeg_0_36000(0.0), 0);
        assert_eq!(cdeg_0_36000(-std::f64::consts::FRAC_PI_2), 27_000);
        assert_eq!(cdeg_0_36000(std::f64::consts::TAU - 1e-9), 0);
        assert_eq!(cdeg_0_36000(359.994_f64.to_radians()), 35_999);
    }

    #[test]
    fn calibrated_airspeed_is_true_airspeed_at_sea_level_isa_and_lower_aloft() {
        for tas in [10.0, 30.0, 60.0] {
            let qc = impact_pressure_pa(tas, P0_PA, T0_K);
            assert!((cas_mps(qc) - tas).abs() < 1e-9, "{tas}");
            assert!((tas_from_impact_pressure_mps(qc, P0_PA, T0_K) - tas).abs() < 1e-9);
            // Incompressible limit: qc ≈ ½ρV² within the (M²/4) compressibility term.
            let q = 0.5 * atmosphere::density_kgpm3(P0_PA, T0_K) * tas * tas;
            let m = tas / atmosphere::speed_of_sound_mps(T0_K);
            assert!((qc / q - 1.0 - m * m / 4.0).abs() < 1e-3, "{tas}");
        }
        // At 3,000 m ISA the density ratio is 0.742: CAS ≈ TAS·√σ (EAS) within 0.5 %.
        let (p, t) = (
            atmosphere::pressure_pa(3000.0),
            atmosphere::isa_temperature_k(3000.0),
        );
        let tas = 50.0;
        let cas = cas_mps(impact_pressure_pa(tas, p, t));
        let eas =
            tas * (atmosphere::density_kgpm3(p, t) / atmosphere::density_kgpm3(P0_PA, T0_K)).sqrt();
        assert!((cas / eas - 1.0).abs() < 5e-3, "{cas} {eas}");
        assert!(
            (tas_from_impact_pressure_mps(impact_pressure_pa(tas, p, t), p, t) - tas).abs() < 1e-9
        );
    }

    #[test]
    fn companion_positions_decode_through_the_local_frame_or_degrees() {
        let origin = Geodetic {
            lat_rad: 45_f64.to_radians(),
            lon_rad: (-90_f64).to_radians(),
            h_m: 300.0,
        };
        let proj = MapProjection::new(&origin);
        let mut odo = apm::ODOMETRY_DATA {
            time_usec: 7,
            x: 1000.0,
            y: -500.0,
            z: -200.0,
            frame_id: apm::MavFrame::MAV_FRAME_LOCAL_NED,
            ..Default::default()
        };
        let fix = odometry_fix(&odo, Some(&proj)).unwrap();
        let back = proj.project(&fix.pos);
        assert!((back[0] - 1000.0).abs() < 1e-6 && (back[1] + 500.0).abs() < 1e-6);
        assert!((fix.pos.h_m - 500.0).abs() < 1e-9);
        assert_eq!(fix.stamp_us, 7);
        assert_eq!(odometry_fix(&odo, None), Err(ExternalFixError::NoOrigin));
        odo.x = f32::NAN;
        assert_eq!(
            odometry_fix(&odo, Some(&proj)),
            Err(ExternalFixError::Invalid)
        );
        odo.x = 0.0;
        odo.frame_id = apm::MavFrame::MAV_FRAME_BODY_FRD;
        assert_eq!(
            odometry_fix(&odo, Some(&proj)),
            Err(ExternalFixError::Frame)
        );
        let mut gps = apm::GPS_INPUT_DATA {
            lat: 450_000_000,
            lon: -900_000_000,
            alt: 321.5,
            fix_type: apm::GpsFixType::GPS_FIX_TYPE_3D_FIX,
            ..Default::default()
        };
        let fix = gps_input_fix(&gps).unwrap();
        assert!((fix.pos.lat_rad - origin.lat_rad).abs() < 1e-15);
        assert_eq!(fix.pos.h_m, 321.5);
        gps.fix_type = apm::GpsFixType::GPS_FIX_TYPE_2D_FIX;
        assert_eq!(gps_input_fix(&gps), Err(ExternalFixError::NoFix));
        gps.fix_type = apm::GpsFixType::GPS_FIX_TYPE_3D_FIX;
        gps.lat = 1_000_000_000;
        assert_eq!(gps_input_fix(&gps), Err(ExternalFixError::Invalid));
    }
}
