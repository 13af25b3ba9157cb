//! WGS84 geodetic ↔ ECEF ↔ local ENU.

use nalgebra::{Matrix3, Vector3};

/// WGS84 semi-major axis, m.
const A: f64 = 6_378_137.0;
/// WGS84 flattening.
const F: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared.
const E2: f64 = F * (2.0 - F);

/// Geodetic (lat, lon in degrees, ellipsoidal height in m) to ECEF, m.
pub(crate) fn geodetic_to_ecef(lat_deg: f64, lon_deg: f64, h_m: f64) -> Vector3<f64> {
    let (slat, clat) = lat_deg.to_radians().sin_cos();
    let (slon, clon) = lon_deg.to_radians().sin_cos();
    let n = A / (1.0 - E2 * slat * slat).sqrt();
    Vector3::new((n + h_m) * clat * clon, (n + h_m) * clat * slon, (n * (1.0 - E2) + h_m) * slat)
}

/// ECEF to geodetic (lat, lon deg, h m), by fixed-point iteration (converges
/// to well below a millimetre near the Earth's surface).
#[cfg_attr(not(test), allow(dead_code))]
pub(crate) fn ecef_to_geodetic(p: &Vector3<f64>) -> (f64, f64, f64) {
    let lon = p.y.atan2(p.x);
    let r = p.x.hypot(p.y);
    let mut lat = p.z.atan2(r * (1.0 - E2));
    let mut h = 0.0;
    for _ in 0..10 {
        let s = lat.sin();
        let n = A / (1.0 - E2 * s * s).sqrt();
        h = r / lat.cos() - n;
        lat = p.z.atan2(r * (1.0 - E2 * n / (n + h)));
    }
    (lat.to_degrees(), lon.to_degrees(), h)
}

/// A local east-north-up frame at a geodetic origin.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Enu {
    origin: Vector3<f64>,
    /// Rows: east, north, up unit vectors in ECEF.
    rot: Matrix3<f64>,
}

impl Enu {
    /// The frame at (lat, lon deg, h m).
    pub(crate) fn new(lat_deg: f64, lon_deg: f64, h_m: f64) -> Enu {
        let (slat, clat) = lat_deg.to_radians().sin_cos();
        let (slon, clon) = lon_deg.to_radians().sin_cos();
        let rot = Matrix3::new(-slon, clon, 0.0, -slat * clon, -slat * slon, clat, clat * clon, clat * slon, slat);
        Enu { origin: geodetic_to_ecef(lat_deg, lon_deg, h_m), rot }
    }

    /// Geodetic to ENU `[e, n, u]`, m.
    pub(crate) fn enu_of(&self, lat_deg: f64, lon_deg: f64, h_m: f64) -> Vector3<f64> {
        self.rot * (geodetic_to_ecef(lat_deg, lon_deg, h_m) - self.origin)
    }

    /// ENU to geodetic (lat, lon deg, h m).
    #[cfg_attr(not(test), allow(dead_code))]
    pub(crate) fn geodetic_of(self, enu: &Vector3<f64>) -> (f64, f64, f64) {
        ecef_to_geodetic(&(self.origin + self.rot.transpose() * enu))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Round-trip tolerance, m: the iteration converges far below this.
    const ROUND_TRIP_TOL_M: f64 = 1e-6;

    #[test]
    fn enu_round_trip_and_axes() {
        let enu = Enu::new(40.442130345, -79.760361018, 322.692);
        for p in [[0.0, 0.0, 0.0], [1000.0, -2000.0, 5.0], [-10954.0, -1691.0, -30.0]] {
            let v = Vector3::new(p[0], p[1], p[2]);
            let (lat, lon, h) = enu.geodetic_of(&v);
            let back = enu.enu_of(lat, lon, h);
            assert!((back - v).norm() < ROUND_TRIP_TOL_M, "{v} -> {back}");
        }
        // 0.001° of latitude north is ~111 m north, ~0 east.
        let p = enu.enu_of(40.443130345, -79.760361018, 322.692);
        assert!((p.y - 111.04).abs() < 0.1 && p.x.abs() < 1e-6, "{p}");
        // Longitude east is +x.
        let p = enu.enu_of(40.442130345, -79.759361018, 322.692);
        assert!((p.x - 84.8).abs() < 0.2 && p.y.abs() < 0.01, "{p}");
    }
}
