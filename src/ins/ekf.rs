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

/// `P ← F P Fᵀ + diag(q)`, symmetrised: the reference of [`predict_covariance_top`].
#[cfg(test)]
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

/// `P ← F P Fᵀ + diag(q)` for `F` whose rows from `R` on are those of the identity (only the
/// first `R` rows, `f_top`, propagate): `F P` differs from `P` in its first `R` rows and
/// `(F P) Fᵀ` from `F P` in its first `R` columns, so both products are `R × N × N` instead of
/// `N³`. The result equals [`predict_covariance`]'s to rounding.
pub(crate) fn predict_covariance_top<const N: usize, const R: usize>(
    p: &mut SMatrix<f64, N, N>,
    f_top: &SMatrix<f64, R, N>,
    q_diag: &SVector<f64, N>,
) {
    transform_covariance_top(p, f_top, None);
    for i in 0..N {
        p[(i, i)] += q_diag[i];
    }
    symmetrize(p);
}

/// `P ← F P Fᵀ` (no noise, not symmetrised) for `F` whose first `R` rows are `f_top` and whose
/// other rows are those of a diagonal matrix (`diag`; the identity's if `None`; its first `R`
/// entries are unused).
pub(crate) fn transform_covariance_top<const N: usize, const R: usize>(
    p: &mut SMatrix<f64, N, N>,
    f_top: &SMatrix<f64, R, N>,
    diag: Option<&SVector<f64, N>>,
) {
    // F P: the first R rows are f_top P, the others scaled by the diagonal.
    let fp_top = f_top * *p;
    p.fixed_rows_mut::<R>(0).copy_from(&fp_top);
    if let Some(d) = diag {
        for i in R..N {
            if d[i] != 1.0 {
                p.row_mut(i).scale_mut(d[i]);
            }
        }
    }
    // (F P) Fᵀ: the first R columns from F P before the column scaling, the others scaled.
    let fpf_left = *p * f_top.transpose();
    if let Some(d) = diag {
        for j in R..N {
            if d[j] != 1.0 {
                p.column_mut(j).scale_mut(d[j]);
            }
        }
    }
    p.fixed_columns_mut::<R>(0).copy_from(&fpf_left);
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
    // Joseph form without its N×N×N products: with A = (I − KH) P = P − K (P Hᵀ)ᵀ,
    // (I − KH) P (I − KH)ᵀ + K R Kᵀ = A − (A Hᵀ − K R) Kᵀ: three N×M×N products.
    let a = *p - k * pht.transpose();
    let mut aht_kr = a * h.transpose();
    for (m, mut col) in aht_kr.column_iter_mut().enumerate() {
        col.axpy(-r_diag[m], &k.column(m), 1.0);
    }
    let mut p_new = a - aht_kr * k.transpose();
    symmetrize(&mut p_new);
    if !dx.iter().all(|v| v.is_finite()) || !p_new.iter().all(|v| v.is_finite()) {
        return Err(UpdateRejection::Numerical);
    }
    *p = p_new;
    Ok(Correction { dx, nis })
}

/// Measurement update with diagonal `R` and no gate, one observation row at a time.
///
/// With the linearisation fixed at the prior and independent noises, processing the rows in
/// turn (row `m` sees the innovation left by the rows before it, `r_m − h_m δx`) gives the
/// batch posterior and correction exactly, in exact arithmetic; each row costs
/// `O(N·(nnz(h_m) + N))` (zero entries of `H` are skipped; the covariance downdate is
/// `P ← P − (P h_mᵀ)(P h_mᵀ)ᵀ / s_m`) instead of the batch's `O(N²M)` products and `M × M`
/// factorisation. On rejection `P` is unchanged.
pub(crate) fn update_rows<const N: usize, const M: usize>(
    p: &mut SMatrix<f64, N, N>,
    h: &SMatrix<f64, M, N>,
    r_diag: &SVector<f64, M>,
    innovation: &SVector<f64, M>,
) -> Result<SVector<f64, N>, UpdateRejection> {
    let prior = *p;
    let mut dx = SVector::<f64, N>::zeros();
    for m in 0..M {
        let row = h.row(m);
        let mut pht = SVector::<f64, N>::zeros();
        let mut h_dx = 0.0;
        for (j, &hj) in row.iter().enumerate() {
            if hj != 0.0 {
                pht.axpy(hj, &p.column(j), 1.0);
                h_dx += hj * dx[j];
            }
        }
        let s = r_diag[m] + row.transpose().dot(&pht);
        if !(s.is_finite() && s > 0.0) {
            *p = prior;
            return Err(UpdateRejection::Numerical);
        }
        let inv_s = 1.0 / s;
        dx.axpy((innovation[m] - h_dx) * inv_s, &pht, 1.0);
        // Column by column over the contiguous column-major storage (vectorised); the last
        // ulp of asymmetry goes below.
        let pht = pht.as_slice();
        for (c, col) in p.as_mut_slice().chunks_exact_mut(N).enumerate() {
            let kc = pht[c] * inv_s;
            for (x, &v) in col.iter_mut().zip(pht) {
                *x -= v * kc;
            }
        }
    }
    symmetrize(p);
    if !dx.iter().all(|v| v.is_finite()) || !p.iter().all(|v| v.is_finite()) {
        *p = prior;
        return Err(UpdateRejection::Numerical);
    }
    Ok(dx)
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

    /// Rows one at a time give the batch Joseph posterior and correction (to rounding) for a
    /// dense 18-state covariance and a sparse 9-row observation with a zero row and mixed
    /// scales, as the attitude filter's; the batch update through the new Joseph
    /// factorisation gives the textbook Joseph form.
    #[test]
    fn row_by_row_updates_equal_the_batch_update_and_the_joseph_form() {
        const N: usize = 18;
        // A well-conditioned SPD prior with correlations: L Lᵀ + I with a pseudo-random L.
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state % 2001) as f64 / 1000.0 - 1.0
        };
        let l = SMatrix::<f64, N, N>::from_fn(|_, _| next());
        let p0 = l * l.transpose() * 0.1 + SMatrix::<f64, N, N>::identity();
        let mut h = SMatrix::<f64, 9, N>::zeros();
        for (m, js) in [
            [0, 3, 6],
            [1, 4, 7],
            [2, 5, 8],
            [0, 1, 3],
            [4, 2, 5],
            [6, 7, 9],
            [0, 10, 12],
            [1, 11, 13],
            [2, 12, 14],
        ]
        .iter()
        .enumerate()
        {
            for (n, &j) in js.iter().enumerate() {
                h[(m, j)] = [1.0, -0.5, 2.5][n] * (1.0 + m as f64);
            }
        }
        h.row_mut(5).fill(0.0);
        let r = SVector::<f64, 9>::from_fn(|i, _| 0.01 * (1.0 + i as f64));
        let y = SVector::<f64, 9>::from_fn(|i, _| (i as f64 - 4.0) * 0.3);

        let (mut p_batch, mut p_rows) = (p0, p0);
        let dx_batch = update(&mut p_batch, &h, &r, &y, None).unwrap().dx;
        let dx_rows = update_rows(&mut p_rows, &h, &r, &y).unwrap();
        let scale = p0.amax();
        assert!((dx_rows - dx_batch).amax() < 1e-12 * dx_batch.amax().max(1.0));
        assert!(
            (p_rows - p_batch).amax() < 1e-12 * scale,
            "{}",
            (p_rows - p_batch).amax()
        );
        assert_eq!(p_rows, p_rows.transpose());

        // Textbook Joseph form.
        let s = h * p0 * h.transpose() + SMatrix::<f64, 9, 9>::from_diagonal(&r);
        let k = p0 * h.transpose() * s.try_inverse().unwrap();
        let ikh = SMatrix::<f64, N, N>::identity() - k * h;
        let joseph = ikh * p0 * ikh.transpose()
            + k * SMatrix::<f64, 9, 9>::from_diagonal(&r) * k.transpose();
        assert!((p_batch - joseph).amax() < 1e-12 * scale);
        assert!((dx_batch - k * y).amax() < 1e-12);

        // A non-positive innovation variance is refused and leaves P alone.
        let mut p_bad = p0;
        let neg = SVector::<f64, 9>::repeat(-1e9);
        assert_eq!(
            update_rows(&mut p_bad, &h, &neg, &y).err(),
            Some(UpdateRejection::Numerical)
        );
        assert_eq!(p_bad, p0);
    }

    /// The prediction through the top rows equals the full `F P Fᵀ` for a transition whose
    /// lower rows are the identity's (the position filter's shape).
    #[test]
    fn the_top_rows_prediction_equals_the_full_product() {
        const N: usize = 12;
        let l = SMatrix::<f64, N, N>::from_fn(|i, j| ((i * 7 + j * 3) % 11) as f64 / 10.0 - 0.5);
        let p0 = l * l.transpose() + SMatrix::<f64, N, N>::identity();
        let mut f = SMatrix::<f64, N, N>::identity();
        for (i, j, v) in [
            (0, 3, 0.01),
            (1, 4, 0.01),
            (3, 3, 0.999),
            (4, 7, -0.02),
            (5, 9, 0.03),
        ] {
            f[(i, j)] = v;
        }
        let q = SVector::<f64, N>::from_fn(|i, _| 1e-3 * (i + 1) as f64);
        let (mut full, mut top) = (p0, p0);
        predict_covariance(&mut full, &f, &q);
        predict_covariance_top(&mut top, &f.fixed_rows::<6>(0).into_owned(), &q);
        assert!(
            (full - top).amax() < 1e-13 * p0.amax(),
            "{}",
            (full - top).amax()
        );
        assert_eq!(top, top.transpose());
        // Diagonal lower rows (the dead reckoning's gust decay).
        let mut d = SVector::<f64, N>::repeat(1.0);
        d[7] = 0.97;
        d[8] = 0.5;
        f[(7, 7)] = d[7];
        f[(8, 8)] = d[8];
        let (mut full, mut top) = (p0, p0);
        predict_covariance(&mut full, &f, &SVector::zeros());
        transform_covariance_top(&mut top, &f.fixed_rows::<6>(0).into_owned(), Some(&d));
        let err = (full - top).amax();
        assert!(err < 1e-13 * p0.amax(), "{err}");
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
