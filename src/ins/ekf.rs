//! Generic EKF mechanics shared by the INS filters (docs/REFERENCES.md A1.3): covariance prediction
//! `P⁻ = F P Fᵀ + Q̃`, the measurement update with the Joseph form
//! `P⁺ = (I − KH) P⁻ (I − KH)ᵀ + K R Kᵀ` and an optional chi-square innovation gate, and the
//! first-order discrete low-pass filter `LPF_Tf` of A1.3.
//!
//! The authors invert `S` explicitly; here `S` is factored by Cholesky, which doubles as the
//! positive-definiteness check: an update whose `S` is not positive definite, or whose result
//! is not finite, is refused and leaves the filter untouched.

use nalgebra::{SMatrix, SVector};

/// Why a measurement update was not applied.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum UpdateRejection {
    /// `S` not positive definite, or a non-finite innovation, gain or covariance.
    Numerical,
    /// Normalised innovation squared above the gate.
    Gated {
        /// The normalised innovation squared `rᵀ S⁻¹ r`.
        nis: f64,
    },
}

/// An accepted update: the state correction and the normalised innovation squared.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Correction<const N: usize> {
    /// State (or error-state) correction `K r`.
    pub dx: SVector<f64, N>,
    /// `rᵀ S⁻¹ r`.
    pub nis: f64,
}

/// `P ← F P Fᵀ + diag(q)`, symmetrised.
pub(crate) fn predict_covariance<const N: usize>(
    p: &mut SMatrix<f64, N, N>,
    f: &SMatrix<f64, N, N>,
    q_diag: &SVector<f64, N>,
) {
    let mut p_new = f * *p * f.transpose();
    for i in 0..N {
        p_new[(i, i)] += q_diag[i];
    }
    symmetrize(&mut p_new);
    *p = p_new;
}

/// Measurement update with diagonal `R` (every observation of the INS has independent noise).
///
/// On success `P` holds the Joseph-form posterior and the correction is returned; the caller
/// applies it to its (nominal) state. On rejection `P` is unchanged.
pub(crate) fn update<const N: usize, const M: usize>(
    p: &mut SMatrix<f64, N, N>,
    h: &SMatrix<f64, M, N>,
    r_diag: &SVector<f64, M>,
    innovation: &SVector<f64, M>,
    gate: Option<f64>,
) -> Result<Correction<N>, UpdateRejection> {
    let pht = *p * h.transpose();
    let mut s = h * pht;
    for i in 0..M {
        s[(i, i)] += r_diag[i];
    }
    let chol = s.cholesky().ok_or(UpdateRejection::Numerical)?;
    let nis = innovation.dot(&chol.solve(innovation));
    if !nis.is_finite() {
        return Err(UpdateRejection::Numerical);
    }
    if let Some(g) = gate
        && nis > g
    {
        return Err(UpdateRejection::Gated { nis });
    }
    // Kᵀ = S⁻¹ H P (S and P symmetric).
    let k = chol.solve(&pht.transpose()).transpose();
    let dx = k * innovation;
    let ikh = SMatrix::<f64, N, N>::identity() - k * h;
    let mut p_new = ikh * *p * ikh.transpose();
    // + K R Kᵀ with R diagonal.
    let mut kr = k;
    for (m, mut col) in kr.column_iter_mut().enumerate() {
        col *= r_diag[m];
    }
    p_new += kr * k.transpose();
    symmetrize(&mut p_new);
    if !dx.iter().all(|v| v.is_finite()) || !p_new.iter().all(|v| v.is_finite()) {
        return Err(UpdateRejection::Numerical);
    }
    *p = p_new;
    Ok(Correction { dx, nis })
}

/// `P ← (P + Pᵀ)/2`: removes the rounding asymmetry of the products.
pub(crate) fn symmetrize<const N: usize>(p: &mut SMatrix<f64, N, N>) {
    for i in 0..N {
        for j in 0..i {
            let m = 0.5 * (p[(i, j)] + p[(j, i)]);
            p[(i, j)] = m;
            p[(j, i)] = m;
        }
    }
}

/// Moving average over the last `window_s` seconds (± one 1-s bin) of time-weighted inputs (a
/// running mean of everything until the window is full).
///
/// It averages noise like a first-order filter of `window_s/2` (same variance of the mean for
/// a window much longer than the input's correlation time) but has no memory beyond the
/// window: an input that changed — the wind through a climb, a take-off roll, a step — is
/// forgotten entirely one window later, where a first-order filter keeps `e^{−t/T_f}` of it. Bins make the
/// window end move in 1-s steps; the total is re-summed from the bins when one closes, so no
/// rounding accumulates over a long flight.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WindowMean<T> {
    /// Window length, s.
    window_s: f64,
    /// Closed bins, oldest first: (time-weighted sum, duration s).
    bins: std::collections::VecDeque<(T, f64)>,
    /// Sum and duration of the closed bins in `bins`.
    closed: (T, f64),
    /// The bin being filled.
    open: (T, f64),
    /// Output before any input.
    initial: T,
    zero: T,
}

/// Duration of one bin of [`WindowMean`], s.
const WINDOW_BIN_S: f64 = 1.0;

impl<T> WindowMean<T>
where
    T: Copy + std::ops::Mul<f64, Output = T> + std::ops::Add<Output = T>,
{
    /// Window of `window_s` (s, ≥ 0; 0 = the latest input) with output `y0` until the first
    /// input.
    pub fn new(window_s: f64, y0: T) -> Self {
        let zero = y0 * 0.0;
        Self {
            window_s,
            bins: std::collections::VecDeque::new(),
            closed: (zero, 0.0),
            open: (zero, 0.0),
            initial: y0,
            zero,
        }
    }

    /// One step of `dt_s` (s, ≥ 0) with input `u`, held over the step.
    pub fn step(&mut self, u: T, dt_s: f64) {
        if self.window_s <= 0.0 {
            // No averaging: the output is the latest input.
            self.open = (u * dt_s.max(f64::MIN_POSITIVE), dt_s.max(f64::MIN_POSITIVE));
            return;
        }
        self.open.0 = self.open.0 + u * dt_s;
        self.open.1 += dt_s;
        if self.open.1 >= WINDOW_BIN_S {
            self.bins.push_back(self.open);
            self.open = (self.zero, 0.0);
            // Keep the newest bins that fit in the window with the next bin.
            let mut fit = 0.0;
            let mut keep = 0;
            for b in self.bins.iter().rev() {
                if fit + b.1 > self.window_s {
                    break;
                }
                fit += b.1;
                keep += 1;
            }
            let drop = self.bins.len() - keep;
            self.bins.drain(..drop);
            self.closed = self
                .bins
                .iter()
                .fold((self.zero, 0.0), |(s, d), b| (s + b.0, d + b.1));
        }
    }

    /// Mean over the window (the initial value before any input of non-zero duration).
    pub fn value(&self) -> T {
        let d = self.closed.1 + self.open.1;
        if d > 0.0 {
            (self.closed.0 + self.open.0) * (1.0 / d)
        } else {
            self.initial
        }
    }

    /// Time the current mean covers, s (once full, the window ± one bin).
    pub fn covered_s(&self) -> f64 {
        self.closed.1 + self.open.1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

    #[test]
    fn window_mean_is_the_running_mean_then_forgets_older_inputs() {
        let mut w = WindowMean::new(20.0, 7.0);
        assert_eq!(w.value(), 7.0);
        // 5 s of 1.0 at 100 Hz, then 5 s of 3.0: the running mean is 2.
        for _ in 0..500 {
            w.step(1.0, 0.01);
        }
        assert!((w.value() - 1.0).abs() < 1e-12);
        for _ in 0..500 {
            w.step(3.0, 0.01);
        }
        assert!((w.value() - 2.0).abs() < 1e-9, "{}", w.value());
        // A step to 5.0: after one window (plus a bin) nothing older remains.
        for _ in 0..2100 {
            w.step(5.0, 0.01);
        }
        assert!((w.value() - 5.0).abs() < 1e-9, "{}", w.value());
        let covered = w.covered_s();
        assert!(
            (20.0 - WINDOW_BIN_S..=20.0 + WINDOW_BIN_S).contains(&covered),
            "{covered}"
        );
    }

    #[test]
    fn window_mean_weights_by_duration_and_handles_vectors() {
        let mut w = WindowMean::new(100.0, Vector3::zeros());
        w.step(Vector3::new(1.0, 0.0, 0.0), 0.3);
        w.step(Vector3::new(0.0, 2.0, 0.0), 0.1);
        let v = w.value();
        assert!((v - Vector3::new(0.75, 0.5, 0.0)).norm() < 1e-12, "{v}");
        // Zero window: the latest input.
        let mut z = WindowMean::new(0.0, 1.0);
        z.step(4.0, 0.01);
        z.step(6.0, 0.01);
        assert_eq!(z.value(), 6.0);
    }

    #[test]
    fn window_mean_after_a_step_beats_the_exponential_filter_of_the_same_noise() {
        // A 120-s window averages noise like a 60-s first-order filter. A 6 m/s step 15 s
        // after the start: 180 s later the filter still holds 1.5·e^{−135/60} ≈ 0.16 m/s of
        // the old value (1.5 m/s at 60 s, when its running mean ends), the window nothing.
        // The filter starts as a running mean until its time constant, as the window does.
        let mut w = WindowMean::new(120.0, 0.0);
        let (mut lp, mut t) = (0.0_f64, 0.0_f64);
        let mut step = |u: f64, w: &mut WindowMean<f64>| {
            let dt = 0.01;
            w.step(u, dt);
            let alpha = dt / (60.0_f64.min(t + dt) + dt);
            lp += alpha * (u - lp);
            t += dt;
        };
        for _ in 0..1500 {
            step(0.0, &mut w);
        }
        for _ in 0..18_000 {
            step(6.0, &mut w);
        }
        assert!((w.value() - 6.0).abs() < 1e-9, "{}", w.value());
        assert!(6.0 - lp > 0.1, "{lp}");
    }

    #[test]
    fn scalar_update_matches_closed_form() {
        // Prior variance 4, R = 1: K = 0.8, posterior variance 0.8, correction 0.8·r.
        let mut p = SMatrix::<f64, 1, 1>::new(4.0);
        let c = update(
            &mut p,
            &SMatrix::<f64, 1, 1>::new(1.0),
            &SVector::<f64, 1>::new(1.0),
            &SVector::<f64, 1>::new(2.0),
            None,
        )
        .unwrap();
        assert!((c.dx[0] - 1.6).abs() < 1e-15);
        assert!((p[(0, 0)] - 0.8).abs() < 1e-15);
        assert!((c.nis - 0.8).abs() < 1e-15);
    }

    #[test]
    fn joseph_update_equals_information_form() {
        // Posterior information = prior information + Hᵀ R⁻¹ H (exact for linear models).
        let p0 = Matrix3::new(2.0, 0.3, 0.1, 0.3, 1.5, -0.2, 0.1, -0.2, 0.7);
        let h = SMatrix::<f64, 2, 3>::new(1.0, 0.5, 0.0, 0.0, -1.0, 2.0);
        let r = Vector2::new(0.3, 0.9);
        let mut p = p0;
        update(&mut p, &h, &r, &Vector2::new(0.1, -0.2), None).unwrap();
        let r_inv = Matrix2::from_diagonal(&r.map(|v| 1.0 / v));
        let info = p0.try_inverse().unwrap() + h.transpose() * r_inv * h;
        let expect = info.try_inverse().unwrap();
        assert!((p - expect).norm() < 1e-13, "{p} {expect}");
    }

    #[test]
    fn gate_rejects_and_leaves_covariance() {
        let p0 = Matrix3::identity();
        let mut p = p0;
        let h = SMatrix::<f64, 1, 3>::new(1.0, 0.0, 0.0);
        // S = 2, r = 10: NIS = 50 > 9.
        let res = update(
            &mut p,
            &h,
            &SVector::<f64, 1>::new(1.0),
            &SVector::<f64, 1>::new(10.0),
            Some(9.0),
        );
        assert!(matches!(res, Err(UpdateRejection::Gated { nis }) if (nis - 50.0).abs() < 1e-12));
        assert_eq!(p, p0);
        // A non-finite innovation is refused as numerical.
        let res = update(
            &mut p,
            &h,
            &SVector::<f64, 1>::new(1.0),
            &SVector::<f64, 1>::new(f64::NAN),
            None,
        );
        assert_eq!(res.unwrap_err(), UpdateRejection::Numerical);
        assert_eq!(p, p0);
    }
}
