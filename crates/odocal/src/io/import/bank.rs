//! The road bank: the vehicle's roll from two GNSS antennas across it, and
//! the lateral specific force f_y = a_y·cos φ − g·sin φ that replaces a
//! derived (kinematic) a_y (`[lateral_acceleration.bank]`, see
//! [`BankSpec`]).

use super::geodesy;
use super::grid::{gaps_of, BadInterval};
use super::limits::{echo_num, within};
use super::manifest::{BankSpec, Manifest};
use super::signal;
use super::source::Stream;
use crate::error::Result;

/// Standard gravity, m/s² (local gravity differs by < 0.3 %).
pub(crate) const G_M_PER_S2: f64 = 9.80665;

/// The manifest key of the bank table.
const KEY: &str = "lateral_acceleration.bank";

/// Largest fraction of antenna pairs whose roll is beyond `max_roll_deg`
/// that is taken for glitches (dropped, a warning) rather than a wrong
/// column or baseline (an error).
const MAX_GLITCH_FRACTION: f64 = 0.01;

/// Largest time difference at which a right-antenna sample counts as taken
/// at a left one's stamp (both on GNSS time), s; otherwise it is
/// interpolated.
pub(crate) const SAME_EPOCH_S: f64 = 1e-3;

/// The roll on the antennas' own (paired) samples.
#[derive(Debug, Clone)]
pub(crate) struct Roll {
    /// Time, s (the antennas' clock, then the wheel clock once shifted).
    pub t: Vec<f64>,
    /// Roll, rad, positive when the left side is lower.
    pub phi: Vec<f64>,
    /// Stretches without a roll measurement longer than `output.max_gap_s`.
    pub bad: Vec<BadInterval>,
    /// Pairs dropped as beyond `max_roll_deg`.
    pub dropped: usize,
}

impl Roll {
    /// Moves the roll onto the wheel clock: adds `offset_s` to every time.
    pub(super) fn shift(&mut self, offset_s: f64) {
        for t in self.t.iter_mut() {
            *t += offset_s;
        }
        for b in self.bad.iter_mut() {
            b.from += offset_s;
            b.to += offset_s;
        }
    }
}

/// sin φ of one antenna pair: right minus left altitude plus the mounting
/// height offset (left minus right on level ground), over the baseline.
pub(crate) fn sin_roll(h_left: f64, h_right: f64, height_offset_m: f64, baseline_m: f64) -> f64 {
    (h_right - h_left + height_offset_m) / baseline_m
}

/// The lateral specific force in the vehicle frame from the kinematic
/// lateral acceleration `a_kin` (horizontal, positive to the left) and the
/// roll `phi` (positive when the left side is lower).
pub(crate) fn specific_force(a_kin: f64, phi: f64) -> f64 {
    a_kin * phi.cos() - G_M_PER_S2 * phi.sin()
}

/// One antenna's accepted samples: time, [east, north, altitude], m.
fn antenna(
    m: &Manifest,
    b: &BankSpec,
    s: &Stream,
    side: &str,
    enu: &mut Option<geodesy::Enu>,
) -> Result<(Vec<f64>, Vec<[f64; 3]>)> {
    let (lat, lon, alt) = (s.col(&b.lat), s.col(&b.lon), s.col(&b.alt));
    let (mut t, mut p) = (Vec::new(), Vec::new());
    for i in 0..s.t.len() {
        if let Some(q) = &b.quality {
            if !q.accepts(s.col(&q.column)[i]) {
                continue;
            }
        }
        for (col, v, max, key) in [(&b.lat, lat[i], 90.0, "lat"), (&b.lon, lon[i], 180.0, "lon")] {
            if !within(v, max) {
                return Err(s.error_at(
                    i,
                    Some(col),
                    format!(
                        "{KEY}.{key} ({side} antenna): {} is outside ±{max}°; the column must hold WGS84 degrees",
                        echo_num(v)
                    ),
                ));
            }
        }
        if !alt[i].is_finite() {
            return Err(s.error_at(i, Some(&b.alt), format!("{KEY}.alt ({side} antenna): altitude is not finite")));
        }
        let e = enu.get_or_insert_with(|| geodesy::Enu::new(lat[i], lon[i], alt[i]));
        let v = e.enu_of(lat[i], lon[i], alt[i]);
        t.push(s.t[i]);
        // the altitude itself, not ENU up: away from the ENU origin, "up"
        // tilts by distance / Earth radius
        p.push([v.x, v.y, alt[i]]);
    }
    if t.is_empty() {
        let key = if b.quality.is_some() { format!("{KEY}.quality") } else { format!("{KEY}.{side}") };
        return Err(
            m.error(&key, format!("the {side} antenna ({}) has no sample of accepted quality", s.path.display()))
        );
    }
    Ok((t, p))
}

/// `v` at `t` from samples `(ts, vs)`: the sample itself within
/// [`SAME_EPOCH_S`], else linear between the two around `t` when they are
/// at most `max_gap` apart.
pub(crate) fn at(ts: &[f64], vs: &[[f64; 3]], t: f64, max_gap: f64) -> Option<[f64; 3]> {
    let j = ts.partition_point(|x| *x < t);
    for k in [j.checked_sub(1), Some(j)].into_iter().flatten() {
        if ts.get(k).is_some_and(|x| (x - t).abs() <= SAME_EPOCH_S) {
            return Some(vs[k]);
        }
    }
    if j == 0 || j >= ts.len() || ts[j] - ts[j - 1] > max_gap {
        return None;
    }
    let w = (t - ts[j - 1]) / (ts[j] - ts[j - 1]);
    Some(std::array::from_fn(|c| vs[j - 1][c] * (1.0 - w) + vs[j][c] * w))
}

/// The roll from the two antennas of `b` (streams `left`, `right`) on the
/// left antenna's accepted samples. Errors name the key: no common
/// samples, a measured separation that disagrees with `baseline_m`, more
/// than [`MAX_GLITCH_FRACTION`] of the pairs beyond `max_roll_deg`.
pub(crate) fn roll(
    m: &Manifest,
    b: &BankSpec,
    left: &Stream,
    right: &Stream,
    warnings: &mut Vec<String>,
) -> Result<Roll> {
    let mut enu = None;
    let (tl, pl) = antenna(m, b, left, "left", &mut enu)?;
    let (tr, pr) = antenna(m, b, right, "right", &mut enu)?;
    let max_sin = b.max_roll_deg.to_radians().sin();
    let (mut t, mut phi, mut sep) = (Vec::new(), Vec::new(), Vec::new());
    let mut beyond: Vec<(f64, f64)> = Vec::new();
    for (i, l) in pl.iter().enumerate() {
        let Some(r) = at(&tr, &pr, tl[i], m.output.max_gap_s) else { continue };
        sep.push((r[0] - l[0]).hypot(r[1] - l[1]).hypot(r[2] - l[2]));
        let s = sin_roll(l[2], r[2], b.height_offset_m, b.baseline_m);
        if !within(s, max_sin) {
            beyond.push((tl[i], s));
            continue;
        }
        t.push(tl[i]);
        phi.push(s.asin());
    }
    if sep.len() < 2 {
        return Err(m.error(
            &format!("{KEY}.right"),
            format!(
                "fewer than two times where both antennas ('{}' and '{}') have a sample of accepted quality \
                 (within output.max_gap_s = {} s of each other)",
                b.left, b.right, m.output.max_gap_s
            ),
        ));
    }
    sep.sort_by(f64::total_cmp);
    let median = sep[sep.len() / 2];
    if !within(median / b.baseline_m - 1.0, BankSpec::BASELINE_TOLERANCE) {
        return Err(m.error(
            &format!("{KEY}.baseline_m"),
            format!(
                "the antennas of streams '{}' and '{}' are a median {median:.3} m apart ({} pairs), not \
                 baseline_m = {} (tolerance {} %); check the streams, the lat/lon/alt columns or the baseline",
                b.left,
                b.right,
                sep.len(),
                echo_num(b.baseline_m),
                BankSpec::BASELINE_TOLERANCE * 100.0
            ),
        ));
    }
    judge_glitches(m, b, beyond.len(), beyond.first().copied(), sep.len(), warnings)?;
    if t.len() < 2 {
        return Err(m.error(&format!("{KEY}.max_roll_deg"), "fewer than two antenna pairs within the roll limit"));
    }
    let bad = gaps_of(&t, m.output.max_gap_s, "roll (both antennas accepted)");
    Ok(Roll { t, phi, bad, dropped: beyond.len() })
}

/// The glitch rule over `pairs` antenna pairs of which `beyond` gave a roll
/// beyond `max_roll_deg`, the first at antenna time `first.0` with sin φ
/// `first.1`: more than [`MAX_GLITCH_FRACTION`] of them (and more than two)
/// is an error naming the key, fewer are dropped with a warning.
pub(crate) fn judge_glitches(
    m: &Manifest,
    b: &BankSpec,
    beyond: usize,
    first: Option<(f64, f64)>,
    pairs: usize,
    warnings: &mut Vec<String>,
) -> Result<()> {
    let Some((t0, s0)) = first else { return Ok(()) };
    let what = format!(
        "{beyond} of {pairs} antenna pairs give a roll beyond {KEY}.max_roll_deg = {}° (first at antenna time {t0:.3} s: \
         sin φ = {})",
        b.max_roll_deg,
        echo_num(s0)
    );
    if beyond as f64 > MAX_GLITCH_FRACTION * pairs as f64 && beyond > 2 {
        return Err(m.error(
            &format!("{KEY}.max_roll_deg"),
            format!("{what}; is {KEY}.alt the altitude in metres, height_offset_m right, the vehicle rolled over?"),
        ));
    }
    warnings.push(format!("{what}: dropped as altitude glitches"));
    Ok(())
}

/// What the import says about the bank's correction of a_y: `pairs` antenna
/// pairs, `dropped` of them as glitches, the smoothed roll's mean and
/// largest magnitude over the kept samples, rad.
pub(crate) fn description(b: &BankSpec, pairs: usize, dropped: usize, mean: f64, max: f64) -> String {
    format!(
        "; minus the bank's lateral gravity, a_y·cos φ − g·sin φ, with the roll φ from the antennas '{}' \
         (left) and '{}' (right), baseline {} m, height offset {} m, {} pairs ({} dropped beyond {}°), \
         smoothed over {} s: mean φ {:+.1} mrad, largest |φ| {:.1} mrad",
        b.left,
        b.right,
        b.baseline_m,
        b.height_offset_m,
        pairs,
        dropped,
        b.max_roll_deg,
        b.smoothing_s,
        mean * 1e3,
        max * 1e3
    )
}

/// The roll on the output grid: interpolated linearly, then a centred
/// moving average over `smoothing_s` within each kept part.
pub(crate) fn on_grid(
    roll: &Roll,
    grid: &[f64],
    h: f64,
    kept: &[std::ops::Range<usize>],
    smoothing_s: f64,
) -> Vec<f64> {
    let mut phi = signal::interp_sorted(&roll.t, &roll.phi, grid);
    signal::smooth_parts(&mut phi, kept, smoothing_s, h);
    phi
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roll_sign_and_height_offset() {
        // left antenna 0.14 m lower than the right one on a 1.485 m baseline: left side lower, φ > 0
        let s = sin_roll(100.0, 100.14, 0.0, 1.485);
        assert!((s - 0.14 / 1.485).abs() < 1e-12 && s > 0.0);
        // mounted 0.05 m higher on the left, level: no roll
        assert!(sin_roll(100.05, 100.0, 0.05, 1.485).abs() < 1e-12);
        // the mirror
        assert!(sin_roll(100.14, 100.0, 0.0, 1.485) < 0.0);
    }

    #[test]
    fn specific_force_on_a_bank() {
        let g = G_M_PER_S2;
        // level: the kinematic acceleration
        assert!((specific_force(1.2, 0.0) - 1.2).abs() < 1e-15);
        // left turn (a > 0) on a road banked into the curve (left lower, φ > 0): less
        let phi = 0.094_f64;
        assert!((specific_force(1.02, phi) - (1.02 * phi.cos() - g * phi.sin())).abs() < 1e-12);
        assert!(specific_force(1.02, phi) < 0.15);
        // a bank that exactly balances the curve: no lateral force
        let phi_b = (1.5_f64 / g).atan();
        assert!(specific_force(1.5, phi_b).abs() < 1e-12);
        // mirror symmetry: right turn on a road lower on the right
        assert!((specific_force(-1.02, -phi) + specific_force(1.02, phi)).abs() < 1e-12);
        // standing on a slope lower on the left: the road holds the body against sliding
        // to the lower left, f_y < 0
        assert!(specific_force(0.0, 0.05) < 0.0);
    }

    #[test]
    fn the_right_antenna_is_paired_at_the_same_epoch_or_interpolated_within_a_gap() {
        let ts = [0.0, 0.1, 0.2, 0.6];
        let vs = [[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [6.0, 0.0, 0.0]];
        assert_eq!(at(&ts, &vs, 0.1005, 0.5), Some([1.0, 0.0, 0.0]));
        let v = at(&ts, &vs, 0.15, 0.5).expect("interpolated");
        assert!((v[0] - 1.5).abs() < 1e-12);
        // 0.4 s gap ≤ 0.5: interpolated; with max_gap 0.3: none
        assert!(at(&ts, &vs, 0.4, 0.5).is_some());
        assert_eq!(at(&ts, &vs, 0.4, 0.3), None);
        // outside the samples
        assert_eq!(at(&ts, &vs, -0.1, 0.5), None);
        assert_eq!(at(&ts, &vs, 0.7, 0.5), None);
    }
}
