//! `odocal compensate`: a drive with its wheel rotations compensated for a
//! given θ (the three-step method's input compensation) beside the measured ones.
//!
//! The QP models the rear-axle centre, so it tracks the axle poses the
//! reference implies under the reference extrinsics (docs/method.md,
//! section 5, as the 3-step method's step 2 does): those `validate` would
//! use with the same θ on the drive, by the same rules
//! ([`odocal::ValidateOptions::set_extrinsics`]).

use std::path::PathBuf;

use crate::output::is_stdout;
use anyhow::{bail, Result};
use clap::Args;
use odocal::compensate::{CompensateOptions, QpOptions, SolverKind};
use odocal::segment;
use odocal::settings::ManifestSettings;
use odocal::{Drive, ExtraColumn, ExtraValues, Extrinsics, HeadingOffsetFit, ValidateOptions};

use crate::args::ThetaArg;
use crate::io::{load_drive_with_scale, print_warnings};
use crate::output::{report_line, write_drive, Files};
use crate::progress::Bars;

/// Arguments of `odocal compensate`.
#[derive(Args)]
pub struct CompensateArgs {
    /// The drive: a canonical CSV or a drive manifest (.toml).
    drive: PathBuf,
    /// θ as c_e,c_d,t_r,d (SI), or a parameter file (.yaml, .yml, .json) as
    /// `calibrate --params-out` writes it: its θ and the reference extrinsics
    /// it estimated, applied as `validate` applies them (held ones give way
    /// to the drive's manifest [reference]; an estimated heading offset is
    /// re-estimated on this drive with θ and the lever arm held). The QP
    /// tracks the rear-axle poses the reference implies under them.
    #[arg(long, allow_hyphen_values = true)]
    theta: ThetaArg,
    /// Hold the heading offset as given (a parameter file's estimate, else
    /// the drive's manifest [reference] value, else 0) instead of
    /// re-estimating the drive's own with θ held (done where the file's
    /// calibration estimated one or θ is given as numbers).
    #[arg(long)]
    carry_heading_offset: bool,
    /// Output CSV (the drive plus n_rl_comp, n_rr_comp, compensated
    /// columns; "-" for stdout).
    #[arg(long)]
    out: PathBuf,
    /// QP solver: structured or clarabel.
    #[arg(long, default_value = "structured")]
    qp_solver: SolverKind,
    /// Segment length, samples (the drive is cut into consecutive segments).
    #[arg(long, default_value_t = 650, value_parser = crate::args::samples_at_least::<2>)]
    segment_length: usize,
}

/// Compensates every segment and writes the drive with the new columns.
pub fn run(mut a: CompensateArgs, bars: &Bars) -> Result<()> {
    a.theta = a.theta.resolved(None)?;
    crate::args::check_counts(odocal::settings::Settings {
        segment_length: Some(a.segment_length),
        ..Default::default()
    })?;
    let mut files = Files::default();
    files.drive("the drive being compensated", &a.drive);
    if let Some((p, _)) = &a.theta.file {
        files.input("the --theta parameter file", p);
    }
    files.output("--out", Some(&a.out)).check()?;
    let (drive, scale, settings) = load_drive_with_scale(&a.drive)?;
    let use_ = "the wheels are compensated with θ as it stands";
    if let Some(w) = crate::validate::wheel_scale_warning(a.theta.file.as_ref(), scale.as_deref(), &a.drive, use_) {
        eprintln!("warning: {w}");
    }
    let segs = segment::cut(&drive, 0, a.segment_length, a.segment_length);
    if segs.is_empty() {
        bail!("{}: too short for one segment of {} steps", a.drive.display(), a.segment_length);
    }
    let (extrinsics, notes) = reference_extrinsics(&a, &drive, settings.as_ref())?;
    let cb = |e| bars.event(e);
    let comp = odocal::compensate::compensate_segments(
        &drive,
        &segs,
        &[a.theta.theta],
        &CompensateOptions { extrinsics, ..Default::default() },
        &QpOptions::from(a.qp_solver),
        Some(&cb),
    )?;
    bars.finish();
    print_warnings(&comp.warnings.iter().cloned().map(odocal::Warning::from).collect::<Vec<_>>());
    let (mut c_rl, mut c_rr, mut flag) =
        (drive.measured().n_rl.to_vec(), drive.measured().n_rr.to_vec(), vec![0.0; drive.len()]);
    for (i, s) in comp.segments.iter().enumerate() {
        c_rl[s.start..s.start + s.steps].copy_from_slice(&comp.n_rl[i]);
        c_rr[s.start..s.start + s.steps].copy_from_slice(&comp.n_rr[i]);
        flag[s.start..s.start + s.steps].fill(1.0);
    }
    let drive = drive
        .with_extra(ExtraColumn { name: "n_rl_comp".into(), values: ExtraValues::Numbers(c_rl) })?
        .with_extra(ExtraColumn { name: "n_rr_comp".into(), values: ExtraValues::Numbers(c_rr) })?
        .with_extra(ExtraColumn { name: "compensated".into(), values: ExtraValues::Numbers(flag) })?;
    write_drive(&drive, &a.out)?;
    let summary = format!(
        "wrote {}: {} of {} segments compensated ({} QP solves, rms input change {:.3} %)",
        if is_stdout(&a.out) { "the compensated drive to stdout".into() } else { a.out.display().to_string() },
        comp.step.segments,
        segs.len(),
        comp.step.qp_solves,
        comp.step.rms_relative_input_change * 100.0
    );
    // With the CSV on stdout, the summary goes to stderr.
    for line in notes.iter().chain([&summary]) {
        report_line(is_stdout(&a.out), line);
    }
    Ok(())
}

/// The reference extrinsics the QP tracks the axle under, by `validate`'s
/// rules: the drive's manifest `[reference]`, except those the `--theta`
/// parameter file estimated; the heading offset re-estimated on this drive
/// from there with θ held (an estimated one, or any for θ given as
/// numbers) unless `--carry-heading-offset`. With the lines
/// that say which were used and where from (none at the axle).
fn reference_extrinsics(
    a: &CompensateArgs,
    drive: &Drive,
    settings: Option<&ManifestSettings>,
) -> Result<(Extrinsics, Vec<String>)> {
    let stated = settings.and_then(|s| s.reference.as_ref()).map(Extrinsics::from);
    let file = a.theta.file.as_ref();
    // The heading offset alone: no verdict on θ (the drive's own fit would
    // cost two calibrations).
    let mut opts = ValidateOptions { fit_drive: false, ..ValidateOptions::default() };
    let from_file = opts.set_extrinsics(file.map(|(_, f)| f), stated.as_ref(), a.carry_heading_offset);
    let start = crate::validate::OffsetStart::of(&from_file, stated.is_some());
    let (extrinsics, fit, own): (Extrinsics, Option<HeadingOffsetFit>, bool) = if opts.reestimate_heading_offset {
        let r = odocal::validate(drive, &a.theta.theta, &opts, None).map_err(|e| {
            anyhow::anyhow!(
                "{}: re-estimating the drive's heading offset: {e}; --carry-heading-offset holds it as given",
                a.drive.display()
            )
        })?;
        (r.extrinsics, r.heading_offset_fit, r.calibration_drive)
    } else {
        (opts.extrinsics, None, false)
    };
    let mut notes = Vec::new();
    if extrinsics != Extrinsics::default() {
        let path = file.map(|(p, _)| p.as_path());
        let from = crate::validate::extrinsics_source(path, &from_file, fit.is_some(), stated.is_some());
        notes.push(format!("reference extrinsics: {extrinsics} ({from}); the QP tracks the axle poses they imply"));
    }
    if let Some(w) = fit.as_ref().and_then(|f| crate::validate::heading_offset_warning(f, start)) {
        eprintln!("warning: {w}");
    }
    if let Some(fit) = fit {
        notes.push(start.describe(&fit));
    }
    if own {
        notes.push(crate::validate::calibration_drive_line(extrinsics.heading_offset));
    }
    Ok((extrinsics, notes))
}
