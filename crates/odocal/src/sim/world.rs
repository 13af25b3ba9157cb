//! Random noise worlds: every noise setting of the simulator drawn from a
//! wide range, reproducibly from a world seed.
//!
//! The presets ([`NoiseOptions::paper`], `high`, `white`) are dominated by
//! white wheel noise. A method chosen on them may meet slow common-mode
//! wheel-scale variation, slip with acceleration, a biased reference
//! heading or a biased a_y in the field; a study over random worlds asks
//! how it fares there. [`NoiseOptions::random_world`] draws a world,
//! `WorldSummary` says which kind of wheel noise dominates one
//! ([`NoiseOptions::world_summary`] in words).
//!
//! ## The distribution
//!
//! A world is **white-only** with probability 0.2:
//! white wheel noise, white reference position and heading noise, nothing
//! else (a_y and β exact, no quantisation, no constant errors) — a world
//! whose noise the errors-in-variables model, and so its Cramér–Rao bound,
//! represents exactly. Otherwise it is **full**: every source is drawn on
//! its own. "LU" is log-uniform; a source marked "off 15 %" is 0 with
//! probability 0.15, else drawn from its range.
//!
//! | setting | full world | white-only world |
//! |---|---|---|
//! | `wheel_white_rel_sigma` | LU 0.01–1.5 %, off 15 % | LU 0.1–1.5 % |
//! | `wheel_coloured_rel_sigma` (common) | LU 0.01–2 %, off 15 % | 0 |
//! | `wheel_coloured_time_constant_s` | LU 0.5–10 s | |
//! | `wheel_coloured_differential_rel_sigma` | LU 0.001–0.1 %, off 15 % | 0 |
//! | `wheel_coloured_differential_time_constant_s` | LU 0.5–10 s | |
//! | `wheel_slip_per_m_per_s2` | LU 0.01–1 % per m/s², off 15 % | 0 |
//! | `encoder_ticks_per_revolution` | none 30 %, else 2^U(8, 12) rounded (256–4096) | none |
//! | `position_drift_sigma_m` | LU 0.01–1 m, off 15 % | 0 |
//! | `position_drift_time_constant_s` | LU 10–120 s | |
//! | `position_white_sigma_m` | LU 0.001–0.1 m, off 15 % | LU 0.001–0.1 m |
//! | `heading_bias_rad` | uniform ±30 mrad | 0 |
//! | `heading_drift_sigma_rad` | LU 0.1–5 mrad, off 15 % | 0 |
//! | `heading_drift_time_constant_s` | LU 10–120 s | |
//! | `heading_white_sigma_rad` | LU 0.01–1 mrad, off 15 % | LU 0.01–1 mrad |
//! | `lateral_acceleration_white_sigma_m_per_s2` | LU 0.005–0.2 m/s², off 15 % | 0 |
//! | `lateral_acceleration_bias_m_per_s2` | uniform ±0.1 m/s² | 0 |
//! | `sideslip_sigma_rad` | LU 0.1–5 mrad, off 15 % | 0 |
//! | `sideslip_time_constant_s` | LU 0.3–3 s | |
//! | `sideslip_bias_rad` | uniform ±2 mrad | 0 |
//!
//! Every draw uses the same count of random numbers whatever its outcome,
//! from a ChaCha8 stream of the world seed that no drive uses: world N is
//! the same on every platform, and independent of the drive's seed.
//!
//! ## The regime
//!
//! Per wheel and sample, the relative rotation error has a white part —
//! the white noise and the encoder's counting error at 12 m/s (the mean
//! speed of the simulator's drives) and 40 Hz, `√(1/6)/(ticks·t_s·n)` —
//! and a common-mode part — the common coloured noise and the slip at
//! 0.9 m/s², the RMS longitudinal acceleration of the simulator's drives;
//! each part is the root sum of squares of its sources. A world is
//! - [`NoiseRegime::Quiet`] when both parts together are below 0.2 %,
//! - else [`NoiseRegime::CommonModeSlip`] when the common-mode part is the
//!   larger,
//! - else [`NoiseRegime::White`].
//!
//! The per-wheel coloured noise and the reference's errors do not enter
//! the label. By this rule the `paper` and `high` presets are white
//! dominated (white 0.81 % against common-mode 0.27 % per sample on
//! `paper`). Over 10 s the white part averages out and the common-mode part
//! does not: [`WorldSummary`] also gives both parts as the error of a 10 s
//! mean, where `paper` is common-mode dominated (0.04 % against 0.18 %).

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::route::stream;
use super::NoiseOptions;

/// The random stream of the world draw (a drive's streams are 0–12).
const WORLD_STREAM: u64 = 1000;

/// Probability that a drawn world is white-only.
const WHITE_ONLY_PROBABILITY: f64 = 0.2;
/// Probability that a source of a full world marked "off 15 %" is off.
const SOURCE_OFF_PROBABILITY: f64 = 0.15;
/// Probability that a full world has no encoder quantisation.
const NO_QUANTISATION_PROBABILITY: f64 = 0.3;
/// Speed at which the regime counts the encoder's counting error, m/s:
/// the mean speed of the simulator's drives while moving (11.4–13.9 m/s
/// on 12 km drives of seeds 1–4).
const NOMINAL_SPEED_M_PER_S: f64 = 12.0;
/// RMS longitudinal acceleration of the simulator's drives, m/s²: the
/// regime's slip size per sample (0.80–0.99 m/s² on 12 km drives of seeds
/// 1–4).
const NOMINAL_ACCELERATION_RMS_M_PER_S2: f64 = 0.9;
/// RMS over a drive of the longitudinal acceleration's 10 s mean, m/s²:
/// the slip's share of a 10 s mean error (0.42–0.57 m/s², as above).
const NOMINAL_ACCELERATION_RMS_10S_M_PER_S2: f64 = 0.5;
/// Below this relative wheel error per sample (white and common-mode parts
/// together) a world is quiet.
const QUIET_WHEEL_ERROR: f64 = 0.002;
/// Sample time of the regime's numbers, s (the simulator's 40 Hz).
const SAMPLE_TIME_S: f64 = 0.025;
/// Averaging time of [`WorldSummary`]'s 10 s numbers, s.
const MEAN_TIME_S: f64 = 10.0;
/// Wheel circumference of the regime's counting error, m (the simulator's true c_e).
const CIRCUMFERENCE_M: f64 = 1.95;

research_pub! {
    /// Which kind of wheel noise dominates a world (see the module doc).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
    #[serde(rename_all = "kebab-case")]
    enum NoiseRegime {
        /// Little wheel noise of any kind.
        Quiet,
        /// White noise and quantisation dominate.
        White,
        /// Common-mode coloured noise and slip with acceleration dominate.
        CommonModeSlip,
    }
}

/// The name in tables: `quiet`, `white`, `common-mode/slip`.
impl std::fmt::Display for NoiseRegime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            NoiseRegime::Quiet => "quiet",
            NoiseRegime::White => "white",
            NoiseRegime::CommonModeSlip => "common-mode/slip",
        })
    }
}

research_pub! {
    /// What dominates a noise world's wheel error, and whether its noise is
    /// white only (outside the crate, in words: [`NoiseOptions::world_summary`]).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    struct WorldSummary {
        /// The regime.
        pub regime: NoiseRegime,
        /// True when the only sources are white wheel, reference position and
        /// reference heading noise: the noise the errors-in-variables model
        /// (and its Cramér–Rao bound) represents exactly.
        pub white_only: bool,
        /// White part of a wheel's relative error per sample (white noise and
        /// counting error).
        pub wheel_white_rel: f64,
        /// Common-mode part of a wheel's relative error per sample (common
        /// coloured noise and slip).
        pub wheel_common_slip_rel: f64,
        /// The white part of a wheel's 10 s mean relative error.
        pub wheel_white_rel_10s: f64,
        /// The common-mode part of a wheel's 10 s mean relative error.
        pub wheel_common_slip_rel_10s: f64,
    }
}

/// The summary of any noise settings (a preset's too).
///
/// ```
/// # #[cfg(feature = "research")] {
/// use odocal::sim::{NoiseOptions, NoiseRegime, WorldSummary};
/// assert_eq!(WorldSummary::from(&NoiseOptions::default()).regime, NoiseRegime::White);
/// let off: NoiseOptions = "off".parse().unwrap();
/// assert_eq!(WorldSummary::from(&off).regime, NoiseRegime::Quiet);
/// # }
/// ```
impl From<&NoiseOptions> for WorldSummary {
    fn from(n: &NoiseOptions) -> WorldSummary {
        WorldSummary::of(n)
    }
}

impl WorldSummary {
    /// The summary of any noise settings (outside the crate:
    /// `WorldSummary::from(&noise)`).
    pub(crate) fn of(n: &NoiseOptions) -> WorldSummary {
        let ticks = f64::from(n.encoder_ticks_per_revolution);
        let revs_per_s = NOMINAL_SPEED_M_PER_S / CIRCUMFERENCE_M;
        // The counting error of one interval: the difference of two
        // uniform tick fractions, over the interval's revolutions.
        let count = |interval_s: f64| {
            if ticks > 0.0 {
                (1.0f64 / 6.0).sqrt() / (ticks * interval_s * revs_per_s)
            } else {
                0.0
            }
        };
        let white = n.wheel_white_rel_sigma.hypot(count(SAMPLE_TIME_S));
        let common = n.wheel_coloured_rel_sigma.hypot(n.wheel_slip_per_m_per_s2 * NOMINAL_ACCELERATION_RMS_M_PER_S2);
        let white_10s = (n.wheel_white_rel_sigma * (SAMPLE_TIME_S / MEAN_TIME_S).sqrt()).hypot(count(MEAN_TIME_S));
        let coloured_10s = n.wheel_coloured_rel_sigma * gauss_markov_mean_factor(n.wheel_coloured_time_constant_s);
        let common_10s = coloured_10s.hypot(n.wheel_slip_per_m_per_s2 * NOMINAL_ACCELERATION_RMS_10S_M_PER_S2);
        let regime = if white.hypot(common) < QUIET_WHEEL_ERROR {
            NoiseRegime::Quiet
        } else if common > white {
            NoiseRegime::CommonModeSlip
        } else {
            NoiseRegime::White
        };
        let white_only = n.wheel_slip_per_m_per_s2 == 0.0
            && n.wheel_coloured_rel_sigma == 0.0
            && n.wheel_coloured_differential_rel_sigma == 0.0
            && n.encoder_ticks_per_revolution == 0
            && n.position_drift_sigma_m == 0.0
            && n.heading_drift_sigma_rad == 0.0
            && n.heading_bias_rad == 0.0
            && n.lateral_acceleration_white_sigma_m_per_s2 == 0.0
            && n.lateral_acceleration_bias_m_per_s2 == 0.0
            && n.sideslip_sigma_rad == 0.0
            && n.sideslip_bias_rad == 0.0;
        WorldSummary {
            regime,
            white_only,
            wheel_white_rel: white,
            wheel_common_slip_rel: common,
            wheel_white_rel_10s: white_10s,
            wheel_common_slip_rel_10s: common_10s,
        }
    }
}

/// The standard deviation of the mean over [`MEAN_TIME_S`] of a
/// first-order Gauss-Markov process of correlation time `tau`, relative to
/// the process's own: `√(2x(1 − x(1 − e^{−1/x})))`, x = τ/T.
fn gauss_markov_mean_factor(tau: f64) -> f64 {
    let x = tau / MEAN_TIME_S;
    (2.0 * x * (1.0 - x * (1.0 - (-1.0 / x).exp()))).max(0.0).sqrt()
}

/// The world's random numbers: each draw takes the same count whatever
/// its outcome.
struct Draw(ChaCha8Rng);

impl Draw {
    fn unit(&mut self) -> f64 {
        self.0.random::<f64>()
    }

    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo * (hi / lo).powf(self.unit())
    }

    /// 0 with probability `off`, else log-uniform in `[lo, hi]`.
    fn source(&mut self, off: f64, lo: f64, hi: f64) -> f64 {
        let (u, v) = (self.unit(), self.log_uniform(lo, hi));
        if u < off {
            0.0
        } else {
            v
        }
    }
}

impl NoiseOptions {
    /// Which kind of wheel noise dominates these settings' world, whether
    /// its noise is white only, and a wheel's relative error per sample,
    /// in words (what `odocal simulate --noise random:N` prints).
    ///
    /// ```
    /// let world: odocal::sim::NoiseOptions = "off".parse().unwrap();
    /// assert_eq!(
    ///     world.world_summary(),
    ///     "quiet (white noise only), wheel error per sample 0.00 % white, 0.00 % common-mode and slip"
    /// );
    /// ```
    pub fn world_summary(&self) -> String {
        let w = WorldSummary::of(self);
        format!(
            "{} ({}), wheel error per sample {:.2} % white, {:.2} % common-mode and slip",
            w.regime,
            if w.white_only { "white noise only" } else { "every source drawn" },
            w.wheel_white_rel * 100.0,
            w.wheel_common_slip_rel * 100.0
        )
    }

    research_pub! {
        /// These options with the wheel noise of a heavy common-mode world
        /// (the lab's `random_worlds --heavy`; the regime where batch
        /// Gauss-Newton's errors-in-variables bias is large and EIV may fall
        /// back): common-mode coloured σ uniform 2–4 % with τ log-uniform
        /// 2–10 s, slip uniform 1–2 %/(m/s²), white σ uniform 0.05–0.3 %, no
        /// quantisation; the reference's and the other noise unchanged. Drawn
        /// from `seed` by SplitMix64 on a stream of its own, so a random
        /// world's other draws do not move.
        fn with_heavy_wheels(self, seed: u64) -> NoiseOptions {
            let mut state = seed ^ 0x6865_6176_7977_6865;
            let mut unit = || {
                state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
                let mut z = state;
                z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
                z ^= z >> 31;
                (z >> 11) as f64 / (1u64 << 53) as f64
            };
            NoiseOptions {
                wheel_coloured_rel_sigma: 0.02 + 0.02 * unit(),
                wheel_coloured_time_constant_s: 2.0 * 5f64.powf(unit()),
                wheel_slip_per_m_per_s2: 0.01 + 0.01 * unit(),
                wheel_white_rel_sigma: 5e-4 + 2.5e-3 * unit(),
                encoder_ticks_per_revolution: 0,
                ..self
            }
        }
    }

    research_pub! {
        /// The random noise world of `seed`, with its summary (the
        /// distribution and the regime rule: the [module
        /// doc](crate::sim#random-noise-worlds), `docs/reference.md`). The
        /// same seed gives the same world. Outside the crate:
        /// `"random:7".parse::<NoiseOptions>()` and [`WorldSummary::from`].
        fn random_world(seed: u64) -> (NoiseOptions, WorldSummary) {
            let mut d = Draw(stream(seed, WORLD_STREAM));
            let white_only = d.unit() < WHITE_ONLY_PROBABILITY;
            let off = if white_only { 0.0 } else { SOURCE_OFF_PROBABILITY };
            let wheel_white = if white_only { [1e-3, 0.015] } else { [1e-4, 0.015] };
            let mut n = NoiseOptions {
                wheel_white_rel_sigma: d.source(off, wheel_white[0], wheel_white[1]),
                wheel_coloured_rel_sigma: d.source(off, 1e-4, 0.02),
                wheel_coloured_time_constant_s: d.log_uniform(0.5, 10.0),
                wheel_coloured_differential_rel_sigma: d.source(off, 1e-5, 1e-3),
                wheel_coloured_differential_time_constant_s: Some(d.log_uniform(0.5, 10.0)),
                wheel_slip_per_m_per_s2: d.source(off, 1e-4, 0.01),
                encoder_ticks_per_revolution: {
                    let (u, bits) = (d.unit(), d.uniform(8.0, 12.0));
                    if u < NO_QUANTISATION_PROBABILITY {
                        0
                    } else {
                        bits.exp2().round() as u32
                    }
                },
                position_drift_sigma_m: d.source(off, 0.01, 1.0),
                position_drift_time_constant_s: d.log_uniform(10.0, 120.0),
                position_white_sigma_m: d.source(off, 1e-3, 0.1),
                heading_bias_rad: d.uniform(-0.03, 0.03),
                heading_drift_sigma_rad: d.source(off, 1e-4, 5e-3),
                heading_drift_time_constant_s: d.log_uniform(10.0, 120.0),
                heading_white_sigma_rad: d.source(off, 1e-5, 1e-3),
                lateral_acceleration_white_sigma_m_per_s2: d.source(off, 5e-3, 0.2),
                lateral_acceleration_bias_m_per_s2: d.uniform(-0.1, 0.1),
                sideslip_sigma_rad: d.source(off, 1e-4, 5e-3),
                sideslip_time_constant_s: d.log_uniform(0.3, 3.0),
                sideslip_bias_rad: d.uniform(-2e-3, 2e-3),
            };
            if white_only {
                let keep = (n.wheel_white_rel_sigma, n.position_white_sigma_m, n.heading_white_sigma_rad);
                n = NoiseOptions {
                    wheel_white_rel_sigma: keep.0,
                    position_white_sigma_m: keep.1,
                    heading_white_sigma_rad: keep.2,
                    ..NoiseOptions::off()
                };
            }
            let summary = WorldSummary::of(&n);
            (n, summary)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_world_other_seed_differs() {
        let (a, sa) = NoiseOptions::random_world(3);
        let (b, sb) = NoiseOptions::random_world(3);
        assert_eq!(a, b);
        assert_eq!(sa, sb);
        assert_ne!(NoiseOptions::random_world(4).0, a);
        assert_eq!(NoiseOptions::by_name("random:3").expect("world"), a);
        for bad in ["random:", "random:x", "random:-1", "random:18446744073709551616"] {
            let e = NoiseOptions::by_name(bad).expect_err(bad);
            assert!(e.to_string().contains("random:"), "{e}");
        }
        // The seed as written names the world in the sidecar: no spaces,
        // as the command line has it.
        for spaced in ["random: 3", "random:3 ", "random:\t3"] {
            let e = NoiseOptions::by_name(spaced).expect_err(spaced).to_string();
            assert!(e.contains("without spaces (random:5)"), "{e}");
        }
        let e = NoiseOptions::by_name("random:18446744073709551616").expect_err("above").to_string();
        assert!(e.contains("the world seed is above the largest, 18446744073709551615"), "{e}");
    }

    /// Whether `v` is 0 or within `[lo, hi]` (with rounding slack).
    fn in_range(v: f64, lo: f64, hi: f64) -> bool {
        v == 0.0 || (lo * (1.0 - 1e-12)..=hi * (1.0 + 1e-12)).contains(&v)
    }

    #[test]
    fn ranges_are_respected_over_many_seeds() {
        let worlds: Vec<(NoiseOptions, WorldSummary)> = (0..4000).map(NoiseOptions::random_world).collect();
        for (seed, (n, s)) in worlds.iter().enumerate() {
            let msg = format!("world {seed}: {n:?}");
            crate::sim::SimOptions { noise: n.clone(), ..crate::sim::SimOptions::paper(0) }
                .validate()
                .expect("a valid world");
            assert!(in_range(n.wheel_white_rel_sigma, 1e-4, 0.015), "{msg}");
            assert!(in_range(n.wheel_coloured_rel_sigma, 1e-4, 0.02), "{msg}");
            assert!(in_range(n.wheel_coloured_differential_rel_sigma, 1e-5, 1e-3), "{msg}");
            assert!(in_range(n.wheel_slip_per_m_per_s2, 1e-4, 0.01), "{msg}");
            let t = n.encoder_ticks_per_revolution;
            assert!(t == 0 || (256..=4096).contains(&t), "{msg}");
            assert!(in_range(n.position_drift_sigma_m, 0.01, 1.0), "{msg}");
            assert!(in_range(n.position_white_sigma_m, 1e-3, 0.1), "{msg}");
            assert!(n.heading_bias_rad.abs() <= 0.03, "{msg}");
            assert!(in_range(n.heading_drift_sigma_rad, 1e-4, 5e-3), "{msg}");
            assert!(in_range(n.heading_white_sigma_rad, 1e-5, 1e-3), "{msg}");
            assert!(in_range(n.lateral_acceleration_white_sigma_m_per_s2, 5e-3, 0.2), "{msg}");
            assert!(n.lateral_acceleration_bias_m_per_s2.abs() <= 0.1, "{msg}");
            assert!(in_range(n.sideslip_sigma_rad, 1e-4, 5e-3), "{msg}");
            assert!(n.sideslip_bias_rad.abs() <= 2e-3, "{msg}");
            if !s.white_only {
                assert!(in_range(n.wheel_coloured_time_constant_s, 0.5, 10.0), "{msg}");
                let tau_d = n.wheel_coloured_differential_time_constant_s.unwrap_or(f64::NAN);
                assert!(in_range(tau_d, 0.5, 10.0), "{msg}");
                assert!(in_range(n.position_drift_time_constant_s, 10.0, 120.0), "{msg}");
                assert!(in_range(n.heading_drift_time_constant_s, 10.0, 120.0), "{msg}");
                assert!(in_range(n.sideslip_time_constant_s, 0.3, 3.0), "{msg}");
            } else {
                assert!(n.wheel_white_rel_sigma >= 1e-3 && n.position_white_sigma_m > 0.0, "{msg}");
            }
        }
        // The draw reaches every part of its ranges and every regime.
        let frac = |f: &dyn Fn(&(NoiseOptions, WorldSummary)) -> bool| {
            worlds.iter().filter(|w| f(w)).count() as f64 / worlds.len() as f64
        };
        let white_only = frac(&|w| w.1.white_only);
        assert!((0.17..0.23).contains(&white_only), "white-only {white_only}");
        for r in [NoiseRegime::Quiet, NoiseRegime::White, NoiseRegime::CommonModeSlip] {
            let f = frac(&|w| w.1.regime == r);
            assert!(f > 0.1, "{r}: {f}");
        }
        assert!(frac(&|w| w.0.wheel_coloured_rel_sigma > 0.015) > 0.02);
        assert!(frac(&|w| w.0.wheel_white_rel_sigma > 0.012) > 0.02);
        assert!(frac(&|w| w.0.heading_bias_rad > 0.025) > 0.05 && frac(&|w| w.0.heading_bias_rad < -0.025) > 0.05);
        assert!(frac(&|w| w.0.encoder_ticks_per_revolution == 0) > 0.3);
        assert!(frac(&|w| w.0.encoder_ticks_per_revolution > 3000) > 0.05);
        assert!(frac(&|w| (1..300).contains(&w.0.encoder_ticks_per_revolution)) > 0.01);
    }

    #[test]
    fn regime_follows_the_dominant_wheel_noise() {
        let off = NoiseOptions::off();
        assert_eq!(WorldSummary::of(&off).regime, NoiseRegime::Quiet);
        assert!(WorldSummary::of(&off).white_only);
        let white = WorldSummary::of(&NoiseOptions::white_wheel_only());
        assert_eq!((white.regime, white.white_only), (NoiseRegime::White, true));
        let paper = WorldSummary::of(&NoiseOptions::paper());
        assert_eq!((paper.regime, paper.white_only), (NoiseRegime::White, false));
        assert!(paper.wheel_common_slip_rel_10s > paper.wheel_white_rel_10s, "{paper:?}");
        assert_eq!(WorldSummary::of(&NoiseOptions::high()).regime, NoiseRegime::White);
        let common = NoiseOptions { wheel_coloured_rel_sigma: 0.01, ..NoiseOptions::paper() };
        assert_eq!(WorldSummary::of(&common).regime, NoiseRegime::CommonModeSlip);
        let slip = NoiseOptions { wheel_slip_per_m_per_s2: 0.02, ..NoiseOptions::paper() };
        assert_eq!(WorldSummary::of(&slip).regime, NoiseRegime::CommonModeSlip);
        // Coarse ticks alone make a world white.
        let ticks = NoiseOptions { encoder_ticks_per_revolution: 256, ..NoiseOptions::off() };
        let s = WorldSummary::of(&ticks);
        assert_eq!((s.regime, s.white_only), (NoiseRegime::White, false), "{s:?}");
        // The 10 s mean of a Gauss-Markov process: the whole σ for τ ≫ T, √(2τ/T) for τ ≪ T.
        assert!((gauss_markov_mean_factor(1e4) - 1.0).abs() < 1e-3);
        assert!((gauss_markov_mean_factor(0.01) - (2.0f64 * 0.01 / 10.0).sqrt()).abs() < 1e-4);
    }
}
