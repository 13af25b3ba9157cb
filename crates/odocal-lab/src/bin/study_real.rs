//! batch Gauss-Newton, the 3-step method and EIV on the shipped real logs,
//! as `odocal calibrate` runs them (docs/validation.md, "Real logs").
//!
//! Methods (`--methods`, default the first five): `batch-gn` (`--method
//! batch-gn`, yaw-rate selection), `batch-gn-all` (`--method batch-gn
//! --min-yaw-rate 0`: every cut segment, the EIV method's start and
//! fallback), `three-step` (`--method three-step`), `eiv` (the default
//! method: noise estimated from the production-car start, bias correction,
//! fallback on) and `eiv-fixed` (`--fix-noise`: the production-car noise
//! model as is). Run only when named: `eiv-uncorrected`
//! (`--no-bias-correction`), `eiv-hold-heading` (the reference heading
//! offset held at 0), `eiv-cb` (`--correct-bias 10`), `eiv-scg` (the
//! encoder's quantisation step given, see [`encoder_q`], the heading offset
//! held), and with the suffixes `-nofallback` (the EIV θ whatever the checks
//! say; `eiv-nofallback` too), `-x` (the start also estimates the lever arm
//! and heading offset), `-h` (the heading offset alone) and `-tau` (a
//! reference drift with a 2 s correlation time instead of 100 s).
//!
//! Parts (`--parts`, default the first three):
//! - `testtrack`: the six test-track runs of 2024-08-05: calibrate on one
//!   run, Ē_p on the other five (`testtrack_crossrun`'s table
//!   and criteria), verdict counts, and for EIV how many fits fell back to
//!   batch G-N;
//! - `van`: the highway van fitted on one half, Ē_p on the held-out other
//!   half (`--holdout first-half|second-half`), θ_0's Ē_p beside it, and
//!   for EIV whether it fell back and why;
//! - `rav4`: the comma2k19 RAV4 (1 km, nearly straight): c_e with its σ
//!   and which parameters are named unobservable or held, with the
//!   defaults and with `--auto-fix`;
//! - `swap`: per test-track run, `eiv-scg-nofallback`'s θ with one
//!   parameter at a time from batch G-N (all segments), judged by Ē_p on the
//!   other five runs (which parameter makes the difference), and the same
//!   on the van's held-out halves.
//!
//! σ is the one that stands for the result, as `--params-out` writes it
//! ([`odocal::CalibrationReport::result_sigma`]). Prints markdown tables
//! (stdout) and writes JSON with `--json`; a few minutes in release on two
//! cores.

use std::path::PathBuf;
use std::time::Instant;

use odocal::eiv::{EivOptions, NoiseModel, QuantisationLevel};
use odocal::{
    calibrate, CalibrationOptions, CalibrationReport, EivMethodOptions, Holdout, Method, ParamSet, SigmaCovers,
    ValidationDrive, VerdictLevel, Warning,
};
use odocal_lab::crossrun::{CrossRunFit, CrossRunRow, CrossRunTable, CROSS_RUN_OWN_FIT_RATIO};
use odocal_lab::report_json::eiv_part;
use odocal_lab::{load, repo_path, testtrack_manifest, Args, Res, RAV4_MANIFEST, TESTTRACK_RUNS, VAN_MANIFEST};
use serde_json::{json, Value};

const USAGE: &str = "study_real [--methods batch-gn,batch-gn-all,three-step,eiv,eiv-fixed] [--parts testtrack,van,rav4]
    [--json study_real.json] [--markdown study_real.md]

Methods also: eiv-uncorrected, eiv-hold-heading, eiv-cb, eiv-scg, eiv-nofallback; suffixes -nofallback,
-x, -h, -tau (see the source's header). Parts also: swap.";

const METHODS: [&str; 5] = ["batch-gn", "batch-gn-all", "three-step", "eiv", "eiv-fixed"];

/// Base methods run only when named (each also with the suffixes of [`options`]).
const EXTRA_METHODS: [&str; 5] = ["eiv-uncorrected", "eiv-hold-heading", "eiv-cb", "eiv-scg", "eiv-nofallback"];

/// Correlation time of the reference's position and heading drift for the
/// `-tau` methods, s (the production car's is 100 s).
const SHORT_DRIFT_TAU_S: f64 = 2.0;

/// The lattice of the RAV4's CAN wheel speeds, m/s: 0.01 km/h (measured on
/// `wheel_speeds.csv`: every difference between distinct values is a
/// multiple of 0.002778 m/s).
const CAN_SPEED_STEP_M_PER_S: f64 = 0.01 / 3.6;

/// The encoder quantisation step q of a manifest's wheel signal in model
/// revolutions per second at the drive's output sample time h, with how it
/// was obtained.
///
/// Ticks (`ticks_cumulative`, `ticks_raw`): `q = 1/(ticks_per_rev · h)`,
/// `ticks_per_rev` the ticks of one *model* revolution (on the vans
/// 40,360 / 40,460 ticks = about 2 m of travel, not a physical wheel
/// revolution: the filter's rotation is in those units), h = 1/`rate_hz`
/// (the import interpolates the cumulative count at the output samples and
/// differences it over h, so the count error stays within about a tick).
/// CAN speeds (`m_per_s`): no ticks; the readings lie on the 0.01 km/h
/// lattice, `q = 0.002778 m/s / circumference_m`. That is a rounding of
/// each rate reading (white), not a count's remainder (the MA(1) error of
/// `QuantisationModel::Counting`), but at 8–20 m/s it is ~1/30 of the
/// production car's 0.8 % white wheel noise, so the model's shape there
/// hardly matters.
fn encoder_q(rel: &str) -> Res<(f64, String)> {
    let path = repo_path(rel);
    // The manifest's TOML is its interface: the keys are docs/reference.md's.
    let h = odocal::Manifest::from_path(&path).map_err(|e| format!("{}: {e}", path.display()))?.sample_time_s();
    let m: toml::Table = toml::from_str(&std::fs::read_to_string(&path)?)?;
    let w = m.get("wheels").ok_or("no [wheels]")?;
    let num = |key: &str| w.get(key).and_then(|v| v.as_float().or_else(|| v.as_integer().map(|i| i as f64)));
    match (w.get("signal").and_then(toml::Value::as_str), num("ticks_per_rev"), num("circumference_m")) {
        (Some("ticks_cumulative" | "ticks_raw"), Some(tpr), _) if tpr > 0.0 => {
            Ok((1.0 / (tpr * h), format!("1/({tpr} ticks × {h} s)")))
        }
        (Some("m_per_s"), _, Some(c)) if c > 0.0 => {
            Ok((CAN_SPEED_STEP_M_PER_S / c, format!("{CAN_SPEED_STEP_M_PER_S:.6} m/s CAN lattice / {c} m")))
        }
        (s, ..) => Err(format!("{}: no quantisation step known for wheel signal {s:?}", path.display()).into()),
    }
}

/// The options `odocal calibrate` uses for a study method; `q` is the
/// drive's encoder step ([`encoder_q`], used by `eiv-scg`).
fn options(method: &str, q: f64) -> Res<CalibrationOptions> {
    let (base, fallback) = match method.strip_suffix("-nofallback") {
        Some(b) => (b, false),
        None => (method, true),
    };
    // Suffixes, outermost last: `-x`, `-h`, `-tau` (see the module docs).
    let mut rest = base;
    let mut suffixes = Vec::new();
    for s in ["-tau", "-x", "-h"] {
        if let Some(b) = rest.strip_suffix(s) {
            suffixes.push(s);
            rest = b;
        }
    }
    let mut o = CalibrationOptions::default();
    let eiv = |filter: EivOptions, estimate_heading_offset: bool| {
        Method::Eiv(EivMethodOptions { filter, fallback, estimate_heading_offset, ..EivMethodOptions::default() })
    };
    o.method = match rest {
        "batch-gn" | "batch-gn-all" => {
            if rest == "batch-gn-all" {
                o.segments.min_peak_yaw_rate_rad_per_s = 0.0;
            }
            "batch-gn".parse::<Method>()?
        }
        "three-step" => "three-step".parse::<Method>()?,
        "eiv" => eiv(EivOptions::default(), true),
        "eiv-fixed" => eiv(EivOptions { fix_noise: true, ..EivOptions::default() }, true),
        "eiv-hold-heading" => eiv(EivOptions::default(), false),
        "eiv-uncorrected" => {
            Method::Eiv(EivMethodOptions { correct_bias: None, fallback, ..EivMethodOptions::default() })
        }
        "eiv-cb" => {
            // What the CLI's `--correct-bias 10 --correct-bias-of c_e,c_d,t_r,d`
            // sets (seed 0, antithetic pairs, every parameter).
            Method::Eiv(EivMethodOptions {
                correct_bias: Some(odocal::CorrectBias {
                    replicates: 10,
                    seed: 0,
                    parameters: odocal::ParamSet::THETA,
                }),
                fallback,
                ..EivMethodOptions::default()
            })
        }
        "eiv-scg" => {
            let d = EivOptions::default();
            let noise = NoiseModel { quantisation_step_rev_per_s: q, ..d.noise };
            eiv(EivOptions { noise, quantisation_level: QuantisationLevel::Given, ..d }, false)
        }
        _ => {
            return Err(
                format!("unknown method {method}; use {} or {}", METHODS.join(", "), EXTRA_METHODS.join(", ")).into()
            )
        }
    };
    let is_eiv = matches!(o.method, Method::Eiv(_));
    if !is_eiv && (!fallback || suffixes.contains(&"-tau")) {
        return Err(format!("{method}: -nofallback and -tau apply to the eiv methods").into());
    }
    for s in suffixes {
        match s {
            "-x" => o.identify.free = o.identify.free.union(ParamSet::EXTRINSICS),
            "-h" => o.identify.free = o.identify.free.with(odocal::Param::HeadingOffset),
            _ => {
                if let Method::Eiv(e) = &mut o.method {
                    e.filter.noise.drift_time_constant_s = SHORT_DRIFT_TAU_S;
                }
            }
        }
    }
    Ok(o)
}

/// The σ that stands for the result, per parameter (`None` = held), as
/// `--params-out` writes it.
fn result_sigma(r: &CalibrationReport) -> [Option<f64>; 4] {
    <[_; 4]>::from(r.result_sigma())
}

/// EIV: `Some((fell back, reasons))`; `None` for the other methods.
fn eiv_fallback(r: &CalibrationReport) -> Option<(bool, Vec<String>)> {
    let d = eiv_part(r)?;
    let fell = d.fell_back();
    let mut reasons: Vec<String> = r
        .warnings
        .iter()
        .filter_map(|w| match w {
            Warning::EivCheckFailed { finding, .. } => Some(finding.to_string()),
            _ => None,
        })
        .collect();
    if let Some(e) = &d.eiv_error {
        reasons.push(format!("filter error: {e}"));
    }
    Some((fell, reasons))
}

/// The fallback reasons in one short cell: the first one and how many more.
fn short_reasons(reasons: &[String]) -> String {
    match reasons {
        [] => "–".into(),
        [one] => one.replace('|', "\\|"),
        [first, rest @ ..] => format!("{} (+{} more)", first.replace('|', "\\|"), rest.len()),
    }
}

/// Header of the EIV detail table (every EIV fit, fallen back or not).
const EIV_DETAIL_HEADER: &str = "| method | fit | EIV θ (c_e m / c_d mm / t_r m / d mm/(m/s²)) | fell back | \
     every check that fired | η (L/U = at the lower/upper clamp) | σ_white % / q rev/s / σ_c % / σ_w % / σ_p m / σ_ψ mrad | \
     iterations, termination |\n|---|---|---|---|---|---|---|---|\n";

/// One row of the EIV detail table: the EIV fit's own θ (also when the
/// report's θ is the fallback), every finding that fired, η with its clamp
/// state and the estimated noise in physical units. `None` for other methods.
fn eiv_detail_row(m: &str, fit: &str, r: &CalibrationReport) -> Option<(String, Value)> {
    let d = eiv_part(r)?;
    let fell = d.fell_back();
    let Some(e) = &d.eiv else {
        let why = d.eiv_error.clone().unwrap_or_default();
        return Some((
            format!("| {m} | {fit} | filter failed | {fell} | {} |||||\n", why.replace('|', "\\|")),
            json!({"method": m, "fit": fit, "eiv_error": why}),
        ));
    };
    // No study method changes the clamps.
    let [lo, hi] = EivOptions::default().eta_bounds;
    let eta: Vec<String> = e
        .eta
        .iter()
        .map(|&v| {
            let tag = if v <= lo + 1e-6 {
                "L"
            } else if v >= hi - 1e-6 {
                "U"
            } else {
                ""
            };
            format!("{v:.1}{tag}")
        })
        .collect();
    let n = &e.noise;
    let noise = format!(
        "{:.3} / {:.2e} / {:.3} / {:.4} / {:.3} / {:.3}",
        n.wheel_white_rel_sigma * 100.0,
        n.quantisation_step_rev_per_s,
        n.wheel_common_rel_sigma * 100.0,
        n.wheel_differential_rel_sigma * 100.0,
        n.position_white_sigma_m,
        n.heading_white_sigma_rad * 1e3
    );
    let found: Vec<String> =
        e.warnings.iter().filter(|w| odocal::research::is_misspecification(w, e)).map(|w| w.to_string()).collect();
    let t = &e.theta;
    let row = format!(
        "| {m} | {fit} | {:.4} / {:+.2} / {:.3} / {:+.2} | {} | {} | {} | {noise} | {}, {} |\n",
        t.c_e,
        t.c_d * 1e3,
        t.t_r,
        t.d * 1e3,
        if fell { "yes" } else { "no" },
        if found.is_empty() { "none".into() } else { found.join("; ").replace('|', "\\|") },
        eta.join(", "),
        e.iterations,
        e.termination.to_string().replace('|', "\\|"),
    );
    let v = json!({
        "method": m, "fit": fit, "fell_back": fell, "eiv_theta": e.theta, "eiv_sigma": e.sigma,
        "findings": found, "eta": e.eta, "noise": e.noise, "termination": e.termination.to_string(),
        "iterations": e.iterations,
        "unobservable": e.observability.unobservable,
        "windows": e.windows.iter().map(|w| json!({"index": w.window.index, "updates": w.updates, "nis": w.nis,
            "nis_without_floors": w.nis_without_floors, "lag1": w.lag1, "lag1_without_floors": w.lag1_without_floors})).collect::<Vec<_>>(),
        "halves_z": e.halves.as_ref().map(|h| h.z),
    });
    Some((row, v))
}

fn verdict_json(r: &CalibrationReport) -> Value {
    json!({
        "level": r.verdict.level.to_string(),
        "reasons": r.verdict.reasons.iter().map(|x| x.to_string()).collect::<Vec<_>>(),
    })
}

fn theta_cell(r: &CalibrationReport) -> String {
    let t = &r.theta;
    let x = r.extrinsics.as_ref().map_or(String::new(), |e| {
        format!(" (l {:+.2}, {:+.2} m, δ {:+.1} mrad)", e.value.lever_x, e.value.lever_y, e.value.heading_offset * 1e3)
    });
    format!("{:.4} / {:+.2} / {:.3} / {:+.2}{x}", t.c_e, t.c_d * 1e3, t.t_r, t.d * 1e3)
}

/// (a) calibrate on each test-track run, Ē_p on the other five.
fn testtrack(methods: &[String], md: &mut String) -> Res<Value> {
    let mut drives = Vec::new();
    let mut qs = Vec::new();
    for (run, _) in TESTTRACK_RUNS {
        let (q, how) = encoder_q(&testtrack_manifest(run))?;
        eprintln!("testtrack {run}: encoder q = {q:.6e} rev/s ({how})");
        qs.push(q);
        drives.push((run, load(&testtrack_manifest(run))?));
    }
    md.push_str(
        "#### (a) Test track, 2024-08-05: fit on one run, Ē_p on the other five (m)\n\n\
         | method | own Ē_p, mean | others, mean | θ_0 on others | ratio (≤ 1.5) | worse than θ_0 on another run \
         | accepted / doubtful / rejected | EIV fell back | wall s (6 fits) |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut out = Vec::new();
    let mut per_run_md = String::new();
    let mut detail_md = String::new();
    let mut details = Vec::new();
    for m in methods {
        let started = Instant::now();
        let mut rows = Vec::new();
        let mut extra = Vec::new();
        for (i, (name, drive)) in drives.iter().enumerate() {
            let opts = options(m, qs[i])?;
            let t = Instant::now();
            let r = match calibrate(drive, &opts) {
                Ok(r) => r,
                Err(e) => {
                    rows.push(CrossRunRow { name: name.to_string(), fit: Err(e.to_string()) });
                    extra.push(json!({"run": name, "error": e.to_string()}));
                    continue;
                }
            };
            let others: Vec<ValidationDrive> = drives
                .iter()
                .enumerate()
                .filter(|(j, _)| *j != i)
                .map(|(_, (n, d))| ValidationDrive { name: n, drive: d, reference: None })
                .collect();
            let v = r.validate_on_drives(&others, false)?;
            let wall = t.elapsed().as_secs_f64();
            let fb = eiv_fallback(&r);
            if let Some((row, v)) = eiv_detail_row(m, name, &r) {
                detail_md.push_str(&row);
                details.push(v);
            }
            if let Some(d) = eiv_part(&r) {
                if let Some(e) = &d.eiv {
                    // The EIV fit's consistency numbers (stderr), to read the checks against.
                    eprintln!(
                        "{m} {name}: η {:.2?} {} halves z {:.1?} unobservable {:?}",
                        e.eta,
                        e.termination,
                        e.halves.as_ref().map(|h| h.z),
                        e.observability.unobservable
                    );
                    for w in &e.windows {
                        eprintln!(
                            "   w{} n {} nis {:.3} (no floors {:.3}) lag1 {:.2?} (no floors {:.2?})",
                            w.window.index, w.updates, w.nis, w.nis_without_floors, w.lag1, w.lag1_without_floors
                        );
                    }
                }
            }
            extra.push(json!({
                "run": name,
                "theta": r.theta,
                "extrinsics": r.extrinsics.as_ref().map(|e| e.value),
                "sigma": result_sigma(&r),
                "sigma_source": r.result_sigma().source(),
                "verdict": verdict_json(&r),
                "own_m": r.validation.mean_position_error_m,
                "others_m": v.mean_over_drives_m,
                "initial_others_m": v.initial_mean_over_drives_m,
                "eiv_fell_back": fb.as_ref().map(|f| f.0),
                "eiv_checks_failed": fb.as_ref().map(|f| f.1.clone()),
                "wall_s": wall,
            }));
            per_run_md.push_str(&format!(
                "| {m} | {name} | {} | {} | {:.2} | {:.2} | {:.2} | {} | {:.1} |\n",
                theta_cell(&r),
                r.verdict.level,
                r.validation.mean_position_error_m,
                v.mean_over_drives_m,
                v.initial_mean_over_drives_m,
                fb.map_or("–".into(), |(f, why)| if f {
                    format!("yes: {}", short_reasons(&why))
                } else {
                    "no".into()
                }),
                wall
            ));
            let fit = CrossRunFit {
                theta: r.theta,
                verdict: r.verdict.clone(),
                own_m: r.validation.mean_position_error_m,
                initial_own_m: r.initial.mean_position_error_m,
                others: v,
            };
            rows.push(CrossRunRow { name: name.to_string(), fit: Ok(fit) });
        }
        let wall = started.elapsed().as_secs_f64();
        let table = CrossRunTable { rows };
        let c = table.criteria(CROSS_RUN_OWN_FIT_RATIO);
        let count =
            |l: VerdictLevel| table.rows.iter().filter(|r| r.fit.as_ref().is_ok_and(|f| f.verdict.level == l)).count();
        let (acc, dou, rej) =
            (count(VerdictLevel::Accepted), count(VerdictLevel::Doubtful), count(VerdictLevel::Rejected));
        let fell = extra.iter().filter(|e| e["eiv_fell_back"] == json!(true)).count();
        let is_eiv = m.starts_with("eiv");
        let worse = if c.worse_than_initial.is_empty() {
            "none".to_string()
        } else {
            format!("{} of {}", c.worse_than_initial.len(), 5 * (c.runs - c.failed))
        };
        md.push_str(&format!(
            "| {m} | {:.2} | {:.2} | {:.2} | {:.2} | {worse} | {acc} / {dou} / {rej}{} | {} | {wall:.1} |\n",
            c.mean_own_m,
            c.mean_cross_m,
            c.mean_initial_cross_m,
            c.ratio,
            if c.failed > 0 { format!(" ({} failed)", c.failed) } else { String::new() },
            if is_eiv { format!("{fell} of {}", c.runs - c.failed) } else { "–".into() },
        ));
        out.push(json!({
            "method": m,
            "criteria": c,
            "verdicts": {"accepted": acc, "doubtful": dou, "rejected": rej},
            "eiv_fallbacks": is_eiv.then_some(fell),
            "runs": extra,
            "wall_s": wall,
        }));
    }
    md.push_str(
        "\nPer run (θ = c_e m / c_d mm / t_r m / d mm/(m/s²); Ē_p in m):\n\n\
         | method | run | θ | verdict | own Ē_p | others | θ_0 on others | EIV fell back | wall s |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    md.push_str(&per_run_md);
    md.push('\n');
    if !detail_md.is_empty() {
        md.push_str("EIV fits (the filter's own θ and findings, also where the report fell back):\n\n");
        md.push_str(EIV_DETAIL_HEADER);
        md.push_str(&detail_md);
        md.push('\n');
        out.push(json!({"eiv_details": details}));
    }
    Ok(Value::Array(out))
}

/// (d) which parameter makes the difference on the test track: per run,
/// batch G-N (all segments) and `eiv-scg-nofallback`, and EIV's θ with one
/// parameter at a time replaced by batch G-N's, each judged by the mean Ē_p
/// on the other five runs.
fn swap(md: &mut String) -> Res<Value> {
    let mut drives = Vec::new();
    for (run, _) in TESTTRACK_RUNS {
        let rel = testtrack_manifest(run);
        drives.push((run, load(&rel)?, encoder_q(&rel)?.0));
    }
    md.push_str(
        "#### (d) Test track: EIV (`eiv-scg-nofallback`) with one parameter at a time from batch G-N (all \
         segments); mean Ē_p on the other five runs (m)\n\n\
         | run | batch G-N | EIV | EIV, G-N's c_e | EIV, G-N's c_d | EIV, G-N's t_r | EIV, G-N's d \
         | G-N, EIV's c_e | G-N, EIV's c_d |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut out = Vec::new();
    let mut sums = [0.0; 8];
    for (i, (name, drive, q)) in drives.iter().enumerate() {
        let gn_opts = options("batch-gn-all", *q)?;
        let eiv_opts = options("eiv-scg-nofallback", *q)?;
        let gn = calibrate(drive, &gn_opts)?;
        let eiv = calibrate(drive, &eiv_opts)?;
        let others: Vec<ValidationDrive> = drives
            .iter()
            .enumerate()
            .filter(|(j, _)| *j != i)
            .map(|(_, (n, d, _))| ValidationDrive { name: n, drive: d, reference: None })
            .collect();
        let judge = |t: &odocal::Theta| -> Res<f64> {
            let mut r = gn.clone();
            r.theta = *t;
            Ok(r.validate_on_drives(&others, false)?.mean_over_drives_m)
        };
        let (g, e) = (gn.theta, eiv.theta);
        let mut cells = vec![judge(&g)?, judge(&e)?];
        cells.push(judge(&odocal::Theta { c_e: g.c_e, ..e })?);
        cells.push(judge(&odocal::Theta { c_d: g.c_d, ..e })?);
        cells.push(judge(&odocal::Theta { t_r: g.t_r, ..e })?);
        cells.push(judge(&odocal::Theta { d: g.d, ..e })?);
        cells.push(judge(&odocal::Theta { c_e: e.c_e, ..g })?);
        cells.push(judge(&odocal::Theta { c_d: e.c_d, ..g })?);
        for (s, c) in sums.iter_mut().zip(&cells) {
            *s += c / TESTTRACK_RUNS.len() as f64;
        }
        md.push_str(&format!(
            "| {name} | {} |\n",
            cells.iter().map(|c| format!("{c:.2}")).collect::<Vec<_>>().join(" | ")
        ));
        out.push(json!({"run": name, "batch_gn": g, "eiv": e, "others_m": cells}));
    }
    md.push_str(&format!("| mean | {} |\n\n", sums.iter().map(|c| format!("{c:.2}")).collect::<Vec<_>>().join(" | ")));
    // The same for the van: fitted on one half, Ē_p on the held-out half.
    let drive = load(VAN_MANIFEST)?;
    let q = encoder_q(VAN_MANIFEST)?.0;
    md.push_str(
        "Van (07-11), the same on the held-out half (m):\n\n\
         | held out | batch G-N | EIV | EIV, G-N's c_e | EIV, G-N's c_d | EIV, G-N's t_r | EIV, G-N's d \
         | G-N, EIV's c_e | G-N, EIV's c_d |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    for (label, h) in [("first-half", Holdout::FirstHalf), ("second-half", Holdout::SecondHalf)] {
        let (fit, held) = h.split(&drive)?;
        let gn_opts = options("batch-gn-all", q)?;
        let gn = calibrate(&fit, &gn_opts)?;
        let eiv = calibrate(&fit, &options("eiv-scg-nofallback", q)?)?;
        let others = [ValidationDrive { name: label, drive: &held, reference: None }];
        let judge = |t: &odocal::Theta| -> Res<f64> {
            let mut r = gn.clone();
            r.theta = *t;
            Ok(r.validate_on_drives(&others, false)?.mean_over_drives_m)
        };
        let (g, e) = (gn.theta, eiv.theta);
        let cells = [
            judge(&g)?,
            judge(&e)?,
            judge(&odocal::Theta { c_e: g.c_e, ..e })?,
            judge(&odocal::Theta { c_d: g.c_d, ..e })?,
            judge(&odocal::Theta { t_r: g.t_r, ..e })?,
            judge(&odocal::Theta { d: g.d, ..e })?,
            judge(&odocal::Theta { c_e: e.c_e, ..g })?,
            judge(&odocal::Theta { c_d: e.c_d, ..g })?,
        ];
        md.push_str(&format!(
            "| {label} | {} |\n",
            cells.iter().map(|c| format!("{c:.2}")).collect::<Vec<_>>().join(" | ")
        ));
        out.push(json!({"van_holdout": label, "batch_gn": g, "eiv": e, "held_out_m": cells}));
    }
    md.push('\n');
    Ok(Value::Array(out))
}

/// (b) the highway van, fitted on one half, Ē_p on the other.
fn van(methods: &[String], md: &mut String) -> Res<Value> {
    let drive = load(VAN_MANIFEST)?;
    let (q, how) = encoder_q(VAN_MANIFEST)?;
    eprintln!("van: encoder q = {q:.6e} rev/s ({how})");
    md.push_str(
        "#### (b) Highway van (07-11): fit on one half, Ē_p on the held-out half (m)\n\n\
         | method | held out | θ (c_e m / c_d mm / t_r m / d mm/(m/s²)) | held-out Ē_p | θ_0 Ē_p | verdict \
         | EIV fell back (why) | wall s |\n|---|---|---|---|---|---|---|---|\n",
    );
    let mut out = Vec::new();
    let mut detail_md = String::new();
    let mut details = Vec::new();
    for m in methods {
        let opts = options(m, q)?;
        for (label, h) in [("first-half", Holdout::FirstHalf), ("second-half", Holdout::SecondHalf)] {
            let t = Instant::now();
            let r = match (odocal::Calibration { holdout: Some(&h), ..odocal::Calibration::new(&drive, &opts) }).run() {
                Ok(r) => r,
                Err(e) => {
                    md.push_str(&format!("| {m} | {label} | failed: {} ||||||\n", e.to_string().replace('|', "\\|")));
                    out.push(json!({"method": m, "holdout": label, "error": e.to_string()}));
                    continue;
                }
            };
            let wall = t.elapsed().as_secs_f64();
            let fb = eiv_fallback(&r);
            if let Some((row, v)) = eiv_detail_row(m, label, &r) {
                detail_md.push_str(&row);
                details.push(v);
            }
            md.push_str(&format!(
                "| {m} | {label} | {} | {:.2} | {:.2} | {} | {} | {wall:.1} |\n",
                theta_cell(&r),
                r.validation.mean_position_error_m,
                r.initial.mean_position_error_m,
                r.verdict.level,
                fb.as_ref().map_or("–".into(), |(f, why)| if *f {
                    format!("yes: {}", short_reasons(why))
                } else {
                    "no".into()
                }),
            ));
            out.push(json!({
                "method": m,
                "holdout": label,
                "theta": r.theta,
                "extrinsics": r.extrinsics.as_ref().map(|e| e.value),
                "sigma": result_sigma(&r),
                "sigma_source": r.result_sigma().source(),
                "held_out_m": r.validation.mean_position_error_m,
                "initial_held_out_m": r.initial.mean_position_error_m,
                "verdict": verdict_json(&r),
                "eiv_fell_back": fb.as_ref().map(|f| f.0),
                "eiv_checks_failed": fb.as_ref().map(|f| f.1.clone()),
                "wall_s": wall,
            }));
        }
    }
    md.push('\n');
    if !detail_md.is_empty() {
        md.push_str("EIV fits (held-out half named; the filter's own θ and findings):\n\n");
        md.push_str(EIV_DETAIL_HEADER);
        md.push_str(&detail_md);
        md.push('\n');
        out.push(json!({"eiv_details": details}));
    }
    Ok(Value::Array(out))
}

/// (c) the RAV4: c_e, its σ, what is named unobservable or held.
fn rav4(methods: &[String], md: &mut String) -> Res<Value> {
    let drive = load(RAV4_MANIFEST)?;
    let (q, how) = encoder_q(RAV4_MANIFEST)?;
    eprintln!("rav4: encoder q = {q:.6e} rev/s ({how})");
    md.push_str(
        "#### (c) comma2k19 RAV4 (1 km, nearly straight): c_e and what is named\n\n\
         | method | options | c_e (m) ± 1σ | unobservable (named) | held (auto-fix / EIV start) | verdict | Ē_p / θ_0 (m) \
         | EIV fell back | wall s |\n|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut out = Vec::new();
    let mut detail_md = String::new();
    let mut details = Vec::new();
    for m in methods {
        for auto_fix in [false, true] {
            let opts = CalibrationOptions { auto_fix, ..options(m, q)? };
            let label = if auto_fix { "--auto-fix" } else { "default" };
            let t = Instant::now();
            let r = match calibrate(&drive, &opts) {
                Ok(r) => r,
                Err(e) => {
                    let text = e.to_string();
                    let short: String = text.chars().take(120).collect();
                    md.push_str(&format!(
                        "| {m} | {label} | refused: {}{} ||||||\n",
                        short.replace('|', "\\|"),
                        if text.len() > short.len() { "…" } else { "" }
                    ));
                    out.push(json!({"method": m, "auto_fix": auto_fix, "error": text}));
                    continue;
                }
            };
            let wall = t.elapsed().as_secs_f64();
            let sigma = result_sigma(&r);
            let mut held: Vec<String> = r.auto_fixed.iter().map(|p| p.to_string()).collect();
            if let Some(d) = eiv_part(&r) {
                held.extend(d.start_held.iter().map(|p| format!("{p} (start)")));
            }
            let fb = eiv_fallback(&r);
            if let Some((row, v)) = eiv_detail_row(m, label, &r) {
                detail_md.push_str(&row);
                details.push(v);
            }
            md.push_str(&format!(
                "| {m} | {label} | {:.5} ± {} | {} | {} | {} | {:.2} / {:.2} | {} | {wall:.1} |\n",
                r.theta.c_e,
                // The within-drive σ labelled by its source; the result's σ
                // (for the next drive: within ⊕ between) beside it.
                match (r.within_drive_sigma().c_e, sigma[0]) {
                    (Some(w), Some(s)) if r.result_sigma().covers == SigmaCovers::NextDrive => {
                        format!("{w:.5} ({}; next drive {s:.5})", r.result_sigma().source())
                    }
                    (_, Some(s)) => format!("{s:.5} ({})", r.result_sigma().source()),
                    (_, None) => "held".into(),
                },
                if r.observability.unobservable.is_empty() {
                    "none".into()
                } else {
                    r.observability.unobservable.to_string()
                },
                if held.is_empty() { "none".into() } else { held.join(", ") },
                r.verdict.level,
                r.validation.mean_position_error_m,
                r.initial.mean_position_error_m,
                fb.as_ref().map_or("–".into(), |(f, why)| if *f {
                    format!("yes: {}", short_reasons(why))
                } else {
                    "no".into()
                }),
            ));
            out.push(json!({
                "method": m,
                "auto_fix": auto_fix,
                "theta": r.theta,
                "extrinsics": r.extrinsics.as_ref().map(|e| e.value),
                "sigma": sigma,
                "sigma_source": r.result_sigma().source(),
                "unobservable": r.observability.unobservable.into_iter().map(|p| p.to_string()).collect::<Vec<_>>(),
                "rcond": r.observability.rcond,
                "auto_fixed": r.auto_fixed.iter().map(|p| p.to_string()).collect::<Vec<_>>(),
                "held": held,
                "verdict": verdict_json(&r),
                "mean_position_error_m": r.validation.mean_position_error_m,
                "initial_mean_position_error_m": r.initial.mean_position_error_m,
                "eiv_fell_back": fb.as_ref().map(|f| f.0),
                "eiv_checks_failed": fb.as_ref().map(|f| f.1.clone()),
                "wall_s": wall,
            }));
        }
    }
    md.push('\n');
    if !detail_md.is_empty() {
        md.push_str("EIV fits (the filter's own θ and findings):\n\n");
        md.push_str(EIV_DETAIL_HEADER);
        md.push_str(&detail_md);
        md.push('\n');
        out.push(json!({"eiv_details": details}));
    }
    Ok(Value::Array(out))
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &[])?;
    let methods = a.list("methods", &METHODS);
    let parts = a.list("parts", &["testtrack", "van", "rav4"]);
    let json_path: Option<PathBuf> = a.opt("json")?;
    let md_path: Option<PathBuf> = a.opt("markdown")?;
    a.finish()?;
    for m in &methods {
        options(m, NoiseModel::PRODUCTION_CAR.quantisation_step_rev_per_s)?;
    }
    let started = Instant::now();
    let mut md = String::new();
    let mut out = serde_json::Map::new();
    for p in &parts {
        let t = Instant::now();
        let v = match p.as_str() {
            "testtrack" => testtrack(&methods, &mut md)?,
            "van" => van(&methods, &mut md)?,
            "rav4" => rav4(&methods, &mut md)?,
            "swap" => swap(&mut md)?,
            other => return Err(format!("unknown part {other}; use testtrack, van, rav4, swap").into()),
        };
        eprintln!("{p}: {:.1} s", t.elapsed().as_secs_f64());
        out.insert(p.clone(), v);
    }
    let wall = started.elapsed().as_secs_f64();
    md.push_str(&format!("Total wall time {wall:.0} s ({} threads).\n", rayon_threads()));
    out.insert("wall_s".into(), json!(wall));
    out.insert("methods".into(), json!(methods));
    print!("{md}");
    if let Some(p) = json_path {
        std::fs::write(&p, serde_json::to_string_pretty(&Value::Object(out))? + "\n")?;
    }
    if let Some(p) = md_path {
        std::fs::write(&p, &md)?;
    }
    Ok(())
}

/// The number of threads of rayon's pool (the machine's cores unless
/// `RAYON_NUM_THREADS` says otherwise).
fn rayon_threads() -> usize {
    rayon::current_num_threads()
}
