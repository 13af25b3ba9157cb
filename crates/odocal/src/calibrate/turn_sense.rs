//! One-way turning selections: when every selected calibration
//! segment turns the same way, the straight segments are added.
//!
//! c_d acts on the yaw rate as a bias proportional to the distance driven
//! (`−v·c_d/(c_e·t_r)`), t_r as a scale on the heading change. On segments
//! that all turn one way (a loop driven in one direction) the two are nearly
//! collinear, and with the opposite sign of correlation for the other
//! direction, so any yaw effect outside the model that depends on the
//! turning direction is absorbed by c_d with a direction-dependent sign.
//! Measured on the van's six test-track runs (batch G-N, d held): the
//! correlation of c_d and t_r is −0.86 on a counter-clockwise run and +0.95
//! on a clockwise one with the paper's turning-only selection, ±0.74 with
//! the straight segments added; the default 3-step's mean Ē_p on the other
//! five runs falls from 7.81 m (two runs with no θ) to 4.38 m (README,
//! "Cross-run check on the test track"). Straight segments separate the
//! two: there c_d is the only yaw term.

use crate::drive::segment::Segment;
use crate::drive::Drive;

/// The way all of a selection's segments turn, when they all turn one way.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum TurnSense {
    /// Every segment's net heading change is positive (counter-clockwise).
    Left,
    /// Every segment's net heading change is negative (clockwise).
    Right,
}

impl TurnSense {
    /// "left (counter-clockwise)" or "right (clockwise)".
    pub(crate) fn name(self) -> &'static str {
        match self {
            TurnSense::Left => "left (counter-clockwise)",
            TurnSense::Right => "right (clockwise)",
        }
    }
}

/// The net reference heading change over a segment, rad.
fn net_heading_change(drive: &Drive, s: &Segment) -> f64 {
    drive.psi()[s.start + s.steps] - drive.psi()[s.start]
}

/// `Some` when `segments` is not empty and every segment's net reference
/// heading change has the same strict sign.
pub(crate) fn one_way(drive: &Drive, segments: &[Segment]) -> Option<TurnSense> {
    let mut sense = None;
    for s in segments {
        let dpsi = net_heading_change(drive, s);
        let this = if dpsi > 0.0 {
            TurnSense::Left
        } else if dpsi < 0.0 {
            TurnSense::Right
        } else {
            return None;
        };
        match sense {
            None => sense = Some(this),
            Some(prev) if prev != this => return None,
            Some(_) => {}
        }
    }
    sense
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::assess::warning::Warning;
    use crate::calibrate::{calibrate, CalibrationOptions, Method};
    use crate::drive::Signals;
    use crate::model::{step, wheel_rotations, Input, State, Theta};

    /// A drive whose heading follows `psi` (positions and wheels do not matter here).
    fn drive_with_heading(psi: Vec<f64>) -> Drive {
        let n = psi.len();
        let mut s = Signals::with_capacity(n);
        for (i, p) in psi.iter().enumerate() {
            s.push([i as f64 * 0.25, 0.0, *p, 5.0, 5.0, 0.0, 0.0]);
        }
        crate::drive::DriveBuilder { t: (0..n).map(|i| i as f64 * 0.025).collect(), measured: s, ..Default::default() }
            .build()
            .expect("drive")
    }

    /// A noise-free oval (300 m straights, 40 m radius half circles) at
    /// 10 m/s, driven counter-clockwise (`sign` +1) or clockwise (−1) for
    /// 1.3 laps at 40 Hz: every turning segment turns one way, and some
    /// segments lie on a straight.
    fn oval(sign: f64) -> Drive {
        let (theta, t_s, v, r, straight) = (Theta { c_d: 0.5e-3, ..Theta::PAPER_NOMINAL }, 0.025, 10.0, 40.0, 300.0);
        let lap = 2.0 * straight + 2.0 * std::f64::consts::PI * r;
        let n = (1.3 * lap / v / t_s) as usize;
        let mut x = State::zeros();
        let mut s = Signals::with_capacity(n);
        for i in 0..n {
            let along = (i as f64 * v * t_s) % lap;
            let half = lap / 2.0;
            let omega = if along % half < straight { 0.0 } else { sign * v / r };
            let a_y = v * omega;
            let (n_rl, n_rr) = wheel_rotations(v, omega, a_y, &theta);
            s.push([x[0], x[1], x[2], n_rl, n_rr, 0.0, a_y]);
            x = step(&x, &Input { n_rl, n_rr, beta: 0.0, a_y }, &theta, t_s);
        }
        crate::drive::DriveBuilder { t: (0..n).map(|i| i as f64 * t_s).collect(), measured: s, ..Default::default() }
            .build()
            .expect("oval")
    }

    #[test]
    fn a_one_way_selection_gets_every_segment_and_says_so() {
        let opts = CalibrationOptions { method: Method::from_name("batch-gn").expect("method"), ..Default::default() };
        for (sign, sense) in [(1.0, TurnSense::Left), (-1.0, TurnSense::Right)] {
            let d = oval(sign);
            let r = calibrate(&d, &opts).expect("calibrate");
            let (cut, selected) = (r.segments.cut, r.segments.selected);
            assert!(0 < selected && selected < cut, "{cut} cut, {selected} selected");
            let w: Vec<&Warning> = r.warnings.iter().filter(|w| w.kind() == "one_way_turns").collect();
            assert_eq!(w.len(), 1, "{:?}", r.warnings);
            assert_eq!(
                w[0],
                &Warning::OneWayTurns { sense: sense.name().to_string(), selected, added: cut - selected }
            );
            // the paper's selection on request: no warning
            let keep = CalibrationOptions { keep_one_way_selection: true, ..opts.clone() };
            let r = calibrate(&d, &keep).expect("calibrate");
            assert!(r.warnings.iter().all(|w| w.kind() != "one_way_turns"), "{:?}", r.warnings);
        }
    }

    fn seg(start: usize) -> Segment {
        Segment { start, steps: 10, peak_yaw_rate_rad_per_s: 1.0 }
    }

    #[test]
    fn one_way_names_the_common_sense_and_none_otherwise() {
        // left turn over samples 0..20, right turn over 20..40 (steps exact in binary)
        let psi: Vec<f64> =
            (0..41).map(|i| if i <= 20 { 0.0625 * i as f64 } else { 1.25 - 0.0625 * (i - 20) as f64 }).collect();
        let d = drive_with_heading(psi);
        assert_eq!(one_way(&d, &[seg(0), seg(5), seg(10)]), Some(TurnSense::Left));
        assert_eq!(one_way(&d, &[seg(20), seg(25), seg(30)]), Some(TurnSense::Right));
        assert_eq!(one_way(&d, &[seg(0), seg(25)]), None);
        assert_eq!(one_way(&d, &[]), None);
        // a segment with no net heading change (10 up, 10 down) breaks the run
        assert_eq!(one_way(&d, &[seg(15), seg(0)]), None);
    }
}
