//! Ray geometry: the quadratic map from the camera's local NED frame to texture coordinates and
//! height, and each pixel's ray as quadratics in its depth along the optical axis (module doc
//! of [`super`], "Geometry, per frame").

use nalgebra::{Matrix3, Vector3};

/// Quadratic map from the local NED offset `q` (m, from the camera) to
/// `(x − x_c, y − y_c, h)`: value, gradient and Hessian of each output.
#[derive(Debug, Clone, Copy)]
pub(super) struct LocalMap {
    pub(super) g0: Vector3<f64>,
    pub(super) grad: [Vector3<f64>; 3],
    pub(super) hess: [Matrix3<f64>; 3],
}

impl LocalMap {
    pub(super) fn fit(exact: impl Fn(&Vector3<f64>) -> Vector3<f64>) -> Self {
        const S: f64 = 1_000.0;
        let f0 = exact(&Vector3::zeros());
        let e = [Vector3::x(), Vector3::y(), Vector3::z()];
        let mut grad = [Vector3::zeros(); 3];
        let mut hess = [Matrix3::zeros(); 3];
        let mut fp = [Vector3::zeros(); 3];
        let mut fm = [Vector3::zeros(); 3];
        for i in 0..3 {
            fp[i] = exact(&(e[i] * S));
            fm[i] = exact(&(-e[i] * S));
        }
        for k in 0..3 {
            for i in 0..3 {
                grad[k][i] = (fp[i][k] - fm[i][k]) / (2.0 * S);
                hess[k][(i, i)] = (fp[i][k] - 2.0 * f0[k] + fm[i][k]) / (S * S);
            }
        }
        for i in 0..3 {
            for j in (i + 1)..3 {
                let pp = exact(&((e[i] + e[j]) * S));
                let pm = exact(&((e[i] - e[j]) * S));
                let mp = exact(&((-e[i] + e[j]) * S));
                let mm = exact(&((-e[i] - e[j]) * S));
                for k in 0..3 {
                    let v = (pp[k] - pm[k] - mp[k] + mm[k]) / (4.0 * S * S);
                    hess[k][(i, j)] = v;
                    hess[k][(j, i)] = v;
                }
            }
        }
        Self { g0: f0, grad, hess }
    }
}

/// Ray quadratics: `x(t) = cx1 t + cx2 t²`, `y` likewise, `h(t) = h0 + ch1 t + ch2 t²`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Ray {
    pub(super) cx1: f64,
    pub(super) cx2: f64,
    pub(super) cy1: f64,
    pub(super) cy2: f64,
    pub(super) h0: f64,
    pub(super) ch1: f64,
    pub(super) ch2: f64,
    /// |u|² (the square root is taken only where needed: the fast path does without it).
    pub(super) n2: f64,
}

impl Ray {
    /// |u|.
    #[inline]
    pub(super) fn norm(&self) -> f64 {
        self.n2.sqrt()
    }

    #[inline]
    pub(super) fn xyh(&self, t: f64) -> (f64, f64, f64) {
        (
            t * (self.cx1 + self.cx2 * t),
            t * (self.cy1 + self.cy2 * t),
            self.h0 + t * (self.ch1 + self.ch2 * t),
        )
    }

    /// Smallest `t ≥ 0` where the ray's height equals `level_m`, if any.
    pub(super) fn cross(&self, level_m: f64) -> Option<f64> {
        let c = self.h0 - level_m;
        if c <= 0.0 {
            return Some(0.0);
        }
        let (a, b) = (self.ch2, self.ch1);
        if a.abs() < 1e-15 {
            return (b < 0.0).then(|| -c / b);
        }
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return None;
        }
        // Numerically stable roots of a t² + b t + c.
        let sq = disc.sqrt();
        let qq = -0.5 * (b + b.signum() * sq);
        let (r1, r2) = (qq / a, c / qq);
        let (lo, hi) = (r1.min(r2), r1.max(r2));
        if lo > 0.0 {
            Some(lo)
        } else if hi > 0.0 {
            Some(hi)
        } else {
            None
        }
    }
}

/// The rays of one image row: every coefficient of [`Ray`] as a polynomial in the column `u`
/// (the direction is affine in `u`), so a pixel's ray costs a few multiply-adds.
#[derive(Debug, Clone, Copy)]
pub(super) struct RowRays {
    /// Linear coefficients `p + q u` of x, y, h.
    pub(super) lin: [(f64, f64); 3],
    /// Quadratic coefficients `a + u (b + u c)` of x, y, h.
    pub(super) quad: [(f64, f64, f64); 3],
    /// `|dir|²` as `a + u (b + u c)`.
    pub(super) n2: (f64, f64, f64),
    pub(super) h0: f64,
}

impl RowRays {
    pub(super) fn new(
        map: &LocalMap,
        r_nc: &Matrix3<f64>,
        f_px: f64,
        cu_px: f64,
        y_norm: f64,
    ) -> Self {
        // dir(u) = d0 + u du with d0 = R (−c_u/f, y, 1) and du = R (1/f, 0, 0).
        let d0 = r_nc * Vector3::new(-cu_px / f_px, y_norm, 1.0);
        let du = r_nc * Vector3::new(1.0 / f_px, 0.0, 0.0);
        let mut lin = [(0.0, 0.0); 3];
        let mut quad = [(0.0, 0.0, 0.0); 3];
        for k in 0..3 {
            lin[k] = (map.grad[k].dot(&d0), map.grad[k].dot(&du));
            let hd0 = map.hess[k] * d0;
            let hdu = map.hess[k] * du;
            quad[k] = (0.5 * d0.dot(&hd0), d0.dot(&hdu), 0.5 * du.dot(&hdu));
        }
        Self {
            lin,
            quad,
            n2: (d0.dot(&d0), 2.0 * d0.dot(&du), du.dot(&du)),
            h0: map.g0[2],
        }
    }

    #[inline]
    pub(super) fn at(&self, u: f64) -> Ray {
        let l = |k: usize| self.lin[k].0 + u * self.lin[k].1;
        let q = |k: usize| self.quad[k].0 + u * (self.quad[k].1 + u * self.quad[k].2);
        Ray {
            cx1: l(0),
            cx2: q(0),
            cy1: l(1),
            cy2: q(1),
            h0: self.h0,
            ch1: l(2),
            ch2: q(2),
            n2: self.n2.0 + u * (self.n2.1 + u * self.n2.2),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_slab_crossings() {
        let ray = Ray {
            cx1: 0.0,
            cx2: 0.0,
            cy1: 0.0,
            cy2: 0.0,
            h0: 1000.0,
            ch1: -1.0,
            ch2: 1e-7,
            n2: 1.0,
        };
        let t = ray.cross(200.0).unwrap();
        assert!((ray.xyh(t).2 - 200.0).abs() < 1e-9);
        assert_eq!(ray.cross(2000.0), Some(0.0));
        let up = Ray { ch1: 0.5, ..ray };
        assert_eq!(up.cross(200.0), None);
    }
}
