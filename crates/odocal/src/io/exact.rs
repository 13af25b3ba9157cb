//! Fixed-length number arrays of manifests and settings files: exactly N
//! values, else an error saying how many the key holds (the key is named
//! by the caller's path to it).

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

/// What the four numbers of θ are, in order.
pub(crate) const THETA_VALUES: &str = "c_e, c_d, t_r, d";

/// The message for `got` numbers where exactly `n` are wanted, `names`
/// saying what they are: `expected 4 values c_e, c_d, t_r, d, got 3`.
pub(crate) fn count_message(n: usize, names: &str, got: usize) -> String {
    format!("expected {n} values {names}, got {got}")
}

/// Exactly `N` numbers, `names` saying what they are.
fn exact<'de, D: Deserializer<'de>, const N: usize>(d: D, names: &str) -> Result<[f64; N], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    let n = v.len();
    v.try_into().map_err(|_| D::Error::custom(count_message(N, names, n)))
}

/// θ `[c_e, c_d, t_r, d]`.
pub(crate) fn theta<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 4], D::Error> {
    exact(d, THETA_VALUES)
}

/// A lever arm `[x, y]`.
pub(crate) fn lever_arm<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 2]>, D::Error> {
    exact(d, "x, y").map(Some)
}

/// A geodetic origin `[lat_deg, lon_deg, h_m]`.
pub(crate) fn origin<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    exact(d, "lat_deg, lon_deg, h_m").map(Some)
}
