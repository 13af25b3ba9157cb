//! The reference heading's white noise read off its readings: part of the
//! heading's variance wherever the fit estimates that noise.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::support::{batch_gn_all, input_of};
use crate::eiv::input::make_windows;
use crate::eiv::problem::Problem;
use crate::eiv::*;
use crate::sim::{simulate, SimOptions};

/// A turning vehicle's heading: a yaw rate that swings between ±0.5 rad/s
/// every few seconds, integrated at 40 Hz, with white noise of `sigma`.
fn turning_heading(n: usize, sigma: f64, seed: u64) -> Vec<f64> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let ts = 0.025;
    let mut psi = 0.0;
    (0..n)
        .map(|k| {
            let t = k as f64 * ts;
            psi += ts * 0.5 * (0.9 * t).sin() * (0.23 * t).cos();
            psi + sigma * rng.sample::<f64, _>(StandardNormal)
        })
        .collect()
}

fn input_with<'a>(psi: &'a [f64], zeros: &'a [f64], parts: &'a [std::ops::Range<usize>]) -> EivInput<'a> {
    EivInput {
        sample_time_s: 0.025,
        parts,
        px: zeros,
        py: zeros,
        psi,
        n_rl: zeros,
        n_rr: zeros,
        beta: zeros,
        a_y: zeros,
        reference_measured: None,
    }
}

/// The white noise comes off a turning heading to within a few per cent,
/// also when the reference was measured at every fourth sample only and
/// interpolated between (only the measured samples count), and across
/// the ±π wrap; a clean heading gives a hundredth of it (its motion's
/// share).
#[test]
fn the_readings_white_noise_comes_off_a_turning_heading() {
    let n = 24_000;
    let sigma = 3e-4;
    let zeros = vec![0.0; n];
    let parts = [0..n / 2, n / 2..n];
    let noisy = turning_heading(n, sigma, 5);
    let found = input_with(&noisy, &zeros, &parts).heading_sample_noise();
    assert!((found / sigma - 1.0).abs() < 0.05, "found {found} for σ {sigma}");

    // Measured at every fourth sample, linear in between.
    let measured: Vec<bool> = (0..n).map(|k| k % 4 == 0).collect();
    let interpolated: Vec<f64> = (0..n)
        .map(|k| {
            let (a, b) = (k - k % 4, (k - k % 4 + 4).min(n - 1));
            let w = if b > a { (k - a) as f64 / (b - a) as f64 } else { 0.0 };
            noisy[a] + w * (noisy[b] - noisy[a])
        })
        .collect();
    let sparse = EivInput { reference_measured: Some(&measured), ..input_with(&interpolated, &zeros, &parts) };
    let found = sparse.heading_sample_noise();
    assert!((found / sigma - 1.0).abs() < 0.08, "found {found} at every fourth sample for σ {sigma}");
    // Without the mask the interpolated samples hide most of the noise.
    let unmarked = input_with(&interpolated, &zeros, &parts).heading_sample_noise();
    assert!(unmarked < 0.5 * sigma, "interpolated readings read as measured gave {unmarked}");

    // Wrapped into (−π, π] as a reference may log it.
    let wrapped: Vec<f64> =
        noisy.iter().map(|p| (p + 3.0).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI).collect();
    let found_wrapped = input_with(&wrapped, &zeros, &parts).heading_sample_noise();
    assert!((found_wrapped / sigma - 1.0).abs() < 0.05, "found {found_wrapped} on the wrapped heading");

    let clean = turning_heading(n, 0.0, 5);
    let none = input_with(&clean, &zeros, &parts).heading_sample_noise();
    assert!(none < 0.01 * sigma, "a clean heading gave {none}");
}

/// Where the heading's white noise is estimated, the readings' variance is
/// added to it in R and carries no η derivative (the scale fits what lies
/// above it); with the noise held, or the heading's level known, it is
/// not added: a held model states the whole level (the bias correction's
/// replicates hold the fitted total).
#[test]
// The floor's variance is set, not computed: compared exactly on purpose.
#[allow(clippy::float_cmp)]
fn the_readings_heading_noise_is_added_where_the_heading_noise_is_estimated() {
    let out = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(1) }).expect("sim");
    let input = input_of(&out.drive);
    let windows = || make_windows(input.parts, 6000);
    let floor = 4e-4;
    let eta = [0.0, 0.0, 0.0, 0.0, 0.0, -3.0];
    let opts = EivOptions::default().with_heading_floor(Some(floor));
    assert_eq!(opts.research.heading_white_sigma_floor, Some(floor));
    let v = Problem::new(&input, windows(), &opts).variances(&eta, false);
    let without = Problem::new(&input, windows(), &EivOptions::default()).variances(&eta, false);
    assert_eq!(v.heading_white_floor, floor * floor);
    assert_eq!(v.pose, without.pose, "the scaled part does not change");
    for held in [EivOptions { fix_noise: true, ..EivOptions::default() }, {
        let mut known = EivOptions::default();
        known.hold_known(&[NoiseSource::HeadingWhite]);
        known
    }] {
        assert!(!held.heading_floor_applies());
        let mut given = held.clone();
        given.research.heading_white_sigma_floor = Some(floor);
        let v = Problem::new(&input, windows(), &given).variances(&eta, false);
        assert_eq!(v.heading_white_floor, 0.0, "a held heading noise gets no floor");
    }
}

/// A fit reads the floor off the drive, reports it, and never reports a
/// heading white noise below it; with the option off there is none.
#[test]
fn a_fit_reports_the_heading_noise_of_its_readings() {
    let out = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(2) }).expect("sim");
    let input = input_of(&out.drive);
    let start = batch_gn_all(&out.drive);
    let r = estimate(&input, &start, &EivOptions::default()).expect("eiv");
    let floor = r.heading_noise_floor.expect("a floor read off the readings");
    let truth = out.sidecar.settings.noise.heading_white_sigma_rad;
    assert!((floor / truth - 1.0).abs() < 0.15, "floor {floor} against the simulated {truth}");
    assert!(r.noise.heading_white_sigma_rad >= floor, "{} below {floor}", r.noise.heading_white_sigma_rad);
    let mut off = EivOptions::default();
    off.research.heading_floor_from_readings = false;
    let r_off = estimate(&input, &start, &off).expect("eiv");
    assert!(r_off.heading_noise_floor.is_none());
}

/// With [`EivOptions::heading_white_at_floor`] the readings' floor is the
/// whole of the heading's white noise: the starting level dropped, its
/// scale held, the floor still in R. A level the user holds as known gets
/// no floor, with the option or without.
#[test]
#[allow(clippy::float_cmp)] // set, not computed
fn at_the_floor_the_readings_are_the_whole_heading_noise() {
    let out = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(1) }).expect("sim");
    let input = input_of(&out.drive);
    let windows = || make_windows(input.parts, 6000);
    let floor = 4e-4;
    let at_floor = EivOptions { heading_white_at_floor: true, ..EivOptions::default() };
    let opts = at_floor.clone().with_heading_floor(Some(floor));
    let heading = NoiseSource::HeadingWhite.index();
    assert!(opts.eta_held[heading], "the scale is held");
    assert_eq!(opts.noise.heading_white_sigma_rad, 0.0);
    assert!(opts.heading_floor_applies() && opts.heading_floor_given());
    let eta = [0.0, 0.0, 0.0, 0.0, 0.0, 2.0];
    let v = Problem::new(&input, windows(), &opts).variances(&eta, false);
    assert_eq!(v.heading_white_floor, floor * floor);
    assert_eq!(v.pose[2], 0.0, "no level above the readings'");
    let plain = EivOptions::default().with_heading_floor(Some(floor));
    assert!(Problem::new(&input, windows(), &plain).variances(&eta, false).pose[2] > 0.0);

    let mut known = at_floor;
    known.hold_known(&[NoiseSource::HeadingWhite]);
    let known = known.with_heading_floor(Some(floor));
    assert_eq!(known.research.heading_white_sigma_floor, None, "a known level reads no floor");
    assert!(!known.heading_floor_applies());
    assert_eq!(known.noise.heading_white_sigma_rad, EivOptions::default().noise.heading_white_sigma_rad);
}

/// A fit at the floor reports the readings' level as the heading's white
/// noise, to the bit, with its scale held at 0 and no σ; with the noise
/// held there is no floor and the option does nothing.
#[test]
#[allow(clippy::float_cmp)] // hypot(0, f) is f
fn a_fit_at_the_floor_reports_the_readings_level() {
    let out = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(2) }).expect("sim");
    let input = input_of(&out.drive);
    let start = batch_gn_all(&out.drive);
    let at_floor = EivOptions { heading_white_at_floor: true, ..EivOptions::default() };
    let r = estimate(&input, &start, &at_floor).expect("eiv");
    assert!(r.heading_white_at_floor);
    let floor = r.heading_noise_floor.expect("a floor read off the readings");
    assert_eq!(r.noise.heading_white_sigma_rad, floor);
    let heading = NoiseSource::HeadingWhite.index();
    assert_eq!((r.eta[heading], r.eta_sigma[heading]), (0.0, 0.0));
    let free = estimate(&input, &start, &EivOptions::default()).expect("eiv");
    assert!(!free.heading_white_at_floor);
    assert_ne!(free.theta, r.theta, "the two fits differ");

    let held = estimate(&input, &start, &EivOptions { fix_noise: true, ..at_floor }).expect("eiv");
    assert!(!held.heading_white_at_floor && held.heading_noise_floor.is_none());
}
