//! "True" gravity and magnetic fields (docs/REFERENCES.md A3.5–A3.6): the navigation models plus a
//! constant per-run error.
//!
//! Gravity: the navigation's normal gravity `(0, 0, g(φ, h))` in NED, rotated by a deflection
//! of the vertical (angle 0.0028°·N(0,1) about a horizontal axis of bearing
//! U_int{−179..180}°) and scaled by `1 + Δg/|g|`, Δg = 1e-4 m/s²·N(0,1).
//! Magnetic field: the WMM plus a constant error N(0, diag[138, 89, 165] nT), drawn from the
//! same stream right after the gravity draws (as the authors' `seeder_geo` stream).

use ianav::env::magnetic::{MagneticError, MagneticModel};
use ianav::math::wgs84::{self, Geodetic};
use nalgebra::{Unit, UnitQuaternion, Vector3};

use crate::rng::{self, Stream};

/// σ of the deflection-of-the-vertical angle, degrees.
pub const SIGMA_DEFLECTION_DEG: f64 = 0.0028;
/// σ of the gravity magnitude anomaly, m/s².
pub const SIGMA_GRAVITY_ANOMALY_MPS2: f64 = 1e-4;
/// σ of the per-axis (N, E, D) magnetic model error, nT (WMM 2015–2020 uncertainty).
pub const SIGMA_MAGNETIC_ERROR_NT: [f64; 3] = [138.0, 89.0, 165.0];

/// True gravity: normal gravity rotated by a small deflection of the vertical and scaled by
/// a magnitude anomaly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrueGravity {
    /// Deflection of the vertical.
    pub deflection: UnitQuaternion<f64>,
    /// Magnitude anomaly Δg, m/s².
    pub anomaly_mps2: f64,
}

impl TrueGravity {
    /// Draw the per-run deflection (σ 0.0028°) and anomaly (σ 1e-4 m/s²), in this order:
    /// deflection angle N(0,1), axis bearing U_int{−179..180}°, anomaly N(0,1).
    pub fn draw(rng: &mut Stream) -> Self {
        let angle_rad = (SIGMA_DEFLECTION_DEG * rng::normal(rng)).to_radians();
        let bearing_rad = (rng::uniform_int(rng, -179, 180) as f64).to_radians();
        let anomaly_mps2 = SIGMA_GRAVITY_ANOMALY_MPS2 * rng::normal(rng);
        let axis = Unit::new_unchecked(Vector3::new(bearing_rad.cos(), bearing_rad.sin(), 0.0));
        Self {
            deflection: UnitQuaternion::from_axis_angle(&axis, angle_rad),
            anomaly_mps2,
        }
    }

    /// Gravity vector in NED at `pos`, m/s²: magnitude `g_normal + Δg`, direction the local
    /// down rotated by the deflection.
    pub fn gravity_ned_mps2(&self, pos: &Geodetic) -> Vector3<f64> {
        let g = wgs84::normal_gravity_mps2(pos.lat_rad, pos.h_m);
        // (1 + Δg/g)·g = g + Δg; written as a sum so g = 0 cannot divide by zero.
        self.deflection * Vector3::new(0.0, 0.0, g + self.anomaly_mps2)
    }
}

/// True magnetic field: WMM plus a constant per-run error N(0, diag[138, 89, 165] nT).
#[derive(Debug, Clone)]
pub struct TrueMagneticField {
    /// The model the navigation also uses.
    pub model: MagneticModel,
    /// Constant error added to the model (true − model), NED, nT.
    pub error_ned_nt: Vector3<f64>,
}

impl TrueMagneticField {
    /// Draw the per-run model error (N, E, D in this order). Pass the stream that
    /// [`TrueGravity::draw`] has just used, so the draws follow the authors' order.
    pub fn draw(model: MagneticModel, rng: &mut Stream) -> Self {
        let [sn, se, sd] = SIGMA_MAGNETIC_ERROR_NT;
        let n = sn * rng::normal(rng);
        let e = se * rng::normal(rng);
        let d = sd * rng::normal(rng);
        Self {
            model,
            error_ned_nt: Vector3::new(n, e, d),
        }
    }

    /// True field at `pos` in NED, nT.
    pub fn field_ned_nt(&self, pos: &Geodetic) -> Result<Vector3<f64>, MagneticError> {
        Ok(self.model.field_ned_nt(pos)? + self.error_ned_nt)
    }
}

#[cfg(test)]
mod tests {
    use super::super::offsets::test_stats::mean_std;
    use super::*;
    use crate::rng::stream;

    const RUNS: u64 = 20_000;
    /// Bounds in standard errors (see the offsets tests).
    const K: f64 = 4.5;

    fn pos() -> Geodetic {
        Geodetic {
            lat_rad: 45.0_f64.to_radians(),
            lon_rad: (-90.0_f64).to_radians(),
            h_m: 3000.0,
        }
    }

    #[test]
    fn gravity_geometry() {
        let tg = TrueGravity::draw(&mut stream(11, "env.geo"));
        let g_model = wgs84::normal_gravity_mps2(pos().lat_rad, pos().h_m);
        let g = tg.gravity_ned_mps2(&pos());
        // Magnitude g + Δg (rotation preserves length).
        assert!((g.norm() - (g_model + tg.anomaly_mps2)).abs() < 1e-12);
        // The horizontal part is perpendicular to the (horizontal) rotation axis and its
        // size is |g|·sin(angle).
        let (axis, angle) = tg.deflection.axis_angle().unwrap();
        assert!(axis.z.abs() < 1e-12);
        assert!(g.xy().dot(&axis.xy()).abs() < 1e-12);
        assert!((g.xy().norm() - g.norm() * angle.sin()).abs() < 1e-12);
        // Zero draws reproduce normal gravity exactly.
        let none = TrueGravity {
            deflection: UnitQuaternion::identity(),
            anomaly_mps2: 0.0,
        };
        assert_eq!(
            none.gravity_ned_mps2(&pos()),
            Vector3::new(0.0, 0.0, g_model)
        );
    }

    #[test]
    fn draw_statistics() {
        let n = RUNS as f64;
        let mut angle = Vec::new();
        let mut anomaly = Vec::new();
        let mut mag = [Vec::new(), Vec::new(), Vec::new()];
        let model = MagneticModel::new(2026.0).unwrap();
        for s in 0..RUNS {
            let mut r = stream(s, "env.geo");
            let tg = TrueGravity::draw(&mut r);
            let tm = TrueMagneticField::draw(model.clone(), &mut r);
            // The rotation angle is |θ| (the sign goes into the axis): half-normal.
            angle.push(tg.deflection.angle().to_degrees());
            anomaly.push(tg.anomaly_mps2);
            for (m, e) in mag.iter_mut().zip(tm.error_ned_nt.iter()) {
                m.push(*e);
            }
        }
        // |θ| is half-normal with σ = 0.0028°: RMS = σ (SE of the mean square ≈ σ²√(2/n)).
        let ms = angle.iter().map(|a| a * a).sum::<f64>() / n;
        let s2 = SIGMA_DEFLECTION_DEG.powi(2);
        assert!((ms - s2).abs() < K * s2 * (2.0 / n).sqrt(), "{ms} {s2}");
        for (x, sigma) in [
            (&anomaly, SIGMA_GRAVITY_ANOMALY_MPS2),
            (&mag[0], 138.0),
            (&mag[1], 89.0),
            (&mag[2], 165.0),
        ] {
            let (m, s) = mean_std(x);
            assert!(m.abs() < K * sigma / n.sqrt(), "{m} {sigma}");
            assert!(
                (s - sigma).abs() < K * sigma / (2.0 * n).sqrt(),
                "{s} {sigma}"
            );
        }
    }

    #[test]
    fn draw_order() {
        let mut r = stream(5, "env.geo");
        let tg = TrueGravity::draw(&mut r);
        let tm = TrueMagneticField::draw(MagneticModel::new(2026.0).unwrap(), &mut r);
        let mut q = stream(5, "env.geo");
        let a = (0.0028 * rng::normal(&mut q)).to_radians();
        let b = (rng::uniform_int(&mut q, -179, 180) as f64).to_radians();
        let dg = 1e-4 * rng::normal(&mut q);
        let m = Vector3::new(
            138.0 * rng::normal(&mut q),
            89.0 * rng::normal(&mut q),
            165.0 * rng::normal(&mut q),
        );
        let axis = Unit::new_normalize(Vector3::new(b.cos(), b.sin(), 0.0));
        assert!(
            tg.deflection
                .angle_to(&UnitQuaternion::from_axis_angle(&axis, a))
                < 1e-15
        );
        assert_eq!(tg.anomaly_mps2, dg);
        assert_eq!(tm.error_ned_nt, m);
    }

    #[test]
    fn true_field_is_model_plus_error() {
        let model = MagneticModel::new(2026.0).unwrap();
        let tm = TrueMagneticField::draw(model.clone(), &mut stream(1, "env.geo"));
        let d = tm.field_ned_nt(&pos()).unwrap() - model.field_ned_nt(&pos()).unwrap();
        assert!((d - tm.error_ned_nt).norm() < 1e-9);
        let mut bad = pos();
        bad.lat_rad = f64::NAN;
        assert!(tm.field_ned_nt(&bad).is_err());
    }
}
