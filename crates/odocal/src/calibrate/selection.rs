//! The data and parameters a segment-based method fits: calibration
//! segments cut and chosen by their turning (docs/method.md §3, §6), and with
//! auto-fix the parameters held because the drive does not show them.

use crate::assess::warning::Warning;
use crate::drive::segment::{select_segments, Segment, SegmentData, SegmentOptions, SegmentSelection};
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::identify::{batch_normal_equations, observability, IdentifyOptions};
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

use super::{turn_sense, CalibrationOptions, Prepared};

/// The data and parameters a method fits, chosen by the method.
pub(crate) struct Selection {
    /// Calibration segments to fit (empty for a method over whole parts).
    pub segments: Vec<Segment>,
    /// Segments cut and segments that turn enough (report counts).
    pub cut: usize,
    /// See `cut`.
    pub selected: usize,
    /// The parameters to estimate (the options' free set less those held).
    pub free: ParamSet,
    /// Parameters held at θ_0 by auto-fix, in order.
    pub auto_fixed: Vec<Param>,
    /// Warnings of the selection (auto-fix).
    pub warnings: Vec<Warning>,
}

impl Selection {
    /// The options' Gauss-Newton settings with the selected free set.
    pub(crate) fn identify(&self, opts: &CalibrationOptions) -> IdentifyOptions {
        IdentifyOptions { free: self.free, ..opts.identify.clone() }
    }
}

/// The calibration segments of every method ([`select_segments`]), or
/// an error saying why the drive has none.
pub(crate) fn cut_segments(drive: &Drive, opts: &SegmentOptions) -> Result<SegmentSelection> {
    let selection = select_segments(drive, opts)?;
    if selection.all.is_empty() {
        return Err(Error::NoSegments(format!(
            "the drive has {} samples in {} part(s); a calibration segment needs {} samples (segment_length {} \
             steps in one part): give a longer drive or a shorter segment_length (--segment-length)",
            drive.len(),
            drive.parts().len(),
            opts.length_steps + 1,
            opts.length_steps
        )));
    }
    Ok(selection)
}

/// The segment-based methods' selection (docs/method.md §3, §6): calibration segments
/// turning at least as fast as the threshold; with none, an error naming the
/// yaw-only parameters, or (auto-fix) those held and every segment used;
/// with auto-fix, parameters the observability check names at θ_0 held.
pub(crate) fn turning_segments(prep: &Prepared<'_>) -> Result<Selection> {
    let (drive, opts) = (prep.drive, prep.options);
    let selection = cut_segments(drive, &opts.segments)?;
    let mut free = opts.identify.free;
    let mut auto_fixed = Vec::new();
    let mut warnings = Vec::new();
    if selection.selected.is_empty() {
        let free_yaw = free.intersection(YAW_ONLY);
        let peak = selection.all.iter().map(|s| s.peak_yaw_rate_rad_per_s).fold(0.0, f64::max);
        if !free_yaw.is_empty() && opts.auto_fix {
            free = free.intersection(ParamSet::EMPTY.with(Param::CE));
            auto_fixed.extend(free_yaw.iter());
            warnings.push(Warning::AutoFixNoTurns {
                params: free_yaw,
                segments: selection.all.len(),
                min_peak_yaw_rate_rad_per_s: opts.segments.min_peak_yaw_rate_rad_per_s,
                peak_yaw_rate_rad_per_s: peak,
            });
        } else if !free_yaw.is_empty() {
            return Err(Error::NotObservable {
                params: free_yaw.names(),
                reason: format!(
                    "none of the {} segments turns at {} rad/s or faster (the fastest: {peak:.3} rad/s); these \
                     parameters act only through the yaw equation. Hold them at θ_0 (--fix c_d,t_r,d) and \
                     select every segment (--min-yaw-rate 0) to calibrate c_e alone",
                    selection.all.len(),
                    crate::drive::echo_num(opts.segments.min_peak_yaw_rate_rad_per_s)
                ),
            });
        }
    }
    // Every selected segment turning one way confounds c_d with t_r: add
    // the straight ones (turn_sense; not in the paper).
    let one_way = if selection.selected.is_empty() || opts.keep_one_way_selection {
        None
    } else {
        turn_sense::one_way(drive, &selection.selected)
    };
    let segments = match one_way {
        Some(sense) if selection.all.len() > selection.selected.len() => {
            warnings.push(Warning::OneWayTurns {
                sense: sense.name().to_string(),
                selected: selection.selected.len(),
                added: selection.all.len() - selection.selected.len(),
            });
            selection.all.clone()
        }
        _ if selection.selected.is_empty() => selection.all.clone(),
        _ => selection.selected.clone(),
    };
    if opts.auto_fix && auto_fixed.is_empty() {
        let data: Vec<SegmentData> = segments.iter().map(|s| SegmentData::new(drive, s)).collect();
        let held = hold_unobservable(&data, &opts.theta0, &IdentifyOptions { free, ..opts.identify.clone() });
        if !held.is_empty() {
            warnings.push(Warning::AutoFixUnobservable { params: held.clone(), segments: segments.len() });
            for p in &held {
                free.remove(*p);
            }
        }
        auto_fixed.extend(held);
    }
    Ok(Selection { segments, cut: selection.all.len(), selected: selection.selected.len(), free, auto_fixed, warnings })
}

/// The parameters that act only through the yaw equation.
const YAW_ONLY: ParamSet = ParamSet::EMPTY.with(Param::CD).with(Param::TR).with(Param::D);

/// Holds at θ_0, one at a time, the parameter (never c_e) with the smallest
/// sensitivity among those the observability check names on `segments` at
/// θ_0, until none is named. Returns the parameters held, in order.
pub(crate) fn hold_unobservable(
    segments: &[SegmentData<'_>],
    theta0: &Theta,
    identify: &IdentifyOptions,
) -> Vec<Param> {
    let ne = batch_normal_equations(segments, theta0, &identify.weights);
    let mut free = identify.free;
    let mut held = Vec::new();
    loop {
        let o = observability(&ne, free, identify);
        let pick = o.unobservable.iter().filter(|&p| p != Param::CE && free.contains(p)).min_by(|&a, &b| {
            let s = |p: Param| o.sensitivity_m.map_or(0.0, |s| s[p.index()]);
            s(a).total_cmp(&s(b))
        });
        match pick {
            Some(p) => {
                free.remove(p);
                held.push(p);
            }
            None => return held,
        }
    }
}
