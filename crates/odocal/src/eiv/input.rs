//! The drive as the estimator reads it, and its cut into filter windows.

use std::ops::Range;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::model::wrap_angle;

research_pub! {
    /// The data of a drive as plain slices (all of length N, samples).
    #[derive(Debug, Clone, Copy)]
    struct EivInput<'a> {
        /// Sample time t_s, s.
        pub sample_time_s: f64,
        /// Continuous parts of the drive, sample index ranges; windows never span two.
        pub parts: &'a [Range<usize>],
        /// Reference x, m.
        pub px: &'a [f64],
        /// Reference y, m.
        pub py: &'a [f64],
        /// Reference heading, rad, unwrapped.
        pub psi: &'a [f64],
        /// Measured rear-left wheel rotation, rev/s.
        pub n_rl: &'a [f64],
        /// Measured rear-right wheel rotation, rev/s.
        pub n_rr: &'a [f64],
        /// Measured sideslip, rad.
        pub beta: &'a [f64],
        /// Measured lateral acceleration, m/s².
        pub a_y: &'a [f64],
        /// `true` where the reference pose was really measured (not
        /// interpolated or held); `None` means every sample.
        pub reference_measured: Option<&'a [bool]>,
    }
}

impl<'a> EivInput<'a> {
    research_pub! {
        /// The columns of a checked [`Drive`](crate::Drive), its parts and its
        /// reference mask.
        fn from_drive(d: &'a crate::Drive) -> Self {
            EivInput {
                sample_time_s: d.sample_time_s(),
                parts: d.parts(),
                px: d.px(),
                py: d.py(),
                psi: d.psi(),
                n_rl: d.n_rl(),
                n_rr: d.n_rr(),
                beta: d.beta(),
                a_y: d.a_y(),
                reference_measured: d.reference_measured(),
            }
        }
    }

    research_pub! {
        /// The noise-free truth columns of a simulated drive (its parts and
        /// reference mask as [`EivInput::from_drive`]): the trajectory along
        /// which [`cramer_rao_bound`](crate::eiv::cramer_rao_bound) at θ_true is linearised.
        ///
        /// Why not the measured columns: the bound's sensitivities
        /// are the filter's, linearised along the inputs it is given. Along the
        /// measured wheel rotations the white wheel noise appears as yaw and
        /// speed excitation the vehicle never had (on `high` about 5 mrad of
        /// yaw per 25 ms step), and the information about t_r and d, which grows
        /// with that excitation, is overstated: along the measured inputs the
        /// bound comes out about half the true one for t_r on `high`
        /// (`eiv_mismatch` in crates/odocal-lab with `CRB_MEASURED=1` measures it).
        ///
        /// # Errors
        /// [`Error::InvalidDrive`] when the drive carries no truth (a recorded
        /// drive: its bound cannot be evaluated at the truth).
        ///
        /// ```
        /// # #[cfg(feature = "research")] {
        /// use odocal::eiv::EivInput;
        /// use odocal::sim::{simulate, SimOptions};
        /// let sim = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(1) })?;
        /// let truth = EivInput::from_drive_truth(&sim.drive)?;
        /// let measured = EivInput::from_drive(&sim.drive);
        /// assert_eq!(truth.len(), measured.len());
        /// assert_ne!(truth.n_rl, measured.n_rl);
        /// # }
        /// # Ok::<(), odocal::Error>(())
        /// ```
        fn from_drive_truth(d: &'a crate::Drive) -> Result<Self> {
            let t = d.truth().ok_or_else(|| Error::InvalidDrive {
                context: "EIV input".into(),
                reason: "the drive carries no truth columns (*_true): the bound at the truth needs a simulated drive"
                    .into(),
            })?;
            Ok(EivInput {
                px: &t.px,
                py: &t.py,
                psi: &t.psi,
                n_rl: &t.n_rl,
                n_rr: &t.n_rr,
                beta: &t.beta,
                a_y: &t.a_y,
                ..EivInput::from_drive(d)
            })
        }
    }

    research_pub! {
        /// Number of samples.
        fn len(&self) -> usize {
            self.px.len()
        }
    }

    research_pub! {
        /// True when there are no samples.
        fn is_empty(&self) -> bool {
            self.px.is_empty()
        }
    }

    research_pub! {
        /// The white noise of the reference heading's readings, rad: the
        /// smaller of the robust scales of their second and of their third
        /// divided differences in time, over the samples where the
        /// reference was measured (all samples without
        /// `reference_measured`), within each part. Each divided difference
        /// is normalised by the root sum of squares of its coefficients, so
        /// white noise of σ gives differences of σ, whose median absolute
        /// value is 0.6745 σ. A vehicle's heading is smooth over a few
        /// reference samples, so the motion's share is small at a
        /// reference's rates (it grows with the time between samples; the
        /// smaller of the two orders keeps what remains low). A reference
        /// that is smoothed, or interpolated between its samples, gives a
        /// lower value. Zero without four measured samples in a part.
        fn heading_sample_noise(&self) -> f64 {
            let ts = self.sample_time_s;
            let measured = |i: usize| self.reference_measured.is_none_or(|m| m.get(i).copied().unwrap_or(false));
            let (mut second, mut third) = (Vec::new(), Vec::new());
            for part in self.parts {
                let idx: Vec<usize> = part.clone().filter(|&i| i < self.psi.len() && measured(i)).collect();
                for w in idx.windows(4) {
                    let t: [f64; 4] = std::array::from_fn(|j| w[j] as f64 * ts);
                    // Headings relative to the first, wrapped into (−π, π].
                    let y: [f64; 4] = std::array::from_fn(|j| wrap_angle(self.psi[w[j]] - self.psi[w[0]]));
                    if let Some(v) = normalised_divided_difference(&t[..3], &y[..3]) {
                        second.push(v.abs());
                    }
                    if let Some(v) = normalised_divided_difference(&t, &y) {
                        third.push(v.abs());
                    }
                }
            }
            match (upper_median(&mut second), upper_median(&mut third)) {
                (Some(a), Some(b)) => a.min(b) / 0.6745,
                _ => 0.0,
            }
        }
    }

    research_pub! {
        /// The white noise of the a_y readings, m/s², from their first
        /// differences within each part: the median absolute difference /
        /// (0.6745·√2). White noise of σ gives differences of σ·√2, whose
        /// median absolute value is 0.6745 times that; the median passes over
        /// the signal's own changes between samples, which are small at a
        /// vehicle's sample rates. Zero without two samples in a part.
        fn a_y_sample_noise(&self) -> f64 {
            let mut d: Vec<f64> = self
                .parts
                .iter()
                .filter_map(|p| self.a_y.get(p.clone()))
                .flat_map(|a| a.windows(2).map(|w| (w[1] - w[0]).abs()))
                .filter(|x| x.is_finite())
                .collect();
            upper_median(&mut d).map_or(0.0, |m| m / (0.6745 * std::f64::consts::SQRT_2))
        }
    }

    pub(super) fn validate(&self) -> Result<()> {
        let n = self.px.len();
        let bad = |reason: String| Error::InvalidDrive { context: "EIV input".into(), reason };
        if !(self.sample_time_s.is_finite() && self.sample_time_s > 0.0) {
            return Err(bad(format!("sample_time_s = {} must be positive", self.sample_time_s)));
        }
        for (name, len) in [
            ("py", self.py.len()),
            ("psi", self.psi.len()),
            ("n_rl", self.n_rl.len()),
            ("n_rr", self.n_rr.len()),
            ("beta", self.beta.len()),
            ("a_y", self.a_y.len()),
        ] {
            if len != n {
                return Err(bad(format!("column {name} has {len} samples, px has {n}")));
            }
        }
        if let Some(m) = self.reference_measured {
            if m.len() != n {
                return Err(bad(format!("reference_measured has {} samples, px has {n}", m.len())));
            }
        }
        for p in self.parts {
            if p.start > p.end || p.end > n {
                return Err(bad(format!("part {p:?} is outside 0..{n}")));
            }
        }
        Ok(())
    }
}

research_pub! {
    /// One filter window: steps `start..end` of one part (the state at `start`
    /// is initialised from the reference, the last update is at `end`).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
    struct Window {
        /// Index of the window in the drive (window order).
        pub index: usize,
        /// Index of the part it belongs to.
        pub part: usize,
        /// First sample.
        pub start: usize,
        /// Last sample.
        pub end: usize,
    }
}

/// Cuts every part into windows of about `target` steps (equal lengths within a part).
pub(super) fn make_windows(parts: &[Range<usize>], target: usize) -> Vec<Window> {
    let mut out = Vec::new();
    for (pi, p) in parts.iter().enumerate() {
        if p.end < p.start + 2 {
            continue;
        }
        let steps = p.end - p.start - 1;
        let count = ((steps as f64 / target as f64).round() as usize).max(1);
        for w in 0..count {
            let a = p.start + (w * steps) / count;
            let b = p.start + ((w + 1) * steps) / count;
            if b > a {
                out.push(Window { index: out.len(), part: pi, start: a, end: b });
            }
        }
    }
    out
}

/// The middle value of `d` (the upper one of an even count; `d` reordered);
/// `None` when empty.
fn upper_median(d: &mut [f64]) -> Option<f64> {
    if d.is_empty() {
        return None;
    }
    let mid = d.len() / 2;
    let (_, m, _) = d.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

/// The divided difference `y[t_0, …, t_k]` of the points `(t_i, y_i)`
/// divided by the root sum of squares of its coefficients on the `y_i`
/// (`Σ_i c_i y_i` with `c_i = 1/Π_{m≠i}(t_i − t_m)`): white noise of σ on
/// the `y_i` gives it a standard deviation of σ. `None` for repeated times
/// or a non-finite value.
fn normalised_divided_difference(t: &[f64], y: &[f64]) -> Option<f64> {
    let c: Vec<f64> =
        (0..t.len()).map(|i| 1.0 / (0..t.len()).filter(|&m| m != i).map(|m| t[i] - t[m]).product::<f64>()).collect();
    let norm = c.iter().map(|x| x * x).sum::<f64>().sqrt();
    let v = c.iter().zip(y).map(|(c, y)| c * y).sum::<f64>() / norm;
    v.is_finite().then_some(v)
}
