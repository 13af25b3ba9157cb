//! The verdict's check of batch Gauss-Newton's errors-in-variables bias
//! ([`crate::VerdictReason::InputNoiseBias`]).
//!
//! Batch G-N takes the measured wheel rotations as exact. Their white noise
//! makes the dead-reckoned heading a random walk, and the fit answers it
//! with a wider track and a smaller c_e (a wider t_r damps the walk;
//! docs/method.md, "Batch Gauss-Newton's input-noise bias"): a bias that
//! grows with the noise variance and that none of the fit's σ covers. The
//! check predicts it on the drive itself by SIMEX
//! (simulation-extrapolation; Cook and Stefanski, JASA 1994):
//!
//! 1. **The drive's wheel noise.** Over windows of [`WINDOWS_S`] of the
//!    calibration segments, the wheel-odometry heading change at θ̂ minus
//!    the reference's has variance `a + σ_w² · Σ 2 (v Δt / t_r)²`: `a`
//!    the reference's white heading noise (twice), the sum over the
//!    window's samples what white relative noise σ_w on each wheel adds.
//!    Least squares over the windows of both lengths gives σ_w². Noise that
//!    does not accumulate in the heading (encoder quantisation) falls into
//!    `a`, as it biases nothing; slow heading drift of the reference and
//!    unmodelled yaw add to the slope, so the check predicts more bias
//!    rather than less.
//! 2. **The same noise once more.** White relative noise σ_w is added to
//!    both wheels' rotations and θ refitted from θ̂ by one Gauss-Newton
//!    step (the calibration's free parameters and extrinsics; the move is
//!    of the order of θ's σ, where one step is accurate to first order),
//!    in [`PAIRS`] antithetic pairs (+e, −e: the scatter linear in e
//!    cancels). The bias grows linearly with the noise variance, so
//!    doubling the variance moves θ by about the bias the drive already
//!    has: the mean refit less the same step on the unchanged data.
//!
//! The result is doubtful when the predicted bias of a free parameter
//! exceeds [`MAX_BIAS_SIGMAS`] of its σ for the next drive. EIV (the
//! default method) models this noise, and is not checked. On simulated
//! drives with known noise (docs/validation.md, "Batch Gauss-Newton's
//! input-noise bias") the predicted t_r bias averaged the batch G-N error's mean to
//! within its scatter on every noise preset.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;

use crate::assess::trust::VerdictReason;
use crate::drive::segment::SegmentData;
use crate::drive::Drive;
use crate::identify::{gauss_newton_step_drives, IdentifyOptions};
use crate::model::extrinsics::Extrinsics;
use crate::model::{kinematics, wrap_angle, Theta};

use super::checks::largest_against_sigma;
use super::report::MethodDetail;
use super::{CalibrationOptions, Selection};

/// The predicted bias must exceed this many of the parameter's σ for the
/// next drive.
pub(crate) const MAX_BIAS_SIGMAS: f64 = 1.0;
/// Antithetic pairs of noise draws.
const PAIRS: usize = 2;
/// The window lengths of the wheel-noise estimate, s.
pub(crate) const WINDOWS_S: [f64; 2] = [1.0, 4.0];
/// Fewest windows (both lengths together) for a wheel-noise estimate.
const MIN_WINDOWS: usize = 20;
/// Keeps the check's noise stream apart from other uses of the seed.
const STREAM: u64 = 0x51_4d_45_58; // "SIMEX"

/// The check's reason (module docs): none for other methods, for a drive
/// whose wheel noise does not show, or when a refit fails (the check is
/// then left out rather than failing the calibration).
pub(super) fn input_noise_bias_reason(
    drive: &Drive,
    selection: &Selection,
    (theta, detail): (&Theta, &MethodDetail),
    extrinsics: &Extrinsics,
    opts: &CalibrationOptions,
    sigma_next: &[Option<f64>; 4],
) -> Option<VerdictReason> {
    if !matches!(detail, MethodDetail::BatchGn(_)) {
        return None;
    }
    let data: Vec<SegmentData<'_>> = selection.segments.iter().map(|s| SegmentData::new(drive, s)).collect();
    let sigma_w = wheel_white_noise(&data, theta)?;
    let identify = IdentifyOptions { extrinsics: *extrinsics, ..selection.identify(opts) };
    let bias = simex_bias(&data, drive.drive_starts(), theta, &identify, sigma_w, opts.seed)?;
    let (param, b, sigma, sigmas) = largest_against_sigma(selection.free, sigma_next, |p| bias[p.index()])?;
    (sigmas > MAX_BIAS_SIGMAS).then_some(VerdictReason::InputNoiseBias {
        param,
        estimate: param.value(theta),
        bias: b,
        sigma,
        sigmas,
        wheel_white_rel_sigma: sigma_w,
    })
}

research_pub! {
    /// σ_w, the white relative noise of each wheel's rotation, from the
    /// heading's random walk against the reference over the segments (module
    /// docs, step 1). None when the segments hold too few windows or no
    /// accumulating noise shows.
    fn wheel_white_noise(data: &[SegmentData<'_>], theta: &Theta) -> Option<f64> {
        let dt = data.first()?.sample_time_s;
        let mut rows: Vec<(f64, f64)> = Vec::new();
        for window_s in WINDOWS_S {
            let len = ((window_s / dt).round() as usize).max(1);
            let start = rows.len();
            for s in data {
                for i in (0..s.steps() / len).map(|w| w * len) {
                    let (mut turn, mut x) = (0.0, 0.0);
                    for j in i..i + len {
                        let k = kinematics(&s.input(j), theta);
                        turn += k.yaw_rate_rad_per_s * dt;
                        x += 2.0 * (k.speed_m_per_s * dt / theta.t_r).powi(2);
                    }
                    let r = wrap_angle(turn - (s.psi[i + len] - s.psi[i]));
                    if r.is_finite() && x.is_finite() {
                        rows.push((x, r));
                    }
                }
            }
            // Each length's mean residual (a heading rate the fit left) is not noise.
            let n = rows.len() - start;
            let mean = rows[start..].iter().map(|p| p.1).sum::<f64>() / n.max(1) as f64;
            rows[start..].iter_mut().for_each(|p| p.1 = (p.1 - mean).powi(2));
        }
        if rows.len() < MIN_WINDOWS {
            return None;
        }
        let n = rows.len() as f64;
        let (mx, my) = rows.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
        let (sxx, sxy) = rows.iter().fold((0.0, 0.0), |a, p| (a.0 + (p.0 - mx).powi(2), a.1 + (p.0 - mx) * (p.1 - my)));
        let slope = sxy / sxx;
        (slope > 0.0 && slope.is_finite()).then(|| slope.sqrt())
    }
}

research_pub! {
    /// The predicted bias of θ (module docs, step 2): the mean refit on the
    /// wheel rotations with white relative noise `sigma_w` added less the
    /// refit on them unchanged. None when a refit fails.
    fn simex_bias(
        data: &[SegmentData<'_>],
        drive_starts: &[usize],
        theta: &Theta,
        identify: &IdentifyOptions,
        sigma_w: f64,
        seed: u64,
    ) -> Option<[f64; 4]> {
        let refit = |d: &[SegmentData<'_>]| gauss_newton_step_drives(d, drive_starts, theta, identify);
        // The draws come from one stream in a fixed order, so the result does
        // not depend on how many threads run the refits.
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ STREAM);
        let mut draw = |n: usize| (0..n).map(|_| rng.sample::<f64, _>(StandardNormal)).collect::<Vec<f64>>();
        let draws: Vec<Vec<(Vec<f64>, Vec<f64>)>> =
            (0..PAIRS).map(|_| data.iter().map(|s| (draw(s.n_rl.len()), draw(s.n_rr.len()))).collect()).collect();
        let runs: Vec<(usize, f64)> = (0..PAIRS).flat_map(|k| [(k, 1.0), (k, -1.0)]).collect();
        let (base, shifted) = rayon::join(
            || refit(data),
            || {
                runs.par_iter()
                    .map(|&(k, sign)| {
                        let scale = |n: &[f64], e: &[f64]| -> Vec<f64> {
                            n.iter().zip(e).map(|(n, e)| n * (1.0 + sign * sigma_w * e)).collect()
                        };
                        let wheels: Vec<(Vec<f64>, Vec<f64>)> =
                            data.iter().zip(&draws[k]).map(|(s, (l, r))| (scale(s.n_rl, l), scale(s.n_rr, r))).collect();
                        let noisy: Vec<SegmentData<'_>> =
                            data.iter().zip(&wheels).map(|(s, (l, r))| s.with_wheels(l, r)).collect();
                        refit(&noisy).map(<[f64; 4]>::from)
                    })
                    .collect::<Option<Vec<[f64; 4]>>>()
            },
        );
        let base = <[f64; 4]>::from(base?);
        let shifted = shifted?;
        let bias = std::array::from_fn(|i| shifted.iter().map(|t| t[i] - base[i]).sum::<f64>() / shifted.len() as f64);
        Some(bias)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::{calibrate, CalibrationOptions, Method};
    use crate::drive::segment::{select_segments, SegmentOptions};
    use crate::identify::batch_gauss_newton;
    use crate::sim::{simulate, NoiseOptions, SimOptions};

    fn drive(noise: &str, seed: u64) -> Drive {
        let noise: NoiseOptions = noise.parse().expect("preset");
        simulate(&SimOptions { length_km: 8.0, noise, ..SimOptions::paper(seed) }).expect("sim").drive
    }

    fn batch_gn() -> CalibrationOptions {
        CalibrationOptions { method: Method::BatchGn, ..Default::default() }
    }

    fn reason(r: &crate::CalibrationReport) -> Option<VerdictReason> {
        r.verdict.reasons.iter().find(|x| matches!(x, VerdictReason::InputNoiseBias { .. })).cloned()
    }

    /// The heading's random walk against the reference gives the white
    /// wheel noise the drive was simulated with (0.8 % on `white`, 2 % on
    /// `high`), and nothing on noise-free wheels.
    #[test]
    fn the_wheel_noise_estimate_recovers_the_simulated_level() {
        for (preset, truth) in [("white", 0.008), ("high", 0.02)] {
            let d = drive(preset, 3);
            let sel = select_segments(&d, &SegmentOptions::default()).expect("segments");
            let data: Vec<SegmentData<'_>> = sel.selected.iter().map(|s| SegmentData::new(&d, s)).collect();
            let fit = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &IdentifyOptions::default()).expect("fit");
            let est = wheel_white_noise(&data, &fit.theta).expect("an estimate");
            assert!((est / truth - 1.0).abs() < 0.25, "{preset}: σ_w {est} against {truth}");
        }
        let d = simulate(&SimOptions { length_km: 8.0, ..SimOptions::noise_free(3) }).expect("sim").drive;
        let sel = select_segments(&d, &SegmentOptions::default()).expect("segments");
        let data: Vec<SegmentData<'_>> = sel.selected.iter().map(|s| SegmentData::new(&d, s)).collect();
        let truth = SimOptions::noise_free(3).theta_true;
        assert!(wheel_white_noise(&data, &truth).is_none_or(|s| s < 1e-4), "noise-free wheels");
    }

    /// Heavy white wheel noise: batch G-N's t_r runs wide and c_e short by
    /// more than their σ, and the verdict says so with the bias's sign;
    /// without input noise the check is silent.
    #[test]
    fn batch_gn_under_heavy_wheel_noise_is_doubtful() {
        let r = calibrate(&drive("high", 4), &batch_gn()).expect("batch-gn");
        let Some(VerdictReason::InputNoiseBias { param, bias, sigma, sigmas, wheel_white_rel_sigma, .. }) = reason(&r)
        else {
            panic!("{:?}", r.verdict)
        };
        assert_eq!(r.verdict.level, crate::assess::trust::VerdictLevel::Doubtful);
        assert!(sigmas > MAX_BIAS_SIGMAS && (bias.abs() / sigma - sigmas).abs() < 1e-12, "{bias} {sigma} {sigmas}");
        match param {
            crate::Param::TR => assert!(bias > 0.0, "t_r bias {bias}"),
            crate::Param::CE => assert!(bias < 0.0, "c_e bias {bias}"),
            p => panic!("{p}: {bias}"),
        }
        assert!(wheel_white_rel_sigma > 0.015 && wheel_white_rel_sigma < 0.025, "{wheel_white_rel_sigma}");
        let text = reason(&r).expect("reason").to_string();
        assert!(text.contains("takes the wheel rotations as exact") && text.contains("eiv"), "{text}");
        let quiet = simulate(&SimOptions { length_km: 8.0, ..SimOptions::noise_free(4) }).expect("sim").drive;
        let r = calibrate(&quiet, &batch_gn()).expect("batch-gn, no noise");
        assert!(reason(&r).is_none(), "{:?}", r.verdict);
    }

    /// The prediction is the same on one thread as on two (the draws come
    /// from one stream in a fixed order), and the same seed gives it again.
    #[test]
    fn the_predicted_bias_does_not_depend_on_the_threads() {
        let d = drive("paper", 6);
        let sel = select_segments(&d, &SegmentOptions::default()).expect("segments");
        let data: Vec<SegmentData<'_>> = sel.selected.iter().map(|s| SegmentData::new(&d, s)).collect();
        let o = IdentifyOptions::default();
        let theta = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &o).expect("fit").theta;
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| simex_bias(&data, d.drive_starts(), &theta, &o, 0.01, 9)).expect("bias")
        };
        let one = run(1);
        assert_eq!(one.map(f64::to_bits), run(2).map(f64::to_bits));
        assert_eq!(one.map(f64::to_bits), run(1).map(f64::to_bits));
        assert!(one[2] > 0.0, "t_r's bias points up: {one:?}");
    }
}
