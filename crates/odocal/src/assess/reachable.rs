//! The reachable minimum of the validation error (docs/method.md §7).
//!
//! The *reachable minimum* is the smallest mean position error any θ can
//! achieve on the validation segments,
//!
//! ```text
//! Ē_p* = min over θ ∈ [lower, upper] of Ē_p(θ)
//! ```
//!
//! where `Ē_p` is [`mean_position_error`](crate::assess::position_error::mean_position_error). It is the yardstick a calibration
//! is judged against: the gap between a calibrated θ̂ and the reachable
//! minimum is what better identification could still win.
//!
//! `Ē_p` has no useful derivatives here (it is a mean of distances and is
//! non-smooth at its minimum when the data are noise-free), so the search
//! is derivative-free, in two stages:
//!
//! 1. **global**: a particle swarm (argmin's [`ParticleSwarm`]) over the box,
//!    seeded with the box centre and every caller-supplied start;
//! 2. **local**: Nelder-Mead (argmin's [`NelderMead`]) from the best point
//!    found, with an initial simplex of 2 % of the box per parameter.
//!
//! Both stages work in *scaled coordinates*: each parameter is mapped
//! linearly from `[lower, upper]` to `[0, 1]`, so that a millimetre of `c_d`
//! and a tenth of a metre of `t_r` weigh alike in the swarm's velocities and
//! the simplex's shape. Outside the box (and wherever θ is invalid, e.g.
//! `t_r ≤ 0`) the cost is a large finite penalty growing with the distance
//! to the box: finite so that Nelder-Mead's simplex statistics stay finite,
//! growing so that a simplex that strays out is pushed back.
//!
//! ## A minimum on the box edge
//! A best point within [`EDGE_FRACTION`] of the box width of a bound is *on
//! the edge*: the true minimum may lie outside. The search then re-centres
//! the box (same widths) on the best point and searches again, seeded with
//! it, at most [`ReachableOptions::recentre`] times; the report names the
//! parameters still on the edge ([`ReachableReport::at_edge`]) and whether
//! the minimum is enclosed ([`ReachableReport::enclosed`]).
//!
//! The search is deterministic: the swarm draws from a `ChaCha8Rng` seeded
//! with [`ReachableOptions::seed`], and `Ē_p` itself is computed in a fixed
//! order whatever the number of threads. The result is never worse than the
//! best θ evaluated, which includes the box centre and every start.
//!
//! ## References
//! - G. Fazekas, P. Gáspár, B. Németh, "Wheel Odometry Model Calibration
//!   with Input Compensation by Optimal Control", IFAC-PapersOnLine, 2022
//!   (the reachable minimum; found there with a genetic algorithm).
//! - J. Kennedy, R. Eberhart, "Particle swarm optimization", Proc. ICNN, 1995;
//!   M. Clerc, "Standard Particle Swarm Optimisation", 2012 (the inertia
//!   `1/(2 ln 2)` and acceleration `1/2 + ln 2` argmin uses).
//! - J. A. Nelder, R. Mead, "A simplex method for function minimization",
//!   The Computer Journal 7(4), 1965.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use argmin::core::{CostFunction, Executor, State};
use argmin::solver::neldermead::NelderMead;
use argmin::solver::particleswarm::{Particle, ParticleSwarm};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::assess::position_error::mean_position_error_with;
use crate::drive::segment::Segment;
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::model::extrinsics::Extrinsics;
use crate::model::param::{Param, ParamSet};
use crate::model::{Theta, THETA_NAMES};
use crate::progress::{emit, Progress, ProgressFn};

/// Cost, in metres, of a θ outside the box or invalid (`t_r ≤ 0`, `c_e ≤ 0`,
/// non-finite error). Far above any real `Ē_p` (a few metres to kilometres)
/// yet finite, so Nelder-Mead's simplex statistics stay finite.
const PENALTY_M: f64 = 1e9;

/// Side of Nelder-Mead's initial simplex, as a fraction of the box width of
/// each parameter (2 %: about 4 mm of `c_e` and 0.8 mm of `c_d` for the
/// default box; small enough to stay in the swarm's basin, large enough
/// that the simplex does not start collapsed).
const SIMPLEX_STEP: f64 = 0.02;

/// A best point closer than this fraction of the box width to a bound is
/// *on the edge* of the box (1 %: the swarm and the simplex, pushed back by
/// the penalty, end right at a bound when the minimum is beyond it, while
/// an interior minimum a hundredth of the width from a bound is rare).
pub(crate) const EDGE_FRACTION: f64 = 0.01;

/// Default number of times the box is re-centred on a best point on its edge.
pub(crate) const DEFAULT_RECENTRE: usize = 3;

fn default_recentre() -> usize {
    DEFAULT_RECENTRE
}

/// Options of the reachable-minimum search.
///
/// Users write `ReachableOptions { seed: 7, ..ReachableOptions::around(&theta0) }`;
/// [`Default`] is the box around the paper's θ_0 = `[2.0, 0, 1.6, 0]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReachableOptions {
    /// Lower corner of the search box, SI units. Default (around θ_0):
    /// `c_e − 10 %`, `c_d − 20 mm`, `t_r − 20 %`, `d − 5 mm/(m/s²)`, i.e.
    /// `[1.8, −0.02, 1.28, −0.005]` for the paper's θ_0.
    pub lower: Theta,
    /// Upper corner of the search box, SI units. Default (around θ_0):
    /// `c_e + 10 %`, `c_d + 20 mm`, `t_r + 20 %`, `d + 5 mm/(m/s²)`, i.e.
    /// `[2.2, 0.02, 1.92, 0.005]` for the paper's θ_0.
    pub upper: Theta,
    /// Number of particles in the swarm. Default 40.
    pub particles: usize,
    /// Swarm iterations (each evaluates `Ē_p` once per particle). Default 60.
    pub iterations: usize,
    /// Maximum Nelder-Mead iterations of the local refinement (0 skips the
    /// refinement). Default 200.
    pub refine_iterations: usize,
    /// The refinement stops when the standard deviation of `Ē_p` over the
    /// simplex falls below this, metres. Default 1e-7 m.
    pub refine_tolerance_m: f64,
    /// Seed of the swarm's random numbers; the same seed gives the same
    /// result. Default 0.
    pub seed: u64,
    /// Extra parameter vectors to evaluate and seed the swarm with, e.g.
    /// calibrated estimates. The result is never worse than any of them.
    /// A start outside the box is evaluated as given and enters the swarm
    /// projected onto the box. Default: none (the box centre is always used).
    pub starts: Vec<Theta>,
    /// When the best point is on the box edge, re-centre the box on it and
    /// search again, at most this many times (0: never). Default
    /// `DEFAULT_RECENTRE` = 3.
    #[serde(default = "default_recentre")]
    pub recentre: usize,
    /// The pose reference's mount (lever arm, heading offset), held: every
    /// `Ē_p(θ)` of the search compares the model's antenna position with
    /// the reference, as `crate::assess::position_error::mean_position_error_with` does,
    /// so the minimum is comparable with a validation on the same mount.
    /// [`validate`](crate::validate()) sets it from [`crate::ValidateOptions::extrinsics`].
    /// Default 0: the reference at the rear-axle centre.
    #[serde(default)]
    pub extrinsics: Extrinsics,
}

impl Default for ReachableOptions {
    fn default() -> Self {
        ReachableOptions::around(&Theta::PAPER_INITIAL)
    }
}

impl ReachableOptions {
    /// The default options with the box centred on `theta0`: `c_e ± 10 %`,
    /// `c_d ± 20 mm`, `t_r ± 20 %`, `d ± 5 mm/(m/s²)`.
    pub fn around(theta0: &Theta) -> Self {
        let half = [0.1 * theta0.c_e.abs(), 0.020, 0.2 * theta0.t_r.abs(), 0.005];
        let c = theta0.to_array();
        let corner = |sign: f64| Theta {
            c_e: c[0] + sign * half[0],
            c_d: c[1] + sign * half[1],
            t_r: c[2] + sign * half[2],
            d: c[3] + sign * half[3],
        };
        ReachableOptions {
            lower: corner(-1.0),
            upper: corner(1.0),
            particles: 40,
            iterations: 60,
            refine_iterations: 200,
            refine_tolerance_m: 1e-7,
            seed: 0,
            starts: Vec::new(),
            recentre: DEFAULT_RECENTRE,
            extrinsics: Extrinsics::default(),
        }
    }

    /// The centre of the box, `(lower + upper)/2`.
    pub(crate) fn centre(&self) -> Theta {
        Theta::from_vector(&((self.lower.to_vector() + self.upper.to_vector()) / 2.0))
    }

    /// Checks the options, naming the offending field.
    pub(crate) fn validate(&self) -> Result<()> {
        let (lo, hi) = (self.lower.to_array(), self.upper.to_array());
        for i in 0..4 {
            if !lo[i].is_finite() {
                return Err(Error::InvalidOption {
                    field: "lower",
                    reason: format!("{} = {} is not finite", THETA_NAMES[i], lo[i]),
                });
            }
            if !hi[i].is_finite() {
                return Err(Error::InvalidOption {
                    field: "upper",
                    reason: format!("{} = {} is not finite", THETA_NAMES[i], hi[i]),
                });
            }
            if lo[i] >= hi[i] {
                return Err(Error::InvalidOption {
                    field: "upper",
                    reason: format!(
                        "{} = {} must be above the lower bound {}; widen the box",
                        THETA_NAMES[i], hi[i], lo[i]
                    ),
                });
            }
        }
        if self.upper.c_e <= 0.0 || self.upper.t_r <= 0.0 {
            return Err(Error::InvalidOption {
                field: "upper",
                reason: "the box must contain positive c_e and t_r".into(),
            });
        }
        if self.particles < 2 {
            return Err(Error::InvalidOption { field: "particles", reason: "must be at least 2".into() });
        }
        if !(self.refine_tolerance_m.is_finite() && self.refine_tolerance_m > 0.0) {
            return Err(Error::InvalidOption {
                field: "refine_tolerance_m",
                reason: "must be a positive number of metres".into(),
            });
        }
        for (i, s) in self.starts.iter().enumerate() {
            s.validate().map_err(|e| Error::InvalidOption { field: "starts", reason: format!("start {i}: {e}") })?;
        }
        self.extrinsics.validate()
    }
}

/// The outcome of `reachable_minimum`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReachableReport {
    /// The best θ found.
    pub theta: Theta,
    /// `Ē_p` at [`theta`](Self::theta), metres: the reachable minimum.
    pub mean_position_error_m: f64,
    /// `Ē_p` at the box centre (θ_0 for [`ReachableOptions::around`]), metres.
    pub centre_mean_position_error_m: f64,
    /// Objective evaluations in both stages, each one `Ē_p` over all the
    /// validation segments (points outside the box count but are not simulated).
    pub evaluations: usize,
    /// Best `Ē_p` after the global stage (swarm and starts), metres.
    pub global_best_m: f64,
    /// Wall-clock time of the search, seconds.
    pub time_s: f64,
    /// How the two stages ended, with numbers, e.g. `"swarm: 60 iterations,
    /// best 0.0123 m; refinement: Solver converged after 143 iterations"`
    /// (of the last box searched).
    pub termination: String,
    /// Parameters of [`theta`](Self::theta) within `EDGE_FRACTION` of a
    /// bound of the last box searched: the minimum may lie beyond.
    #[serde(default)]
    pub at_edge: ParamSet,
    /// True when no parameter is on the edge: the minimum is enclosed by
    /// the last box searched.
    #[serde(default = "enclosed_default")]
    pub enclosed: bool,
    /// Times the box was re-centred on a best point on its edge.
    #[serde(default)]
    pub recentred: usize,
    /// Lower corner of the last box searched.
    #[serde(default)]
    pub lower: Option<Theta>,
    /// Upper corner of the last box searched.
    #[serde(default)]
    pub upper: Option<Theta>,
    /// The reference mount every `Ē_p` of the search used
    /// ([`ReachableOptions::extrinsics`]); omitted in JSON when 0.
    #[serde(default, skip_serializing_if = "Extrinsics::is_zero")]
    pub extrinsics: Extrinsics,
}

fn enclosed_default() -> bool {
    true
}

impl std::fmt::Display for ReachableReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "reachable minimum Ē_p = {:.4} m at {} (centre {:.4} m; {} evaluations, {:.2} s",
            self.mean_position_error_m, self.theta, self.centre_mean_position_error_m, self.evaluations, self.time_s
        )?;
        if self.recentred > 0 {
            write!(f, "; box re-centred {} time(s)", self.recentred)?;
        }
        f.write_str(")")?;
        if !self.enclosed {
            write!(f, "; NOT ENCLOSED: {} on the edge of the search box, the minimum may lie beyond", self.at_edge)?;
        }
        Ok(())
    }
}

/// `Ē_p` as a function of scaled coordinates `u ∈ [0, 1]⁴`.
#[derive(Clone)]
struct Objective<'a> {
    drive: &'a Drive,
    segments: &'a [Segment],
    lower: [f64; 4],
    width: [f64; 4],
    evaluations: &'a AtomicUsize,
    progress: Option<ProgressFn<'a>>,
    extrinsics: &'a Extrinsics,
}

impl Objective<'_> {
    fn theta(&self, u: &[f64]) -> Theta {
        Theta {
            c_e: self.lower[0] + u[0] * self.width[0],
            c_d: self.lower[1] + u[1] * self.width[1],
            t_r: self.lower[2] + u[2] * self.width[2],
            d: self.lower[3] + u[3] * self.width[3],
        }
    }

    fn scaled(&self, theta: &Theta) -> Vec<f64> {
        let t = theta.to_array();
        (0..4).map(|i| (t[i] - self.lower[i]) / self.width[i]).collect()
    }

    /// `Ē_p(θ)`, or [`PENALTY_M`] where θ is invalid or the error not finite.
    fn error_at(&self, theta: &Theta) -> f64 {
        self.count();
        mean_position_error_with(self.drive, self.segments, theta, self.extrinsics)
            .map_or(PENALTY_M, |r| r.mean_position_error_m)
    }

    fn count(&self) {
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        emit(self.progress, Progress::Advance(1));
    }

    fn scaled_cost(&self, u: &[f64]) -> f64 {
        let outside: f64 = u.iter().map(|&x| (-x).max(0.0) + (x - 1.0).max(0.0)).sum();
        if outside > 0.0 {
            self.count();
            return PENALTY_M * (1.0 + outside);
        }
        self.error_at(&self.theta(u))
    }
}

impl CostFunction for Objective<'_> {
    type Param = Vec<f64>;
    type Output = f64;

    fn cost(&self, u: &Self::Param) -> std::result::Result<f64, argmin::core::Error> {
        Ok(self.scaled_cost(u))
    }
}

fn argmin_error(stage: &str, e: argmin::core::Error) -> Error {
    Error::Numerical(format!("reachable minimum, {stage}: {e}"))
}

research_pub! {
    /// Finds the reachable minimum `min_θ Ē_p(θ)` on `segments` of `drive` by a
    /// seeded particle swarm over the box of `opts`, refined by Nelder-Mead;
    /// `progress` hears one stage per box searched (`"reachable: swarm"`,
    /// `"reachable: refine"`) advancing by one per evaluation of `Ē_p`.
    ///
    /// Errors when the options are invalid (naming the field), when there are no
    /// segments, or when `Ē_p` cannot be computed at the box centre.
    fn reachable_minimum(
        drive: &Drive,
        segments: &[Segment],
        opts: &ReachableOptions,
        progress: Option<ProgressFn<'_>>,
    ) -> Result<ReachableReport> {
        let started = Instant::now();
        // `search_box` validates the options (and each re-centred box).
        let mut report = search_box(drive, segments, opts, progress)?;
        let mut evaluations = report.evaluations;
        let mut recentred = 0;
        let centre_error = report.centre_mean_position_error_m;
        let mut box_opts = opts.clone();
        while !report.at_edge.is_empty() && recentred < opts.recentre {
            // Same widths around the best point; the best point and the
            // caller's starts seed the new search.
            let best = report.theta;
            let half = (box_opts.upper.to_vector() - box_opts.lower.to_vector()) / 2.0;
            let c = best.to_vector();
            box_opts.lower = Theta::from_vector(&(c - half));
            box_opts.upper = Theta::from_vector(&(c + half));
            box_opts.starts = std::iter::once(best).chain(opts.starts.iter().copied()).collect();
            box_opts.seed = opts.seed.wrapping_add(recentred as u64 + 1);
            recentred += 1;
            let next = search_box(drive, segments, &box_opts, progress)?;
            evaluations += next.evaluations;
            // The new search is seeded with the best point, so never worse.
            report = next;
        }
        report.evaluations = evaluations;
        report.recentred = recentred;
        report.centre_mean_position_error_m = centre_error;
        report.time_s = started.elapsed().as_secs_f64();
        Ok(report)
    }
}

/// One search in the box of `opts` (see the module docs).
fn search_box(
    drive: &Drive,
    segments: &[Segment],
    opts: &ReachableOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<ReachableReport> {
    let started = Instant::now();
    opts.validate()?;
    let evaluations = AtomicUsize::new(0);
    let lower = opts.lower.to_array();
    let upper = opts.upper.to_array();
    let width = [upper[0] - lower[0], upper[1] - lower[1], upper[2] - lower[2], upper[3] - lower[3]];
    let extrinsics = &opts.extrinsics;
    let obj = Objective { drive, segments, lower, width, evaluations: &evaluations, progress, extrinsics };
    let swarm_total = 1 + 2 * opts.starts.len() + opts.particles * (opts.iterations + 1);
    emit(progress, Progress::Stage { name: "reachable: swarm", total: swarm_total as u64 });

    // Starts: the box centre first, then the caller's, each evaluated as given.
    let centre = opts.centre();
    let centre_error = mean_position_error_with(drive, segments, &centre, extrinsics)?.mean_position_error_m;
    evaluations.fetch_add(1, Ordering::Relaxed);
    let (mut best, seeds) = seed_points(&obj, (centre_error, centre), &opts.starts, opts.particles);
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed);
    let population = initial_population(&obj, seeds, opts.particles, &mut rng);

    // Stage 1: particle swarm in [0, 1]⁴.
    let (swarm_best, swarm_iterations) = swarm(&obj, population, &rng, opts)?;
    if swarm_best.0 < best.0 {
        best = (swarm_best.0, obj.theta(&swarm_best.1));
    }
    let global_best_m = best.0;
    let mut termination = format!("swarm: {swarm_iterations} iterations, best {global_best_m:.6} m");

    // Stage 2: Nelder-Mead from the swarm's best (always inside the box).
    if opts.refine_iterations > 0 {
        emit(progress, Progress::Stage { name: "reachable: refine", total: 2 * opts.refine_iterations as u64 + 5 });
        termination.push_str(&refine(&obj, swarm_best.1, opts, &mut best)?);
    }

    let u = obj.scaled(&best.1);
    let at_edge: ParamSet =
        (0..4).filter(|&i| u[i] < EDGE_FRACTION || u[i] > 1.0 - EDGE_FRACTION).filter_map(Param::from_index).collect();
    Ok(ReachableReport {
        theta: best.1,
        mean_position_error_m: best.0,
        centre_mean_position_error_m: centre_error,
        evaluations: evaluations.load(Ordering::Relaxed),
        global_best_m,
        time_s: started.elapsed().as_secs_f64(),
        termination,
        enclosed: at_edge.is_empty(),
        at_edge,
        recentred: 0,
        lower: Some(opts.lower),
        upper: Some(opts.upper),
        extrinsics: opts.extrinsics,
    })
}

/// A point of the unit box with its Ē_p.
type ScaledPoint = (Vec<f64>, f64);

/// The swarm's seeds: the box centre (`centre`, with its Ē_p) and each of
/// `starts` evaluated as given, then clamped into the box (re-evaluated
/// there when it was outside); the best `particles` of them (stable order
/// for ties). Also the best point evaluated, `(Ē_p, θ)`.
fn seed_points(
    obj: &Objective<'_>,
    centre: (f64, Theta),
    starts: &[Theta],
    particles: usize,
) -> ((f64, Theta), Vec<ScaledPoint>) {
    let mut best = centre;
    let mut seeds: Vec<ScaledPoint> = vec![(obj.scaled(&centre.1), centre.0)];
    for s in starts {
        let e = obj.error_at(s);
        if e < best.0 {
            best = (e, *s);
        }
        let u = obj.scaled(s);
        let inside = u.iter().all(|x| (0.0..=1.0).contains(x));
        let clamped: Vec<f64> = u.iter().map(|x| x.clamp(0.0, 1.0)).collect();
        let e_clamped = if inside { e } else { obj.scaled_cost(&clamped) };
        seeds.push((clamped, e_clamped));
    }
    seeds.sort_by(|a, b| a.1.total_cmp(&b.1));
    seeds.truncate(particles);
    (best, seeds)
}

/// The swarm's first population: the seeds, then random points of the box
/// up to `particles`, each with a random velocity.
fn initial_population(
    obj: &Objective<'_>,
    seeds: Vec<ScaledPoint>,
    particles: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<Particle<Vec<f64>, f64>> {
    let mut population = Vec::with_capacity(particles);
    let random_unit =
        |rng: &mut ChaCha8Rng, lo: f64| -> Vec<f64> { (0..4).map(|_| rng.random_range(lo..1.0)).collect() };
    for (u, e) in seeds {
        let v = random_unit(rng, -1.0);
        population.push(Particle::new(u, e, v));
    }
    while population.len() < particles {
        let u = random_unit(rng, 0.0);
        let v = random_unit(rng, -1.0);
        let e = obj.scaled_cost(&u);
        population.push(Particle::new(u, e, v));
    }
    population
}

/// The particle swarm from `population`: argmin's default inertia and
/// acceleration factors (Clerc's standard PSO); `rng` replaces the
/// OS-seeded default so the search is reproducible. Its best `(Ē_p, u)`
/// and its iterations.
fn swarm(
    obj: &Objective<'_>,
    population: Vec<Particle<Vec<f64>, f64>>,
    rng: &ChaCha8Rng,
    opts: &ReachableOptions,
) -> Result<((f64, Vec<f64>), u64)> {
    let swarm = ParticleSwarm::new((vec![0.0; 4], vec![1.0; 4]), opts.particles).with_rng_generator(rng.clone());
    let res = Executor::new(obj.clone(), swarm)
        .configure(|s| s.population(population).max_iters(opts.iterations as u64))
        .timer(false)
        .run()
        .map_err(|e| argmin_error("particle swarm", e))?;
    let best = res
        .state()
        .get_best_param()
        .map(|p| (p.cost, p.position.clone()))
        .ok_or_else(|| Error::Numerical("reachable minimum: the swarm returned no particle".into()))?;
    Ok((best, res.state().get_iter()))
}

/// Nelder-Mead from `x0` (one to two evaluations per iteration, four more
/// at a shrink), replacing `best` when it finds a lower Ē_p; what it did,
/// as the termination text goes on.
fn refine(obj: &Objective<'_>, x0: Vec<f64>, opts: &ReachableOptions, best: &mut (f64, Theta)) -> Result<String> {
    let mut simplex = vec![x0.clone()];
    for i in 0..4 {
        let mut x = x0.clone();
        x[i] += if x[i] + SIMPLEX_STEP <= 1.0 { SIMPLEX_STEP } else { -SIMPLEX_STEP };
        simplex.push(x);
    }
    let nm = NelderMead::new(simplex)
        .with_sd_tolerance(opts.refine_tolerance_m)
        .map_err(|e| argmin_error("Nelder-Mead", e))?;
    let res = Executor::new(obj.clone(), nm)
        .configure(|s| s.max_iters(opts.refine_iterations as u64))
        .timer(false)
        .run()
        .map_err(|e| argmin_error("Nelder-Mead", e))?;
    let state = res.state();
    let reason = state.get_termination_reason().map_or("stopped", |r| r.text());
    if let Some(p) = state.get_best_param() {
        let cost = state.get_best_cost();
        if cost < best.0 {
            *best = (cost, obj.theta(p));
        }
    }
    Ok(format!("; refinement: {reason} after {} iterations, best {:.6} m", state.get_iter(), best.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::assess::position_error::mean_position_error;
    use crate::drive::segment::{validation_segments, ValidationSegmentOptions};
    use crate::drive::Signals;
    use crate::model::{step, Input, State};

    /// Sample time of the synthetic drive, s (40 Hz).
    const TS: f64 = 0.025;
    /// With noise-free data the minimum is exactly 0; the search must get
    /// within a millimetre of it.
    const ZERO_ERROR_M: f64 = 1e-3;

    /// A reference mounted off the axle: with the mount, the search finds
    /// the noise-free minimum (≈ 0 at θ_true) and `validate`'s Ē_p of θ_true
    /// can never beat its reachable minimum; at the axle (what the search
    /// did before) the minimum is metres and θ_true, validated on its mount,
    /// appears to beat the "reachable minimum".
    #[test]
    fn the_search_uses_the_reference_mount_of_the_validation() {
        use crate::assess::validate::{validate_theta as validate, ValidateOptions};
        use crate::sim::{simulate, SimOptions};
        let mount = Extrinsics { lever_x: -0.9, lever_y: 0.3, heading_offset: -0.01 };
        let sim = SimOptions { length_km: 2.0, substeps: 1, reference_mount: mount, ..SimOptions::noise_free(3) };
        let s = simulate(&sim).expect("simulate");
        let truth = s.sidecar.theta_true;
        let search = ReachableOptions {
            particles: 12,
            iterations: 10,
            refine_iterations: 150,
            starts: vec![truth],
            ..ReachableOptions::around(&truth)
        };
        let run = |extrinsics: Extrinsics| {
            let opts = ValidateOptions { extrinsics, reachable: Some(search.clone()), ..Default::default() };
            validate(&s.drive, &truth, &opts, None).expect("validate")
        };
        let mounted = run(mount);
        let rm = mounted.reachable_minimum.as_ref().expect("searched");
        assert!(mounted.validation.mean_position_error_m < 1e-6, "{}", mounted.validation.mean_position_error_m);
        assert_eq!(rm.extrinsics, mount);
        assert!(rm.mean_position_error_m <= mounted.validation.mean_position_error_m, "{rm:?}");
        assert!(rm.mean_position_error_m < ZERO_ERROR_M, "{}", rm.mean_position_error_m);
        // Ignoring the mount, the best θ still misses by far more.
        let at_axle = reachable_minimum(
            &s.drive,
            &validation_segments(&s.drive, &ValidationSegmentOptions::default()).expect("segments"),
            &search,
            None,
        )
        .expect("search");
        eprintln!(
            "reachable minimum: {} m with the mount, {} m at the axle",
            rm.mean_position_error_m, at_axle.mean_position_error_m
        );
        assert!(at_axle.mean_position_error_m > 100.0 * ZERO_ERROR_M, "{}", at_axle.mean_position_error_m);
        // A bad mount is an option error naming it.
        let bad = ReachableOptions { extrinsics: Extrinsics { lever_x: f64::NAN, ..mount }, ..search.clone() };
        assert!(bad.validate().is_err());
    }

    /// A noise-free ~3 min drive: speed 7–13 m/s, curvature alternating in
    /// sign (figure-of-eight-like) with varying amplitude, wheel rotations
    /// from inverting the model at θ_true, reference = the model trajectory.
    fn synthetic_drive(theta: &Theta) -> Drive {
        let n = 7200;
        let mut cols: [Vec<f64>; 8] = Default::default();
        let mut x = State::new(10.0, -5.0, 0.3);
        for k in 0..n {
            let t = k as f64 * TS;
            let v = 10.0 + 3.0 * (2.0 * std::f64::consts::PI * t / 57.0).sin();
            let kappa = 0.04 * (2.0 * std::f64::consts::PI * t / 40.0).sin()
                + 0.02 * (2.0 * std::f64::consts::PI * t / 13.0).sin();
            let omega = v * kappa;
            let a_y = v * omega;
            let beta = -0.002 * a_y;
            let (n_rl, n_rr) = crate::model::wheel_rotations(v, omega, a_y, theta);
            for (c, val) in cols.iter_mut().zip([t, x[0], x[1], x[2], n_rl, n_rr, beta, a_y]) {
                c.push(val);
            }
            x = step(&x, &Input { n_rl, n_rr, beta, a_y }, theta, TS);
        }
        let [t, px, py, psi, n_rl, n_rr, beta, a_y] = cols;
        crate::drive::DriveBuilder {
            t,
            measured: Signals { px, py, psi, n_rl, n_rr, beta, a_y },
            context: "synthetic".into(),
            ..Default::default()
        }
        .build()
        .expect("valid drive")
    }

    fn setup() -> (Drive, Vec<Segment>) {
        let drive = synthetic_drive(&Theta::SIM_DEFAULT_TRUE);
        let segs = validation_segments(&drive, &ValidationSegmentOptions::default()).expect("segments");
        assert!(segs.len() >= 5, "{} segments", segs.len());
        (drive, segs)
    }

    #[test]
    fn reachable_recovers_true_theta_without_noise() {
        let (drive, segs) = setup();
        let truth = Theta::SIM_DEFAULT_TRUE;
        let opts = ReachableOptions::around(&Theta::PAPER_INITIAL);
        let r = reachable_minimum(&drive, &segs, &opts, None).expect("search");
        eprintln!("{r}\n{}", r.termination);
        // The start is off: θ_0 is metres away.
        assert!(r.centre_mean_position_error_m > 1.0, "Ē_p(θ_0) = {}", r.centre_mean_position_error_m);
        assert!(r.mean_position_error_m < ZERO_ERROR_M, "{r}");
        assert!(r.mean_position_error_m <= r.global_best_m);
        // Ē_p < 1 mm over 1300-step (~330 m) segments pins θ to about these.
        approx::assert_relative_eq!(r.theta.c_e, truth.c_e, max_relative = 1e-5);
        approx::assert_abs_diff_eq!(r.theta.c_d, truth.c_d, epsilon = 2e-5);
        approx::assert_relative_eq!(r.theta.t_r, truth.t_r, max_relative = 1e-3);
        approx::assert_abs_diff_eq!(r.theta.d, truth.d, epsilon = 2e-5);
        let again = mean_position_error(&drive, &segs, &r.theta).expect("valid").mean_position_error_m;
        approx::assert_relative_eq!(again, r.mean_position_error_m, max_relative = 1e-12);
        assert!(r.evaluations >= opts.particles * (opts.iterations + 1));
    }

    #[test]
    fn reachable_is_deterministic_and_seed_dependent() {
        let (drive, segs) = setup();
        let opts = ReachableOptions { iterations: 10, refine_iterations: 20, seed: 42, ..Default::default() };
        let a = reachable_minimum(&drive, &segs, &opts, None).expect("a");
        let b = reachable_minimum(&drive, &segs, &opts, None).expect("b");
        assert_eq!(ReachableReport { time_s: 0.0, ..a.clone() }, ReachableReport { time_s: 0.0, ..b });
        let c = reachable_minimum(&drive, &segs, &ReachableOptions { seed: 43, ..opts }, None).expect("c");
        assert_ne!(a.theta, c.theta, "a different seed should search differently");
    }

    #[test]
    fn reachable_is_never_worse_than_a_start() {
        let (drive, segs) = setup();
        // A good start inside the box, and one outside it (c_e 1.7 < 1.8);
        // a tiny search cannot improve on the first.
        let near = Theta { c_e: 1.95001, ..Theta::SIM_DEFAULT_TRUE };
        let outside = Theta { c_e: 1.7, ..Theta::SIM_DEFAULT_TRUE };
        let opts = ReachableOptions {
            particles: 4,
            iterations: 2,
            refine_iterations: 0,
            starts: vec![outside, near],
            ..Default::default()
        };
        let r = reachable_minimum(&drive, &segs, &opts, None).expect("search");
        for s in [opts.centre(), outside, near] {
            let e = mean_position_error(&drive, &segs, &s).expect("valid").mean_position_error_m;
            assert!(r.mean_position_error_m <= e, "{r} vs start {s}: {e}");
        }
        // centre, two starts, the projected outside start, one random particle, two iterations
        assert_eq!(r.evaluations, 1 + 2 + 1 + 1 + 4 * 2);
        // A start outside the box that is the best seen is returned as is.
        let opts = ReachableOptions {
            lower: Theta { c_e: 1.96, ..opts.lower },
            starts: vec![Theta::SIM_DEFAULT_TRUE],
            recentre: 0,
            ..opts
        };
        let r = reachable_minimum(&drive, &segs, &opts, None).expect("search");
        assert_eq!(r.theta, Theta::SIM_DEFAULT_TRUE);
    }

    /// θ_0 with t_r = 1.2 m: the box's t_r range [0.96, 1.44] m leaves out
    /// the truth, 1.53 m. Without re-centring the result is flagged; with
    /// it, the minimum is enclosed and found.
    #[test]
    fn a_minimum_outside_the_box_is_flagged_or_enclosed() {
        let (drive, segs) = setup();
        let truth = Theta::SIM_DEFAULT_TRUE;
        let theta0 = Theta { t_r: 1.2, ..Theta::PAPER_INITIAL };
        let small = ReachableOptions {
            particles: 12,
            iterations: 15,
            refine_iterations: 80,
            ..ReachableOptions::around(&theta0)
        };
        assert!(small.upper.t_r < truth.t_r);
        let flagged =
            reachable_minimum(&drive, &segs, &ReachableOptions { recentre: 0, ..small.clone() }, None).expect("search");
        assert!(!flagged.enclosed, "{flagged}");
        assert!(flagged.at_edge.contains(Param::TR), "{flagged}");
        assert_eq!(flagged.recentred, 0);
        assert!(flagged.to_string().contains("NOT ENCLOSED: t_r"), "{flagged}");
        assert!(small.upper.t_r - flagged.theta.t_r < EDGE_FRACTION * 0.48, "{flagged}");

        let enclosed = reachable_minimum(&drive, &segs, &small, None).expect("search");
        eprintln!("{enclosed}");
        assert!(enclosed.recentred >= 1, "{enclosed}");
        assert!(enclosed.recentred <= DEFAULT_RECENTRE);
        assert!(enclosed.enclosed && enclosed.at_edge.is_empty(), "{enclosed}");
        assert!(enclosed.mean_position_error_m < flagged.mean_position_error_m, "{enclosed} vs {flagged}");
        assert!((enclosed.theta.t_r - truth.t_r).abs() < 0.03, "{enclosed}");
        assert!(enclosed.evaluations > flagged.evaluations);
        let u = enclosed.upper.expect("box");
        assert!(u.t_r > truth.t_r, "the last box holds the truth: {u}");
    }

    #[test]
    fn invalid_options_name_the_field() {
        let (drive, segs) = setup();
        let d = ReachableOptions::default();
        let cases = [
            ("particles", ReachableOptions { particles: 1, ..d.clone() }),
            ("upper", ReachableOptions { upper: Theta { c_d: -0.03, ..d.upper }, ..d.clone() }),
            ("lower", ReachableOptions { lower: Theta { d: f64::NAN, ..d.lower }, ..d.clone() }),
            ("refine_tolerance_m", ReachableOptions { refine_tolerance_m: 0.0, ..d.clone() }),
            ("starts", ReachableOptions { starts: vec![Theta { t_r: -1.0, ..d.upper }], ..d.clone() }),
        ];
        for (field, o) in cases {
            let e = reachable_minimum(&drive, &segs, &o, None).expect_err(field);
            assert!(e.to_string().contains(&format!("`{field}`")), "{field}: {e}");
        }
        assert!(matches!(reachable_minimum(&drive, &[], &d, None), Err(Error::NoSegments(_))));
    }

    #[test]
    fn default_box_matches_spec() {
        let o = ReachableOptions::default();
        approx::assert_relative_eq!(o.lower.c_e, 1.8, max_relative = 1e-12);
        approx::assert_relative_eq!(o.upper.c_d, 0.02, max_relative = 1e-12);
        approx::assert_relative_eq!(o.lower.t_r, 1.28, max_relative = 1e-12);
        approx::assert_relative_eq!(o.upper.d, 0.005, max_relative = 1e-12);
        let c = o.centre();
        approx::assert_relative_eq!(c.c_e, 2.0, max_relative = 1e-12);
        approx::assert_relative_eq!(c.t_r, 1.6, max_relative = 1e-12);
        o.validate().expect("default is valid");
    }
}
