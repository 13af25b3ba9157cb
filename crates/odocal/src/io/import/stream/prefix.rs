//! The whole import's checks of the drive as a whole, on the warm-up
//! prefix: the prefix is imported as the whole import imports a drive
//! (grid, gaps, parts, resampling, a_y) and the wheel and heading
//! convention checks and the IMU's a_y sign and scale check judge it,
//! with the whole import's messages and warnings. A drive no longer than
//! the warm-up is judged on all of it, as the whole import judges it.

use std::collections::BTreeMap;

use super::super::bank::Roll;
use super::super::grid;
use super::super::manifest::Manifest;
use super::super::pose::Pose;
use super::super::source::Stream;
use super::super::wheels::Wheels;
use super::super::{checks, lateral, marked_grid, spans, OnGrid};
use crate::error::Result;
use crate::model::Theta;

/// The warm-up prefix: every stream's rows up to the warm-up's end (the
/// wheel stream without its corrupt rows), its wheels' rotation, the pose
/// and the road bank's roll on the wheel clock.
pub(crate) struct Prefix<'a> {
    pub streams: &'a BTreeMap<String, Stream>,
    pub wheels: &'a Wheels,
    pub pose: &'a Pose,
    pub roll: Option<&'a Roll>,
}

/// Judges the prefix's conventions. A prefix without a part of
/// `min_part_s` (or whose streams do not overlap) is not judged: the
/// stream's own checks of the whole drive decide then.
pub(crate) fn check_conventions(m: &Manifest, p: &Prefix<'_>, h: f64, warnings: &mut Vec<String>) -> Result<()> {
    let o = &m.output;
    let theta0: Theta = o.theta0();
    let Ok((start, end)) = grid::common_span(m, &spans(m, p.streams, p.pose, p.roll), h) else { return Ok(()) };
    let ws = &p.streams[&m.wheels.stream];
    let wheel_bad = grid::gaps_of(&ws.t, o.max_gap_s, "wheel");
    let g = marked_grid(m, (start, end, h), p.streams, &wheel_bad, p.pose, p.roll);
    let s = OnGrid::resample(m, p.streams, p.wheels, p.pose, &g.t, h);
    let Ok(grid::Parts { kept, .. }) = g.parts(m, "") else { return Ok(()) };
    let resampled = s.for_checks(h, start, &kept);
    // The wheel speeds first, as the whole import judges them.
    checks::wheel_speeds(m, &resampled, &theta0)?;
    checks::conventions(m, &resampled, &theta0, warnings)?;
    if !matches!(m.lateral_acceleration, super::super::LateralAccelerationSpec::Imu { .. }) {
        return Ok(());
    }
    let inputs = lateral::Inputs {
        grid: &g.t,
        h,
        n_rl: &s.n_rl,
        n_rr: &s.n_rr,
        px: &s.px,
        py: &s.py,
        psi: &s.psi,
        kept: &kept,
        roll: p.roll,
    };
    let (a_y, _) = lateral::lateral_acceleration(m, p.streams, &inputs, &theta0);
    let measured = g.measured(&p.pose.t);
    // A prefix whose samples the drive's checks refuse is judged by the
    // stream's own checks, sample by sample.
    let Ok(d) = s.assemble(m, h, &kept, &a_y, &measured) else { return Ok(()) };
    checks::lateral_convention(m, &d)
}
