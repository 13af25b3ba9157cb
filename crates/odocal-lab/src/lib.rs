//! What the lab's programs share: argument parsing ([`Args`]), the
//! batch Gauss-Newton start ([`batch_gn_all`]), simulated and real drives
//! ([`simulate_preset`], [`testtrack_runs`], [`repo_path`]), error units and
//! statistics ([`errors`], [`Summary`], [`coverage`]), markdown tables
//! ([`Table`]) and cross-run checks ([`crossrun`]). The programs are in
//! `src/bin/`; README.md lists them.

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use odocal::identify::{batch_gauss_newton, IdentifyOptions};
use odocal::segment::{SegmentData, SegmentOptions};
use odocal::sim::{simulate, NoiseOptions, SimOptions, SimOutput};
use odocal::{CalibrationOptions, Drive, Method, Theta};

pub mod crossrun;
pub mod report_json;

/// The programs' result type.
pub type Res<T> = Result<T, Box<dyn std::error::Error>>;

/// Runs a program's body and, on an error, prints it and exits with status 1.
pub fn main_with(run: impl FnOnce() -> Res<()>) {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

/// Command-line arguments: `--name value` options, `--name` switches (the
/// names given to [`Args::parse`]) and positional values, read by name or
/// position; [`Args::finish`] rejects what no read asked for. `--help`
/// prints the program's usage and exits.
pub struct Args {
    options: BTreeMap<String, String>,
    switches: Vec<String>,
    positional: Vec<String>,
    used: Vec<String>,
    usage: &'static str,
}

impl Args {
    /// The process's arguments; `switches` are the options without a value.
    pub fn parse(usage: &'static str, switches: &[&str]) -> Res<Args> {
        Args::from_iter(usage, switches, std::env::args().skip(1))
    }

    /// `args` (without the program name) as [`Args::parse`] reads them.
    pub fn from_iter(usage: &'static str, switches: &[&str], args: impl IntoIterator<Item = String>) -> Res<Args> {
        let mut a =
            Args { options: BTreeMap::new(), switches: Vec::new(), positional: Vec::new(), used: Vec::new(), usage };
        let mut it = args.into_iter();
        while let Some(arg) = it.next() {
            if arg == "--help" || arg == "-h" {
                println!("{usage}");
                std::process::exit(0);
            }
            match arg.strip_prefix("--") {
                Some(name) if switches.contains(&name) => a.switches.push(name.to_string()),
                Some(name) => {
                    let value = it.next().ok_or_else(|| format!("--{name} needs a value\n\n{usage}"))?;
                    a.options.insert(name.to_string(), value);
                }
                None => a.positional.push(arg),
            }
        }
        Ok(a)
    }

    /// The value of `--name`, or `default`.
    pub fn get<T: FromStr>(&mut self, name: &str, default: T) -> Res<T>
    where
        T::Err: fmt::Display,
    {
        Ok(self.opt(name)?.unwrap_or(default))
    }

    /// The value of `--name`, if given.
    pub fn opt<T: FromStr>(&mut self, name: &str) -> Res<Option<T>>
    where
        T::Err: fmt::Display,
    {
        self.used.push(name.to_string());
        self.options
            .get(name)
            .map(|v| v.parse::<T>().map_err(|e| format!("--{name} {v}: {e}\n\n{}", self.usage).into()))
            .transpose()
    }

    /// The comma-separated values of `--name`, or `default`.
    pub fn list(&mut self, name: &str, default: &[&str]) -> Vec<String> {
        self.used.push(name.to_string());
        match self.options.get(name) {
            Some(v) => v.split(',').map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect(),
            None => default.iter().map(|s| s.to_string()).collect(),
        }
    }

    /// Whether the switch `--name` was given.
    pub fn flag(&self, name: &str) -> bool {
        self.switches.iter().any(|s| s == name)
    }

    /// The positional value at `index`, or `default`.
    pub fn pos<T: FromStr>(&self, index: usize, default: T) -> Res<T>
    where
        T::Err: fmt::Display,
    {
        match self.positional.get(index) {
            Some(v) => {
                v.parse::<T>().map_err(|e| format!("argument {} '{v}': {e}\n\n{}", index + 1, self.usage).into())
            }
            None => Ok(default),
        }
    }

    /// Every positional value.
    pub fn positional(&self) -> &[String] {
        &self.positional
    }

    /// An error naming every `--option` that no read asked for.
    pub fn finish(self) -> Res<()> {
        let unknown: Vec<String> =
            self.options.keys().filter(|k| !self.used.contains(k)).map(|k| format!("--{k}")).collect();
        if unknown.is_empty() {
            Ok(())
        } else {
            Err(format!("unknown option(s) {}\n\n{}", unknown.join(", "), self.usage).into())
        }
    }
}

/// Batch Gauss-Newton from the paper's θ_0 on every cut segment of `drive`
/// (no yaw-rate selection, up to 20 iterations): the start of the EIV fits
/// that the programs run through `odocal::eiv::estimate` directly (the EIV
/// method of `calibrate` also estimates the reference heading offset).
pub fn batch_gn_all(drive: &Drive) -> Result<Theta, odocal::Error> {
    let o = SegmentOptions::default();
    let all = odocal::segment::cut(drive, o.offset_steps, o.length_steps, o.stride_steps);
    let data: Vec<SegmentData> = all.iter().map(|s| SegmentData::new(drive, s)).collect();
    let opts = IdentifyOptions { max_iterations: 20, ..Default::default() };
    Ok(batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts)?.theta)
}

/// The simulator's noise presets by name (`NoiseOptions`'s `FromStr`) and
/// `coloured` ([`NoiseOptions::coloured_wheels_only`]).
pub fn noise_preset(name: &str) -> Result<NoiseOptions, odocal::Error> {
    match name {
        "coloured" => Ok(NoiseOptions::coloured_wheels_only()),
        _ => name.parse::<NoiseOptions>(),
    }
}

/// A simulated drive of the paper's route: `km` long, noise `preset`
/// ([`noise_preset`]), seed `seed`.
pub fn simulate_preset(preset: &str, km: f64, seed: u64) -> Result<SimOutput, odocal::Error> {
    simulate(&SimOptions { length_km: km, noise: noise_preset(preset)?, ..SimOptions::paper(seed) })
}

/// Seed offset of the *fresh* drive a θ is also judged on: same preset and
/// length, seen by no fit.
pub const FRESH_SEED_OFFSET: u64 = 10_000;

/// A path in the repository (`rel` from its root), wherever the program runs.
pub fn repo_path(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// A drive manifest (or CSV) of the repository, imported.
pub fn load(rel: &str) -> Res<Drive> {
    let path = repo_path(rel);
    let (drive, _) = odocal::load_drive(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(drive)
}

/// The PSU van's six test-track runs of 2024-08-05 (manifest
/// `examples/psu-mapping-van-testtrack/run-NAME.toml`) with their driving
/// direction: three counter-clockwise, then three clockwise.
pub const TESTTRACK_RUNS: [(&str, &str); 6] = [
    ("14-45-26", "ccw"),
    ("15-28-33", "ccw"),
    ("16-06-28", "ccw"),
    ("16-47-33", "cw"),
    ("17-45-46", "cw"),
    ("18-01-26", "cw"),
];

/// The manifest of test-track run `name`, relative to the repository.
pub fn testtrack_manifest(name: &str) -> String {
    format!("examples/psu-mapping-van-testtrack/run-{name}.toml")
}

/// The six test-track runs, imported, in [`TESTTRACK_RUNS`] order.
pub fn testtrack_runs() -> Res<Vec<(&'static str, Drive)>> {
    TESTTRACK_RUNS.iter().map(|(name, _)| Ok((*name, load(&testtrack_manifest(name))?))).collect()
}

/// `drive` with its measured signals replaced by `signals` (same times,
/// sample time, parts and reference-measured flags).
pub fn with_signals(drive: &Drive, signals: odocal::Signals) -> Result<Drive, odocal::Error> {
    let b = odocal::DriveBuilder {
        t: drive.t().to_vec(),
        measured: signals,
        sample_time_s: Some(drive.sample_time_s()),
        parts: Some(drive.parts().to_vec()),
        reference_measured: drive.reference_measured().map(<[bool]>::to_vec),
        ..Default::default()
    };
    b.build()
}

/// Batch Gauss-Newton on every cut segment (`--method batch-gn
/// --min-yaw-rate 0`), with d held at θ_0 when `hold_d`.
pub fn batch_gn_all_options(hold_d: bool) -> CalibrationOptions {
    let mut o = CalibrationOptions { method: Method::BatchGn, ..Default::default() };
    o.segments.min_peak_yaw_rate_rad_per_s = 0.0;
    if hold_d {
        o.identify.free = o.identify.free.without(odocal::Param::D);
    }
    o
}

/// Prints joint batch-G-N fits (every segment, d held and free) of the
/// three counter-clockwise test-track runs, the three clockwise ones and
/// all six (`runs` in [`TESTTRACK_RUNS`] order), with their verdicts.
pub fn print_joint_fits(runs: &[Drive]) -> Res<()> {
    let refs: Vec<&Drive> = runs.iter().collect();
    for hold_d in [true, false] {
        let o = batch_gn_all_options(hold_d);
        for (label, set) in [("CCW", &refs[..3]), ("CW", &refs[3..]), ("all", &refs[..])] {
            let r = odocal::calibrate(&Drive::concat(set)?, &o)?;
            let t = r.theta;
            println!(
                "joint {label:3} d {}: c_e {:.5} c_d {:+.3} mm t_r {:.4} d {:+.3}  Ē_p {:.3} (θ_0 {:.3}) {}",
                if hold_d { "held" } else { "free" },
                t.c_e,
                t.c_d * 1e3,
                t.t_r,
                t.d * 1e3,
                r.validation.mean_position_error_m,
                r.initial.mean_position_error_m,
                r.verdict.level
            );
        }
    }
    Ok(())
}

/// Prints the cross-run summary (each run calibrated, validated on the
/// other five) of the default method, batch G-N with d held and batch G-N,
/// with each run's c_d and d; with `full`, the default's whole table.
pub fn print_cross_runs(runs: &[Drive], full: bool) -> Res<()> {
    use crate::crossrun::{cross_run, CROSS_RUN_OWN_FIT_RATIO};
    let named: Vec<(&str, &Drive)> = TESTTRACK_RUNS.iter().map(|r| r.0).zip(runs.iter()).collect();
    for (label, o) in [
        ("default", CalibrationOptions::default()),
        ("gn hold d", batch_gn_all_options(true)),
        ("gn", batch_gn_all_options(false)),
    ] {
        let t = cross_run(&named, &o, None)?;
        let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
        let cd: Vec<String> = t
            .rows
            .iter()
            .map(|r| {
                r.fit.as_ref().map_or("fail".into(), |f| format!("{:+.2}/{:+.2}", f.theta.c_d * 1e3, f.theta.d * 1e3))
            })
            .collect();
        println!(
            "crossrun {label:9}: own {:.3} cross {:.3} ratio {:.2} worse {} rejected {} failed {}  c_d/d mm [{}]",
            c.mean_own_m,
            c.mean_cross_m,
            c.ratio,
            c.worse_than_initial.len(),
            c.rejected,
            c.failed,
            cd.join(" ")
        );
        if full && label == "default" {
            println!("{t}{c}");
        }
    }
    Ok(())
}

/// The highway van's manifest (2024-07-11), relative to the repository.
pub const VAN_MANIFEST: &str = "examples/psu-mapping-van/manifest.toml";

/// The comma2k19 RAV4's manifest, relative to the repository.
pub const RAV4_MANIFEST: &str = "examples/comma2k19-rav4/manifest.toml";

/// Units of [`errors`]: c_e and t_r in % of the truth, c_d in mm, d in
/// mm/(m/s²).
pub const ERROR_UNITS: [&str; 4] = ["c_e %", "c_d mm", "t_r %", "d mm/(m/s²)"];

/// The parameter names, θ order.
pub const PARAMETERS: [&str; 4] = ["c_e", "c_d", "t_r", "d"];

/// Factors from SI to [`ERROR_UNITS`] at `truth`.
pub fn error_scale(truth: &Theta) -> [f64; 4] {
    [100.0 / truth.c_e, 1e3, 100.0 / truth.t_r, 1e3]
}

/// `theta − truth` in [`ERROR_UNITS`].
pub fn errors(theta: &Theta, truth: &Theta) -> [f64; 4] {
    let (a, b, s) = (<[_; 4]>::from(theta), <[_; 4]>::from(truth), error_scale(truth));
    std::array::from_fn(|i| (a[i] - b[i]) * s[i])
}

/// `e` as `c_e +0.0123% c_d +0.045mm t_r +1.23% d −0.012`.
pub fn format_errors(e: &[f64; 4]) -> String {
    format!("c_e {:+.4}% c_d {:+.3}mm t_r {:+.3}% d {:+.3}", e[0], e[1], e[2], e[3])
}

/// Sample statistics of a set of values (an estimator's errors over drives).
#[derive(Debug, Clone, Copy)]
pub struct Summary {
    /// Number of values.
    pub n: usize,
    /// Mean.
    pub mean: f64,
    /// Standard deviation (n − 1 in the denominator; NaN for fewer than two).
    pub sd: f64,
    /// Root mean square (about zero, not about the mean).
    pub rms: f64,
}

impl Summary {
    /// The statistics of `x`.
    pub fn of(x: &[f64]) -> Summary {
        let n = x.len();
        let nf = n as f64;
        let mean = x.iter().sum::<f64>() / nf;
        let sd = if n > 1 { (x.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / (nf - 1.0)).sqrt() } else { f64::NAN };
        let rms = (x.iter().map(|a| a * a).sum::<f64>() / nf).sqrt();
        Summary { n, mean, sd, rms }
    }

    /// Standard error of the mean, `sd/√n`.
    pub fn se(&self) -> f64 {
        self.sd / (self.n as f64).sqrt()
    }

    /// The bias t statistic `|mean|/(sd/√n)` (above about 2.1 the mean is
    /// significantly non-zero at 5 % for 20 values).
    pub fn t(&self) -> f64 {
        self.mean.abs() / self.se()
    }
}

/// The median of the finite values of `v` (the mean of the middle two for
/// an even count; NaN for none).
pub fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f64::total_cmp);
    match s.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => s[n / 2],
        n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
    }
}

/// The usage lines of [`ReadingsNoise`]'s switches, a literal for a tool's
/// `concat!`ed usage text.
#[macro_export]
macro_rules! readings_noise_usage {
    () => {
        "--lateral-from-readings: the default with a_y's noise held at each drive's a_y readings' sample noise
    (the median absolute first difference / (0.6745·√2)) and β's at the noise model's, instead of both scaled
    with the white wheel noise (LateralNoise::Stated).
--a-y-held-from-readings: the same for a_y with β's noise still scaled with the white wheel noise
    (ResearchOptions::a_y_sigma_held)."
    };
}

/// The lab's two a_y-noise switches, as every tool that takes them reads
/// and applies them (crates/odocal-lab/STUDIES.md):
/// - `--lateral-from-readings`: the default method's a_y noise held at the
///   drive's own a_y readings' white noise
///   ([`EivInput::a_y_sample_noise`](odocal::eiv::EivInput::a_y_sample_noise),
///   within each part) and β's at the noise
///   model's (`LateralNoise::Stated`), instead of both scaled with the white
///   wheel noise;
/// - `--a-y-held-from-readings`: a_y's noise held so while β's stays tied
///   to the white wheel noise (`ResearchOptions::a_y_sigma_held`).
#[derive(Clone, Copy, Debug, Default)]
pub struct ReadingsNoise {
    /// `--lateral-from-readings`.
    pub lateral: bool,
    /// `--a-y-held-from-readings`.
    pub a_y_held: bool,
}

impl ReadingsNoise {
    /// The switches' names, for [`Args::parse`].
    pub const SWITCHES: [&'static str; 2] = ["lateral-from-readings", "a-y-held-from-readings"];

    /// The switches as `a` holds them.
    pub fn from_args(a: &Args) -> ReadingsNoise {
        ReadingsNoise { lateral: a.flag(Self::SWITCHES[0]), a_y_held: a.flag(Self::SWITCHES[1]) }
    }

    /// `options` for `drive` with the switches that are on (the default
    /// method only; other methods are left as they are).
    pub fn apply(self, options: &mut odocal::CalibrationOptions, drive: &odocal::Drive) {
        let odocal::Method::Eiv(e) = &mut options.method else { return };
        let a_y = odocal::eiv::EivInput::from_drive(drive).a_y_sample_noise();
        if self.lateral {
            e.filter.noise.lateral_acceleration_sigma_m_per_s2 = a_y;
            e.filter.lateral_noise = odocal::eiv::LateralNoise::Stated;
        }
        if self.a_y_held {
            e.filter.research.a_y_sigma_held = Some(a_y);
        }
    }
}

/// The fraction of `errors` within `z` of their `sigmas` (`|e| ≤ z·σ`),
/// pairwise: the coverage of the interval ±z·σ (z = 1.96: 95 %).
pub fn coverage(errors: &[f64], sigmas: &[f64], z: f64) -> f64 {
    let inside = errors.iter().zip(sigmas).filter(|(e, s)| e.abs() <= z * **s).count();
    inside as f64 / errors.len().max(1) as f64
}

/// The 0.975 quantile of Student's t with `df` degrees of freedom
/// (Cornish-Fisher expansion about z = 1.96; within 0.3 % of tables for
/// df ≥ 3).
pub fn t975(df: f64) -> f64 {
    let z: f64 = 1.959964;
    z + (z.powi(3) + z) / (4.0 * df)
        + (5.0 * z.powi(5) + 16.0 * z.powi(3) + 3.0 * z) / (96.0 * df * df)
        + (3.0 * z.powi(7) + 19.0 * z.powi(5) + 17.0 * z.powi(3) - 15.0 * z) / (384.0 * df.powi(3))
}

/// A markdown table: a header and rows of cells, printed with `{}`.
pub struct Table {
    header: Vec<String>,
    align_right: Vec<bool>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with these column headers; a header starting with `>` is
    /// right-aligned (the `>` is not printed).
    pub fn new(header: &[&str]) -> Table {
        Table {
            header: header.iter().map(|h| h.trim_start_matches('>').to_string()).collect(),
            align_right: header.iter().map(|h| h.starts_with('>')).collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row (cells beyond the header's are dropped, missing ones empty).
    pub fn row<S: ToString>(&mut self, cells: impl IntoIterator<Item = S>) {
        let mut r: Vec<String> = cells.into_iter().map(|c| c.to_string().replace('|', "\\|")).collect();
        r.resize(self.header.len(), String::new());
        self.rows.push(r);
    }

    /// Whether no row was added.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

impl fmt::Display for Table {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "| {} |", self.header.join(" | "))?;
        let rule: Vec<&str> = self.align_right.iter().map(|r| if *r { "---:" } else { "---" }).collect();
        writeln!(f, "|{}|", rule.join("|"))?;
        for r in &self.rows {
            writeln!(f, "| {} |", r.join(" | "))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(v: &[&str]) -> Args {
        Args::from_iter("usage", &["check"], v.iter().map(|s| s.to_string())).expect("args")
    }

    #[test]
    fn options_switches_and_positionals_are_read_and_unknown_options_refused() {
        let mut a = args(&["12", "--seeds", "3", "--check", "paper", "--presets", "a,b"]);
        assert_eq!(a.get("seeds", 20u64).expect("seeds"), 3);
        assert_eq!(a.get("km", 6.5f64).expect("default").to_bits(), 6.5f64.to_bits());
        assert_eq!(a.list("presets", &["x"]), ["a", "b"]);
        assert!(a.flag("check"));
        assert_eq!(a.pos(0, 0.0f64).expect("km").to_bits(), 12.0f64.to_bits());
        assert_eq!(a.pos::<String>(1, String::new()).expect("preset"), "paper");
        assert_eq!(a.pos(2, 7u32).expect("default"), 7);
        assert!(a.finish().is_ok());
        let mut b = args(&["--seeds", "x", "--typo", "1"]);
        assert!(b.get("seeds", 1u64).is_err());
        assert!(b.finish().is_err(), "--typo was not read");
        assert!(Args::from_iter("u", &[], ["--km".to_string()]).is_err(), "--km needs a value");
    }

    #[test]
    fn summary_and_coverage() {
        let s = Summary::of(&[1.0, 2.0, 3.0]);
        assert!((s.mean - 2.0).abs() < 1e-15 && (s.sd - 1.0).abs() < 1e-15);
        assert!((s.rms - (14.0f64 / 3.0).sqrt()).abs() < 1e-15);
        assert!((s.t() - 2.0 * 3f64.sqrt()).abs() < 1e-12);
        assert!(Summary::of(&[1.0]).sd.is_nan());
        assert!((coverage(&[0.5, -2.5, 1.0], &[1.0, 1.0, 0.1], 1.96) - 1.0 / 3.0).abs() < 1e-15);
        assert!((median(&[3.0, 1.0, 2.0]) - 2.0).abs() < 1e-15 && (median(&[4.0, 1.0, 2.0, 3.0]) - 2.5).abs() < 1e-15);
        assert!((t975(1e9) - 1.959964).abs() < 1e-6 && (t975(10.0) - 2.228).abs() < 0.01);
    }

    #[test]
    fn errors_are_in_percent_and_millimetres() {
        let truth = Theta { c_e: 2.0, c_d: 0.0, t_r: 1.5, d: 0.0 };
        let e = errors(&Theta { c_e: 2.002, c_d: 0.001, t_r: 1.5, d: -0.0005 }, &truth);
        assert!(
            (e[0] - 0.1).abs() < 1e-9 && (e[1] - 1.0).abs() < 1e-12 && e[2].abs() < 1e-15 && (e[3] + 0.5).abs() < 1e-12
        );
    }

    #[test]
    fn table_prints_markdown() {
        let mut t = Table::new(&["a", ">b"]);
        t.row(["x|y", "1"]);
        t.row(["only"]);
        assert_eq!(t.to_string(), "| a | b |\n|---|---:|\n| x\\|y | 1 |\n| only |  |\n");
    }
}
