//! The wheel rotations that scale the relative wheel noise with the fitted
//! input ([`WheelNoiseScale`](crate::eiv::WheelNoiseScale)): ñ itself, its
//! moving average over ±K samples within the window (nearly independent of
//! the white error of sample i), or the rotations the reference implies.

use super::Variances;
use crate::eiv::{EivInput, Window};
use crate::model::{wrap_angle, Theta};

/// The smoothed rotations of one window (empty without smoothing).
pub(super) struct NoiseRotations {
    /// Half-width K of the smoothing, samples (0: ñ itself).
    half: usize,
    left: Vec<f64>,
    right: Vec<f64>,
}

impl NoiseRotations {
    /// The rotations of `window` as `v` asks (`noise_input_half_width`,
    /// `noise_input_from_reference`; only with the fitted-input scale and
    /// the covariance following θ).
    pub(super) fn new(input: &EivInput<'_>, window: &Window, v: &Variances, follows: bool, theta_ref: &Theta) -> Self {
        let half = if v.fitted_input && follows { v.noise_input_half_width } else { 0 };
        let (left, right) = if half > 0 && v.noise_input_from_reference {
            reference_rotations(input, window, half, theta_ref)
        } else {
            (moving_average(input.n_rl, window, half), moving_average(input.n_rr, window, half))
        };
        NoiseRotations { half, left, right }
    }

    /// The rotations at offset `k` into the window, given the measured ones.
    #[inline(always)]
    pub(super) fn at(&self, k: usize, nl: f64, nr: f64) -> (f64, f64) {
        if self.half > 0 {
            (self.left[k], self.right[k])
        } else {
            (nl, nr)
        }
    }
}

/// The moving average of `n` over ±`half` samples within the window (empty
/// when `half` is 0).
fn moving_average(n: &[f64], window: &Window, half: usize) -> Vec<f64> {
    if half == 0 {
        return Vec::new();
    }
    let (a0, a1) = (window.start, window.end);
    let mut prefix = Vec::with_capacity(a1 - a0 + 1);
    prefix.push(0.0);
    for k in a0..a1 {
        let last = prefix[prefix.len() - 1];
        prefix.push(last + n[k]);
    }
    (a0..a1)
        .map(|k| {
            let (lo, hi) = (k.saturating_sub(half).max(a0), (k + half + 1).min(a1));
            (prefix[hi - a0] - prefix[lo - a0]) / (hi - lo) as f64
        })
        .collect()
}

/// Wheel rotations implied by the reference at θ_ref: speed and yaw rate by
/// central differences over ±K samples (within the window),
/// `C_l n_l = v − ψ̇ t_r/2, C_r n_r = v + ψ̇ t_r/2` (rev/s), with the sign of
/// the measured rotation (independent of the wheel noise).
fn reference_rotations(input: &EivInput<'_>, window: &Window, half: usize, theta_ref: &Theta) -> (Vec<f64>, Vec<f64>) {
    let ts = input.sample_time_s;
    let (a0, a1) = (window.start, window.end);
    let mut l = Vec::with_capacity(a1 - a0);
    let mut r = Vec::with_capacity(a1 - a0);
    for k in a0..a1 {
        let (lo, hi) = (k.saturating_sub(half).max(a0), (k + half).min(a1));
        let dt = (hi - lo).max(1) as f64 * ts;
        let speed = (input.px[hi] - input.px[lo]).hypot(input.py[hi] - input.py[lo]) / dt;
        let yaw_rate = wrap_angle(input.psi[hi] - input.psi[lo]) / dt;
        let (c_l, c_r) = theta_ref.wheel_circumferences(input.a_y[k]);
        let nl_ = (speed - 0.5 * yaw_rate * theta_ref.t_r) / c_l;
        let nr_ = (speed + 0.5 * yaw_rate * theta_ref.t_r) / c_r;
        l.push(nl_.abs() * input.n_rl[k].signum() * f64::from(u8::from(input.n_rl[k] != 0.0)));
        r.push(nr_.abs() * input.n_rr[k].signum() * f64::from(u8::from(input.n_rr[k] != 0.0)));
    }
    (l, r)
}
