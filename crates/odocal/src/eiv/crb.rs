//! The Cramér–Rao bound of θ for one drive.

use nalgebra::Matrix4;

use super::covariance::fisher_covariance;
use super::filter::Mode;
use super::input::make_windows;
use super::problem::{free_inverse, to_array, Problem};
use super::{CrbReport, EivInput, EivOptions, HeadingScale, InputJacobian, NoiseModel, QuantisationLevel};
use crate::error::{Error, Result};
use crate::model::Theta;

research_pub! {
    /// The Cramér–Rao bound of θ for this drive: the inverse of the Gaussian
    /// Fisher information at `theta` (θ_true) with the given (true) noise
    /// model unscaled, over the free parameters of `opts`.
    ///
    /// The innovations form of the state-space likelihood gives, with the
    /// covariance recursion following θ (S depends on θ through `F_n Σ_n F_nᵀ`),
    ///
    /// ```text
    /// I_ij = Σ_k (∂ν_k/∂θ_i)ᵀ S_k⁻¹ (∂ν_k/∂θ_j) + ½ tr(S_k⁻¹ ∂S_k/∂θ_i S_k⁻¹ ∂S_k/∂θ_j)
    /// ```
    ///
    /// with the exact sensitivities of the filter. The second term is
    /// information that the size of the innovations carries about θ when the
    /// noise model is known (the wheel noise in metres scales with the wheel
    /// circumferences); the mean-only part is reported too
    /// ([`CrbReport::sigma_mean_only`]). η is not estimated (known noise), so
    /// this is the bound of an estimator that knows the noise model;
    /// [`CrbReport::sigma_noise_estimated`] is the bound with the noise scales
    /// as nuisance parameters, the one an estimator that estimates the noise
    /// model from the drive (the EIV default) can reach.
    ///
    /// The sensitivities are linearised along `input`. For the bound at the
    /// truth pass the *true* inputs, [`EivInput::from_drive_truth`] of a
    /// simulated drive: along the measured ones the wheel noise counts as
    /// excitation and the bound on t_r and d comes out too small (on the `high`
    /// preset about half of t_r's).
    ///
    /// ## References
    /// R. H. Shumway, D. S. Stoffer, *Time Series Analysis and Its
    /// Applications*, §6.3 (innovations form of the likelihood); the Gaussian
    /// Fisher information `I = ∂μᵀΣ⁻¹∂μ + ½ tr(Σ⁻¹∂Σ Σ⁻¹∂Σ)` (e.g. S. M. Kay,
    /// *Fundamentals of Statistical Signal Processing: Estimation Theory*, §3.9).
    fn cramer_rao_bound(
        input: &EivInput<'_>,
        theta: &Theta,
        noise: &NoiseModel,
        opts: &EivOptions,
    ) -> Result<CrbReport> {
        opts.validate()?;
        noise.validate()?;
        input.validate()?;
        theta.validate()?;
        let windows = make_windows(input.parts, opts.window_samples);
        if windows.is_empty() {
            return Err(Error::NoSegments("the Cramér–Rao bound needs a drive part of at least two samples".into()));
        }
        // With `FromReadings` the bound takes `noise`'s q as the encoder's
        // (held, not scaled by η_0) where the readings lie on a lattice.
        let prob = Problem {
            noise: *noise,
            quantisation_given: opts.quantisation_level == QuantisationLevel::Given
                || opts.quantisation_level.step_found(input).is_some(),
            // The CRB uses the information matrix only.
            input_jacobian: InputJacobian::None,
            // The bound is the model's: every covariance derivative.
            c_d_covariance_derivative: true,
            ..Problem::new(input, windows, opts)
        };
        let ev = prob.evaluate(theta, theta, &[0.0; 6], Mode::full(true, true))?;
        let h: Matrix4<f64> = ev.total.info.fixed_view::<4, 4>(0, 0).into_owned();
        let h_mean = ev.total.info_mean_theta;
        let singular = || Error::NotObservable {
            params: (0..4)
                .filter(|i| opts.free[*i])
                .map(|i| crate::model::param::Param::THETA[i])
                .collect::<crate::model::param::ParamSet>()
                .names(),
            reason: "the information matrix is singular; fix some parameters (EivOptions::free)".into(),
        };
        let cov = free_inverse(&h, &opts.free).ok_or_else(singular)?;
        let cov_mean = free_inverse(&h_mean, &opts.free).ok_or_else(singular)?;
        let sd = |c: &Matrix4<f64>| std::array::from_fn(|i| if opts.free[i] { c[(i, i)].max(0.0).sqrt() } else { 0.0 });
        // η of the sources present (a zero σ gives a zero information row).
        let present = noise_sources_present(noise, opts.heading_scale == HeadingScale::Separate);
        let eta_free: [bool; 6] = std::array::from_fn(|j| present[j] && ev.total.info[(4 + j, 4 + j)] > 0.0);
        let sigma_noise_estimated = fisher_covariance(&ev.total.info, &opts.free, &eta_free).map(|c| sd(&c));
        Ok(CrbReport {
            theta: *theta,
            free: opts.free,
            information: to_array(&h),
            covariance: to_array(&cov),
            sigma: sd(&cov),
            information_mean_only: to_array(&h_mean),
            sigma_mean_only: sd(&cov_mean),
            sigma_noise_estimated,
        })
    }
}

/// Which of the six noise log-scales η have a source in `noise` (a group
/// whose standard deviations are all zero carries no information about its
/// scale). η_5 (the heading white noise) is a separate scale only with
/// `heading_separate`; otherwise η_3 scales it with the position white noise.
pub(super) fn noise_sources_present(noise: &NoiseModel, heading_separate: bool) -> [bool; 6] {
    let n = noise;
    let any = |v: &[f64]| v.iter().any(|x| *x > 0.0);
    [
        any(&[
            n.wheel_white_rel_sigma,
            n.quantisation_step_rev_per_s,
            n.lateral_acceleration_sigma_m_per_s2,
            n.sideslip_sigma_rad,
        ]),
        any(&[n.wheel_common_rel_sigma]),
        any(&[n.wheel_differential_rel_sigma]),
        if heading_separate {
            any(&[n.position_white_sigma_m])
        } else {
            any(&[n.position_white_sigma_m, n.heading_white_sigma_rad])
        },
        any(&[n.position_drift_sigma_m, n.heading_drift_sigma_rad]),
        heading_separate && any(&[n.heading_white_sigma_rad]),
    ]
}
