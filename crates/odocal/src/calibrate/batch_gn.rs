//! Raw batch Gauss-Newton: one identification from θ_0 over every selected
//! segment with the measured wheel rotations (docs/method.md §4). Biased by input
//! noise (docs/method.md §9), but fast and the reference the other methods are
//! judged against.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::{Estimator, MethodDetail, MethodOutcome, Prepared, Selection, Timing};
use crate::drive::segment::SegmentData;
use crate::error::Result;
use crate::identify::{batch_gauss_newton_drives, IdentifyReport};
use crate::progress::{emit, Progress, ProgressFn};

/// Batch Gauss-Newton as a method ([`super::Method::BatchGn`]; its
/// settings are [`super::CalibrationOptions::identify`]).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub(crate) struct BatchGnOptions {}

/// What batch Gauss-Newton reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct BatchGnDetail {
    /// The identification.
    pub identification: IdentifyReport,
}

impl Estimator for BatchGnOptions {
    fn name(&self) -> &'static str {
        "batch-gn"
    }

    fn validate(&self) -> Result<()> {
        Ok(())
    }

    fn supports_extrinsics(&self) -> bool {
        true
    }

    fn run(
        &self,
        prep: &Prepared<'_>,
        selection: &Selection,
        progress: Option<ProgressFn<'_>>,
    ) -> Result<MethodOutcome> {
        let t = Instant::now();
        emit(progress, Progress::Stage { name: "batch Gauss-Newton", total: 1 });
        let data: Vec<SegmentData> = selection.segments.iter().map(|s| SegmentData::new(prep.drive, s)).collect();
        let identify = selection.identify(prep.options);
        let report = batch_gauss_newton_drives(&data, prep.drive.drive_starts(), &prep.options.theta0, &identify)?;
        emit(progress, Progress::Advance(1));
        Ok(MethodOutcome {
            theta: report.theta,
            iterations: Some(report.iterations),
            covariance: report.covariance,
            observability: report.observability.clone(),
            detail: MethodDetail::BatchGn(BatchGnDetail { identification: report }),
            timing: Timing { initial_identification: t.elapsed().as_secs_f64(), ..Timing::default() },
            warnings: Vec::new(),
            compensated: None,
        })
    }
}
