//! Earth magnetic field from the World Magnetic Model (WMM2025, through the `world_magnetic_model`
//! crate), in NED, nT (docs/REFERENCES.md A3.6; the authors froze a 1°×1° box of WMM values — here
//! the model itself is evaluated, optionally through a cached grid).
//!
//! Inputs: geodetic latitude/longitude (WGS84) and the height `h_m` above the WGS84
//! ellipsoid, which is exactly what the crate expects (`GeomagneticField::new` takes the height
//! above the ellipsoid), so no geoid/MSL conversion is involved. The crate computes in `f32`
//! (relative precision ~6e-8, i.e. < 0.01 nT), far below the WMM error (~140 nT).

use nalgebra::Vector3;
use world_magnetic_model::GeomagneticField;
use world_magnetic_model::time::{Date, util::days_in_year};
use world_magnetic_model::uom::si::angle::degree;
use world_magnetic_model::uom::si::f32::{Angle, Length};
use world_magnetic_model::uom::si::length::meter;
use world_magnetic_model::uom::si::magnetic_flux_density::nanotesla;

use crate::math::angle::wrap_180_deg;
use crate::math::wgs84::Geodetic;

/// First decimal year of the WMM2025 validity span (inclusive).
pub const WMM2025_START_YEAR: f64 = 2025.0;
/// End of the WMM2025 validity span (exclusive: the model expires at the end of 2029).
pub const WMM2025_END_YEAR: f64 = 2030.0;

/// Errors of the magnetic model.
#[derive(Debug, thiserror::Error)]
pub enum MagneticError {
    /// The date or position is outside the model's validity.
    #[error("magnetic model unavailable: {0}")]
    Unavailable(String),
}

/// World Magnetic Model evaluated at a fixed epoch (the field's secular variation over one
/// flight is negligible: ~100 nT/yr is ~0.01 nT/h).
#[derive(Debug, Clone)]
pub struct MagneticModel {
    /// Decimal year of evaluation.
    pub decimal_year: f64,
    /// The calendar day the crate evaluates (its time resolution is one day).
    date: Date,
}

/// Calendar day containing decimal year `y` (day `1 + ⌊frac·days_in_year⌋`).
fn date_from_decimal_year(y: f64) -> Result<Date, MagneticError> {
    let year_f = y.floor();
    // Caller validated the range, so the cast is exact.
    let year = year_f as i32;
    let days = days_in_year(year);
    let ordinal = (1.0 + ((y - year_f) * f64::from(days)).floor()).clamp(1.0, f64::from(days));
    Date::from_ordinal_date(year, ordinal as u16)
        .map_err(|e| MagneticError::Unavailable(format!("decimal year {y}: {e}")))
}

impl MagneticModel {
    /// Model at the given decimal year (must lie within the WMM2025 validity span
    /// [`WMM2025_START_YEAR`, `WMM2025_END_YEAR`)).
    pub fn new(decimal_year: f64) -> Result<Self, MagneticError> {
        // Also rejects NaN.
        if !(WMM2025_START_YEAR..WMM2025_END_YEAR).contains(&decimal_year) {
            return Err(MagneticError::Unavailable(format!(
                "decimal year {decimal_year} outside WMM2025 validity \
                 [{WMM2025_START_YEAR}, {WMM2025_END_YEAR})"
            )));
        }
        Ok(Self {
            decimal_year,
            date: date_from_decimal_year(decimal_year)?,
        })
    }

    /// Field at `pos` in NED, nT (evaluates the spherical-harmonic model, ~1–2 µs; see
    /// [`MagneticGrid`] for a cached variant). Latitude must be within ±90° and the height
    /// within the model's −1 km … 850 km; any longitude is wrapped.
    pub fn field_ned_nt(&self, pos: &Geodetic) -> Result<Vector3<f64>, MagneticError> {
        let lat_deg = pos.lat_rad.to_degrees();
        // Wrap to (−180°, 180°] (the crate accepts the closed range; the authors' scenarios
        // use λ = 270°).
        let lon_deg = wrap_180_deg(pos.lon_rad.to_degrees());
        let f = GeomagneticField::new(
            Length::new::<meter>(pos.h_m as f32),
            Angle::new::<degree>(lat_deg as f32),
            Angle::new::<degree>(lon_deg as f32),
            self.date,
        )
        .map_err(|e| MagneticError::Unavailable(format!("{e} at {pos:?}")))?;
        Ok(Vector3::new(
            f64::from(f.x().get::<nanotesla>()),
            f64::from(f.y().get::<nanotesla>()),
            f64::from(f.z().get::<nanotesla>()),
        ))
    }
}

/// Default cell size of [`MagneticGrid`] in latitude and longitude, degrees.
pub const GRID_CELL_DEG: f64 = 0.25;
/// Default cell size of [`MagneticGrid`] in height, m.
pub const GRID_CELL_H_M: f64 = 1000.0;
/// Latitude beyond which [`MagneticGrid`] falls back to the exact model (cells would cross the
/// pole), degrees.
const GRID_MAX_LAT_DEG: f64 = 89.0;

/// One cached grid cell: its integer indices and the field at its 8 corners.
#[derive(Debug, Clone, Copy)]
struct GridCell {
    index: [i64; 3],
    /// `corners[i_lat][i_lon][i_h]`, NED nT.
    corners: [[[Vector3<f64>; 2]; 2]; 2],
}

/// WMM through a cached trilinear grid in (latitude, longitude, height) — the authors'
/// 1°×1° box idea, made seamless. Cells are aligned to multiples of the cell size, so the
/// result is a pure function of the position (the cache only avoids recomputing the 8 corner
/// values while the aircraft stays in one cell): ~40 ns per call instead of ~0.8 µs. The
/// interpolation error is ≤ (Δ²/8)·|f''| per direction: with the field's curvature of
/// ~30 nT/deg² at mid-latitudes and the default 0.25° × 1000 m cells it stays below 0.5 nT
/// (|B| ∝ r⁻³ is nearly linear over 1 km), far below the WMM error (~140 nT) and the
/// magnetometer noise (50 nT per sample).
#[derive(Debug, Clone)]
pub struct MagneticGrid {
    model: MagneticModel,
    cell_deg: f64,
    cell_h_m: f64,
    cell: Option<GridCell>,
}

impl MagneticGrid {
    /// Grid over `model` with the default cell sizes.
    pub fn new(model: MagneticModel) -> Self {
        Self::with_cell(model, GRID_CELL_DEG, GRID_CELL_H_M)
    }

    /// Grid with explicit cell sizes (degrees, metres); non-positive or non-finite sizes fall
    /// back to the defaults.
    pub fn with_cell(model: MagneticModel, cell_deg: f64, cell_h_m: f64) -> Self {
        let ok = |x: f64| x.is_finite() && x > 0.0;
        Self {
            model,
            cell_deg: if ok(cell_deg) {
                cell_deg
            } else {
                GRID_CELL_DEG
            },
            cell_h_m: if ok(cell_h_m) {
                cell_h_m
            } else {
                GRID_CELL_H_M
            },
            cell: None,
        }
    }

    /// The underlying model.
    pub fn model(&self) -> &MagneticModel {
        &self.model
    }

    /// Field at `pos` in NED, nT (trilinear interpolation; exact model within 1° of the
    /// poles). Errors as [`MagneticModel::field_ned_nt`].
    pub fn field_ned_nt(&mut self, pos: &Geodetic) -> Result<Vector3<f64>, MagneticError> {
        let lat_deg = pos.lat_rad.to_degrees();
        // Any wrapping convention works here: cells are aligned to multiples of the cell size
        // and the corners are evaluated through the (wrapping) model, so the cells on either
        // side of ±180° meet seamlessly.
        let lon_deg = wrap_180_deg(pos.lon_rad.to_degrees());
        let in_grid =
            lat_deg.abs() <= GRID_MAX_LAT_DEG && lon_deg.is_finite() && pos.h_m.is_finite();
        if !in_grid {
            // Near the poles, or invalid input (the model reports the error).
            return self.model.field_ned_nt(pos);
        }
        let f = [
            lat_deg / self.cell_deg,
            lon_deg / self.cell_deg,
            pos.h_m / self.cell_h_m,
        ];
        // Finite and bounded (|lat| ≤ 89°, |lon| ≤ 180°, h checked by the model), so the
        // casts are exact for any sane cell size.
        let index = f.map(|x| x.floor() as i64);
        let cell = match self.cell {
            Some(c) if c.index == index => c,
            _ => {
                let c = self.compute_cell(index)?;
                self.cell = Some(c);
                c
            }
        };
        let w: [f64; 3] = std::array::from_fn(|k| f[k] - index[k] as f64);
        let lerp = |a: Vector3<f64>, b: Vector3<f64>, t: f64| a + (b - a) * t;
        let c = &cell.corners;
        let at_lat = |i: usize| {
            lerp(
                lerp(c[i][0][0], c[i][0][1], w[2]),
                lerp(c[i][1][0], c[i][1][1], w[2]),
                w[1],
            )
        };
        Ok(lerp(at_lat(0), at_lat(1), w[0]))
    }

    fn compute_cell(&self, index: [i64; 3]) -> Result<GridCell, MagneticError> {
        let mut corners = [[[Vector3::zeros(); 2]; 2]; 2];
        for (i, plane) in corners.iter_mut().enumerate() {
            for (j, row) in plane.iter_mut().enumerate() {
                for (k, b) in row.iter_mut().enumerate() {
                    let corner = Geodetic {
                        lat_rad: ((index[0] + i as i64) as f64 * self.cell_deg).to_radians(),
                        lon_rad: ((index[1] + j as i64) as f64 * self.cell_deg).to_radians(),
                        h_m: (index[2] + k as i64) as f64 * self.cell_h_m,
                    };
                    *b = self.model.field_ned_nt(&corner)?;
                }
            }
        }
        Ok(GridCell { index, corners })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn wisconsin(h_m: f64) -> Geodetic {
        Geodetic {
            lat_rad: 45.0_f64.to_radians(),
            lon_rad: (-90.0_f64).to_radians(),
            h_m,
        }
    }

    #[test]
    fn invalid_years_are_rejected() {
        for y in [2024.99, 2030.0, 2031.0, 1900.0, f64::NAN, f64::INFINITY] {
            assert!(MagneticModel::new(y).is_err(), "{y}");
        }
        for y in [2025.0, 2026.5, 2029.999] {
            assert!(MagneticModel::new(y).is_ok(), "{y}");
        }
    }

    #[test]
    fn decimal_year_to_date() {
        let d = date_from_decimal_year(2026.0).unwrap();
        assert_eq!((d.year(), d.ordinal()), (2026, 1));
        let d = date_from_decimal_year(2026.5).unwrap();
        assert_eq!((d.year(), d.ordinal()), (2026, 183));
        let d = date_from_decimal_year(2028.9999).unwrap();
        assert_eq!((d.year(), d.ordinal()), (2028, 366));
    }

    #[test]
    fn wisconsin_field_matches_the_authors_box() {
        // docs/REFERENCES.md A3.6: WMM2015 at 2018-01-01, 3000 m, (45°N, 90°W):
        // (17455.7, −764.6, 52192.7) nT.
        let reference = Vector3::new(17_455.7, -764.6, 52_192.7);
        let p = wisconsin(3000.0);
        let b = MagneticModel::new(2026.0)
            .unwrap()
            .field_ned_nt(&p)
            .unwrap();
        // Direct comparison, 8 years later: secular variation over North America is at most
        // ~150 nT/yr per component (→ 1200 nT), plus ~200 nT of model-to-model differences
        // (WMM2015 vs WMM2025 at one date, ~the WMM 1σ error): 1400 nT per component.
        for i in 0..3 {
            assert!((b[i] - reference[i]).abs() < 1400.0, "{b:?}");
        }
        // Tighter: take WMM2025's own secular variation (from its values 2025.0 → 2029.99)
        // and extrapolate back to 2018.0. Remaining differences: model-to-model (~200 nT)
        // plus the secular acceleration ignored by the linear extrapolation,
        // ½·|ä|·t² ≤ ½·5 nT/yr²·(7 yr)² ≈ 120 nT: 320 nT.
        let b25 = MagneticModel::new(2025.0)
            .unwrap()
            .field_ned_nt(&p)
            .unwrap();
        let b30 = MagneticModel::new(2029.99)
            .unwrap()
            .field_ned_nt(&p)
            .unwrap();
        let sv = (b30 - b25) / 4.99;
        assert!(sv.amax() < 150.0, "{sv:?}");
        let b18 = b25 - 7.0 * sv;
        for i in 0..3 {
            assert!((b18[i] - reference[i]).abs() < 320.0, "{b18:?}");
        }
        // Magnitude ≈ 55,000 nT and dip ≈ 71.5° in the reference: the same 1400 nT bound on
        // |B|; dip = atan(Z/H) moves by ≤ (H + Z)·1400 nT/F² ≈ 1.85° for 1400 nT errors on H
        // and Z: 2°.
        assert!((b.norm() - reference.norm()).abs() < 1400.0);
        let dip = b.z.atan2(b.xy().norm()).to_degrees();
        let dip_ref = reference.z.atan2(reference.xy().norm()).to_degrees();
        assert!((dip - dip_ref).abs() < 2.0, "{dip} vs {dip_ref}");
    }

    #[test]
    fn height_is_passed_in_metres_above_the_ellipsoid() {
        // The field is dominated by the dipole, |B| ∝ r⁻³: climbing 3000 m lowers |B| by a
        // fraction ≈ 3·3000/6.37e6 = 0.141 %; higher-degree terms change the factor slightly
        // (the degree-n term scales as r^−(n+2)), so allow ±15 % of the predicted drop.
        let m = MagneticModel::new(2026.0).unwrap();
        let b0 = m.field_ned_nt(&wisconsin(0.0)).unwrap();
        let b3 = m.field_ned_nt(&wisconsin(3000.0)).unwrap();
        let predicted = b0.norm() * 3.0 * 3000.0 / 6.371e6;
        let drop = b0.norm() - b3.norm();
        assert!(
            (drop - predicted).abs() < 0.15 * predicted,
            "{drop} vs {predicted}"
        );
    }

    #[test]
    fn longitude_is_wrapped_and_bad_positions_error() {
        let m = MagneticModel::new(2026.0).unwrap();
        let mut p = wisconsin(3000.0);
        let b = m.field_ned_nt(&p).unwrap();
        p.lon_rad = 270.0_f64.to_radians();
        let b270 = m.field_ned_nt(&p).unwrap();
        assert!((b - b270).norm() < 0.1);
        p.lat_rad = f64::NAN;
        assert!(m.field_ned_nt(&p).is_err());
        let mut p = wisconsin(3000.0);
        p.lat_rad = 2.0;
        assert!(m.field_ned_nt(&p).is_err());
        let p = wisconsin(-5000.0);
        assert!(m.field_ned_nt(&p).is_err());
        let p = wisconsin(f64::NAN);
        assert!(m.field_ned_nt(&p).is_err());
    }

    #[test]
    fn grid_matches_the_model() {
        // Bound on the trilinear error: (Δ²/8)·|f''| per direction. Estimate |f''| from
        // second differences of the exact model over the test region (~30 nT/deg², i.e.
        // ~1.7 nT per 0.25° second difference); the tolerance is that bound plus the
        // crate's f32 rounding (~0.01 nT per corner).
        let m = MagneticModel::new(2026.0).unwrap();
        let mut grid = MagneticGrid::new(m.clone());
        let d = GRID_CELL_DEG;
        let at = |lat: f64, lon: f64, h: f64| {
            m.field_ned_nt(&Geodetic {
                lat_rad: lat.to_radians(),
                lon_rad: lon.to_radians(),
                h_m: h,
            })
            .unwrap()
        };
        let mut curv: f64 = 0.0;
        for (lat, lon) in [(44.0, -91.0), (45.0, -90.0), (46.0, -89.0)] {
            let c = at(lat, lon, 3000.0);
            curv = curv
                .max((at(lat + d, lon, 3000.0) - 2.0 * c + at(lat - d, lon, 3000.0)).amax())
                .max((at(lat, lon + d, 3000.0) - 2.0 * c + at(lat, lon - d, 3000.0)).amax());
        }
        // curv ≈ f''·Δ²: error ≤ 2·curv/8 (two directions) + height term + rounding.
        let tol = 2.0 * curv / 8.0 + 0.05;
        let mut worst: f64 = 0.0;
        for i in 0..400 {
            let x = f64::from(i);
            let pos = Geodetic {
                lat_rad: (44.0 + 0.0051 * x).to_radians(),
                lon_rad: (-91.0 + 0.0047 * x).to_radians(),
                h_m: 2500.0 + 2.9 * x,
            };
            let e = (grid.field_ned_nt(&pos).unwrap() - m.field_ned_nt(&pos).unwrap()).amax();
            worst = worst.max(e);
        }
        assert!(worst < tol, "{worst} nT vs {tol} nT");
    }

    #[test]
    fn grid_is_a_pure_function_of_position() {
        let m = MagneticModel::new(2026.0).unwrap();
        let p = wisconsin(3000.0);
        let mut g1 = MagneticGrid::new(m.clone());
        let b1 = g1.field_ned_nt(&p).unwrap();
        let mut g2 = MagneticGrid::new(m.clone());
        let far = Geodetic {
            lat_rad: 0.1,
            lon_rad: 2.0,
            h_m: 100.0,
        };
        g2.field_ned_nt(&far).unwrap();
        assert_eq!(g2.field_ned_nt(&p).unwrap(), b1);
        // Near the pole and on bad input it defers to the model.
        let pole = Geodetic {
            lat_rad: 89.5_f64.to_radians(),
            lon_rad: 0.3,
            h_m: 0.0,
        };
        assert_eq!(
            g1.field_ned_nt(&pole).unwrap(),
            m.field_ned_nt(&pole).unwrap()
        );
        let mut bad = p;
        bad.h_m = f64::NAN;
        assert!(g1.field_ned_nt(&bad).is_err());
        bad = p;
        bad.h_m = -5000.0;
        assert!(g1.field_ned_nt(&bad).is_err());
    }

    #[test]
    fn grid_is_seamless_across_the_antimeridian() {
        // Both ±π map to +180°, a cell corner, where the grid returns the exact model value.
        // Just either side of the seam the cells differ (indices 719 and −720), but both end
        // on corners evaluated at ±180°: the two sides agree within the crate's f32 rounding
        // (~0.01 nT per value) plus the field change over 2e-9 rad (~1e-5 nT).
        let m = MagneticModel::new(2026.0).unwrap();
        let mut grid = MagneticGrid::new(m.clone());
        let at = |lon_rad: f64| Geodetic {
            lat_rad: 45.0_f64.to_radians(),
            lon_rad,
            h_m: 3000.0,
        };
        let east = grid.field_ned_nt(&at(PI)).unwrap();
        assert_eq!(grid.field_ned_nt(&at(-PI)).unwrap(), east);
        assert!((east - m.field_ned_nt(&at(PI)).unwrap()).amax() < 0.05);
        let near_east = grid.field_ned_nt(&at(PI - 1e-9)).unwrap();
        let near_west = grid.field_ned_nt(&at(-PI + 1e-9)).unwrap();
        assert!(
            (near_east - near_west).amax() < 0.05,
            "{near_east} {near_west}"
        );
        assert!((near_east - east).amax() < 0.05);
    }
}
