//! Tests of the errors-in-variables estimator, by theme.

mod bias_correction;
mod covariance;
mod crb;
mod derivatives;
mod diagnostics;
mod fingerprints;
mod heading_drift;
mod heading_noise;
mod lateral_noise;
mod noise_estimation;
mod quantisation;
mod scoring;
mod support;

pub(crate) use support::{slow_drift_noise, StraightDrive};
