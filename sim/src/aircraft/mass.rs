//! Mass, centre of gravity and inertia with fuel burn (docs/REFERENCES.md A4.1): the CG position
//! and the inertia tensor are interpolated linearly in the mass ratio
//! `r = (m_full − m)/(m_full − m_empty)` between the full-tank and empty-tank values; the inertia
//! tensor is symmetric about the body x–z plane, so it has one product of inertia and a closed-form
//! inverse.

use nalgebra::Vector3;
use serde::{Deserialize, Serialize};

use super::AircraftError;

/// Mass properties at full and empty tank (docs/REFERENCES.md A4.1).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MassParams {
    /// Mass with a full tank, kg.
    pub mass_full_kg: f64,
    /// Mass with an empty tank, kg.
    pub mass_empty_kg: f64,
    /// Vector from the aircraft reference point to the CG at full tank, body axes, m.
    pub cg_full_from_ref_b_m: [f64; 3],
    /// Vector from the aircraft reference point to the CG at empty tank, body axes, m.
    pub cg_empty_from_ref_b_m: [f64; 3],
    /// Inertia tensor at full tank: `[I_xx, I_yy, I_zz, I_xz]`, kg·m², where `I_xz` is the
    /// matrix entry (0, 2) = (2, 0), i.e. `−∫x z dm`.
    pub inertia_full_kgm2: [f64; 4],
    /// Inertia tensor at empty tank, same layout, kg·m².
    pub inertia_empty_kgm2: [f64; 4],
}

impl Default for MassParams {
    fn default() -> Self {
        Self {
            mass_full_kg: 19.715,
            mass_empty_kg: 17.835,
            cg_full_from_ref_b_m: [0.207, 0.0, -0.005],
            cg_empty_from_ref_b_m: [0.219, 0.0, -0.006],
            inertia_full_kgm2: [2.202, 3.462, 5.490, -0.191],
            inertia_empty_kgm2: [2.198, 3.430, 5.458, -0.192],
        }
    }
}

impl MassParams {
    /// Checks physical consistency; the error names the offending field.
    pub fn validate(&self) -> Result<(), AircraftError> {
        let bad = |field: &'static str, reason: &str| {
            Err(AircraftError::Invalid {
                field,
                reason: reason.to_owned(),
            })
        };
        if !(self.mass_empty_kg.is_finite() && self.mass_empty_kg > 0.0) {
            return bad("mass.mass_empty_kg", "must be finite and positive");
        }
        if !(self.mass_full_kg.is_finite() && self.mass_full_kg > self.mass_empty_kg) {
            return bad(
                "mass.mass_full_kg",
                "must be finite and greater than mass_empty_kg",
            );
        }
        if !self.cg_full_from_ref_b_m.iter().all(|c| c.is_finite()) {
            return bad("mass.cg_full_from_ref_b_m", "must be finite");
        }
        if !self.cg_empty_from_ref_b_m.iter().all(|c| c.is_finite()) {
            return bad("mass.cg_empty_from_ref_b_m", "must be finite");
        }
        if !Inertia::from_array(&self.inertia_full_kgm2).is_positive_definite() {
            return bad(
                "mass.inertia_full_kgm2",
                "must be a finite positive-definite tensor",
            );
        }
        if !Inertia::from_array(&self.inertia_empty_kgm2).is_positive_definite() {
            return bad(
                "mass.inertia_empty_kgm2",
                "must be a finite positive-definite tensor",
            );
        }
        Ok(())
    }
}

/// Inertia tensor symmetric about the body x–z plane:
/// `[[I_xx, 0, I_xz], [0, I_yy, 0], [I_xz, 0, I_zz]]`, kg·m².
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Inertia {
    /// `I_xx`, kg·m².
    pub ixx: f64,
    /// `I_yy`, kg·m².
    pub iyy: f64,
    /// `I_zz`, kg·m².
    pub izz: f64,
    /// Matrix entry (0, 2) = (2, 0), kg·m².
    pub ixz: f64,
}

impl Inertia {
    fn from_array(a: &[f64; 4]) -> Self {
        Self {
            ixx: a[0],
            iyy: a[1],
            izz: a[2],
            ixz: a[3],
        }
    }

    fn is_positive_definite(&self) -> bool {
        let finite = [self.ixx, self.iyy, self.izz, self.ixz]
            .iter()
            .all(|v| v.is_finite());
        finite
            && self.ixx > 0.0
            && self.iyy > 0.0
            && self.ixx * self.izz - self.ixz * self.ixz > 0.0
    }

    /// `I·w`.
    #[inline]
    pub fn mul(&self, w: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(
            self.ixx * w.x + self.ixz * w.z,
            self.iyy * w.y,
            self.ixz * w.x + self.izz * w.z,
        )
    }

    /// `I⁻¹·m` in closed form: the x–z block is a 2×2 inverse with determinant
    /// `I_xx·I_zz − I_xz²`, the y axis decouples.
    #[inline]
    pub fn solve(&self, m: &Vector3<f64>) -> Vector3<f64> {
        let inv_det = 1.0 / (self.ixx * self.izz - self.ixz * self.ixz);
        Vector3::new(
            (self.izz * m.x - self.ixz * m.z) * inv_det,
            m.y / self.iyy,
            (self.ixx * m.z - self.ixz * m.x) * inv_det,
        )
    }

    /// The full 3×3 matrix (tests, reports).
    pub fn matrix(&self) -> nalgebra::Matrix3<f64> {
        nalgebra::Matrix3::new(
            self.ixx, 0.0, self.ixz, //
            0.0, self.iyy, 0.0, //
            self.ixz, 0.0, self.izz,
        )
    }
}

/// Mass model built from [`MassParams`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MassModel {
    mass_full_kg: f64,
    mass_empty_kg: f64,
    cg_full_b_m: Vector3<f64>,
    cg_empty_b_m: Vector3<f64>,
    inertia_full: Inertia,
    inertia_empty: Inertia,
}

impl MassModel {
    /// Builds the model.
    pub fn new(p: &MassParams) -> Self {
        Self {
            mass_full_kg: p.mass_full_kg,
            mass_empty_kg: p.mass_empty_kg,
            cg_full_b_m: Vector3::from(p.cg_full_from_ref_b_m),
            cg_empty_b_m: Vector3::from(p.cg_empty_from_ref_b_m),
            inertia_full: Inertia::from_array(&p.inertia_full_kgm2),
            inertia_empty: Inertia::from_array(&p.inertia_empty_kgm2),
        }
    }

    /// Mass ratio `r = (m_full − m)/(m_full − m_empty)`, clamped to [0, 1] so that a mass
    /// outside the fuel range (or NaN, mapped to full) never extrapolates the tables.
    #[inline]
    pub fn ratio(&self, mass_kg: f64) -> f64 {
        let r = (self.mass_full_kg - mass_kg) / (self.mass_full_kg - self.mass_empty_kg);
        if r.is_nan() { 0.0 } else { r.clamp(0.0, 1.0) }
    }

    /// Mass with an empty tank, kg.
    pub fn empty_kg(&self) -> f64 {
        self.mass_empty_kg
    }

    /// CG position from the reference point, body axes, m.
    #[inline]
    pub fn cg_from_ref_b_m(&self, mass_kg: f64) -> Vector3<f64> {
        let r = self.ratio(mass_kg);
        self.cg_full_b_m + (self.cg_empty_b_m - self.cg_full_b_m) * r
    }

    /// CG position at full tank (the aerodynamic moment reference), body axes, m.
    pub fn cg_full_from_ref_b_m(&self) -> Vector3<f64> {
        self.cg_full_b_m
    }

    /// Inertia tensor about the CG at this mass.
    #[inline]
    pub fn inertia(&self, mass_kg: f64) -> Inertia {
        let r = self.ratio(mass_kg);
        let lerp = |a: f64, b: f64| a + (b - a) * r;
        Inertia {
            ixx: lerp(self.inertia_full.ixx, self.inertia_empty.ixx),
            iyy: lerp(self.inertia_full.iyy, self.inertia_empty.iyy),
            izz: lerp(self.inertia_full.izz, self.inertia_empty.izz),
            ixz: lerp(self.inertia_full.ixz, self.inertia_empty.ixz),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_form_inverse_matches_general_inverse() {
        let m = MassModel::new(&MassParams::default());
        for mass in [17.835, 18.5, 19.5, 19.715] {
            let inertia = m.inertia(mass);
            let inv = inertia.matrix().try_inverse().unwrap();
            let v = Vector3::new(0.3, -1.2, 2.5);
            // Both are exact up to rounding: relative 1e-14 covers a few ulps of a 3×3 solve.
            assert!((inertia.solve(&v) - inv * v).norm() < 1e-14 * (inv * v).norm());
            assert!((inertia.mul(&v) - inertia.matrix() * v).norm() < 1e-15 * v.norm() * 10.0);
        }
    }

    #[test]
    fn interpolation_hits_the_end_points_and_midpoint() {
        let p = MassParams::default();
        let m = MassModel::new(&p);
        assert_eq!(m.ratio(p.mass_full_kg), 0.0);
        assert_eq!(m.ratio(p.mass_empty_kg), 1.0);
        assert_eq!(m.ratio(30.0), 0.0);
        assert_eq!(m.ratio(1.0), 1.0);
        let mid = 0.5 * (p.mass_full_kg + p.mass_empty_kg);
        let cg = m.cg_from_ref_b_m(mid);
        assert!((cg.x - 0.213).abs() < 1e-12 && (cg.z + 0.0055).abs() < 1e-12);
        let i = m.inertia(mid);
        assert!((i.iyy - 3.446).abs() < 1e-12 && (i.ixz + 0.1915).abs() < 1e-12);
        assert!(m.inertia(f64::NAN).ixx.is_finite());
    }
}
