//! The reference pose on its own samples: quality filtering, positions in a
//! local frame, the heading in the model's convention.

use super::geodesy;
use super::grid::{gaps_of, BadInterval};
use super::limits::{echo_num, within};
use super::manifest::{HeadingConvention, Manifest, PositionSpec};
use super::source::Stream;
use crate::drive::unwrap_in_place;
use crate::error::Result;

/// The pose on its own (good-quality) samples.
pub(crate) struct Pose {
    /// Time, s (the pose stream's clock, then the wheel clock once the clock
    /// offset is applied).
    pub t: Vec<f64>,
    /// East, m.
    pub x: Vec<f64>,
    /// North, m.
    pub y: Vec<f64>,
    /// Heading, rad, ENU, unwrapped.
    pub psi: Vec<f64>,
    /// Gaps and quality rejections, on the pose's time.
    pub bad: Vec<BadInterval>,
}

impl Pose {
    /// Moves the pose onto the wheel clock: adds `offset_s` to every time.
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

/// The pose of stream `s` on its accepted-quality samples: positions in a
/// local frame (lat/lon converted to ENU), the heading in ENU and unwrapped
/// (or derived from the track), rejected and missing stretches as
/// [`BadInterval`]s.
pub(crate) fn build_pose(m: &Manifest, s: &Stream, warnings: &mut Vec<String>) -> Result<Pose> {
    let p = &m.pose;
    let n = s.t.len();
    let good: Vec<bool> = match &p.quality {
        Some(q) => s.col(&q.column).iter().map(|v| q.accepts(*v)).collect(),
        None => vec![true; n],
    };
    let first_good = good.iter().position(|g| *g).ok_or_else(|| {
        let mut seen: Vec<f64> = p.quality.as_ref().map(|q| s.col(&q.column).to_vec()).unwrap_or_default();
        seen.sort_by(f64::total_cmp);
        seen.dedup();
        seen.truncate(10);
        let key = p.quality.as_ref().map_or("pose.quality.accept", |q| q.key());
        m.error(key, format!("no pose sample has an accepted quality value (values found: {seen:?})"))
    })?;
    let (x, y): (Vec<f64>, Vec<f64>) = match &p.position {
        PositionSpec::Local { x, y } => (s.col(x).to_vec(), s.col(y).to_vec()),
        PositionSpec::LatLon { lat: lat_col, lon: lon_col, alt, origin } => {
            let (lat, lon) = (s.col(lat_col), s.col(lon_col));
            for (col, v, max, key) in
                [(lat_col, lat, 90.0, "pose.position.lat"), (lon_col, lon, 180.0, "pose.position.lon")]
            {
                if let Some(i) = (0..n).find(|&i| good[i] && !within(v[i], max)) {
                    return Err(s.error_at(
                        i,
                        Some(col),
                        format!(
                            "{key}: {} is outside ±{max}°; the column must hold WGS84 degrees (ECEF or local \
                             metres? use kind = \"local\" with x and y)",
                            echo_num(v[i])
                        ),
                    ));
                }
            }
            let h: Vec<f64> = alt.as_ref().map(|a| s.col(a).to_vec()).unwrap_or_else(|| vec![0.0; n]);
            let o = origin.unwrap_or([lat[first_good], lon[first_good], h[first_good]]);
            let enu = geodesy::Enu::new(o[0], o[1], o[2]);
            (0..n).map(|i| enu.enu_of(lat[i], lon[i], h[i])).map(|v| (v.x, v.y)).unzip()
        }
    };
    // Keep good samples; remember rejected runs between them.
    let mut out = Pose { t: Vec::new(), x: Vec::new(), y: Vec::new(), psi: Vec::new(), bad: Vec::new() };
    let mut heading_raw = Vec::new();
    let mut rejected_since_last = 0usize;
    let mut rejected_values: Vec<f64> = Vec::new();
    let qcol = p.quality.as_ref().map(|q| s.col(&q.column));
    for i in 0..n {
        if !good[i] {
            rejected_since_last += 1;
            if let Some(v) = qcol.and_then(|c| c.get(i)) {
                if !rejected_values.iter().any(|r| (r - v).abs() < 1e-9) {
                    rejected_values.push(*v);
                }
            }
            continue;
        }
        if !(x[i].is_finite() && y[i].is_finite()) {
            return Err(s.error_at(i, None, "pose position is not finite"));
        }
        if rejected_since_last > 0 {
            if let (Some(&t0), Some(q)) = (out.t.last(), &p.quality) {
                out.bad.push(BadInterval {
                    from: t0,
                    to: s.t[i],
                    reason: format!(
                        "pose quality rejected ({} = {:?}, {} samples)",
                        q.column, rejected_values, rejected_since_last
                    ),
                });
            }
            rejected_since_last = 0;
            rejected_values.clear();
        }
        out.t.push(s.t[i]);
        out.x.push(x[i]);
        out.y.push(y[i]);
        if let Some(h) = &p.heading {
            let v = s.col(&h.column)[i] * h.unit.radians();
            heading_raw.push(match h.convention {
                HeadingConvention::Enu => v,
                HeadingConvention::Ned => std::f64::consts::FRAC_PI_2 - v,
            });
        }
    }
    if out.t.len() < 2 {
        let key = p.quality.as_ref().map_or("pose.quality.accept", |q| q.key());
        return Err(m.error(key, "fewer than two pose samples of accepted quality"));
    }
    check_speed(m, &out, warnings)?;
    out.bad.extend(gaps_of(&out.t, m.output.max_gap_s, "pose"));
    out.bad.sort_by(|a, b| a.from.total_cmp(&b.from));
    if p.heading.is_some() {
        unwrap_in_place(&mut heading_raw);
        out.psi = heading_raw;
    } else {
        out.psi =
            derive_heading(&out.t, &out.x, &out.y, p.derive_heading_min_speed_m_per_s, p.derive_heading_baseline_m);
    }
    Ok(out)
}

/// Heading from the track: at each sample, the direction of the chord
/// from the track point `baseline_m / 2` of travelled distance behind it
/// to the point as far ahead (see [`Chord`]); held below `min_speed`
/// (the first direction back-filled onto the samples before it),
/// unwrapped.
pub(crate) fn derive_heading(t: &[f64], x: &[f64], y: &[f64], min_speed: f64, baseline_m: f64) -> Vec<f64> {
    let mut points: Vec<TrackPoint> = Vec::with_capacity(t.len());
    for i in 0..t.len() {
        let s = points.last().map_or(0.0, |p| p.next_distance(x[i], y[i]));
        points.push(TrackPoint { t: t[i], x: x[i], y: y[i], s });
    }
    let chord = Chord::new(baseline_m, min_speed);
    let n = points.len();
    let dirs: Vec<Option<f64>> = (0..n).map(|i| chord.direction(|k| points[k], n, i)).collect();
    // Hold the last heading through slow stretches (and back-fill the start).
    let first = dirs.iter().flatten().next().copied().unwrap_or(0.0);
    let mut last = first;
    let mut psi: Vec<f64> = dirs
        .into_iter()
        .map(|d| {
            if let Some(h) = d {
                last = h;
            }
            last
        })
        .collect();
    unwrap_in_place(&mut psi);
    psi
}

/// An accepted pose sample on the track: time, east, north, and the
/// distance travelled from the first sample (the sum of the straight steps
/// between samples), m.
#[derive(Debug, Clone, Copy)]
pub(crate) struct TrackPoint {
    pub(crate) t: f64,
    pub(crate) x: f64,
    pub(crate) y: f64,
    pub(crate) s: f64,
}

impl TrackPoint {
    /// The travelled distance at the next sample, at `(x, y)`.
    pub(crate) fn next_distance(&self, x: f64, y: f64) -> f64 {
        self.s + (x - self.x).hypot(y - self.y)
    }
}

/// The chord whose direction is a sample's derived heading.
///
/// Its ends are the track points half the baseline of travelled distance
/// behind and ahead of the sample, each interpolated linearly (position
/// and time) along the travelled distance between the two samples around
/// it. A chord centred on its sample on a circular arc is parallel to the
/// tangent at the sample, so the direction has no lag and no bias on
/// circles; its noise is that of two positions a baseline apart, not a
/// step apart. The interpolation keeps the direction continuous as the
/// ends pass from one pair of samples to the next (the nearest samples
/// spanning the baseline would jump there, and centre the chord only to
/// within a step). With steps longer than half the baseline the ends lie on
/// the steps either side of the sample and the direction is the mean of
/// the two steps'.
///
/// An end is looked for no further than `span` of time from the sample
/// (the baseline's travel at `min_speed`, or at
/// [`CHORD_SPEED_FLOOR_M_PER_S`] when `min_speed` is lower), which bounds
/// a sample's wait for the track ahead. Where the track on a side is
/// shorter than half the baseline (before the first sample, after the
/// last, or within the span up to a stop), the chord ends there: it stays
/// at least half the baseline long where the other side allows, and its
/// direction is the tangent's up to a quarter baseline further in rather
/// than the noise of a shorter chord. The chord's speed (its length over
/// the time between its ends; an end at a stop is its arrival or its
/// departure) must exceed `min_speed`, otherwise the heading is held.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Chord {
    /// Half the baseline, m.
    half: f64,
    /// The longest time an end of the chord may lie from its sample, s.
    span: f64,
    /// Speed of the chord above which its direction is the heading, m/s.
    min_speed: f64,
}

/// The lowest speed `span` is figured with, m/s: the longest wait
/// for the track ahead is the baseline's travel at this speed (20 s for
/// 2 m) when `derive_heading_min_speed_m_per_s` is lower.
pub(crate) const CHORD_SPEED_FLOOR_M_PER_S: f64 = 0.1;

impl Chord {
    pub(crate) fn new(baseline_m: f64, min_speed: f64) -> Chord {
        Chord { half: 0.5 * baseline_m, span: baseline_m / min_speed.max(CHORD_SPEED_FLOOR_M_PER_S), min_speed }
    }

    /// Whether the chord of `c` ends at or after `p`, behind `c`: `p` is
    /// half the baseline behind or more than `span` earlier.
    pub(crate) fn ends_behind(&self, c: &TrackPoint, p: &TrackPoint) -> bool {
        p.s <= c.s - self.half || c.t - p.t > self.span
    }

    /// Whether the chord of `c` ends at or before `q`, ahead of `c`: `q` is
    /// half the baseline ahead or more than `span` later.
    pub(crate) fn ends_ahead(&self, c: &TrackPoint, q: &TrackPoint) -> bool {
        q.s >= c.s + self.half || q.t - c.t > self.span
    }

    /// The direction of the chord at sample `i` of the track `at(0..n)`,
    /// or `None` where it is slower than `min_speed` (or has no length).
    /// Reads the samples from `i` back to the first where
    /// [`Chord::ends_behind`] holds (or the track's first) and ahead to the
    /// first where [`Chord::ends_ahead`] holds (or the track's last).
    pub(crate) fn direction(&self, at: impl Fn(usize) -> TrackPoint, n: usize, i: usize) -> Option<f64> {
        let (lo, target_a) = self.reach_behind(&at, i);
        let (hi, target_b) = self.reach_ahead(&at, n, i);
        if target_b <= target_a {
            return None;
        }
        let mut j = i;
        while j > lo && at(j - 1).s > target_a {
            j -= 1;
        }
        let a = if j > lo { between(&at(j - 1), &at(j), target_a) } else { at(j) };
        let mut k = i;
        while k < hi && at(k + 1).s < target_b {
            k += 1;
        }
        let b = if k < hi { between(&at(k), &at(k + 1), target_b) } else { at(k) };
        let (dx, dy) = (b.x - a.x, b.y - a.y);
        (dx.hypot(dy) / (b.t - a.t) > self.min_speed).then(|| dy.atan2(dx))
    }

    /// The first sample behind `i` the chord may read, and the travelled
    /// distance its end may reach: half the baseline behind (that sample at
    /// or beyond it), or the last sample within the span, or the first.
    fn reach_behind(&self, at: &impl Fn(usize) -> TrackPoint, i: usize) -> (usize, f64) {
        let c = at(i);
        let mut lo = i;
        while lo > 0 {
            let p = at(lo - 1);
            if p.s <= c.s - self.half {
                return (lo - 1, c.s - self.half);
            }
            if self.ends_behind(&c, &p) {
                break;
            }
            lo -= 1;
        }
        (lo, at(lo).s)
    }

    /// The last sample ahead of `i` the chord may read, and the travelled
    /// distance its end may reach: half the baseline ahead (that sample at
    /// or beyond it), or the last sample within the span, or the last.
    fn reach_ahead(&self, at: &impl Fn(usize) -> TrackPoint, n: usize, i: usize) -> (usize, f64) {
        let c = at(i);
        let mut hi = i;
        while hi + 1 < n {
            let q = at(hi + 1);
            if q.s >= c.s + self.half {
                return (hi + 1, c.s + self.half);
            }
            if self.ends_ahead(&c, &q) {
                break;
            }
            hi += 1;
        }
        (hi, at(hi).s)
    }
}

/// The point at travelled distance `s` between samples `p` and `q`
/// (`p.s <= s <= q.s`), time and position linear in it; `q` where the two
/// are at the same distance.
fn between(p: &TrackPoint, q: &TrackPoint, s: f64) -> TrackPoint {
    let w = q.s - p.s;
    let f = if w > 0.0 { ((s - p.s) / w).clamp(0.0, 1.0) } else { 1.0 };
    TrackPoint { t: p.t + f * (q.t - p.t), x: p.x + f * (q.x - p.x), y: p.y + f * (q.y - p.y), s }
}

/// Pose steps faster than `limits.max_speed_m_per_s`: a few are glitches (a
/// warning); more than [`MAX_FAST_STEPS_FRACTION`] of the steps mean wrong
/// position columns or units (an error naming the key).
fn check_speed(m: &Manifest, p: &Pose, warnings: &mut Vec<String>) -> Result<()> {
    let vmax = m.limits.max_speed_m_per_s;
    let fast: Vec<(usize, f64)> = (1..p.t.len())
        .map(|j| (j, (p.x[j] - p.x[j - 1]).hypot(p.y[j] - p.y[j - 1]) / (p.t[j] - p.t[j - 1])))
        .filter(|(_, v)| !within(*v, vmax))
        .collect();
    let Some(&(j, v)) = fast.first() else { return Ok(()) };
    let steps = p.t.len() - 1;
    let key = match &m.pose.position {
        PositionSpec::Local { .. } => "pose.position.x",
        PositionSpec::LatLon { .. } => "pose.position.lat",
    };
    let what = format!(
        "{} of {steps} pose steps are faster than limits.max_speed_m_per_s = {vmax} (first at pose time {:.3} s: {} m/s)",
        fast.len(),
        p.t[j],
        echo_num(v)
    );
    if fast.len() as f64 > MAX_FAST_STEPS_FRACTION * steps as f64 && fast.len() > 2 {
        let hint = match &m.pose.position {
            PositionSpec::Local { .. } => "are x and y in metres?",
            PositionSpec::LatLon { .. } => "do the lat/lon columns hold degrees (not ECEF or local metres)?",
        };
        return Err(m.error(key, format!("{what}; {hint}")));
    }
    warnings.push(format!("{what}: position glitches in the reference"));
    Ok(())
}

/// Largest fraction of pose steps faster than the speed limit that is
/// taken for glitches rather than wrong columns or units.
const MAX_FAST_STEPS_FRACTION: f64 = 0.01;

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// The heading of consecutive steps (held below `min_speed`, the
    /// first back-filled), the mean of the two steps either side of a
    /// sample: the step-by-step arithmetic, to compare the chord with.
    fn consecutive_steps(t: &[f64], x: &[f64], y: &[f64], min_speed: f64) -> Vec<f64> {
        let n = t.len();
        let steps: Vec<Option<f64>> = (0..n - 1)
            .map(|j| {
                let (dx, dy) = (x[j + 1] - x[j], y[j + 1] - y[j]);
                (dx.hypot(dy) / (t[j + 1] - t[j]) > min_speed).then(|| dy.atan2(dx))
            })
            .collect();
        let mut last = steps.iter().flatten().next().copied().unwrap_or(0.0);
        let mut mid: Vec<f64> = steps
            .iter()
            .map(|s| {
                last = s.unwrap_or(last);
                last
            })
            .collect();
        unwrap_in_place(&mut mid);
        (0..n)
            .map(|i| match i {
                0 => mid[0],
                i if i == n - 1 => mid[n - 2],
                i => 0.5 * (mid[i - 1] + mid[i]),
            })
            .collect()
    }

    /// `(t, x, y, heading)` of a track driven at `v` m/s with the
    /// curvature `kappa(s)`, sampled at `rate_hz` (integrated in 1 mm
    /// chords of the arc; `v / rate_hz` a whole number of millimetres).
    fn track(rate_hz: f64, v: f64, duration_s: f64, kappa: impl Fn(f64) -> f64) -> [Vec<f64>; 4] {
        let ds = 1e-3;
        let per_sample = (v / rate_hz / ds).round() as usize;
        let (mut x, mut y, mut th) = (5.0f64, -7.0f64, 0.4f64);
        let mut out: [Vec<f64>; 4] = Default::default();
        for k in 0..(duration_s * rate_hz) as usize {
            out[0].push(k as f64 / rate_hz);
            out[1].push(x);
            out[2].push(y);
            out[3].push(th);
            for m in 0..per_sample {
                let s = (k * per_sample + m) as f64 * ds;
                let mid = th + 0.5 * ds * kappa(s + 0.25 * ds);
                x += ds * mid.cos();
                y += ds * mid.sin();
                th += ds * kappa(s + 0.5 * ds);
            }
        }
        out
    }

    fn max_error(psi: &[f64], truth: &[f64], skip: usize) -> f64 {
        (skip..psi.len() - skip).map(|i| (psi[i] - truth[i]).abs()).fold(0.0, f64::max)
    }

    /// On a noise-free circle the centred chord is the tangent at its
    /// sample, at every rate and baseline (steps longer than the baseline
    /// included); within half the baseline of the track's ends the chord
    /// ends there, and its direction is the tangent's at most a quarter
    /// baseline further in.
    #[test]
    fn on_a_circle_the_derived_heading_is_the_tangent() {
        let (r, v) = (8.0, 3.0);
        for rate_hz in [5.0, 10.0, 20.0, 100.0] {
            let n = (20.0 * rate_hz) as usize;
            let t: Vec<f64> = (0..n).map(|k| k as f64 / rate_hz).collect();
            let phi: Vec<f64> = t.iter().map(|t| 0.3 + v * t / r).collect();
            let x: Vec<f64> = phi.iter().map(|p| 4.0 + r * p.cos()).collect();
            let y: Vec<f64> = phi.iter().map(|p| -9.0 + r * p.sin()).collect();
            let tangent: Vec<f64> = phi.iter().map(|p| p + std::f64::consts::FRAC_PI_2).collect();
            for baseline in [0.1, 2.0, 6.0] {
                let psi = derive_heading(&t, &x, &y, 1.0, baseline);
                // Samples whose chord is whole (half the baseline from the
                // ends; the steps are chords of the arc, a little shorter).
                let skip = (0.5 * baseline / v * rate_hz).ceil() as usize + 1;
                let e = max_error(&psi, &tangent, skip);
                assert!(e < 1e-9, "{rate_hz} Hz, baseline {baseline} m: {e} rad");
                // Off-centre at the ends: the tangent a quarter baseline in
                // at most (half a step where that is longer), and an end
                // interpolated on a step inside the arc (its sag).
                let step = v / rate_hz;
                let sag = step * step / (8.0 * r);
                let bound = 0.5 * (0.5 * baseline).max(step) / r + sag / (0.5 * baseline);
                let e = max_error(&psi, &tangent, 0);
                assert!(e < bound + 1e-9, "{rate_hz} Hz, baseline {baseline} m, ends: {e} rad > {bound}");
            }
        }
    }

    /// On a clothoid (curvature 0 to 0.2 /m over 20 m) the chord's
    /// direction is the tangent's to within the curvature's change over
    /// it: κ'·L²/24 for a baseline L, and κ'·h²/8 for the ends'
    /// interpolation on steps h long.
    #[test]
    fn on_a_clothoid_the_derived_heading_is_the_tangent_to_within_the_curvature_change() {
        let rate = 0.01;
        for rate_hz in [10.0, 20.0, 100.0] {
            for baseline in [0.5, 2.0] {
                let [t, x, y, th] = track(rate_hz, 2.0, 10.0, |s| rate * s);
                let psi = derive_heading(&t, &x, &y, 1.0, baseline);
                let step = 2.0 / rate_hz;
                let bound = rate * (baseline * baseline / 24.0 + step * step / 8.0);
                // Samples whose chord is whole.
                let skip = (0.5 * baseline / 2.0 * rate_hz).ceil() as usize + 1;
                let e = max_error(&psi, &th, skip);
                assert!(e < 1.05 * bound + 1e-6, "{rate_hz} Hz, baseline {baseline} m: {e} rad > {bound}");
            }
        }
    }

    /// 20 Hz positions with 2 cm of white noise at 2 m/s on a gentle
    /// curve: the chord's heading error is a small fraction of the
    /// consecutive steps', and it turns slowly enough for the drive's
    /// check (5 rad/s) where the steps' does not.
    #[test]
    fn noisy_positions_at_walking_speeds_give_a_usable_heading() {
        let [t, mut x, mut y, th] = track(20.0, 2.0, 60.0, |s| 0.05 * (s / 15.0).sin());
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let noise = Normal::new(0.0, 0.02).expect("normal");
        for v in x.iter_mut().chain(y.iter_mut()) {
            *v += noise.sample(&mut rng);
        }
        let rms = |psi: &[f64]| {
            let e: Vec<f64> = (20..psi.len() - 20).map(|i| psi[i] - th[i]).collect();
            (e.iter().map(|e| e * e).sum::<f64>() / e.len() as f64).sqrt()
        };
        let fastest = |psi: &[f64]| psi.windows(2).map(|w| (w[1] - w[0]).abs() * 20.0).fold(0.0, f64::max);

        let chord = derive_heading(&t, &x, &y, 1.0, DEFAULT_BASELINE);
        let steps = consecutive_steps(&t, &x, &y, 1.0);
        let (e_chord, e_steps) = (rms(&chord), rms(&steps));
        eprintln!(
            "heading error RMS: chord {e_chord:.4} rad, consecutive steps {e_steps:.4} rad; fastest turn: chord {:.2} \
             rad/s, steps {:.2} rad/s",
            fastest(&chord),
            fastest(&steps)
        );
        assert!(e_chord < 0.012 && e_steps > 0.08 && e_chord < e_steps / 8.0, "{e_chord} vs {e_steps}");
        assert!(fastest(&chord) < 2.0 && fastest(&steps) > 5.0);
    }

    const DEFAULT_BASELINE: f64 = super::super::manifest::DEFAULT_DERIVE_HEADING_BASELINE_M;
}
