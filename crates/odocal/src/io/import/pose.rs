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
        out.psi = derive_heading(&out.t, &out.x, &out.y, p.derive_heading_min_speed_m_per_s);
    }
    Ok(out)
}

/// Heading from the track: direction of motion between consecutive samples,
/// held below `min_speed`, averaged back onto the samples, unwrapped.
pub(crate) fn derive_heading(t: &[f64], x: &[f64], y: &[f64], min_speed: f64) -> Vec<f64> {
    let n = t.len();
    let mut mid: Vec<Option<f64>> = (0..n - 1)
        .map(|j| {
            let (dx, dy) = (x[j + 1] - x[j], y[j + 1] - y[j]);
            (dx.hypot(dy) / (t[j + 1] - t[j]) > min_speed).then(|| dy.atan2(dx))
        })
        .collect();
    // Hold the last heading through slow stretches (and back-fill the start).
    let first = mid.iter().flatten().next().copied().unwrap_or(0.0);
    let mut last = first;
    for v in mid.iter_mut() {
        match v {
            Some(h) => last = *h,
            None => *v = Some(last),
        }
    }
    let mut mid: Vec<f64> = mid.into_iter().map(|v| v.unwrap_or(first)).collect();
    unwrap_in_place(&mut mid);
    (0..n)
        .map(|i| match i {
            0 => mid[0],
            i if i == n - 1 => mid[n - 2],
            i => 0.5 * (mid[i - 1] + mid[i]),
        })
        .collect()
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
