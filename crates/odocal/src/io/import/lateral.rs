//! Lateral acceleration a_y on the output grid: an IMU column, or derived
//! from the wheels (v·ω of the model at θ_0) or from the reference pose.

use std::ops::Range;

use super::bank::{self, Roll};
use super::manifest::{LateralAccelerationSpec, Manifest};
use super::signal;
use super::source::Stream;
use crate::model::{kinematics, Input, Theta};

/// What the lateral acceleration is computed from.
pub(crate) struct Inputs<'a> {
    /// Output sample times, s.
    pub grid: &'a [f64],
    /// Output step, s.
    pub h: f64,
    /// Wheel rotation speeds on the grid, rev/s.
    pub n_rl: &'a [f64],
    /// Wheel rotation speeds on the grid, rev/s.
    pub n_rr: &'a [f64],
    /// Reference pose on the grid.
    pub px: &'a [f64],
    /// Reference pose on the grid.
    pub py: &'a [f64],
    /// Reference heading on the grid.
    pub psi: &'a [f64],
    /// The kept parts (smoothing never crosses their ends).
    pub kept: &'a [Range<usize>],
    /// The roll from two antennas (on the wheel clock), when
    /// `[lateral_acceleration.bank]` is given.
    pub roll: Option<&'a Roll>,
}

/// a_y on the full grid and a description of its source: the IMU column,
/// or the derived kinematic a_y, turned into the lateral specific force
/// when a bank is given.
pub(crate) fn lateral_acceleration(
    m: &Manifest,
    streams: &std::collections::BTreeMap<String, Stream>,
    x: &Inputs<'_>,
    theta0: &Theta,
) -> (Vec<f64>, String) {
    let (mut a, mut desc) = kinematic(m, streams, x, theta0);
    if let (Some(b), Some(roll)) = (m.lateral_acceleration.bank(), x.roll) {
        let phi = bank::on_grid(roll, x.grid, x.h, x.kept, b.smoothing_s);
        for k in x.kept.iter().flat_map(|r| r.clone()) {
            a[k] = bank::specific_force(a[k], phi[k]);
        }
        let kept: Vec<f64> = x.kept.iter().flat_map(|r| r.clone()).map(|k| phi[k]).collect();
        let n = kept.len().max(1) as f64;
        let mean = kept.iter().sum::<f64>() / n;
        let max = kept.iter().fold(0.0_f64, |m, p| m.max(p.abs()));
        desc.push_str(&bank::description(b, roll.t.len() + roll.dropped, roll.dropped, mean, max));
    }
    (a, desc)
}

/// a_y before any bank correction.
fn kinematic(
    m: &Manifest,
    streams: &std::collections::BTreeMap<String, Stream>,
    x: &Inputs<'_>,
    theta0: &Theta,
) -> (Vec<f64>, String) {
    let (grid, h, n_grid) = (x.grid, x.h, x.grid.len());
    match &m.lateral_acceleration {
        LateralAccelerationSpec::Imu { stream, column, sign } => {
            let s = &streams[stream];
            let v: Vec<f64> = s.col(column).iter().map(|a| sign * a).collect();
            let cum = signal::cumulative_integral(&s.t, &v);
            (
                signal::interval_rates(&s.t, &cum, grid, h),
                format!("IMU column '{column}' of stream '{stream}' × {sign:+}, mean over each output interval"),
            )
        }
        LateralAccelerationSpec::FromWheels { smoothing_s, .. } => {
            let mut a = vec![0.0; n_grid];
            for k in 0..n_grid {
                // Fixed point through d·a_y (a single pass when d = 0).
                for _ in 0..3 {
                    let kin = kinematics(&Input { n_rl: x.n_rl[k], n_rr: x.n_rr[k], beta: 0.0, a_y: a[k] }, theta0);
                    a[k] = kin.speed_m_per_s * kin.yaw_rate_rad_per_s;
                }
            }
            signal::smooth_parts(&mut a, x.kept, *smoothing_s, h);
            (a, format!("from wheels: v·ω of the model at θ_0 ({theta0}), smoothed over {smoothing_s} s"))
        }
        LateralAccelerationSpec::FromPose { smoothing_s, .. } => {
            let mut a = vec![0.0; n_grid];
            for r in x.kept {
                for k in r.clone() {
                    let (k0, k1) = (k.saturating_sub(1).max(r.start), (k + 1).min(r.end - 1));
                    let dt = (k1 - k0) as f64 * h;
                    let v = (x.px[k1] - x.px[k0]).hypot(x.py[k1] - x.py[k0]) / dt;
                    let om = (x.psi[k1] - x.psi[k0]) / dt;
                    a[k] = v * om;
                }
            }
            signal::smooth_parts(&mut a, x.kept, *smoothing_s, h);
            (
                a,
                format!(
                    "from pose: speed × yaw rate of the reference, smoothed over {smoothing_s} s (feeds the \
                     reference yaw rate into the model through d)"
                ),
            )
        }
    }
}
