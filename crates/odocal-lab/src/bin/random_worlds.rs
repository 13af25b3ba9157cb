//! The calibration methods on random noise worlds: simulated drives whose
//! noise settings are drawn from wide ranges
//! (`odocal::sim::NoiseOptions::random_world`; the distribution and the
//! regime rule are in docs/reference.md, "Random noise worlds"), not from
//! the white-noise dominated presets the default was chosen on
//! (docs/validation.md, "Random noise worlds").
//!
//! World i (i = 0..N) has world seed S + i; its drive is simulated with
//! that seed as the drive seed too (paper route and speed options, true θ
//! [`Theta::SIM_DEFAULT_TRUE`], `--length-km` long). Estimates are judged
//! against the truth the data are consistent with
//! (`SimOptions::equivalent_truth`): c_d shifted by −2·d·(a_y bias), and
//! the reference heading offset δ = heading bias + sideslip bias; no
//! calibration can tell these apart. Methods, all through
//! `odocal::calibrate` as a user runs them:
//! - `eiv`: the default (`calibrate` without options);
//! - `batch-gn`: `--method batch-gn --estimate heading-offset`;
//! - `three-step`: `--method three-step --estimate heading-offset`.
//!
//! Per method and parameter (c_e, t_r in %, c_d in mm, d in mm/(m/s²)):
//! mean error (bias) with t = |mean|/(sd/√n), RMS error, RMS of error/σ,
//! coverage of the reported 95 % interval (|error| ≤ 1.96 σ of the
//! result's σ, `CalibrationReport::result_sigma`), and on the white-only
//! worlds (white wheel and reference noise: the noise the bound
//! represents) the RMS of error/CRB, the mean-only Cramér–Rao bound at
//! θ_true with the true noise model (`eiv::cramer_rao_bound`,
//! `EivOptions::spec`). Per method: verdicts (accepted / doubtful /
//! rejected), results accepted with some parameter beyond 3 σ, the EIV
//! fallback rate, and Ē_p on held-out data: a fresh drive of the same world
//! (seed + 10 000, same noise settings, never seen by a fit), dead reckoned
//! with the estimated θ and extrinsics, less Ē_p of the equivalent truth
//! (θ and δ) there. Overall and by regime.
//!
//! Output: Markdown tables on stdout; with `--out DIR`, `DIR/results.csv`
//! (a row per world × method; for the default method also its own EIV
//! estimate before any fallback, error and σ, its fitted η and its check
//! findings) and `DIR/worlds.csv` (a row per world: its noise settings). Worlds run in parallel (rayon; `--threads`), the
//! output is the same for any thread count. Progress and wall times go to
//! stderr.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use odocal::eiv::{cramer_rao_bound, EivInput, EivOptions, NoiseModel};
use odocal::research::mean_position_error_with;
use odocal::segment::{validation_segments, Segment, ValidationSegmentOptions};
use odocal::sim::{simulate, NoiseOptions, NoiseRegime, SimOptions, WorldSummary};
use odocal::{
    calibrate, CalibrationOptions, CalibrationReport, Drive, Extrinsics, Method, Param, ParamSet, Theta, VerdictLevel,
    VerdictReason,
};
use odocal_lab::report_json::{eiv_part, EivPart};
use odocal_lab::{
    coverage, error_scale, errors, median, Args, ReadingsNoise, Res, Summary, Table, ERROR_UNITS, FRESH_SEED_OFFSET,
};
use rayon::prelude::*;

const USAGE: &str = concat!(
    "random_worlds [--worlds 100] [--length-km 12] [--seed 1] [--methods eiv,batch-gn,three-step]
    [--out DIR] [--threads N] [--heading-drift-gate G] [--heading-drift-lr T] [--heavy]
    [--eta-max X] [--tau-c S] [--tau-drift S] [--heavy-without slip|common]
    [--eta-without-jacobian] [--no-common-jacobian] [--position-drift-own-scale] [--position-drift-tau S]
    [--heading-drift-two-sided] [--no-clamp-refit] [--clamp-refit-common-eta X] [--heading-drift-min-eta X]
    [--correct-bias-of PARAMS] [--lateral-from-readings] [--a-y-held-from-readings] [--no-a-y-floor] [--no-heading-floor] [--heading-white-estimated]
    [--time-constant-choice]

World i has world seed S + i (drive seed too); every method runs through odocal::calibrate.
--heavy: each world's wheel noise replaced by heavy common-mode coloured noise and slip (NoiseOptions::with_heavy_wheels).
--eta-max, --tau-c, --tau-drift: the default's upper clamp of the noise scales η, its common-mode time constant τ_c
    and its reference-drift time constant.
--heavy-without slip|common: the heavy worlds without their acceleration slip or their common-mode noise.
--eta-without-jacobian: the default's η step on M without the Gauss-Markov log-Jacobian
    (coloured_jacobian_in_marginal off).
--no-common-jacobian: the default without the common-mode state's log-Jacobian in J and M
    (common_mode_jacobian off).
--position-drift-own-scale: the default with the pose-drift scale η_4 on the reference's position drift only, the
    heading drift on the heading white noise's scale (position_drift_own_scale).
--position-drift-tau S: the default with the reference's position drift at correlation time S
    (position_drift_time_constant_s; the heading drift keeps --tau-drift or the default).
--heading-drift-two-sided: the default's heading-drift test releases the heading drift in both directions
    (heading_drift_two_sided).
--no-clamp-refit: the default without the refit, after a fit that fails with a noise scale at its upper clamp, with
    c_e held at the batch G-N start's (clamp_refit_hold_scale off).
--no-a-y-floor: the default without the floor of a_y's σ at its readings' white noise (a_y_floor_from_readings off).
--no-heading-floor: the default without the heading readings' white noise in the heading's variance (heading_floor_from_readings off).
--heading-white-estimated: the heading's white noise estimated above its readings' from the start (heading_white_readings_first off).
--time-constant-choice: the default with a slow wheel-noise model (τ_c × 10, τ_w × 20) tried where a noise source
    ends at its lower clamp, the fit with the lower M kept (choose_time_constants on).
--clamp-refit-common-eta X: in that refit, the common-mode wheel noise scale η_1 held at X
    (clamp_refit_common_mode_eta; the refit runs with this alone too).
--heading-drift-min-eta X: the floor of the heading drift's tie to the pose-drift scale η_4 (heading_drift_min_eta;
    -20, the η lower bound, ties it all the way).
--correct-bias-of PARAMS: the parameters of θ the default's bias correction corrects (`c_e,c_d,t_r,d`: every one;
    the default c_e,c_d).
",
    odocal_lab::readings_noise_usage!()
);

/// The methods the study knows, by their `--method` names.
const METHODS: [&str; 3] = ["eiv", "batch-gn", "three-step"];

struct Settings {
    worlds: u64,
    km: f64,
    seed: u64,
    methods: Vec<String>,
    out: Option<PathBuf>,
    /// The default's heading-drift score gate and likelihood-ratio threshold (None: the defaults).
    heading_drift: (Option<f64>, Option<f64>),
    /// `--heavy`: the worlds' wheel noise replaced (`NoiseOptions::with_heavy_wheels`).
    heavy: bool,
    /// The default's noise-scale upper clamp and common-mode τ_c (None: the defaults).
    eiv_noise: (Option<f64>, Option<f64>),
    /// The default's reference-drift time constant (None: the default).
    tau_drift: Option<f64>,
    /// `--heavy-without`: the heavy worlds without their acceleration slip
    /// (`slip`) or without their common-mode coloured noise (`common`).
    heavy_without: Option<String>,
    /// `--eta-without-jacobian`: `ResearchOptions::coloured_jacobian_in_marginal` off.
    eta_without_jacobian: bool,
    /// `--no-common-jacobian`: `ResearchOptions::common_mode_jacobian` off.
    no_common_jacobian: bool,
    /// `--position-drift-own-scale`: `ResearchOptions::position_drift_own_scale` on.
    position_drift_own_scale: bool,
    /// `--position-drift-tau`: `ResearchOptions::position_drift_time_constant_s`.
    position_drift_tau: Option<f64>,
    /// `--heading-drift-two-sided`: `ResearchOptions::heading_drift_two_sided` on.
    heading_drift_two_sided: bool,
    /// `--no-clamp-refit`: `ResearchOptions::clamp_refit_hold_scale` off.
    no_clamp_refit: bool,
    /// `--no-a-y-floor`: `ResearchOptions::a_y_floor_from_readings` off.
    no_a_y_floor: bool,
    /// `--no-heading-floor`: `ResearchOptions::heading_floor_from_readings` off.
    no_heading_floor: bool,
    /// `--heading-white-estimated`: `EivMethodOptions::heading_white_readings_first` off.
    heading_white_estimated: bool,
    /// `--time-constant-choice`: `ResearchOptions::choose_time_constants` on.
    time_constant_choice: bool,
    /// `--clamp-refit-common-eta`: `ResearchOptions::clamp_refit_common_mode_eta`.
    clamp_refit_common_eta: Option<f64>,
    /// `--heading-drift-min-eta`: `ResearchOptions::heading_drift_min_eta`
    /// (the η lower bound, −20, ties the heading drift to η_4 all the way).
    heading_drift_min_eta: Option<f64>,
    /// `--correct-bias-of`: the parameters the default's bias correction
    /// corrects (`CorrectBias::parameters`); None: the default's.
    correct_bias_of: Option<ParamSet>,
    /// `--lateral-from-readings`, `--a-y-held-from-readings`.
    readings_noise: ReadingsNoise,
}

fn settings() -> Res<(Settings, Option<usize>)> {
    let [lateral, a_y_held] = ReadingsNoise::SWITCHES;
    let mut a = Args::parse(
        USAGE,
        &[
            "heavy",
            "eta-without-jacobian",
            "no-common-jacobian",
            "position-drift-own-scale",
            "heading-drift-two-sided",
            "no-clamp-refit",
            "no-a-y-floor",
            "no-heading-floor",
            "heading-white-estimated",
            "time-constant-choice",
            lateral,
            a_y_held,
        ],
    )?;
    let s = Settings {
        worlds: a.get("worlds", 100)?,
        km: a.get("length-km", 12.0)?,
        seed: a.get("seed", 1)?,
        methods: a.list("methods", &METHODS),
        out: a.opt("out")?,
        heading_drift: (a.opt("heading-drift-gate")?, a.opt("heading-drift-lr")?),
        heavy: a.flag("heavy"),
        eiv_noise: (a.opt("eta-max")?, a.opt("tau-c")?),
        tau_drift: a.opt("tau-drift")?,
        heavy_without: a.opt("heavy-without")?,
        eta_without_jacobian: a.flag("eta-without-jacobian"),
        no_common_jacobian: a.flag("no-common-jacobian"),
        position_drift_own_scale: a.flag("position-drift-own-scale"),
        position_drift_tau: a.opt("position-drift-tau")?,
        heading_drift_two_sided: a.flag("heading-drift-two-sided"),
        no_clamp_refit: a.flag("no-clamp-refit"),
        no_a_y_floor: a.flag("no-a-y-floor"),
        no_heading_floor: a.flag("no-heading-floor"),
        heading_white_estimated: a.flag("heading-white-estimated"),
        time_constant_choice: a.flag("time-constant-choice"),
        clamp_refit_common_eta: a.opt("clamp-refit-common-eta")?,
        heading_drift_min_eta: a.opt("heading-drift-min-eta")?,
        readings_noise: ReadingsNoise::from_args(&a),
        correct_bias_of: a.opt("correct-bias-of")?,
    };
    let threads = a.opt("threads")?;
    a.finish()?;
    if let Some(m) = s.methods.iter().find(|m| !METHODS.contains(&m.as_str())) {
        return Err(format!("unknown method '{m}'; expected some of {}", METHODS.join(", ")).into());
    }
    Ok((s, threads))
}

/// The options a user's `calibrate` runs with for `method`.
fn options(
    method: &str,
    heading_drift: (Option<f64>, Option<f64>),
    eiv_noise: (Option<f64>, Option<f64>),
) -> Res<CalibrationOptions> {
    let mut o = CalibrationOptions { method: method.parse::<Method>()?, ..Default::default() };
    if let Method::Eiv(e) = &mut o.method {
        if let Some(x) = eiv_noise.0 {
            e.filter.eta_bounds[1] = x;
        }
        if let Some(t) = eiv_noise.1 {
            e.filter.noise.wheel_common_time_constant_s = t;
        }
        let r = &mut e.filter.research;
        r.heading_drift_score_gate = heading_drift.0.unwrap_or(r.heading_drift_score_gate);
        r.heading_drift_lr_threshold = heading_drift.1.unwrap_or(r.heading_drift_lr_threshold);
    }
    if method != "eiv" {
        // `--estimate heading-offset`; the default method estimates δ by itself.
        o.identify.free = o.identify.free.with(Param::HeadingOffset);
    }
    Ok(o)
}

/// One method's result on one world's drive.
struct Run {
    theta: Theta,
    /// The result's 1σ (NaN where none), SI.
    sigma: [f64; 4],
    sigma_source: String,
    /// The method's within-drive 1σ (`sigma_within_drive`), SI.
    within: [f64; 4],
    verdict: VerdictLevel,
    /// The verdict would be accepted with the within-drive σ: without the
    /// reasons the σ for the next drive adds (a fallback far from EIV's
    /// own estimate; a σ large only with the between-drive and gap parts).
    accepted_within: bool,
    /// EIV only: the result is the batch G-N fallback.
    fallback: Option<bool>,
    /// EIV only: the filter's own θ and its 1σ (SI) before any fallback,
    /// its findings (kinds, `;`-separated) and its fitted η.
    eiv_own: Option<(Theta, [f64; 4], String, [f64; 6])>,
    /// EIV only: the fit's further diagnostics (`eiv_extra`, see [`eiv_extra`]).
    eiv_extra: String,
    /// The estimated (or held) reference heading offset, rad.
    delta: f64,
    /// Ē_p on the drive's own validation segments, m.
    e_p_fit_m: f64,
    /// Ē_p on the fresh drive of the same world, m.
    e_p_held_m: f64,
    time_s: f64,
}

/// One world: its settings, bound, the truth's held-out Ē_p and the runs.
struct World {
    index: u64,
    seed: u64,
    noise: NoiseOptions,
    summary: WorldSummary,
    /// The equivalent truth: θ and the reference heading offset δ.
    truth: Theta,
    delta: f64,
    /// Mean-only Cramér–Rao bound (SI), white-only worlds only.
    crb: Option<[f64; 4]>,
    /// Ē_p of θ_true with the true δ on the fresh drive, m.
    e_p_held_true_m: f64,
    /// Per method (in `Settings::methods` order): the run or its error.
    runs: Vec<Result<Run, String>>,
}

/// The fresh drive and its validation segments.
struct HeldOut {
    drive: Drive,
    segments: Vec<Segment>,
}

impl HeldOut {
    fn e_p(&self, theta: &Theta, ext: &Extrinsics) -> Res<f64> {
        Ok(mean_position_error_with(&self.drive, &self.segments, theta, ext)?.mean_position_error_m)
    }
}

fn run_method(method: &str, drive: &Drive, held: &HeldOut, a: &Settings) -> Res<Run> {
    let mut opts = options(method, a.heading_drift, a.eiv_noise)?;
    if let Method::Eiv(e) = &mut opts.method {
        e.filter.research.coloured_jacobian_in_marginal = !a.eta_without_jacobian;
        e.filter.research.common_mode_jacobian = !a.no_common_jacobian;
        e.filter.research.position_drift_own_scale = a.position_drift_own_scale;
        e.filter.research.position_drift_time_constant_s = a.position_drift_tau;
        e.filter.research.heading_drift_two_sided = a.heading_drift_two_sided;
        e.filter.research.clamp_refit_hold_scale = !a.no_clamp_refit;
        e.filter.research.a_y_floor_from_readings = !a.no_a_y_floor;
        e.filter.research.heading_floor_from_readings = !a.no_heading_floor;
        e.heading_white_readings_first = !a.heading_white_estimated;
        e.filter.research.choose_time_constants = a.time_constant_choice;
        e.filter.research.clamp_refit_common_mode_eta = a.clamp_refit_common_eta;
        if let Some(m) = a.heading_drift_min_eta {
            e.filter.research.heading_drift_min_eta = m;
        }
        if let Some(t) = a.tau_drift {
            e.filter.noise.drift_time_constant_s = t;
        }
        if let (Some(parameters), Some(c)) = (a.correct_bias_of, &mut e.correct_bias) {
            c.parameters = parameters;
        }
    }
    a.readings_noise.apply(&mut opts, drive);
    let t = Instant::now();
    let r: CalibrationReport = calibrate(drive, &opts)?;
    let time_s = t.elapsed().as_secs_f64();
    let ext = r.extrinsics.as_ref().map_or(r.options.identify.extrinsics, |e| e.value);
    let eiv = eiv_part(&r);
    let fallback = eiv.as_ref().map(EivPart::fell_back);
    let eiv_own = match &eiv {
        Some(d) => d.eiv.as_ref().map(|e| {
            let mut kinds: Vec<String> = e.warnings.iter().map(finding_kind).collect();
            if let Some(h) = &e.heading_drift {
                // hd:score:LR:r:separate (LR empty where the gate kept the tie).
                let lr = h.likelihood_ratio.map_or(String::new(), |x| format!("{x:.2}"));
                kinds.push(format!("hd:{:.2}:{lr}:{:.2}:{}", h.score_statistic, h.log_ratio, h.separate));
            }
            (e.theta, e.sigma, kinds.join(";"), e.eta)
        }),
        _ => None,
    };
    let rs = r.result_sigma();
    let within = <[_; 4]>::from(r.within_drive_sigma()).map(|s| s.unwrap_or(f64::NAN));
    let accepted_within = r.verdict.reasons.iter().all(|reason| match reason {
        VerdictReason::FallbackDisagrees { .. } | VerdictReason::RefitDisagrees { .. } => true,
        VerdictReason::LargeUncertainty { param, sigma, fraction } => {
            let w = ParamSet::THETA.into_iter().position(|q| q == *param).map_or(f64::NAN, |i| within[i]);
            // Not above (NaN counts as not above).
            w.partial_cmp(&(0.1 * sigma / fraction)) != Some(std::cmp::Ordering::Greater)
        }
        _ => false,
    });
    Ok(Run {
        theta: r.theta,
        sigma: <[_; 4]>::from(rs).map(|s| s.unwrap_or(f64::NAN)),
        sigma_source: rs.source().to_string(),
        within,
        verdict: r.verdict.level,
        accepted_within,
        fallback,
        eiv_own,
        eiv_extra: eiv.as_ref().map_or(String::new(), eiv_extra),
        delta: ext.heading_offset,
        e_p_fit_m: r.validation.mean_position_error_m,
        e_p_held_m: held.e_p(&r.theta, &ext)?,
        time_s,
    })
}

/// The EIV fit's further diagnostics as `key=v v v v` groups (SI; `;`-separated):
/// the start's θ (`start`), the fit's σ of each kind (`block`, `sandwich`,
/// `fisher`, `noise`, `bias_mc`), the bias subtracted (`bias`), the halves'
/// z (`halves`), η's σ (`eta_sigma`), the largest and mean window NIS (`nis`),
/// θ's correlation matrix's t_r–d entry (`rho_td`), the scoring iterations
/// and filter passes (`iterations`, `evaluations`), and each parameter's σ
/// of `H_θ⁻¹` at the estimate over its resolution (`sor`).
fn eiv_extra(d: &EivPart) -> String {
    let v = |a: &[f64]| a.iter().map(|x| format!("{x:.4e}")).collect::<Vec<_>>().join(" ");
    let mut out = vec![format!("start={}", v(&<[_; 4]>::from(d.identification.theta)))];
    if let Some(c) = &d.clamp_refit {
        // The first fit's θ before the refit after a clamp.
        let first = c.get("first_theta").map_or(String::new(), |t| {
            ["c_e", "c_d", "t_r", "d"]
                .iter()
                .map(|k| format!("{:.4e}", t[*k].as_f64().unwrap_or(f64::NAN)))
                .collect::<Vec<_>>()
                .join(" ")
        });
        out.push(format!("clamp_refit_first={first}"));
    }
    if let Some(e) = &d.eiv {
        out.push(format!("block={}", v(&e.sigma_block)));
        out.push(format!("sandwich={}", v(&e.sigma_sandwich)));
        out.push(format!("fisher={}", v(&e.sigma_fisher)));
        out.push(format!("noise={}", v(&e.sigma_noise_estimate)));
        out.push(format!("bias_mc={}", v(&e.sigma_bias_correction)));
        out.push(format!("bias={}", v(&e.bias_subtracted)));
        out.push(format!("uncorrected={}", v(&<[_; 4]>::from(e.theta_uncorrected))));
        if let Some(h) = &e.halves {
            out.push(format!("halves={}", v(&h.z)));
        }
        out.push(format!("eta_sigma={}", v(&e.eta_sigma)));
        let nis: Vec<f64> = e.windows.iter().map(|w| w.nis).filter(|x| x.is_finite()).collect();
        let mean = nis.iter().sum::<f64>() / nis.len().max(1) as f64;
        out.push(format!("nis={}", v(&[nis.iter().cloned().fold(f64::NAN, f64::max), mean])));
        let c = &e.covariance;
        out.push(format!("rho_td={:.4}", c[2][3] / (c[2][2] * c[3][3]).sqrt()));
        out.push(format!("iterations={}", e.iterations));
        out.push(format!("evaluations={} {}", e.evaluations[0], e.evaluations[1]));
        out.push(format!("sor={}", v(&e.observability.sigma_over_resolution)));
    }
    out.join(";")
}

/// A filter finding's kind, with its detail (component and lag-1, source
/// and η, parameter and z, termination).
fn finding_kind(w: &odocal::eiv::EivWarning) -> String {
    use odocal::eiv::EivWarning as W;
    match w {
        W::NoiseAtUpperClamp { source, eta } => format!("clamp:{source:?}:{eta:.1}"),
        W::FilterDiverged { window, .. } => format!("diverged:w{window}"),
        W::InconsistentInnovations { window, nis, .. } => format!("nis:w{window}:{nis:.2}"),
        W::CorrelatedInnovations { window, component, lag1, .. } => format!("lag1:w{window}:{component:?}:{lag1:.2}"),
        W::UnstableAcrossHalves { parameter, z, .. } => format!("halves:{parameter}:{z:.1}"),
        W::NotConverged { termination } => format!("notconverged:{termination}").replace(',', " "),
        W::Unobservable { .. } => "unobservable".into(),
    }
}

fn study_world(index: u64, a: &Settings) -> Res<World> {
    let seed = a.seed + index;
    let (noise, summary) = NoiseOptions::random_world(seed);
    let (noise, summary) = if a.heavy {
        let mut n = noise.with_heavy_wheels(seed);
        match a.heavy_without.as_deref() {
            Some("slip") => n.wheel_slip_per_m_per_s2 = 0.0,
            Some("common") => n.wheel_coloured_rel_sigma = 0.0,
            Some(x) => return Err(format!("--heavy-without {x}: expected slip or common").into()),
            None => {}
        }
        let s = WorldSummary::from(&n);
        (n, s)
    } else {
        (noise, summary)
    };
    let sim = SimOptions { length_km: a.km, noise: noise.clone(), ..SimOptions::paper(seed) };
    let out = simulate(&sim)?;
    let drive = &out.drive;
    let (truth, true_ext) = sim.equivalent_truth();
    let fresh = simulate(&SimOptions { seed: seed + FRESH_SEED_OFFSET, ..sim })?.drive;
    let segments = validation_segments(&fresh, &ValidationSegmentOptions::default())?;
    let held = HeldOut { drive: fresh, segments };
    let e_p_held_true_m = held.e_p(&truth, &true_ext)?;
    let crb = if summary.white_only {
        let model = NoiseModel::from_sim(&noise, drive.sample_time_s());
        let input = EivInput::from_drive_truth(drive)?;
        match cramer_rao_bound(&input, &truth, &model, &EivOptions::spec()) {
            Ok(c) => Some(c.sigma_mean_only),
            Err(e) => {
                eprintln!("world {index}: no bound: {e}");
                None
            }
        }
    } else {
        None
    };
    let runs = a.methods.iter().map(|m| run_method(m, drive, &held, a).map_err(|e| e.to_string())).collect();
    Ok(World { index, seed, noise, summary, truth, delta: true_ext.heading_offset, crb, e_p_held_true_m, runs })
}

/// A world's line on stderr.
fn progress_line(w: &World, methods: &[String]) -> String {
    let mut line = format!("world {} ({}, seed {}):", w.index, w.summary.regime, w.seed);
    for (m, r) in methods.iter().zip(&w.runs) {
        match r {
            Ok(r) => {
                let e = errors(&r.theta, &w.truth).map(|v| format!("{v:+.3}"));
                let fb = if r.fallback == Some(true) { " fallback" } else { "" };
                let _ = write!(line, " | {m} [{}] {}{fb} {:.1}s", e.join(" "), r.verdict, r.time_s);
            }
            Err(e) => {
                let _ = write!(line, " | {m} failed: {e}");
            }
        }
    }
    line
}

/// The worlds of a table row: all, or one regime's.
fn groups(worlds: &[World]) -> Vec<(String, Vec<&World>)> {
    let mut g = vec![("all".to_string(), worlds.iter().collect::<Vec<_>>())];
    for r in [NoiseRegime::Quiet, NoiseRegime::White, NoiseRegime::CommonModeSlip] {
        let v: Vec<&World> = worlds.iter().filter(|w| w.summary.regime == r).collect();
        if !v.is_empty() {
            g.push((r.to_string(), v));
        }
    }
    g
}

/// The successful runs of method `m` (index) in `worlds`.
fn runs_of<'a>(worlds: &[&'a World], m: usize) -> Vec<(&'a World, &'a Run)> {
    worlds.iter().filter_map(|w| w.runs[m].as_ref().ok().map(|r| (*w, r))).collect()
}

/// |error| / σ of each parameter (NaN where σ is missing).
fn z_scores(w: &World, r: &Run) -> [f64; 4] {
    z_scores_with(w, r, &r.sigma)
}

/// |error| / `sigma` of each parameter.
fn z_scores_with(w: &World, r: &Run, sigma: &[f64; 4]) -> [f64; 4] {
    let e = errors(&r.theta, &w.truth);
    let s = error_scale(&w.truth);
    std::array::from_fn(|i| e[i] / (sigma[i] * s[i]))
}

fn pct(k: usize, n: usize) -> String {
    if n == 0 {
        "–".into()
    } else {
        format!("{:.0} %", 100.0 * k as f64 / n as f64)
    }
}

/// Per group and method, each parameter's bias (t), RMS error and 95 %
/// coverage; and the RMS of error/σ over the four.
fn accuracy_table(worlds: &[World], methods: &[String]) -> Table {
    let mut header = vec!["worlds".to_string(), "method".to_string(), ">n".to_string()];
    header.extend(ERROR_UNITS.iter().map(|u| format!(">{u}: bias (t) · RMS · coverage")));
    header.push(">RMS error/σ".to_string());
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut t = Table::new(&header);
    for (group, ws) in groups(worlds) {
        for (m, name) in methods.iter().enumerate() {
            let rs = runs_of(&ws, m);
            let mut row = vec![group.clone(), name.clone(), rs.len().to_string()];
            let mut z_all = Vec::new();
            for i in 0..4 {
                let e: Vec<f64> = rs.iter().map(|(w, r)| errors(&r.theta, &w.truth)[i]).collect();
                let sig: Vec<f64> = rs.iter().map(|(w, r)| r.sigma[i] * error_scale(&w.truth)[i]).collect();
                z_all.extend(rs.iter().map(|(w, r)| z_scores(w, r)[i]));
                let s = Summary::of(&e);
                let digits = if i == 0 { 4 } else { 3 };
                row.push(format!(
                    "{:+.digits$} ({:.1}) · {:.digits$} · {:.0} %",
                    s.mean,
                    s.t(),
                    s.rms,
                    100.0 * coverage(&e, &sig, 1.96)
                ));
            }
            row.push(format!("{:.2}", Summary::of(&z_all).rms));
            t.row(row);
        }
    }
    t
}

fn verdict_table(worlds: &[World], methods: &[String]) -> Table {
    let mut t = Table::new(&[
        "worlds",
        "method",
        ">n",
        ">failed",
        ">accepted",
        ">doubtful",
        ">rejected",
        ">accepted beyond 3σ",
        ">EIV fallback",
        ">held-out Ē_p − truth's: mean",
        ">median",
        ">max",
        ">own Ē_p: mean",
        ">δ RMS error",
    ]);
    for (group, ws) in groups(worlds) {
        for (m, name) in methods.iter().enumerate() {
            let rs = runs_of(&ws, m);
            let n = rs.len();
            let level = |l: VerdictLevel| rs.iter().filter(|(_, r)| r.verdict == l).count();
            let beyond = rs
                .iter()
                .filter(|(w, r)| {
                    r.verdict == VerdictLevel::Accepted && z_scores(w, r).iter().any(|z| z.is_finite() && z.abs() > 3.0)
                })
                .count();
            let fallback = rs.iter().filter(|(_, r)| r.fallback == Some(true)).count();
            let excess: Vec<f64> = rs.iter().map(|(w, r)| r.e_p_held_m - w.e_p_held_true_m).collect();
            let own: Vec<f64> = rs.iter().map(|(_, r)| r.e_p_fit_m).collect();
            let max = excess.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let delta: Vec<f64> = rs.iter().map(|(w, r)| (r.delta - w.delta) * 1e3).collect();
            t.row([
                group.clone(),
                name.clone(),
                n.to_string(),
                (ws.len() - n).to_string(),
                pct(level(VerdictLevel::Accepted), n),
                pct(level(VerdictLevel::Doubtful), n),
                pct(level(VerdictLevel::Rejected), n),
                format!("{beyond} ({})", pct(beyond, n)),
                if name == "eiv" { format!("{fallback} ({})", pct(fallback, n)) } else { "–".into() },
                format!("{:+.3} m", Summary::of(&excess).mean),
                format!("{:+.3} m", median(&excess)),
                format!("{max:+.3} m"),
                format!("{:.3} m", Summary::of(&own).mean),
                format!("{:.2} mrad", Summary::of(&delta).rms),
            ]);
        }
    }
    t
}

/// The default method's results split by outcome (its own estimate or the
/// batch G-N fallback): coverage per parameter and the verdicts, with the
/// σ that stands for the result (the σ for the next drive) and with the
/// within-drive σ and the verdict it would give.
fn eiv_outcome_table(worlds: &[World], methods: &[String]) -> Option<Table> {
    let m = methods.iter().position(|x| x == "eiv")?;
    let mut header = vec!["worlds".to_string(), "EIV result".to_string(), ">n".to_string()];
    header.extend(ERROR_UNITS.iter().map(|u| format!(">{u} coverage")));
    header.extend([">accepted".to_string(), ">accepted beyond 3σ".to_string()]);
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut t = Table::new(&header);
    for (group, ws) in groups(worlds) {
        let cases = [("own estimate", false, true), ("batch G-N fallback", true, true)];
        let before =
            [("own estimate, within-drive σ", false, false), ("batch G-N fallback, within-drive σ", true, false)];
        for (label, fallback, next) in cases.into_iter().chain(before) {
            let rs: Vec<(&World, &Run)> =
                runs_of(&ws, m).into_iter().filter(|(_, r)| r.fallback == Some(fallback)).collect();
            let n = rs.len();
            let z = |w: &World, r: &Run| z_scores_with(w, r, if next { &r.sigma } else { &r.within });
            let mut row = vec![group.clone(), label.to_string(), n.to_string()];
            for i in 0..4 {
                let inside = rs.iter().filter(|(w, r)| z(w, r)[i].abs() <= 1.96).count();
                row.push(pct(inside, n));
            }
            let accepted: Vec<&(&World, &Run)> = rs
                .iter()
                .filter(|(_, r)| if next { r.verdict == VerdictLevel::Accepted } else { r.accepted_within })
                .collect();
            let beyond = accepted.iter().filter(|(w, r)| z(w, r).iter().any(|z| z.abs() > 3.0)).count();
            row.push(pct(accepted.len(), n));
            row.push(format!("{beyond} ({})", pct(beyond, n)));
            t.row(row);
        }
    }
    Some(t)
}

/// RMS of error/CRB on the white-only worlds, per method and parameter
/// (and for the default method, on the worlds where it did not fall back).
fn bound_table(worlds: &[World], methods: &[String]) -> Option<Table> {
    let bounded: Vec<&World> = worlds.iter().filter(|w| w.crb.is_some()).collect();
    if bounded.is_empty() {
        return None;
    }
    let mut header = vec!["method".to_string(), ">n".to_string()];
    header.extend(ERROR_UNITS.iter().map(|u| format!(">{u}: RMS/CRB, bias/CRB")));
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut t = Table::new(&header);
    let mut rows: Vec<(String, Vec<(&World, &Run)>)> = Vec::new();
    for (m, name) in methods.iter().enumerate() {
        let rs = runs_of(&bounded, m);
        if name == "eiv" {
            let own = rs.iter().copied().filter(|(_, r)| r.fallback == Some(false)).collect();
            rows.push((name.clone(), rs));
            rows.push(("eiv, own estimates (no fallback)".into(), own));
        } else {
            rows.push((name.clone(), rs));
        }
    }
    for (name, rs) in rows {
        let mut row = vec![name, rs.len().to_string()];
        for i in 0..4 {
            let r: Vec<f64> = rs
                .iter()
                .filter_map(|(w, r)| w.crb.map(|c| errors(&r.theta, &w.truth)[i] / (c[i] * error_scale(&w.truth)[i])))
                .collect();
            let s = Summary::of(&r);
            row.push(format!("{:.2}, {:+.2} (t {:.1})", s.rms, s.mean, s.t()));
        }
        t.row(row);
    }
    Some(t)
}

fn print_tables(a: &Settings, worlds: &[World]) {
    let count = |r: NoiseRegime| worlds.iter().filter(|w| w.summary.regime == r).count();
    let white_only = worlds.iter().filter(|w| w.summary.white_only).count();
    println!(
        "## Random noise worlds{}: {} worlds x {} km (world seeds {}..={}), methods {}\n",
        if a.heavy { " (heavy wheels: --heavy)" } else { "" },
        worlds.len(),
        a.km,
        a.seed,
        a.seed + a.worlds.saturating_sub(1),
        a.methods.join(", ")
    );
    println!(
        "Regimes: quiet {}, white {}, common-mode/slip {}; white-only (bound) worlds {white_only}.\n",
        count(NoiseRegime::Quiet),
        count(NoiseRegime::White),
        count(NoiseRegime::CommonModeSlip)
    );
    println!("### Accuracy and coverage\n\n{}", accuracy_table(worlds, &a.methods));
    println!("### Verdicts, fallback, held-out Ē_p\n\n{}", verdict_table(worlds, &a.methods));
    if let Some(t) = eiv_outcome_table(worlds, &a.methods) {
        println!("### The default by outcome: its own estimate or the batch G-N fallback\n\n{t}");
    }
    match bound_table(worlds, &a.methods) {
        Some(t) => println!("### White-only worlds against the Cramér–Rao bound (mean-only)\n\n{t}"),
        None => println!("No white-only world: no comparison with the bound.\n"),
    }
}

/// A CSV cell of a number (empty when not finite).
fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.6e}")
    } else {
        String::new()
    }
}

fn write_csvs(dir: &std::path::Path, a: &Settings, worlds: &[World]) -> Res<()> {
    std::fs::create_dir_all(dir)?;
    let mut w_csv = String::from(
        "world,world_seed,regime,white_only,wheel_white_rel,wheel_common_slip_rel,wheel_white_rel_10s,\
         wheel_common_slip_rel_10s,wheel_white_rel_sigma,wheel_coloured_rel_sigma,wheel_coloured_time_constant_s,\
         wheel_coloured_differential_rel_sigma,wheel_coloured_differential_time_constant_s,wheel_slip_per_m_per_s2,\
         encoder_ticks_per_revolution,position_drift_sigma_m,position_drift_time_constant_s,position_white_sigma_m,\
         heading_bias_rad,heading_drift_sigma_rad,heading_drift_time_constant_s,heading_white_sigma_rad,\
         lateral_acceleration_white_sigma_m_per_s2,lateral_acceleration_bias_m_per_s2,sideslip_sigma_rad,\
         sideslip_time_constant_s,sideslip_bias_rad\n",
    );
    for w in worlds {
        let (s, n) = (&w.summary, &w.noise);
        let cells = [
            w.index.to_string(),
            w.seed.to_string(),
            s.regime.to_string(),
            s.white_only.to_string(),
            num(s.wheel_white_rel),
            num(s.wheel_common_slip_rel),
            num(s.wheel_white_rel_10s),
            num(s.wheel_common_slip_rel_10s),
            num(n.wheel_white_rel_sigma),
            num(n.wheel_coloured_rel_sigma),
            num(n.wheel_coloured_time_constant_s),
            num(n.wheel_coloured_differential_rel_sigma),
            n.wheel_coloured_differential_time_constant_s.map_or(String::new(), num),
            num(n.wheel_slip_per_m_per_s2),
            n.encoder_ticks_per_revolution.to_string(),
            num(n.position_drift_sigma_m),
            num(n.position_drift_time_constant_s),
            num(n.position_white_sigma_m),
            num(n.heading_bias_rad),
            num(n.heading_drift_sigma_rad),
            num(n.heading_drift_time_constant_s),
            num(n.heading_white_sigma_rad),
            num(n.lateral_acceleration_white_sigma_m_per_s2),
            num(n.lateral_acceleration_bias_m_per_s2),
            num(n.sideslip_sigma_rad),
            num(n.sideslip_time_constant_s),
            num(n.sideslip_bias_rad),
        ];
        w_csv.push_str(&cells.join(","));
        w_csv.push('\n');
    }
    std::fs::write(dir.join("worlds.csv"), w_csv)?;
    let mut header = vec!["world", "world_seed", "regime", "white_only", "method", "status", "verdict", "fallback"];
    header.extend(["sigma_source", "err_c_e_pct", "err_c_d_mm", "err_t_r_pct", "err_d_mm_per_m_per_s2"]);
    header.extend(["sigma_c_e_pct", "sigma_c_d_mm", "sigma_t_r_pct", "sigma_d_mm_per_m_per_s2"]);
    header.extend(["crb_c_e_pct", "crb_c_d_mm", "crb_t_r_pct", "crb_d_mm_per_m_per_s2"]);
    header.extend(["c_d_shift_mm", "delta_true_mrad", "delta_mrad", "e_p_own_m", "e_p_held_out_m"]);
    header.push("e_p_held_out_truth_m");
    header.extend([
        "eiv_own_err_c_e_pct",
        "eiv_own_err_c_d_mm",
        "eiv_own_err_t_r_pct",
        "eiv_own_err_d_mm_per_m_per_s2",
    ]);
    header.extend(["eiv_own_sigma_c_e_pct", "eiv_own_sigma_c_d_mm", "eiv_own_sigma_t_r_pct"]);
    header.extend(["eiv_own_sigma_d_mm_per_m_per_s2", "eiv_eta", "eiv_findings", "eiv_extra"]);
    let mut r_csv = header.join(",") + "\n";
    for w in worlds {
        for (m, run) in a.methods.iter().zip(&w.runs) {
            let mut cells = vec![
                w.index.to_string(),
                w.seed.to_string(),
                w.summary.regime.to_string(),
                w.summary.white_only.to_string(),
                m.clone(),
            ];
            let scale = error_scale(&w.truth);
            let crb: Vec<String> = (0..4).map(|i| w.crb.map_or(String::new(), |c| num(c[i] * scale[i]))).collect();
            match run {
                Ok(r) => {
                    cells.push("ok".into());
                    cells.push(r.verdict.to_string());
                    cells.push(r.fallback.map_or(String::new(), |f| f.to_string()));
                    cells.push(r.sigma_source.clone());
                    cells.extend(errors(&r.theta, &w.truth).map(num));
                    cells.extend((0..4).map(|i| num(r.sigma[i] * scale[i])));
                    cells.extend(crb);
                    cells.push(num((w.truth.c_d - Theta::SIM_DEFAULT_TRUE.c_d) * 1e3));
                    cells.push(num(w.delta * 1e3));
                    cells.push(num(r.delta * 1e3));
                    cells.extend([num(r.e_p_fit_m), num(r.e_p_held_m), num(w.e_p_held_true_m)]);
                    match &r.eiv_own {
                        Some((theta, sigma, kinds, eta)) => {
                            cells.extend(errors(theta, &w.truth).map(num));
                            cells.extend((0..4).map(|i| num(sigma[i] * scale[i])));
                            let eta: Vec<String> = eta.iter().map(|e| format!("{e:.2}")).collect();
                            cells.push(eta.join(" "));
                            cells.push(kinds.clone());
                            cells.push(r.eiv_extra.clone());
                        }
                        None => cells.resize(header.len(), String::new()),
                    }
                }
                Err(e) => {
                    cells.push(format!("\"error: {}\"", e.replace('"', "'")));
                    cells.resize(header.len(), String::new());
                }
            }
            r_csv.push_str(&cells.join(","));
            r_csv.push('\n');
        }
    }
    std::fs::write(dir.join("results.csv"), r_csv)?;
    Ok(())
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let (a, threads) = settings()?;
    if let Some(n) = threads {
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
    }
    let t0 = Instant::now();
    let worlds: Vec<World> = (0..a.worlds)
        .into_par_iter()
        .map(|i| {
            let w = study_world(i, &a).map_err(|e| format!("world {i}: {e}"))?;
            eprintln!("{}", progress_line(&w, &a.methods));
            Ok(w)
        })
        .collect::<Result<_, String>>()?;
    print_tables(&a, &worlds);
    if let Some(dir) = &a.out {
        write_csvs(dir, &a, &worlds)?;
    }
    let mut times = String::new();
    for (m, name) in a.methods.iter().enumerate() {
        let all: Vec<&World> = worlds.iter().collect();
        let t: Vec<f64> = runs_of(&all, m).iter().map(|(_, r)| r.time_s).collect();
        let _ = write!(times, " {name} {:.1} s", Summary::of(&t).mean);
    }
    eprintln!("wall time {:.0} s; mean calibration time per drive:{times}", t0.elapsed().as_secs_f64());
    Ok(())
}
