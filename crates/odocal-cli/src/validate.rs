//! `odocal validate`: Ē_p of a given θ on a drive's validation segments,
//! and optionally the reachable minimum of Ē_p.

use std::path::{Path, PathBuf};

use crate::output::is_stdout;
use anyhow::Result;
use clap::Args;
use odocal::{Param, Theta, ValidateOptions};

use crate::args::ThetaArg;
use crate::io::{drive_entry, load_drive_with_scale, write_json};
use crate::output::Files;
use crate::progress::Bars;
use crate::Outcome;

/// Arguments of `odocal validate`.
#[derive(Args)]
pub struct ValidateArgs {
    /// The drive: a canonical CSV or a drive manifest (.toml).
    drive: PathBuf,
    /// θ as c_e,c_d,t_r,d (SI), or a parameter file (.yaml, .yml, .json) as
    /// `calibrate --params-out` writes it: its θ and the reference extrinsics
    /// it estimated (held ones give way to the drive's manifest [reference]).
    #[arg(long, allow_hyphen_values = true)]
    theta: ThetaArg,
    /// Hold the heading offset as given: a parameter file's estimate,
    /// carried to this drive, else the drive's manifest [reference] value,
    /// else 0. By default the drive's own heading offset is re-estimated
    /// from there with θ and the lever arm held where the file's calibration
    /// estimated one or θ is given as numbers (the reference's heading bias
    /// changes from drive to drive).
    #[arg(long)]
    carry_heading_offset: bool,
    /// Skip the drive's own fit (batch G-N on this drive, started from θ
    /// and from θ_0, or the default method where batch G-N's fit is worse
    /// than θ or held what the drive does not determine) and with it the
    /// verdict on whether θ fits the drive (exit code 3 when it does not).
    #[arg(long)]
    no_drive_fit: bool,
    /// Validation segment length K_v, samples (stride K_v/2) [default: 1300].
    #[arg(long, value_parser = crate::args::samples_at_least::<2>)]
    validation_length: Option<usize>,
    /// Also search the reachable minimum of Ē_p (global particle swarm over a
    /// box around θ_0, refined by Nelder-Mead).
    #[arg(long)]
    reachable_minimum: bool,
    /// Centre of the reachable-minimum search box (default the paper's θ_0;
    /// c_e,c_d,t_r,d or a parameter file).
    #[arg(long, allow_hyphen_values = true)]
    theta0: Option<ThetaArg>,
    /// Seed of the reachable-minimum search.
    #[arg(long, default_value_t = 0, value_parser = crate::args::whole::<u64>)]
    seed: u64,
    /// The node of the --theta (and --theta0) parameter file to read, when
    /// it holds several nodes' parameters or several YAML documents.
    #[arg(long)]
    params_node: Option<String>,
    /// Write the JSON report here ("-" for stdout).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Validates θ and prints (or writes) the report: [`Outcome::Rejected`]
/// when θ does not fit the drive.
pub fn run(mut a: ValidateArgs, bars: &Bars) -> Result<Outcome> {
    a.theta = a.theta.resolved(a.params_node.as_deref())?;
    a.theta0 = a.theta0.map(|t| t.resolved(a.params_node.as_deref())).transpose()?;
    crate::args::check_counts(odocal::settings::Settings {
        validation_length: a.validation_length,
        ..Default::default()
    })?;
    let mut files = Files::default();
    files.drive("the drive being validated", &a.drive);
    if let Some((p, _)) = &a.theta.file {
        files.input("the --theta parameter file", p);
    }
    if let Some((p, _)) = a.theta0.as_ref().and_then(|t| t.file.as_ref()) {
        files.input("the --theta0 parameter file", p);
    }
    files.output("--json", a.json.as_deref()).check()?;
    let (drive, scale, settings) = load_drive_with_scale(&a.drive)?;
    if let Some(w) =
        wheel_scale_warning(a.theta.file.as_ref(), scale.as_deref(), &a.drive, "θ is judged here as it stands")
    {
        eprintln!("warning: {w}");
    }
    let mut opts = ValidateOptions { fit_drive: !a.no_drive_fit, ..ValidateOptions::default() };
    // A manifest's [reference]: the drive's own mount.
    let stated = settings.as_ref().and_then(|s| s.reference.as_ref()).map(odocal::Extrinsics::from);
    let file = a.theta.file.as_ref();
    let from_file = opts.set_extrinsics(file.map(|(_, f)| f), stated.as_ref(), a.carry_heading_offset);
    let start = OffsetStart::of(&from_file, stated.is_some());
    if let Some(v) = a.validation_length {
        opts.segments.length_steps = v;
        opts.segments.stride_steps = (v / 2).max(1);
    }
    if a.reachable_minimum {
        let centre = a.theta0.as_ref().map_or(Theta::PAPER_INITIAL, |t| t.theta);
        opts.reachable = Some(odocal::ReachableOptions {
            seed: a.seed,
            starts: vec![a.theta.theta],
            ..odocal::ReachableOptions::around(&centre)
        });
    }
    let cb = |e| bars.event(e);
    let report =
        odocal::validate(&drive, &a.theta.theta, &opts, Some(&cb)).map_err(|e| crate::io::name_drive(e, &a.drive))?;
    bars.finish();
    if let Some(w) = report.heading_offset_fit.as_ref().and_then(|f| heading_offset_warning(f, start)) {
        eprintln!("warning: {w}");
    }
    if let Some(why) = report.drive_fit.as_ref().and_then(|f| f.batch_gn_failure.as_ref()) {
        eprintln!("note: the verdict's fit is the default method's: {why}");
    }
    if let Some(w) = drive_fit_warning(&report) {
        eprintln!("warning: {w}");
    }
    let outcome = match &report.drive_fit {
        Some(f) if !f.fits => Outcome::Rejected,
        _ => Outcome::Done,
    };
    let reestimated = report.heading_offset_fit.is_some();
    let extrinsics_from = extrinsics_source(file.map(|(p, _)| p.as_path()), &from_file, reestimated, stated.is_some());
    if let Some(p) = &a.json {
        let mut v = serde_json::to_value(&report)?;
        if let Some(obj) = v.as_object_mut() {
            let entry = drive_entry("validation", &a.drive.display().to_string(), &drive.fingerprint());
            obj.insert("drives".into(), serde_json::Value::Array(vec![entry]));
        }
        write_json(p, v)?;
        if is_stdout(p) {
            return Ok(outcome);
        }
    }
    print_report(&a, &report, &extrinsics_from, start);
    Ok(outcome)
}

/// Where the heading offset that a drive's own is re-estimated from came
/// from ([`ValidateOptions::set_extrinsics`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum OffsetStart {
    /// The `--theta` parameter file (its estimate, or its held value on a
    /// drive whose manifest states no reference).
    File,
    /// The drive's manifest `[reference]`.
    Manifest,
    /// Neither states one: 0.
    Zero,
}

impl OffsetStart {
    /// From the extrinsics taken from the file (`from_file`) and whether
    /// the drive's manifest states a reference.
    pub(crate) fn of(from_file: &[&str], manifest: bool) -> OffsetStart {
        if from_file.contains(&"heading_offset") {
            OffsetStart::File
        } else if manifest {
            OffsetStart::Manifest
        } else {
            OffsetStart::Zero
        }
    }

    /// The line that says what the drive's heading offset was re-estimated
    /// from and what `--carry-heading-offset` would hold instead.
    pub(crate) fn describe(self, fit: &odocal::HeadingOffsetFit) -> String {
        match self {
            OffsetStart::File => format!("{fit} (--carry-heading-offset carries the calibration's)"),
            OffsetStart::Manifest => format!(
                "heading offset re-estimated on this drive: {:.1} mrad (the drive's manifest states {:.1}; \
                 --carry-heading-offset holds that)",
                fit.value * 1e3,
                fit.calibration * 1e3
            ),
            OffsetStart::Zero => format!(
                "heading offset re-estimated on this drive: {:.1} mrad (from 0: neither θ nor the drive states one; \
                 --carry-heading-offset holds 0)",
                fit.value * 1e3
            ),
        }
    }
}

/// How many of its cluster-robust σ a re-estimated heading offset may lie
/// from a stated one before [`heading_offset_warning`] says so.
const HEADING_OFFSET_SIGMAS: f64 = 4.0;

/// A warning when the heading offset re-estimated on this drive is not
/// believable as the drive's own: beyond the plausible range the verdict
/// guards an estimated one with ([`odocal::Guards::heading_offset_abs_rad`]),
/// or more than [`HEADING_OFFSET_SIGMAS`] of its cluster-robust σ from the
/// one the parameter file or the drive's manifest states (the model σ
/// understates it, so it is not used). A fit from 0, where neither states
/// one, is judged by the range alone.
pub(crate) fn heading_offset_warning(fit: &odocal::HeadingOffsetFit, start: OffsetStart) -> Option<String> {
    let limit = odocal::Guards::default().heading_offset_abs_rad;
    let what = format!(
        "the heading offset re-estimated on this drive, {:.1} mrad ({:.1}°),",
        fit.value * 1e3,
        fit.value.to_degrees()
    );
    let off = (fit.value - fit.calibration).abs();
    let check = match start {
        OffsetStart::File => {
            "check that the --theta file is this vehicle's and that this drive's reference heading has the \
             calibration drive's convention and unit (manifest [pose] heading)"
        }
        OffsetStart::Manifest | OffsetStart::Zero => {
            "check that θ is this vehicle's and this drive's reference heading's convention and unit (manifest \
             [pose] heading)"
        }
    };
    let stated = match start {
        OffsetStart::File => "the parameter file's",
        OffsetStart::Manifest => "the drive's manifest's",
        OffsetStart::Zero => "",
    };
    if !fit.value.is_finite() || fit.value.abs() > limit {
        Some(format!(
            "{what} is beyond the plausible ±{:.0} mrad of a reference's mount and heading bias: θ may be another \
             vehicle's, or the heading of another convention or unit; {check}",
            limit * 1e3
        ))
    } else if start != OffsetStart::Zero && fit.robust && off > HEADING_OFFSET_SIGMAS * fit.std_dev {
        Some(format!(
            "{what} is {:.1} mrad from {stated} {:.1} mrad, {:.0} times its cluster-robust σ ({:.1} \
             mrad): the reference was mounted or set up otherwise on this drive, or θ is another vehicle's, or \
             the heading of another convention; {check}",
            off * 1e3,
            fit.calibration * 1e3,
            off / fit.std_dev,
            fit.std_dev * 1e3
        ))
    } else {
        None
    }
}

/// Where the extrinsics in force came from: the `--theta` parameter file
/// (`path`) for those in `from_file`, except a heading offset `reestimated`
/// on this drive; the drive's manifest (when it states a reference,
/// `manifest`) for the rest.
pub(crate) fn extrinsics_source(path: Option<&Path>, from_file: &[&str], reestimated: bool, manifest: bool) -> String {
    let manifest_text = "the drive's manifest [reference]".to_string();
    let kept: Vec<&str> = from_file.iter().copied().filter(|n| !(reestimated && *n == "heading_offset")).collect();
    let mut parts = Vec::new();
    match path {
        Some(p) if kept.len() == 3 => parts.push(p.display().to_string()),
        Some(p) if !kept.is_empty() => parts.push(format!("{} from {}", kept.join(", "), p.display())),
        _ => {}
    }
    if reestimated {
        parts.push("heading_offset re-estimated on this drive".to_string());
    }
    // The rest is the manifest's; with nothing else to name, the manifest.
    if from_file.len() < 3 && (manifest || parts.is_empty()) {
        parts.push(if parts.is_empty() { manifest_text } else { format!("the rest from {manifest_text}") });
    }
    parts.join(", ")
}

/// The line that says the heading offset `delta` (rad) was held at the
/// calibration's own estimate for this drive, which the calibration ran on
/// ([`odocal::ValidateReport::calibration_drive`]).
pub(crate) fn calibration_drive_line(delta: f64) -> String {
    format!(
        "heading offset held at {:.1} mrad, the calibration's own estimate for this drive: the parameter file's \
         calibration ran on it (the same drive fingerprint)",
        delta * 1e3
    )
}

/// The report for humans.
fn print_report(a: &ValidateArgs, report: &odocal::ValidateReport, extrinsics_from: &str, start: OffsetStart) {
    let r = &report.validation;
    match &a.theta.file {
        Some((path, f)) => println!(
            "θ: {} (from {}{})",
            a.theta.theta,
            path.display(),
            f.verdict.as_ref().map(|v| format!(", verdict {v}")).unwrap_or_default()
        ),
        None => println!("θ: {}", a.theta.theta),
    }
    if report.extrinsics != odocal::Extrinsics::default() {
        println!("reference extrinsics: {} ({extrinsics_from})", report.extrinsics);
    }
    if let Some(fit) = &report.heading_offset_fit {
        println!("{}", start.describe(fit));
    }
    if report.calibration_drive {
        println!("{}", calibration_drive_line(report.extrinsics.heading_offset));
    }
    println!("mean position error Ē_p: {:.4} m over {} validation segments", r.mean_position_error_m, r.segments);
    if let Some(line) = verdict_line(&a.theta.theta, report) {
        println!("{line}");
    }
    if let Some(rm) = &report.reachable_minimum {
        println!(
            "reachable minimum: Ē_p {:.4} m at {} ({} evaluations, {:.1} s)",
            rm.mean_position_error_m, rm.theta, rm.evaluations, rm.time_s
        );
        if report.extrinsics != odocal::Extrinsics::default() {
            println!("  (the search, too, takes the reference at the extrinsics above)");
        }
        if rm.recentred > 0 {
            println!("  the search box was re-centred {} time(s) on a best point at its edge", rm.recentred);
        }
        if !rm.enclosed {
            println!(
                "  NOT ENCLOSED: {} ended on the edge of the search box; the minimum may lie beyond \
                 (widen the box with --theta0 nearer the best point)",
                rm.at_edge
            );
        }
    }
}

/// The verdict line: whether θ fits the drive as well as θ fitted on it,
/// and the fit; `None` when the drive was not fitted.
fn verdict_line(theta: &Theta, report: &odocal::ValidateReport) -> Option<String> {
    if let Some(e) = &report.drive_fit_error {
        return Some(format!("verdict: NOT JUDGED, the drive could not be fitted: {e}"));
    }
    let f = report.drive_fit.as_ref()?;
    let word = if f.fits { "FITS" } else { "DOES NOT FIT" };
    Some(format!(
        "verdict: θ {word} this drive: Ē_p {:.2} × the {:.4} m of θ fitted on it by {}; {}",
        f.ratio,
        f.mean_position_error_m,
        f.method,
        change(theta, f)
    ))
}

/// How θ fitted on the drive differs from the given θ, per parameter;
/// `held` for one the fit held at its start, which the drive does not
/// determine.
fn change(theta: &Theta, fit: &odocal::DriveFit) -> String {
    let f = &fit.theta;
    let each = [
        (Param::CE, format!("{} %", signed((f.c_e / theta.c_e - 1.0) * 100.0, 3))),
        (Param::CD, format!("{} mm", signed((f.c_d - theta.c_d) * 1e3, 2))),
        (Param::TR, format!("{} %", signed((f.t_r / theta.t_r - 1.0) * 100.0, 2))),
        (Param::D, format!("{} mm/(m/s²)", signed((f.d - theta.d) * 1e3, 2))),
    ];
    let parts: Vec<String> = each
        .iter()
        .map(|(p, v)| if fit.held.contains(*p) { format!("{p} held") } else { format!("{p} {v}") })
        .collect();
    format!("fitted {}", parts.join(", "))
}

/// A warning when θ's parameter file was calibrated on drives that count
/// wheel revolutions otherwise than `drive` (its provenance `wheel_scale`
/// against the drive's import): θ's c_e, c_d and d then mean other units;
/// `use_` says what is done with θ all the same.
pub(crate) fn wheel_scale_warning(
    file: Option<&(PathBuf, odocal::ParamFile)>,
    drive_scale: Option<&str>,
    drive: &Path,
    use_: &str,
) -> Option<String> {
    let (path, f) = file?;
    let theta_scale = f.provenance.iter().find(|(k, _)| k == "wheel_scale").map(|(_, v)| v.clone());
    let mut first = theta_scale.map(|w| (format!("θ's parameter file {}", path.display()), w));
    let why = odocal::wheel_scale_mismatch(&mut first, &drive.display().to_string(), drive_scale)?;
    Some(format!("{why}; {use_}"))
}

/// A warning when θ does not fit the drive: what it means and what to do.
fn drive_fit_warning(report: &odocal::ValidateReport) -> Option<String> {
    let f = report.drive_fit.as_ref().filter(|f| !f.fits)?;
    Some(format!(
        "θ does not fit this drive: its Ē_p, {:.4} m, is {:.2} times that of θ fitted on the drive ({:.4} m): \
         the vehicle may have changed (tyres, load), θ may be another vehicle's, or this drive's data may differ \
         from the calibration's (units, mount); recalibrate on this drive or check its inputs",
        report.validation.mean_position_error_m, f.ratio, f.mean_position_error_m
    ))
}

/// `x` with its sign and `digits` decimals; a value that rounds to zero is
/// `+0.00`, not `-0.00`.
fn signed(x: f64, digits: usize) -> String {
    let x = if (x * 10f64.powi(digits as i32)).round() == 0.0 { 0.0 } else { x };
    format!("{x:+.digits$}")
}

#[cfg(test)]
mod tests {
    use super::signed;

    #[test]
    fn signed_prints_no_negative_zero() {
        assert_eq!(signed(-0.001, 2), "+0.00");
        assert_eq!(signed(-0.0, 3), "+0.000");
        assert_eq!(signed(-0.006, 2), "-0.01");
        assert_eq!(signed(2.345, 1), "+2.3");
    }
}
