//! The encoder's quantisation step read off the wheel readings
//! ([`quantisation_step_of_readings`], [`super::QuantisationLevel::FromReadings`]).
//!
//! A wheel rate computed from counted ticks, `(ticks_k − ticks_{k−1}) /
//! (ticks per revolution · t_s)`, is a whole multiple of the step
//! `q = 1/(ticks per revolution · t_s)`: the readings lie on a lattice whose
//! spacing is the quantisation level the filter needs. No crate does this
//! (it is a one-dimensional approximate-GCD problem special to readings of
//! counted ticks): the smallest gap between distinct readings is the
//! candidate, a least-squares fit of `q` to the readings' lattice indices
//! refines it, and the lattice is accepted only when every reading sits on
//! it, so that readings off a lattice (interpolated ticks, CAN speeds
//! resampled to the output grid, noise added after quantisation) never
//! yield a step.

use super::EivInput;

/// Fewest distinct non-zero readings a lattice is accepted from.
pub(crate) const MIN_LATTICE_LEVELS: usize = 20;

/// Largest distance of a reading from its lattice point, in steps, for the
/// lattice to be accepted: a reading written with six decimals in rev/s
/// is within 5e-7 rev/s of its value, far below 1e-3 of any step an
/// encoder has at the sample rates odocal takes (q ≥ 1e-4 rev/s).
pub(crate) const LATTICE_TOLERANCE_STEPS: f64 = 1e-3;

/// Largest lattice index accepted: a "step" that makes the fastest reading
/// more than this many steps is indistinguishable from no lattice.
pub(crate) const MAX_LATTICE_INDEX: f64 = 1e7;

research_pub! {
    /// The quantisation step q (rev/s) of wheel readings that lie on a common
    /// lattice `k·q` (k whole), or `None` when they do not.
    ///
    /// Readings that are zero or not finite are skipped (a standing wheel
    /// counts nothing); both wheels must share the step (they are read by the
    /// same kind of encoder at the same sample time). The lattice is accepted
    /// only with at least `MIN_LATTICE_LEVELS` distinct non-zero levels and
    /// every reading within `LATTICE_TOLERANCE_STEPS` of its lattice point.
    ///
    /// ```
    /// # #[cfg(feature = "research")] {
    /// use odocal::eiv::quantisation_step_of_readings;
    /// // 512 ticks per revolution read at 100 Hz: q = 100/512 rev/s.
    /// let q = 100.0 / 512.0;
    /// let counted: Vec<f64> = (0..400).map(|k| f64::from(50 + k % 37) * q).collect();
    /// let found = quantisation_step_of_readings(&counted, &counted).unwrap();
    /// assert!((found - q).abs() < 1e-12 * q);
    /// // The same readings with 0.1 % noise added after counting: no lattice.
    /// let noisy: Vec<f64> = counted.iter().enumerate().map(|(k, v)| v * (1.0 + 1e-3 * (k as f64).sin())).collect();
    /// assert_eq!(quantisation_step_of_readings(&noisy, &noisy), None);
    /// # }
    /// ```
    fn quantisation_step_of_readings(n_rl: &[f64], n_rr: &[f64]) -> Option<f64> {
        let mut v: Vec<f64> = n_rl.iter().chain(n_rr).map(|x| x.abs()).filter(|x| x.is_finite() && *x > 0.0).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let top = v[v.len() - 1];
        // Distinct levels: readings of one lattice point written through
        // different arithmetic differ by rounding only.
        let same = top * 1e-12;
        let mut levels: Vec<f64> = Vec::new();
        for &x in &v {
            match levels.last() {
                Some(&l) if x - l <= same => {}
                _ => levels.push(x),
            }
        }
        if levels.len() < MIN_LATTICE_LEVELS {
            return None;
        }
        let smallest_gap = levels.windows(2).map(|w| w[1] - w[0]).fold(f64::INFINITY, f64::min);
        // The smallest level is itself a multiple of q: a gap below it is a
        // candidate, and so is the level when no gap is smaller.
        let candidate = smallest_gap.min(levels[0]);
        if candidate <= 0.0 || top / candidate > MAX_LATTICE_INDEX {
            return None;
        }
        // Least squares q = Σ k·x / Σ k² over the levels, then every reading
        // (not only the levels) checked against the refined lattice.
        let (mut kx, mut kk) = (0.0, 0.0);
        for &x in &levels {
            let k = (x / candidate).round();
            kx += k * x;
            kk += k * k;
        }
        let q = kx / kk;
        let on_lattice = |x: f64| {
            let r = x / q;
            (r - r.round()).abs() <= LATTICE_TOLERANCE_STEPS && r.round() >= 1.0
        };
        (q.is_finite() && q > 0.0 && v.iter().all(|&x| on_lattice(x))).then_some(q)
    }
}

/// [`quantisation_step_of_readings`] of an EIV input's two wheels, over its
/// parts only.
pub(crate) fn input_quantisation_step(input: &EivInput<'_>) -> Option<f64> {
    let pick = |n: &[f64]| -> Vec<f64> { input.parts.iter().flat_map(|r| n[r.clone()].iter().copied()).collect() };
    quantisation_step_of_readings(&pick(input.n_rl), &pick(input.n_rr))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, NoiseOptions, SimOptions};

    #[test]
    fn simulated_encoder_readings_give_the_encoders_step() {
        for (noise, ticks) in [(NoiseOptions::paper(), 2048.0), (NoiseOptions::high(), 512.0)] {
            let opts = SimOptions { length_km: 0.5, noise, seed: 3, ..SimOptions::default() };
            let out = simulate(&opts).expect("sim");
            let d = &out.drive;
            let expected = 1.0 / (ticks * d.sample_time_s());
            let q = quantisation_step_of_readings(&d.measured().n_rl, &d.measured().n_rr).expect("lattice");
            assert!((q / expected - 1.0).abs() < 1e-9, "q {q} expected {expected}");
        }
    }

    #[test]
    fn readings_without_quantisation_give_no_step() {
        // White wheel noise only (no encoder): continuous readings.
        let opts =
            SimOptions { length_km: 0.5, noise: NoiseOptions::white_wheel_only(), seed: 3, ..SimOptions::default() };
        let out = simulate(&opts).expect("sim");
        let m = out.drive.measured();
        assert_eq!(quantisation_step_of_readings(&m.n_rl, &m.n_rr), None);
        // Noise-free readings: the true rotation rates, no lattice either.
        let off = SimOptions { length_km: 0.5, noise: NoiseOptions::off(), seed: 3, ..SimOptions::default() };
        let m = simulate(&off).expect("sim").drive.measured().clone();
        assert_eq!(quantisation_step_of_readings(&m.n_rl, &m.n_rr), None);
    }

    #[test]
    fn a_few_levels_or_one_reading_off_the_lattice_give_no_step() {
        let q = 0.05;
        let few: Vec<f64> = (0..200).map(|k| f64::from(100 + k % 5) * q).collect();
        assert_eq!(quantisation_step_of_readings(&few, &few), None, "5 levels");
        let mut many: Vec<f64> = (0..400).map(|k| f64::from(100 + k % 60) * q).collect();
        assert!(quantisation_step_of_readings(&many, &many).is_some());
        many[17] += 0.3 * q;
        assert_eq!(quantisation_step_of_readings(&many, &many), None, "one reading between lattice points");
        // Readings written with six decimals keep their lattice.
        let rounded: Vec<f64> = (0..400).map(|k| (f64::from(100 + k % 60) * 0.0390625 * 1e6).round() / 1e6).collect();
        let found = quantisation_step_of_readings(&rounded, &rounded).expect("lattice");
        assert!((found / 0.0390625 - 1.0).abs() < 1e-6, "{found}");
        assert_eq!(quantisation_step_of_readings(&[], &[f64::NAN, 0.0]), None);
    }
}
