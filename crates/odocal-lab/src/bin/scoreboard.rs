//! The scoreboard that chooses the default method (docs/validation.md,
//! "Choosing the default").
//!
//! Methods, each as a user runs it through `odocal::calibrate`:
//! - `eiv`: the default (`odocal calibrate` without options);
//! - `batch-gn`: `--method batch-gn --estimate heading-offset`;
//! - `three-step`: `--method three-step --estimate heading-offset`.
//!
//! Parts, printed in this order as each finishes:
//! - **time**: CPU time of each method on one simulated 24 km paper drive
//!   (seed 1), the process's user + system time from `/proc/self/stat` (run
//!   with `RAYON_NUM_THREADS=1`: one thread), and its ratio to batch G-N's
//!   in the same run;
//! - **testtrack**: the six shipped test-track runs, each calibrated with
//!   its manifest's settings and the method, validated on the other five
//!   with that run's heading offset δ re-estimated (θ and lever arm held,
//!   `odocal validate OTHER --theta FILE`'s default): mean Ē_p over the 30
//!   pairs and its ratio to the mean of the runs' own fits;
//! - **van**: the highway van (2024-07-11) calibrated on one half and
//!   validated on the other, δ re-estimated, both directions; the ratio is
//!   to the other half's own fit with the same method;
//! - **worlds**: random noise worlds as in `random_worlds` (world i has world
//!   and drive seed S + i, `--length-km`, judged against
//!   `SimOptions::equivalent_truth`): per method and regime, bias |t| per
//!   parameter, coverage of the 95 % interval (±1.96 σ) with the σ the
//!   result reports (`sigma`, next drive) and with the within-drive σ
//!   (`sigma_within_drive`), results accepted beyond 3 σ, and held-out Ē_p
//!   (a fresh drive of the world, seed + 10 000) less the equivalent truth's.
//!   Each world's rows are appended to `--csv` as the world finishes;
//!   `--from-csv FILE` prints the tables and the verdict from such a file
//!   (a run stopped early included).
//!
//! Then the rule (docs/validation.md, "Choosing the default"): the
//! eligible methods are those with |t| ≤ 3 and coverage ≥ 90 % for every
//! parameter over all worlds, with the σ the method reports; among them,
//! those within 5 % of the best on real Ē_p (test-track cross-run and van
//! halves, each); the fastest of those.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;

use odocal::research::mean_position_error_with;
use odocal::segment::{validation_segments, ValidationSegmentOptions};
use odocal::settings::{Caller, ManifestSettings, Settings};
use odocal::sim::{simulate, NoiseOptions, NoiseRegime, SimOptions};
use odocal::{
    calibrate, Calibration, CalibrationOptions, CalibrationReport, Drive, Holdout, Method, Param, ValidationDrive,
    VerdictLevel,
};
use odocal_lab::{
    coverage, error_scale, errors, repo_path, testtrack_manifest, Args, Res, Summary, Table, ERROR_UNITS,
    FRESH_SEED_OFFSET, TESTTRACK_RUNS, VAN_MANIFEST,
};
use rayon::prelude::*;

const USAGE: &str = "scoreboard [--worlds 100] [--length-km 12] [--seed 1] [--methods eiv,batch-gn,three-step]
    [--parts time,testtrack,van,worlds] [--csv FILE] [--from-csv FILE]

Run with RAYON_NUM_THREADS=1 for the CPU times.";

const METHODS: [&str; 3] = ["eiv", "batch-gn", "three-step"];
const PARTS: [&str; 4] = ["time", "testtrack", "van", "worlds"];

/// `options` with `method` as a user selects it: a method other than the
/// default also gets `--estimate heading-offset` (the default estimates δ
/// by itself).
fn with_method(mut o: CalibrationOptions, method: &str) -> Res<CalibrationOptions> {
    o.method = method.parse::<Method>()?;
    if method != "eiv" {
        o.identify.free = o.identify.free.with(Param::HeadingOffset);
    }
    Ok(o)
}

/// The process's CPU time (user + system), s.
fn cpu_time_s() -> Res<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat")?;
    // Fields after the command name (which ends with ')'): state is field 3; utime, stime are 14, 15.
    let rest = stat.rsplit_once(')').ok_or("malformed /proc/self/stat")?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f[11].parse::<f64>()? + f[12].parse::<f64>()?;
    // Linux reports these in USER_HZ, 100 on every common platform.
    Ok(ticks / 100.0)
}

fn time_part(methods: &[String]) -> Res<Vec<(String, f64)>> {
    let drive = simulate(&SimOptions { length_km: 24.0, ..SimOptions::paper(1) })?.drive;
    let mut out = Vec::new();
    for m in methods {
        let opts = with_method(CalibrationOptions::default(), m)?;
        let t0 = cpu_time_s()?;
        let r = calibrate(&drive, &opts)?;
        let t = cpu_time_s()? - t0;
        eprintln!("time: {m} {t:.2} s CPU (verdict {})", r.verdict.level);
        out.push((m.clone(), t));
    }
    let gn = out.iter().find(|(m, _)| m == "batch-gn").map(|(_, t)| *t);
    let mut t = Table::new(&["method", ">CPU time on 24 km, s", ">ratio to batch G-N"]);
    for (m, s) in &out {
        t.row([m.clone(), format!("{s:.2}"), gn.map_or("–".into(), |g| format!("{:.1}", s / g))]);
    }
    println!("### CPU time, one 24 km paper drive (seed 1), one thread\n\n{t}");
    Ok(out)
}

/// A manifest imported, with the calibration options `odocal calibrate` resolves for it.
fn load_with_options(rel: &str) -> Res<(Drive, CalibrationOptions)> {
    let path = repo_path(rel);
    let (drive, report) = odocal::load_drive(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let manifest = report.as_ref().map(ManifestSettings::try_from).transpose()?;
    let options = Settings::default().resolve(manifest.as_slice(), Caller::CommandLine)?.options;
    Ok((drive, options))
}

/// Ē_p of the calibration `r` on `drive`, δ re-estimated there.
fn held_out_e_p(r: &CalibrationReport, drive: &Drive) -> Res<f64> {
    let others = [ValidationDrive { name: "other", drive, reference: None }];
    let v = r.validate_on_drives(&others, false)?;
    Ok(v.drives[0].mean_position_error_m)
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Per method: (mean own Ē_p, mean cross-run Ē_p), m.
fn testtrack_part(methods: &[String]) -> Res<Vec<(String, f64, f64)>> {
    let runs: Vec<(Drive, CalibrationOptions)> =
        TESTTRACK_RUNS.iter().map(|(n, _)| load_with_options(&testtrack_manifest(n))).collect::<Res<_>>()?;
    let mut out = Vec::new();
    for m in methods {
        let mut fits = Vec::new();
        for (drive, opts) in &runs {
            let o = with_method(opts.clone(), m)?;
            fits.push((Calibration::new(drive, &o).run()?, o));
        }
        let own: Vec<f64> = fits.iter().map(|(r, _)| r.validation.mean_position_error_m).collect();
        let mut cross = Vec::new();
        for (i, (r, _)) in fits.iter().enumerate() {
            for (j, (drive, _)) in runs.iter().enumerate() {
                if i != j {
                    cross.push(held_out_e_p(r, drive)?);
                }
            }
        }
        eprintln!("testtrack: {m} own {:.3} m, cross {:.3} m", mean(&own), mean(&cross));
        out.push((m.clone(), mean(&own), mean(&cross)));
    }
    let mut t = Table::new(&["method", ">own fit Ē_p, m", ">cross-run Ē_p (δ re-estimated), m", ">ratio"]);
    for (m, own, cross) in &out {
        t.row([m.clone(), format!("{own:.3}"), format!("{cross:.3}"), format!("{:.2}", cross / own)]);
    }
    println!("### Test track, six runs, 30 pairs\n\n{t}");
    Ok(out)
}

/// Per method: the held-out Ē_p of both directions and their ratios to the
/// other half's own fit.
type VanRows = Vec<(String, [f64; 2], [f64; 2])>;

fn van_part(methods: &[String]) -> Res<VanRows> {
    let (drive, opts) = load_with_options(VAN_MANIFEST)?;
    let (first, second) = Holdout::SecondHalf.split(&drive)?;
    let halves = [first.into_owned(), second.into_owned()];
    let mut out = Vec::new();
    let mut t = Table::new(&[
        "method",
        ">own fit, first half m",
        ">own fit, second half m",
        ">first → second m",
        ">ratio",
        ">second → first m",
        ">ratio",
    ]);
    for m in methods {
        let o = with_method(opts.clone(), m)?;
        let fits: Vec<CalibrationReport> =
            halves.iter().map(|h| Calibration::new(h, &o).run()).collect::<Result<_, _>>()?;
        let own = [0, 1].map(|i| fits[i].validation.mean_position_error_m);
        let held = [held_out_e_p(&fits[0], &halves[1])?, held_out_e_p(&fits[1], &halves[0])?];
        let ratio = [held[0] / own[1], held[1] / own[0]];
        eprintln!("van: {m} own {own:?} held {held:?}");
        t.row([
            m.clone(),
            format!("{:.3}", own[0]),
            format!("{:.3}", own[1]),
            format!("{:.3}", held[0]),
            format!("{:.2}", ratio[0]),
            format!("{:.3}", held[1]),
            format!("{:.2}", ratio[1]),
        ]);
        out.push((m.clone(), held, ratio));
    }
    println!("### Highway van (2024-07-11), halves, δ re-estimated\n\n{t}");
    Ok(out)
}

/// One method's result on one world (errors in [`ERROR_UNITS`]).
#[derive(Clone)]
struct Row {
    world: u64,
    regime: String,
    method: String,
    err: [f64; 4],
    sigma: [f64; 4],
    within: [f64; 4],
    accepted: bool,
    excess_e_p_m: f64,
}

const CSV_HEADER: &str = "world,regime,method,err_c_e,err_c_d,err_t_r,err_d,sigma_c_e,sigma_c_d,sigma_t_r,sigma_d,\
                          within_c_e,within_c_d,within_t_r,within_d,accepted,held_out_e_p_minus_truth_m";

impl Row {
    fn csv(&self) -> String {
        let nums: Vec<String> =
            self.err.iter().chain(&self.sigma).chain(&self.within).map(|v| format!("{v:.6e}")).collect();
        format!(
            "{},{},{},{},{},{:.6e}",
            self.world,
            self.regime,
            self.method,
            nums.join(","),
            self.accepted,
            self.excess_e_p_m
        )
    }

    fn parse(line: &str) -> Res<Row> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 17 {
            return Err(format!("malformed row '{line}'").into());
        }
        let num = |i: usize| -> Res<f64> { Ok(f[i].parse::<f64>()?) };
        let arr = |s: usize| -> Res<[f64; 4]> { Ok([num(s)?, num(s + 1)?, num(s + 2)?, num(s + 3)?]) };
        Ok(Row {
            world: f[0].parse()?,
            regime: f[1].to_string(),
            method: f[2].to_string(),
            err: arr(3)?,
            sigma: arr(7)?,
            within: arr(11)?,
            accepted: f[15] == "true",
            excess_e_p_m: num(16)?,
        })
    }
}

fn world_rows(index: u64, seed0: u64, km: f64, methods: &[String]) -> Res<Vec<Row>> {
    let seed = seed0 + index;
    let (noise, summary) = NoiseOptions::random_world(seed);
    let sim = SimOptions { length_km: km, noise, ..SimOptions::paper(seed) };
    let drive = simulate(&sim)?.drive;
    let (truth, true_ext) = sim.equivalent_truth();
    let fresh = simulate(&SimOptions { seed: seed + FRESH_SEED_OFFSET, ..sim })?.drive;
    let segments = validation_segments(&fresh, &ValidationSegmentOptions::default())?;
    let truth_e_p = mean_position_error_with(&fresh, &segments, &truth, &true_ext)?.mean_position_error_m;
    let mut rows = Vec::new();
    for m in methods {
        let r = calibrate(&drive, &with_method(CalibrationOptions::default(), m)?)?;
        let ext = r.extrinsics.as_ref().map_or(r.options.identify.extrinsics, |e| e.value);
        let scale = error_scale(&truth);
        let si = |s: [Option<f64>; 4]| std::array::from_fn(|i| s[i].unwrap_or(f64::NAN) * scale[i]);
        let e_p = mean_position_error_with(&fresh, &segments, &r.theta, &ext)?.mean_position_error_m;
        rows.push(Row {
            world: index,
            regime: summary.regime.to_string(),
            method: m.clone(),
            err: errors(&r.theta, &truth),
            sigma: si(<[_; 4]>::from(r.result_sigma())),
            within: si(<[_; 4]>::from(r.within_drive_sigma())),
            accepted: r.verdict.level == VerdictLevel::Accepted,
            excess_e_p_m: e_p - truth_e_p,
        });
    }
    Ok(rows)
}

fn worlds_part(a: &WorldSettings, methods: &[String]) -> Res<Vec<Row>> {
    let file = a.csv.as_ref().map(std::fs::File::create).transpose()?;
    let file = std::sync::Mutex::new(file);
    if let Some(f) = file.lock().map_err(|_| "poisoned")?.as_mut() {
        writeln!(f, "{CSV_HEADER}")?;
    }
    let rows: Vec<Vec<Row>> = (0..a.worlds)
        .into_par_iter()
        .map(|i| {
            let rows = world_rows(i, a.seed, a.km, methods).map_err(|e| format!("world {i}: {e}"))?;
            let mut line = format!("world {i} ({}):", rows.first().map_or("", |r| r.regime.as_str()));
            for r in &rows {
                let _ = write!(line, " | {} [{}]", r.method, r.err.map(|v| format!("{v:+.3}")).join(" "));
            }
            eprintln!("{line}");
            if let Some(f) = file.lock().map_err(|_| "poisoned".to_string())?.as_mut() {
                for r in &rows {
                    writeln!(f, "{}", r.csv()).map_err(|e| e.to_string())?;
                }
                f.flush().map_err(|e| e.to_string())?;
            }
            Ok(rows)
        })
        .collect::<Result<_, String>>()?;
    Ok(rows.into_iter().flatten().collect())
}

/// Per method over all worlds: (max |t|, min coverage with the reported σ).
type Eligibility = Vec<(String, f64, f64)>;

fn worlds_tables(rows: &[Row], methods: &[String]) -> Eligibility {
    let mut header = vec!["worlds".to_string(), "method".to_string(), ">n".to_string()];
    header.extend(ERROR_UNITS.iter().map(|u| format!(">{u}: bias t · coverage σ · coverage σ within")));
    header.extend([">accepted beyond 3σ".to_string(), ">held-out Ē_p − truth's, m".to_string()]);
    let header: Vec<&str> = header.iter().map(String::as_str).collect();
    let mut t = Table::new(&header);
    let mut eligibility = Vec::new();
    let regimes = [NoiseRegime::White, NoiseRegime::CommonModeSlip, NoiseRegime::Quiet].map(|r| r.to_string());
    let groups = std::iter::once("all".to_string()).chain(regimes);
    for g in groups {
        for m in methods {
            let rs: Vec<&Row> = rows.iter().filter(|r| &r.method == m && (g == "all" || r.regime == g)).collect();
            if rs.is_empty() {
                continue;
            }
            let mut row = vec![g.clone(), m.clone(), rs.len().to_string()];
            let (mut max_t, mut min_cov) = (0.0f64, 1.0f64);
            for i in 0..4 {
                let e: Vec<f64> = rs.iter().map(|r| r.err[i]).collect();
                let s: Vec<f64> = rs.iter().map(|r| r.sigma[i]).collect();
                let w: Vec<f64> = rs.iter().map(|r| r.within[i]).collect();
                let (tt, cov) = (Summary::of(&e).t(), coverage(&e, &s, 1.96));
                max_t = max_t.max(tt);
                min_cov = min_cov.min(cov);
                row.push(format!("{tt:.1} · {:.0} % · {:.0} %", 100.0 * cov, 100.0 * coverage(&e, &w, 1.96)));
            }
            let beyond = rs.iter().filter(|r| r.accepted && (0..4).any(|i| r.err[i].abs() > 3.0 * r.sigma[i])).count();
            row.push(format!("{beyond} of {}", rs.len()));
            let ex: Vec<f64> = rs.iter().map(|r| r.excess_e_p_m).collect();
            row.push(format!("{:+.3}", Summary::of(&ex).mean));
            t.row(row);
            if g == "all" {
                eligibility.push((m.clone(), max_t, min_cov));
            }
        }
    }
    let n = rows.iter().map(|r| r.world).collect::<std::collections::BTreeSet<_>>().len();
    println!(
        "### Random noise worlds: {n} worlds\n\nCoverage of ±1.96 σ with the σ the result reports (`sigma`, next \
         drive: in a simulated world the truth is fixed, so its between-drive part only widens it) and with the \
         within-drive σ (`sigma_within_drive`).\n\n{t}"
    );
    eligibility
}

struct WorldSettings {
    worlds: u64,
    km: f64,
    seed: u64,
    csv: Option<PathBuf>,
}

/// Applies the rule and prints the verdict.
fn verdict(
    elig: Option<&Eligibility>,
    track: Option<&[(String, f64, f64)]>,
    van: Option<&VanRows>,
    time: Option<&[(String, f64)]>,
) {
    let mut text = String::from("### The rule\n\n");
    let Some(elig) = elig else {
        println!("{text}No random-world results: no verdict.");
        return;
    };
    let eligible: Vec<&str> =
        elig.iter().filter(|(_, t, c)| *t <= 3.0 && *c >= 0.90).map(|(m, _, _)| m.as_str()).collect();
    for (m, t, c) in elig {
        let _ = writeln!(text, "- {m}: max bias |t| {t:.1}, min coverage {:.0} % with its reported σ", 100.0 * c);
    }
    let within5 = |scores: &[(String, f64)]| -> Vec<String> {
        let best = scores.iter().map(|(_, s)| *s).fold(f64::INFINITY, f64::min);
        scores.iter().filter(|(_, s)| *s <= 1.05 * best).map(|(m, _)| m.clone()).collect()
    };
    let pool: Vec<&str> = if eligible.is_empty() {
        let _ = writeln!(
            text,
            "\nNo method is eligible (|t| ≤ 3 and coverage ≥ 90 % for every parameter). For information, the \
             rest of the rule over all methods:"
        );
        elig.iter().map(|(m, _, _)| m.as_str()).collect()
    } else {
        let _ = writeln!(text, "\nEligible: {}.", eligible.join(", "));
        eligible
    };
    let mut ties: Vec<String> = pool.iter().map(|s| s.to_string()).collect();
    if let Some(track) = track {
        let s: Vec<(String, f64)> =
            track.iter().filter(|(m, _, _)| pool.contains(&m.as_str())).map(|(m, _, c)| (m.clone(), *c)).collect();
        let w = within5(&s);
        let _ = writeln!(text, "- within 5 % of the best test-track cross-run Ē_p: {}", w.join(", "));
        ties.retain(|m| w.contains(m));
    }
    if let Some(van) = van {
        let s: Vec<(String, f64)> = van
            .iter()
            .filter(|(m, _, _)| pool.contains(&m.as_str()))
            .map(|(m, h, _)| (m.clone(), 0.5 * (h[0] + h[1])))
            .collect();
        let w = within5(&s);
        let _ = writeln!(text, "- within 5 % of the best van held-out Ē_p (mean of both directions): {}", w.join(", "));
        ties.retain(|m| w.contains(m));
    }
    let fastest = time.and_then(|t| {
        t.iter().filter(|(m, _)| ties.contains(m)).min_by(|a, b| a.1.total_cmp(&b.1)).map(|(m, _)| m.clone())
    });
    let _ = writeln!(
        text,
        "- within 5 % on both: {}; fastest of those: {}",
        if ties.is_empty() { "none".into() } else { ties.join(", ") },
        fastest.as_deref().unwrap_or("–")
    );
    println!("{text}");
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &[])?;
    let w = WorldSettings {
        worlds: a.get("worlds", 100)?,
        km: a.get("length-km", 12.0)?,
        seed: a.get("seed", 1)?,
        csv: a.opt("csv")?,
    };
    let methods = a.list("methods", &METHODS);
    let parts = a.list("parts", &PARTS);
    let from: Option<PathBuf> = a.opt("from-csv")?;
    a.finish()?;
    if let Some(m) = methods.iter().find(|m| !METHODS.contains(&m.as_str())) {
        return Err(format!("unknown method '{m}'").into());
    }
    let has = |p: &str| parts.iter().any(|x| x == p);
    let time = if has("time") { Some(time_part(&methods)?) } else { None };
    std::io::stdout().flush()?;
    let track = if has("testtrack") { Some(testtrack_part(&methods)?) } else { None };
    std::io::stdout().flush()?;
    let van = if has("van") { Some(van_part(&methods)?) } else { None };
    std::io::stdout().flush()?;
    let rows = match &from {
        Some(p) => Some(std::fs::read_to_string(p)?.lines().skip(1).map(Row::parse).collect::<Res<Vec<Row>>>()?),
        None if has("worlds") => Some(worlds_part(&w, &methods)?),
        None => None,
    };
    let elig = rows.as_ref().map(|r| worlds_tables(r, &methods));
    verdict(elig.as_ref(), track.as_deref(), van.as_ref(), time.as_deref());
    Ok(())
}
