//! The autopilots' local horizontal frame (docs/REFERENCES.md M2.2): PX4 (and ArduPilot's
//! `Location` offsets for small distances) express local NED positions by an azimuthal
//! equidistant projection on a sphere of radius [`EARTH_RADIUS_M`] around a reference point,
//! with down = reference altitude − altitude. A companion that publishes `ODOMETRY` in
//! `MAV_FRAME_LOCAL_NED` must use the same projection, or its position drifts away from the
//! autopilot's by the difference between the sphere and the ellipsoid (metres at 100 km).
//! Formulas: Snyder, *Map Projections — A Working Manual* (USGS 1395), azimuthal equidistant.

use super::wgs84::Geodetic;

/// Radius of the projection sphere, m (PX4 `CONSTANTS_RADIUS_OF_EARTH`).
pub const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// An azimuthal equidistant projection about a reference point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapProjection {
    ref_lat_rad: f64,
    ref_lon_rad: f64,
    ref_h_m: f64,
    sin_ref_lat: f64,
    cos_ref_lat: f64,
}

impl MapProjection {
    /// Projection about `origin` (its height is the local frame's zero of "down").
    pub fn new(origin: &Geodetic) -> Self {
        Self {
            ref_lat_rad: origin.lat_rad,
            ref_lon_rad: origin.lon_rad,
            ref_h_m: origin.h_m,
            sin_ref_lat: origin.lat_rad.sin(),
            cos_ref_lat: origin.lat_rad.cos(),
        }
    }

    /// The reference point.
    pub fn origin(&self) -> Geodetic {
        Geodetic {
            lat_rad: self.ref_lat_rad,
            lon_rad: self.ref_lon_rad,
            h_m: self.ref_h_m,
        }
    }

    /// Local `[north, east, down]` of `p`, m.
    pub fn project(&self, p: &Geodetic) -> [f64; 3] {
        let (sin_lat, cos_lat) = p.lat_rad.sin_cos();
        let d_lon = p.lon_rad - self.ref_lon_rad;
        let (sin_d_lon, cos_d_lon) = d_lon.sin_cos();
        let cos_c =
            (self.sin_ref_lat * sin_lat + self.cos_ref_lat * cos_lat * cos_d_lon).clamp(-1.0, 1.0);
        let c = cos_c.acos();
        // c / sin c → 1 as c → 0 (the reference point itself).
        let k = if c > 1e-12 { c / c.sin() } else { 1.0 };
        let north = k
            * (self.cos_ref_lat * sin_lat - self.sin_ref_lat * cos_lat * cos_d_lon)
            * EARTH_RADIUS_M;
        let east = k * cos_lat * sin_d_lon * EARTH_RADIUS_M;
        [north, east, self.ref_h_m - p.h_m]
    }

    /// Geodetic point of local `[north, east, down]`, m (inverse of [`MapProjection::project`]).
    pub fn reproject(&self, ned_m: &[f64; 3]) -> Geodetic {
        let x = ned_m[0] / EARTH_RADIUS_M;
        let y = ned_m[1] / EARTH_RADIUS_M;
        let c = x.hypot(y);
        let (lat_rad, lon_rad) = if c > 1e-15 {
            let (sin_c, cos_c) = c.sin_cos();
            let lat = (cos_c * self.sin_ref_lat + x * sin_c * self.cos_ref_lat / c)
                .clamp(-1.0, 1.0)
                .asin();
            let lon = self.ref_lon_rad
                + (y * sin_c).atan2(c * self.cos_ref_lat * cos_c - x * self.sin_ref_lat * sin_c);
            (lat, lon)
        } else {
            (self.ref_lat_rad, self.ref_lon_rad)
        };
        Geodetic {
            lat_rad,
            lon_rad: crate::math::angle::wrap_pi(lon_rad),
            h_m: self.ref_h_m - ned_m[2],
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn geo(lat_deg: f64, lon_deg: f64, h_m: f64) -> Geodetic {
        Geodetic {
            lat_rad: lat_deg.to_radians(),
            lon_rad: lon_deg.to_radians(),
            h_m,
        }
    }

    #[test]
    fn distances_along_a_meridian_and_the_parallel_are_arc_lengths_on_the_sphere() {
        let proj = MapProjection::new(&geo(45.0, -75.0, 100.0));
        // 0.1° of latitude north: arc length R·Δφ exactly (meridians are straight lines).
        let [n, e, d] = proj.project(&geo(45.1, -75.0, 150.0));
        assert!((n - EARTH_RADIUS_M * 0.1_f64.to_radians()).abs() < 1e-6);
        assert!(e.abs() < 1e-6);
        assert!((d + 50.0).abs() < 1e-12);
        // A point due east: the projected distance is the great-circle distance.
        let p = geo(45.0, -74.0, 100.0);
        let [n, e, _] = proj.project(&p);
        let (a, b) = (45.0_f64.to_radians(), 1.0_f64.to_radians());
        let great_circle =
            EARTH_RADIUS_M * (a.sin() * a.sin() + a.cos() * a.cos() * b.cos()).acos();
        assert!((n.hypot(e) - great_circle).abs() < 1e-6);
        assert!(n > 0.0, "the great circle bulges poleward of the parallel");
    }

    #[test]
    fn reprojection_inverts_the_projection_over_the_scenario_reach() {
        let origin = geo(-33.0, 151.0, 20.0);
        let proj = MapProjection::new(&origin);
        for (dn_km, de_km) in [
            (0.0, 0.0),
            (1.0, 0.0),
            (-125.0, 80.0),
            (60.0, -125.0),
            (0.001, 0.002),
        ] {
            let ned = [dn_km * 1e3, de_km * 1e3, -500.0];
            let back = proj.project(&proj.reproject(&ned));
            for i in 0..3 {
                assert!((back[i] - ned[i]).abs() < 1e-6, "{ned:?} → {back:?}");
            }
        }
        assert_eq!(proj.origin(), origin);
    }
}
