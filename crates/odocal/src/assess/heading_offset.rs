//! The reference's heading offset δ of one drive, re-estimated with θ and
//! the lever arm held.
//!
//! δ is the reference's own heading bias as much as a mount angle: on the
//! PSU test-track van it reads 14–24 mrad over one afternoon's drives.
//! Carried from the drive a calibration came from to another drive, it
//! tilts every dead-reckoned path of that drive. Validation therefore fits
//! the validation drive's own δ — one parameter, batch Gauss-Newton on the
//! drive's validation segments with θ and the lever arm held — before it
//! judges θ. This uses the reference's heading only, which is what the
//! validation compares against anyway.

use serde::{Deserialize, Serialize};

use crate::drive::segment::{Segment, SegmentData};
use crate::drive::Drive;
use crate::error::Result;
use crate::identify::{batch_gauss_newton, IdentifyOptions};
use crate::model::extrinsics::Extrinsics;
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

/// Iteration limit of the one-parameter fit (it is nearly linear in δ and
/// converges in two or three steps).
const MAX_ITERATIONS: usize = 20;

/// A drive's heading offset δ re-estimated with θ and the lever arm held.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HeadingOffsetFit {
    /// δ fitted on this drive, rad.
    pub value: f64,
    /// The δ the fit started from, rad: the calibration's (a parameter
    /// file's estimate), else the drive's manifest `[reference]` value or
    /// the file's held one, else 0.
    pub calibration: f64,
    /// 1σ of the fitted δ, rad: cluster-robust when the drive has enough
    /// segments for it ([`IdentifyOptions::robust_min_clusters`]), else the
    /// model σ, which assumes independent residuals and understates it
    /// (`robust` says which).
    pub std_dev: f64,
    /// True when `std_dev` is the cluster-robust σ.
    #[serde(default)]
    pub robust: bool,
    /// Segments fitted on.
    pub segments: usize,
}

impl std::fmt::Display for HeadingOffsetFit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "heading offset re-estimated on this drive: {:.1} mrad (calibration's {:.1})",
            self.value * 1e3,
            self.calibration * 1e3
        )
    }
}

/// Fits δ of `drive` on `segments` at `theta`, the lever arm of `e` held,
/// starting from `e.heading_offset`.
///
/// # Errors
/// No segments, a singular fit (δ unobservable), non-finite costs.
pub(crate) fn fit_heading_offset(
    drive: &Drive,
    segments: &[Segment],
    theta: &Theta,
    e: &Extrinsics,
) -> Result<HeadingOffsetFit> {
    let data: Vec<SegmentData<'_>> = segments.iter().map(|s| SegmentData::new(drive, s)).collect();
    let opts = IdentifyOptions {
        free: ParamSet::EMPTY.with(Param::HeadingOffset),
        extrinsics: *e,
        max_iterations: MAX_ITERATIONS,
        ..Default::default()
    };
    let r = batch_gauss_newton(&data, theta, &opts)?;
    let x = r.extrinsics.as_ref().map_or(*e, |x| x.value);
    let robust = r.extrinsics.as_ref().and_then(|x| x.robust.as_ref()).map(|r| r.std_dev.heading_offset);
    let model = r.extrinsics.as_ref().map_or(0.0, |x| x.std_dev.heading_offset);
    Ok(HeadingOffsetFit {
        value: x.heading_offset,
        calibration: e.heading_offset,
        std_dev: robust.unwrap_or(model),
        robust: robust.is_some(),
        segments: data.len(),
    })
}

/// `e` with the heading offset of `fit`.
pub(crate) fn with_fit(e: &Extrinsics, fit: &HeadingOffsetFit) -> Extrinsics {
    Extrinsics { heading_offset: fit.value, ..*e }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::segment::validation_segments;

    #[test]
    fn noise_free_drive_gives_back_its_own_heading_offset() {
        use crate::sim::{simulate, SimOptions};
        let mount = Extrinsics { lever_x: -0.9, lever_y: 0.05, heading_offset: 0.0142 };
        let o = SimOptions { length_km: 2.0, substeps: 1, reference_mount: mount, ..SimOptions::noise_free(8) };
        let s = simulate(&o).expect("simulate");
        let segs = validation_segments(&s.drive, &Default::default()).expect("segments");
        let start = Extrinsics { heading_offset: 0.0188, ..mount };
        let fit = fit_heading_offset(&s.drive, &segs, &s.sidecar.theta_true, &start).expect("fit");
        assert!((fit.value - mount.heading_offset).abs() < 1e-10, "{fit:?}");
        assert_eq!(fit.calibration.to_bits(), 0.0188f64.to_bits());
        assert_eq!(fit.segments, segs.len());
        assert_eq!(fit.to_string(), "heading offset re-estimated on this drive: 14.2 mrad (calibration's 18.8)");
    }

    /// On a drive with enough validation segments the fit's σ is the
    /// cluster-robust one, several times the model σ on paper noise, whose
    /// residuals are not independent.
    #[test]
    fn the_fits_sigma_is_cluster_robust_where_the_drive_allows() {
        use crate::sim::{simulate, SimOptions};
        let s = simulate(&SimOptions { length_km: 8.0, ..SimOptions::paper(4) }).expect("simulate");
        let segs = validation_segments(&s.drive, &Default::default()).expect("segments");
        let zero = Extrinsics::default();
        let fit = fit_heading_offset(&s.drive, &segs, &s.sidecar.theta_true, &zero).expect("fit");
        let data: Vec<SegmentData<'_>> = segs.iter().map(|x| SegmentData::new(&s.drive, x)).collect();
        let opts = IdentifyOptions { free: ParamSet::EMPTY.with(Param::HeadingOffset), ..Default::default() };
        let r = batch_gauss_newton(&data, &s.sidecar.theta_true, &opts).expect("fit");
        let x = r.extrinsics.expect("extrinsics");
        let robust = x.robust.expect("enough segments for the robust σ").std_dev.heading_offset;
        assert!(fit.robust && fit.std_dev.to_bits() == robust.to_bits(), "{fit:?}");
        assert!(
            fit.std_dev > 2.0 * x.std_dev.heading_offset,
            "{} against the model's {}",
            fit.std_dev,
            x.std_dev.heading_offset
        );
    }
}
