//! Corrections of the estimator's own bias (bootstrap, first order).

use super::bootstrap;
use super::BootstrapOptions;
use std::time::Instant;

use super::filter::WindowSums;
use super::problem::{free_inverse, free_sigma, theta_add};
use super::{BiasCorrection, EivInput, EivOptions, EivReport, FirstOrderBias};
use crate::error::{Error, Result};
use crate::model::param::Param;

research_pub! {
    /// Applies `opts.research.bias_correction` to a fit made without it (nothing for
    /// `BiasCorrection::None`): runs the [`bootstrap`](fn@bootstrap) it names at the fit
    /// (replicates on `opts.research.bootstrap_inputs`, each holding the fitted noise
    /// model; in antithetic pairs with `opts.research.bootstrap_antithetic`), subtracts its bias from `report.theta`
    /// (the free parameters of those it names) and adds the bias's Monte Carlo
    /// covariance to `report.covariance` and `report.sigma`.
    ///
    /// [`estimate`](fn@crate::eiv::estimate) calls it at its end; `calibrate` calls it itself after
    /// deciding whether to fall back, so that a fit it replaces by batch
    /// Gauss-Newton costs no bootstrap. `report` must be that of [`estimate`](fn@crate::eiv::estimate)
    /// on `input` with `opts` except for the correction (and with its
    /// `bias_subtracted` zero).
    ///
    /// ```
    /// # fn main() -> Result<(), odocal::Error> {
    /// # #[cfg(feature = "research")] {
    /// use odocal::{eiv, sim};
    /// let out = sim::simulate(&sim::SimOptions { length_km: 1.0, ..sim::SimOptions::paper(2) })?;
    /// let input = eiv::EivInput::from_drive(&out.drive);
    /// let mut opts = eiv::EivOptions { fix_noise: true, ..Default::default() };
    /// let mut report = eiv::estimate(&input, &out.sidecar.theta_true, &opts)?;
    /// opts.correct_bias(2, 0, odocal::ParamSet::THETA); // one antithetic pair, every parameter
    /// eiv::apply_bias_correction(&input, &mut report, &opts)?;
    /// assert_ne!(report.theta, report.theta_uncorrected);
    /// // Each corrected (free) parameter's σ includes the correction's Monte Carlo error.
    /// for (s, free) in report.sigma_bias_correction.iter().zip(report.free) {
    ///     assert_eq!(*s > 0.0, free);
    /// }
    /// // The same as asking `estimate` for the correction.
    /// assert_eq!(eiv::estimate(&input, &out.sidecar.theta_true, &opts)?.theta, report.theta);
    /// # }
    /// # Ok(()) }
    /// ```
    fn apply_bias_correction(input: &EivInput<'_>, report: &mut EivReport, opts: &EivOptions) -> Result<()> {
        let BiasCorrection::Bootstrap { replicates, seed, parameters } = opts.research.bias_correction else {
            return Ok(());
        };
        opts.validate()?;
        if report.bias_subtracted.iter().any(|b| *b != 0.0) {
            return Err(Error::InvalidOption {
                field: "bias_correction",
                reason: "the report was already corrected".into(),
            });
        }
        let t0 = Instant::now();
        // The fit's own quantisation level (as `estimate` resolved it on the
        // drive's readings).
        let opts = &opts.with_resolved_readings(report.quantisation_step_from_readings, report.a_y_noise_floor);
        // The replicates are fitted without correction (their mean estimates
        // the uncorrected estimator's mean at θ̂), holding the fitted noise model.
        let inner = EivOptions { noise: report.noise, fix_noise: true, ..opts.without_bias_correction() };
        let boot = bootstrap(
            input,
            &*report,
            &inner,
            &BootstrapOptions {
                replicates,
                seed,
                true_inputs: opts.research.bootstrap_inputs,
                antithetic: opts.research.bootstrap_antithetic,
                refit: opts.research.bias_correction_refit,
                ..Default::default()
            },
        )?;
        let b = boot.bias;
        let named: [bool; 4] = std::array::from_fn(|i| parameters.contains(Param::THETA[i]));
        report.bias_subtracted = std::array::from_fn(|i| if named[i] { b[i] } else { 0.0 });
        report.theta = theta_add(&report.theta, &report.bias_subtracted, -1.0);
        // The subtracted bias is a mean of B replicates: its Monte Carlo
        // covariance (replicates' covariance / B) joins θ's.
        let corrected: [bool; 4] = std::array::from_fn(|i| report.free[i] && named[i]);
        let mc = boot.mean_covariance();
        let mut cov = report.covariance;
        for i in 0..4 {
            for j in 0..4 {
                if corrected[i] && corrected[j] {
                    cov[i][j] += mc[i][j];
                }
            }
        }
        report.covariance = cov;
        report.sigma_bias_correction = free_sigma(&corrected, |i| mc[i][i]);
        report.bias_replicates_failed = boot.failed;
        report.sigma = free_sigma(&report.free, |i| cov[i][i]);
        report.timing_s += t0.elapsed().as_secs_f64();
        Ok(())
    }
}

/// The first-order bias of the profile cost's root ([`FirstOrderBias`]):
/// `H_θ⁻¹ (g_logdet − g_corr)` over the free parameters, from the sums of
/// one filter pass with the covariance following θ. None when `H_θ` is
/// singular over `free`.
pub(crate) fn first_order_bias(sums: &WindowSums, free: &[bool; 4]) -> Option<FirstOrderBias> {
    let inv = free_inverse(&sums.h_theta, free)?;
    let mask = nalgebra::Vector4::from_fn(|i, _| if free[i] { 1.0 } else { 0.0 });
    let gl = sums.grad_logdet.component_mul(&mask);
    let gc = sums.grad_correction.component_mul(&mask);
    let gap = gl - gc;
    let b = inv * gap;
    let b_l = inv * gl;
    let arr = |v: nalgebra::Vector4<f64>| -> [f64; 4] { std::array::from_fn(|i| v[i]) };
    let conditional = std::array::from_fn(|i| {
        let h = sums.h_theta[(i, i)];
        if free[i] && h > 0.0 {
            gap[i] / h
        } else {
            0.0
        }
    });
    Some(FirstOrderBias {
        score_logdet: arr(gl),
        score_correction: arr(gc),
        bias: arr(b),
        bias_logdet_only: arr(b_l),
        bias_conditional: conditional,
    })
}
