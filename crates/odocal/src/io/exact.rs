//! Fixed-length number arrays of manifests and settings files: exactly N
//! values, else an error saying how many the key holds (the key is named
//! by the caller's path to it).

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

/// Exactly `N` numbers, `names` saying what they are.
fn exact<'de, D: Deserializer<'de>, const N: usize>(d: D, names: &str) -> Result<[f64; N], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    let n = v.len();
    v.try_into().map_err(|_| D::Error::custom(format!("expected {N} values {names}, got {n}")))
}

/// θ `[c_e, c_d, t_r, d]`.
pub(crate) fn theta<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 4], D::Error> {
    exact(d, "c_e, c_d, t_r, d")
}

/// A lever arm `[x, y]`.
pub(crate) fn lever_arm<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
    exact(d, "x, y").map(Some)
}

/// A geodetic origin `[lat_deg, lon_deg, h_m]`.
pub(crate) fn origin<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    exact(d, "lat_deg, lon_deg, h_m").map(Some)
}
