//! Lens distortion on normalised image coordinates (docs/CAMERA.md): OpenCV's
//! radial-tangential model (`cv::calibrateCamera`; ROS `plumb_bob`, `rational_polynomial`) and
//! its fisheye model (`cv::fisheye`; ROS `equidistant`), with their Jacobians and iterative,
//! checked inverses.
//!
//! A model maps the normalised point `x = (X/Z, Y/Z)` of the ideal pinhole to the distorted
//! normalised point `x_d`; the camera then applies its focal lengths and principal point.
//! Polynomial models fold back on themselves far enough off axis (the distorted radius stops
//! growing): [`Lens::new`] finds the radius where the radial part stops increasing, and the
//! lens refuses to project or undistort beyond it, so that a point off the field can never
//! land in the image as a phantom.

use nalgebra::{Matrix2, Vector2};
use serde::{Deserialize, Serialize};

/// Distortion model and coefficients, in OpenCV's order and conventions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum Distortion {
    /// The ideal pinhole.
    None,
    /// OpenCV's radial-tangential model with the rational radial factor, `r² = x² + y²`:
    /// `x_d = x g + 2 p1 x y + p2 (r² + 2x²)`, `y_d = y g + p1 (r² + 2y²) + 2 p2 x y`,
    /// `g = (1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)`. ROS `plumb_bob` is
    /// k4 = k5 = k6 = 0.
    RadialTangential {
        /// Radial, r².
        k1: f64,
        /// Radial, r⁴.
        k2: f64,
        /// Tangential.
        p1: f64,
        /// Tangential.
        p2: f64,
        /// Radial, r⁶.
        k3: f64,
        /// Radial denominator, r².
        k4: f64,
        /// Radial denominator, r⁴.
        k5: f64,
        /// Radial denominator, r⁶.
        k6: f64,
    },
    /// OpenCV's fisheye (equidistant) model: with `θ = atan r`,
    /// `θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)` and `x_d = (θ_d / r) x`.
    Fisheye {
        /// θ³ term.
        k1: f64,
        /// θ⁵ term.
        k2: f64,
        /// θ⁷ term.
        k3: f64,
        /// θ⁹ term.
        k4: f64,
    },
}

impl Distortion {
    /// The coefficients in OpenCV's order (k1, k2, p1, p2, k3, k4, k5, k6 or k1..k4).
    pub fn coefficients(&self) -> Vec<f64> {
        match *self {
            Self::None => Vec::new(),
            Self::RadialTangential {
                k1,
                k2,
                p1,
                p2,
                k3,
                k4,
                k5,
                k6,
            } => vec![k1, k2, p1, p2, k3, k4, k5, k6],
            Self::Fisheye { k1, k2, k3, k4 } => vec![k1, k2, k3, k4],
        }
    }

    /// Whether the model is the identity (no model, or every coefficient zero).
    pub fn is_identity(&self) -> bool {
        self.coefficients().iter().all(|c| *c == 0.0)
    }
}

/// Why a normalised point could not be undistorted.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum UndistortError {
    /// The point is not finite.
    #[error("the point is not finite")]
    NotFinite,
    /// The point lies beyond where the model is invertible (past its fold).
    #[error("the point lies beyond the lens model's invertible field")]
    OutsideModel,
    /// The iteration did not converge.
    #[error("the undistortion did not converge in {0} iterations")]
    NoConvergence(u32),
}

/// Why a distortion model was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum LensError {
    /// A coefficient is not finite.
    #[error("distortion coefficient {index} ({value}) is not finite")]
    NotFinite {
        /// Index in OpenCV's order.
        index: usize,
        /// The value.
        value: f64,
    },
    /// The radial part does not increase even near the optical axis.
    #[error("the distortion folds within 1° of the optical axis")]
    FoldsAtAxis,
}

/// Newton iterations of the radial-tangential undistortion at most (a realistic lens needs 3–6).
const MAX_NEWTON_ITERATIONS: u32 = 40;
/// Safeguarded Newton iterations of the fisheye undistortion at most (bisection alone would
/// need 60 to reach f64 resolution on [0, π/2]).
const MAX_FISHEYE_ITERATIONS: u32 = 100;
/// Convergence: the residual in normalised units relative to the point's size (1e-14 rad at
/// the centre: far below a pixel and the 1e-9 rad of the round-trip tests).
const RESIDUAL_TOLERANCE: f64 = 1e-14;
/// The field scanned for the fold of the radial part: up to 89.9° off axis.
const SCAN_MAX_ANGLE_RAD: f64 = 89.9 * std::f64::consts::PI / 180.0;
/// Angular step of the scan (a fold is found to within this).
const SCAN_STEP_RAD: f64 = 1e-4;
/// Radius below which the fisheye factor and its derivative use their series (the closed
/// forms lose relative precision as 1/r²).
const FISHEYE_SERIES_RADIUS: f64 = 1e-3;

/// A distortion model with the field over which it is invertible.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    distortion: Distortion,
    /// Undistorted normalised radius up to which the radial part increases (∞: everywhere
    /// in front of the camera).
    max_radius: f64,
}

impl Default for Lens {
    fn default() -> Self {
        Self::pinhole()
    }
}

impl Lens {
    /// The ideal pinhole.
    pub fn pinhole() -> Self {
        Self {
            distortion: Distortion::None,
            max_radius: f64::INFINITY,
        }
    }

    /// The lens of `distortion`. A model whose coefficients are all zero is the pinhole, and
    /// is stored as [`Distortion::None`] so that the camera takes the pinhole's arithmetic.
    pub fn new(distortion: Distortion) -> Result<Self, LensError> {
        for (index, value) in distortion.coefficients().into_iter().enumerate() {
            if !value.is_finite() {
                return Err(LensError::NotFinite { index, value });
            }
        }
        if distortion.is_identity() {
            return Ok(Self::pinhole());
        }
        let max_radius = match distortion {
            Distortion::None => Some(f64::INFINITY),
            Distortion::RadialTangential { .. } => {
                // Last angle where r g(r²) still increases and the denominator stays positive.
                let increasing = |theta: f64| {
                    let r = theta.tan();
                    let (g, dg) = rational_factor(&distortion, r * r);
                    g > 0.0 && g + 2.0 * r * r * dg > 0.0
                };
                scan_fold(increasing).map(radius_at)
            }
            Distortion::Fisheye { .. } => {
                let increasing = |theta: f64| fisheye_theta_d(&distortion, theta).1 > 0.0;
                scan_fold(increasing).map(radius_at)
            }
        }
        .ok_or(LensError::FoldsAtAxis)?;
        Ok(Self {
            distortion,
            max_radius,
        })
    }

    /// The model (after [`Lens::new`]: `None` for all-zero coefficients).
    pub fn distortion(&self) -> &Distortion {
        &self.distortion
    }

    /// Whether this is the ideal pinhole.
    pub fn is_pinhole(&self) -> bool {
        matches!(self.distortion, Distortion::None)
    }

    /// Undistorted normalised radius up to which the model is invertible (∞ for the pinhole,
    /// and for a model that increases all the way to 89.9° off axis).
    pub fn max_radius(&self) -> f64 {
        self.max_radius
    }

    /// Distorted normalised point of `x`; `None` beyond [`Lens::max_radius`] (or not finite).
    pub fn distort(&self, x: &Vector2<f64>) -> Option<Vector2<f64>> {
        self.distort_with_jacobian(x).map(|(d, _)| d)
    }

    /// Distorted point and the Jacobian `∂x_d/∂x`; `None` beyond [`Lens::max_radius`].
    pub fn distort_with_jacobian(&self, x: &Vector2<f64>) -> Option<(Vector2<f64>, Matrix2<f64>)> {
        let r2 = x.norm_squared();
        if !(r2.is_finite() && r2 <= self.max_radius * self.max_radius) {
            return None;
        }
        Some(distort_unchecked(&self.distortion, x))
    }

    /// The normalised point whose distortion is `x_d`: Newton's method on the model (the
    /// fisheye's radial equation safeguarded by bisection), to a residual of 1e-14 of the
    /// point's size. Fails for a point past the model's fold, and after a bounded number of
    /// iterations.
    pub fn undistort(&self, x_d: &Vector2<f64>) -> Result<Vector2<f64>, UndistortError> {
        if !x_d.iter().all(|v| v.is_finite()) {
            return Err(UndistortError::NotFinite);
        }
        match self.distortion {
            Distortion::None => Ok(*x_d),
            Distortion::RadialTangential { .. } => self.undistort_newton(x_d),
            Distortion::Fisheye { .. } => self.undistort_fisheye(x_d),
        }
    }

    fn undistort_newton(&self, x_d: &Vector2<f64>) -> Result<Vector2<f64>, UndistortError> {
        let tolerance = RESIDUAL_TOLERANCE * x_d.norm().max(1.0);
        // Start at the distorted point, pulled inside the field if it lies beyond.
        let mut x = x_d * (0.9 * self.max_radius / x_d.norm()).min(1.0);
        let (mut d, mut j) = self
            .distort_with_jacobian(&x)
            .ok_or(UndistortError::OutsideModel)?;
        // A NaN determinant fails this too.
        if j.determinant().partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(UndistortError::OutsideModel);
        }
        for _ in 0..MAX_NEWTON_ITERATIONS {
            let residual = d - x_d;
            if residual.norm() <= tolerance {
                return Ok(x);
            }
            // Every accepted iterate has det J > 0 (this side of any fold).
            let det = j.determinant();
            let step = Vector2::new(
                (j[(1, 1)] * residual.x - j[(0, 1)] * residual.y) / det,
                (j[(0, 0)] * residual.y - j[(1, 0)] * residual.x) / det,
            );
            // Backtrack until the residual shrinks without crossing a fold: a full step may
            // overshoot past the field's edge for points near it.
            let mut t = 1.0;
            loop {
                let candidate = x - step * t;
                if let Some((dc, jc)) = self.distort_with_jacobian(&candidate)
                    && jc.determinant() > 0.0
                    && (dc - x_d).norm() < residual.norm()
                {
                    (x, d, j) = (candidate, dc, jc);
                    break;
                }
                t *= 0.5;
                if t < 1e-12 {
                    // Rounding can stall the last digits just above the tolerance; far from
                    // it, no descent means no preimage this side of the fold.
                    return if residual.norm() <= 1e3 * tolerance {
                        Ok(x)
                    } else {
                        Err(UndistortError::OutsideModel)
                    };
                }
            }
        }
        Err(UndistortError::NoConvergence(MAX_NEWTON_ITERATIONS))
    }

    fn undistort_fisheye(&self, x_d: &Vector2<f64>) -> Result<Vector2<f64>, UndistortError> {
        let theta_d = x_d.norm();
        if theta_d == 0.0 {
            return Ok(*x_d);
        }
        // θ_d(θ) increases on [0, θ_max]: bracket the root and refine.
        let theta_max = self.max_radius.atan();
        let (d_max, _) = fisheye_theta_d(&self.distortion, theta_max);
        if theta_d > d_max {
            return Err(UndistortError::OutsideModel);
        }
        let tolerance = RESIDUAL_TOLERANCE * theta_d.max(1.0);
        let (mut lo, mut hi) = (0.0, theta_max);
        let mut theta = theta_d.min(theta_max);
        for _ in 0..MAX_FISHEYE_ITERATIONS {
            let (d, slope) = fisheye_theta_d(&self.distortion, theta);
            let residual = d - theta_d;
            if residual.abs() <= tolerance {
                let r = theta.tan();
                return Ok(x_d * (r / theta_d));
            }
            if residual > 0.0 {
                hi = theta;
            } else {
                lo = theta;
            }
            let newton = theta - residual / slope;
            theta = if slope > 0.0 && newton > lo && newton < hi {
                newton
            } else {
                0.5 * (lo + hi)
            };
        }
        Err(UndistortError::NoConvergence(MAX_FISHEYE_ITERATIONS))
    }
}

/// The undistorted normalised radius at `theta` off axis; ∞ at 90° (no fold in front of the
/// camera).
fn radius_at(theta: f64) -> f64 {
    if theta >= std::f64::consts::FRAC_PI_2 {
        f64::INFINITY
    } else {
        theta.tan()
    }
}

/// The last scanned angle at which `increasing` still holds, from the axis outwards; `None`
/// if it fails within the first degree.
fn scan_fold(increasing: impl Fn(f64) -> bool) -> Option<f64> {
    let steps = (SCAN_MAX_ANGLE_RAD / SCAN_STEP_RAD).ceil() as u32;
    let mut last = 0.0;
    for i in 1..=steps {
        let theta = (f64::from(i) * SCAN_STEP_RAD).min(SCAN_MAX_ANGLE_RAD);
        if !increasing(theta) {
            return (last >= 1.0_f64.to_radians()).then_some(last);
        }
        last = theta;
    }
    // Increasing over the whole scanned field: invertible everywhere in front of the camera
    // for the fisheye (θ < π/2 always); the rational model is taken as increasing beyond too.
    Some(std::f64::consts::FRAC_PI_2)
}

/// The radial-tangential model's rational factor `g(r²)` and its derivative `dg/d(r²)`.
fn rational_factor(distortion: &Distortion, r2: f64) -> (f64, f64) {
    let Distortion::RadialTangential {
        k1,
        k2,
        k3,
        k4,
        k5,
        k6,
        ..
    } = *distortion
    else {
        return (1.0, 0.0);
    };
    let num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    let den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6));
    let d_num = k1 + r2 * (2.0 * k2 + r2 * 3.0 * k3);
    let d_den = k4 + r2 * (2.0 * k5 + r2 * 3.0 * k6);
    (num / den, (d_num * den - num * d_den) / (den * den))
}

/// The fisheye's `θ_d(θ)` and its derivative `dθ_d/dθ`.
fn fisheye_theta_d(distortion: &Distortion, theta: f64) -> (f64, f64) {
    let Distortion::Fisheye { k1, k2, k3, k4 } = *distortion else {
        return (theta, 1.0);
    };
    let t2 = theta * theta;
    let poly = 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)));
    let d_poly = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)));
    (theta * poly, d_poly)
}

/// The model and its Jacobian at `x`, without the field check.
fn distort_unchecked(distortion: &Distortion, x: &Vector2<f64>) -> (Vector2<f64>, Matrix2<f64>) {
    let (u, v) = (x.x, x.y);
    let r2 = u * u + v * v;
    match *distortion {
        Distortion::None => (*x, Matrix2::identity()),
        Distortion::RadialTangential { p1, p2, .. } => {
            let (g, dg) = rational_factor(distortion, r2);
            let d = Vector2::new(
                u * g + 2.0 * p1 * u * v + p2 * (r2 + 2.0 * u * u),
                v * g + p1 * (r2 + 2.0 * v * v) + 2.0 * p2 * u * v,
            );
            let cross = 2.0 * u * v * dg + 2.0 * p1 * u + 2.0 * p2 * v;
            let j = Matrix2::new(
                g + 2.0 * u * u * dg + 2.0 * p1 * v + 6.0 * p2 * u,
                cross,
                cross,
                g + 2.0 * v * v * dg + 6.0 * p1 * v + 2.0 * p2 * u,
            );
            (d, j)
        }
        Distortion::Fisheye { k1, k2, .. } => {
            // x_d = s(r) x with s = θ_d / r: J = s I + (s'(r) / r) x xᵀ.
            let r = r2.sqrt();
            let (s, ds_over_r) = if r < FISHEYE_SERIES_RADIUS {
                // θ = r − r³/3 + r⁵/5, θ_d = θ + k1 θ³ + k2 θ⁵: s = 1 + a r² + b r⁴.
                let a = k1 - 1.0 / 3.0;
                let b = 0.2 - k1 + k2;
                (1.0 + r2 * (a + r2 * b), 2.0 * a + 4.0 * b * r2)
            } else {
                let theta = r.atan();
                let (theta_d, slope) = fisheye_theta_d(distortion, theta);
                let s = theta_d / r;
                // s' = (θ_d'(θ) θ'(r) r − θ_d) / r², θ'(r) = 1 / (1 + r²).
                let ds = (slope * r / (1.0 + r2) - theta_d) / r2;
                (s, ds / r)
            };
            let j = Matrix2::identity() * s + x * x.transpose() * ds_over_r;
            (x * s, j)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A strongly barrel-distorted wide-angle lens (OpenCV order k1, k2, p1, p2, k3).
    pub(crate) fn plumb_bob() -> Distortion {
        Distortion::RadialTangential {
            k1: -0.2847,
            k2: 0.0913,
            p1: 3.1e-4,
            p2: -1.7e-4,
            k3: -0.0125,
            k4: 0.0,
            k5: 0.0,
            k6: 0.0,
        }
    }

    fn rational() -> Distortion {
        Distortion::RadialTangential {
            k1: 0.41,
            k2: -0.12,
            p1: -2.0e-4,
            p2: 4.0e-4,
            k3: 0.02,
            k4: 0.72,
            k5: -0.05,
            k6: 0.01,
        }
    }

    fn fisheye() -> Distortion {
        Distortion::Fisheye {
            k1: -0.0134,
            k2: 0.0048,
            k3: -0.0021,
            k4: 0.0003,
        }
    }

    #[test]
    fn jacobians_match_central_differences() {
        for model in [plumb_bob(), rational(), fisheye()] {
            let lens = Lens::new(model).unwrap();
            for x in [
                Vector2::new(0.0, 0.0),
                Vector2::new(2e-4, -5e-4),
                Vector2::new(0.31, -0.22),
                Vector2::new(-0.6, 0.45),
                Vector2::new(0.05, 0.9),
            ] {
                let (_, j) = lens.distort_with_jacobian(&x).unwrap();
                let h = 1e-6;
                for k in 0..2 {
                    let mut dx = Vector2::zeros();
                    dx[k] = h;
                    let fd = (lens.distort(&(x + dx)).unwrap() - lens.distort(&(x - dx)).unwrap())
                        / (2.0 * h);
                    assert!(
                        (fd - j.column(k)).norm() < 1e-8,
                        "{model:?} at {x}: column {k}: fd {fd} vs {}",
                        j.column(k)
                    );
                }
            }
        }
    }

    #[test]
    fn undistortion_inverts_the_model() {
        for model in [plumb_bob(), rational(), fisheye()] {
            let lens = Lens::new(model).unwrap();
            for i in 0..=40 {
                for k in 0..=40 {
                    let x = Vector2::new(-0.8 + 0.04 * f64::from(i), -0.8 + 0.04 * f64::from(k));
                    let d = lens.distort(&x).unwrap();
                    let back = lens.undistort(&d).unwrap();
                    assert!((back - x).norm() < 1e-13, "{model:?}: {x} -> {back}");
                }
            }
        }
    }

    #[test]
    fn zero_coefficients_are_the_pinhole() {
        let zero = Distortion::RadialTangential {
            k1: 0.0,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            k4: 0.0,
            k5: 0.0,
            k6: 0.0,
        };
        assert_eq!(Lens::new(zero).unwrap(), Lens::pinhole());
        let zero_fisheye = Distortion::Fisheye {
            k1: 0.0,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
        };
        assert!(Lens::new(zero_fisheye).unwrap().is_pinhole());
        // The model's own arithmetic at zero coefficients is the identity too.
        let x = Vector2::new(0.3, -0.7);
        let (d, j) = distort_unchecked(&zero, &x);
        assert_eq!((d, j), (x, Matrix2::identity()));
    }

    #[test]
    fn a_fold_bounds_the_field_and_undistortion_reports_it() {
        // Strong barrel: r g(r²) = r (1 − 0.4 r²) peaks at r = √(1/1.2) ≈ 0.913.
        let model = Distortion::RadialTangential {
            k1: -0.4,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            k4: 0.0,
            k5: 0.0,
            k6: 0.0,
        };
        let lens = Lens::new(model).unwrap();
        let r_fold = (1.0_f64 / 1.2).sqrt();
        assert!(
            (lens.max_radius() - r_fold).abs() < 2e-4,
            "{}",
            lens.max_radius()
        );
        // Beyond the fold nothing projects: the polynomial would fold points back inwards.
        assert!(lens.distort(&Vector2::new(0.95, 0.0)).is_none());
        // The largest distorted radius is r_fold (1 − 0.4 r_fold²) ≈ 0.609; past it there is
        // no inverse, and the failure comes back in bounded time.
        let d_max = r_fold * (1.0 - 0.4 * r_fold * r_fold);
        let err = lens
            .undistort(&Vector2::new(d_max + 0.05, 0.0))
            .unwrap_err();
        assert_eq!(err, UndistortError::OutsideModel);
        assert!(lens.undistort(&Vector2::new(d_max - 0.01, 0.0)).is_ok());
        assert_eq!(
            lens.undistort(&Vector2::new(f64::NAN, 0.0)),
            Err(UndistortError::NotFinite)
        );
        // The fisheye's inverse stops at its own fold too.
        let fe = Lens::new(Distortion::Fisheye {
            k1: -0.3,
            k2: 0.0,
            k3: 0.0,
            k4: 0.0,
        })
        .unwrap();
        // θ (1 − 0.3 θ²) peaks at θ = 1/√0.9 ≈ 1.054 rad.
        let theta_fold = (1.0_f64 / 0.9).sqrt();
        assert!((fe.max_radius().atan() - theta_fold).abs() < 2e-4);
        assert_eq!(
            fe.undistort(&Vector2::new(0.0, 0.8)),
            Err(UndistortError::OutsideModel)
        );
        // Realistic lenses: the plumb_bob folds far outside its image (r ≈ 1.8, 61°); the
        // fisheye increases all the way to 90°.
        let r = Lens::new(plumb_bob()).unwrap().max_radius();
        assert!((1.7..1.9).contains(&r), "{r}");
        assert_eq!(Lens::new(fisheye()).unwrap().max_radius(), f64::INFINITY);
        // A model that folds at once is refused.
        let bad = Distortion::RadialTangential {
            k1: -1e6,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
            k3: 0.0,
            k4: 0.0,
            k5: 0.0,
            k6: 0.0,
        };
        assert_eq!(Lens::new(bad), Err(LensError::FoldsAtAxis));
        let nan = Distortion::Fisheye {
            k1: 0.0,
            k2: f64::NAN,
            k3: 0.0,
            k4: 0.0,
        };
        assert!(matches!(
            Lens::new(nan),
            Err(LensError::NotFinite { index: 1, .. })
        ));
    }
}
