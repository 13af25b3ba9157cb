//! a_y's noise floor: tied to the white wheel noise, a_y's σ is never
//! below the white noise of the drive's own a_y readings.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::support::{batch_gn_all, input_of};
use crate::eiv::input::make_windows;
use crate::eiv::problem::Problem;
use crate::eiv::*;
use crate::sim::{simulate, NoiseOptions, SimOptions};

/// The readings' white noise comes off a smooth a_y to within a few per
/// cent, each part on its own: a step between two parts is no difference.
#[test]
fn the_readings_white_noise_comes_off_a_smooth_signal() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let n = 20_000;
    let sigma = 0.12;
    let a_y: Vec<f64> = (0..n)
        .map(|k| {
            let t = k as f64 * 0.025;
            // Two parts whose levels differ by 40 m/s², and a slow swing.
            let level = if k < n / 2 { 0.0 } else { 40.0 };
            level + 2.0 * (0.3 * t).sin() + sigma * rng.sample::<f64, _>(StandardNormal)
        })
        .collect();
    let zeros = vec![0.0; n];
    let parts = [0..n / 2, n / 2..n];
    let input = EivInput {
        sample_time_s: 0.025,
        parts: &parts,
        px: &zeros,
        py: &zeros,
        psi: &zeros,
        n_rl: &zeros,
        n_rr: &zeros,
        beta: &zeros,
        a_y: &a_y,
        reference_measured: None,
    };
    let found = input.a_y_sample_noise();
    assert!((found / sigma - 1.0).abs() < 0.03, "found {found} for σ {sigma}");
    let clean = vec![1.5; n];
    assert!(EivInput { a_y: &clean, ..input }.a_y_sample_noise() == 0.0);
}

/// Tied to the white wheel noise, a_y's variance is its floor where η_0
/// would take it lower, and then does not follow η_0; above the floor, and
/// with a_y's noise stated, the floor does nothing.
#[test]
// The floor's variance is set, not computed: compared exactly on purpose.
#[allow(clippy::float_cmp)]
fn the_floor_holds_a_y_where_the_tie_would_take_it_lower() {
    let out = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(1) }).expect("sim");
    let input = input_of(&out.drive);
    let windows = || make_windows(input.parts, 6000);
    let floor = 0.1;
    let opts = EivOptions::default().with_resolved_readings(None, Some(floor));
    let prob = Problem::new(&input, windows(), &opts);
    let low = prob.variances(&[-6.0, 0.0, 0.0, 0.0, 0.0, 0.0], false);
    assert!((low.a_y, low.a_y_scaled) == (floor * floor, false), "{} {}", low.a_y, low.a_y_scaled);
    // 0.05 m/s² × e^{η_0/2} lies above the floor from η_0 = 2 ln 2.
    let high = prob.variances(&[2.0, 0.0, 0.0, 0.0, 0.0, 0.0], false);
    assert!(high.a_y_scaled && high.a_y > floor * floor, "{} {}", high.a_y, high.a_y_scaled);
    let stated = EivOptions { lateral_noise: LateralNoise::Stated, ..EivOptions::default() };
    let stated = stated.with_resolved_readings(None, Some(floor));
    assert!(stated.research.a_y_sigma_floor.is_none(), "a stated a_y noise has no floor");
}

/// Random noise world 207 (clean wheels, 0.02 % white; an a_y with
/// 0.146 m/s² of white noise): tied to the wheels' white noise, a_y's σ
/// goes to 0.6 mm/s², a_y is taken as exact and d, which multiplies it, is
/// pulled toward 0: −9.6 σ on this 6 km drive. With the floor at the
/// readings' own noise d is within 2 σ, and the fitted model grants a_y
/// the noise it has.
#[test]
// The reported σ is the floor itself: compared exactly on purpose.
#[allow(clippy::float_cmp)]
fn a_noisy_a_y_beside_clean_wheels_keeps_d() {
    let noise: NoiseOptions = "random:207".parse().expect("world");
    let out = simulate(&SimOptions { length_km: 6.0, noise, ..SimOptions::paper(207) }).expect("sim");
    let input = input_of(&out.drive);
    let start = batch_gn_all(&out.drive);
    let truth = out.sidecar.theta_true;
    let z_d = |opts: &EivOptions| {
        let r = estimate(&input, &start, opts).expect("eiv");
        ((r.theta.d - truth.d) / r.sigma[3], r)
    };
    let (with_floor, r) = z_d(&EivOptions::default());
    let floor = r.a_y_noise_floor.expect("a floor read off the readings");
    assert!((floor / 0.146 - 1.0).abs() < 0.05, "floor {floor}");
    assert!(r.noise.lateral_acceleration_sigma_m_per_s2 == floor, "{}", r.noise.lateral_acceleration_sigma_m_per_s2);
    let mut off = EivOptions::default();
    off.research.a_y_floor_from_readings = false;
    let (without, r_off) = z_d(&off);
    assert!(r_off.a_y_noise_floor.is_none());
    assert!(with_floor.abs() < 2.0, "d {with_floor:+.2} σ with the floor");
    assert!(without < -4.0, "d {without:+.2} σ without the floor: the drive does not show what the floor cures");
}
