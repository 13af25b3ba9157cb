//! `odocal compensate`: a drive with its wheel rotations compensated for a
//! given θ (the three-step method's input compensation) beside the measured ones.

use std::path::PathBuf;

use anyhow::{bail, Result};
use clap::Args;
use odocal::compensate::{CompensateOptions, QpOptions, SolverKind};
use odocal::output::is_stdout;
use odocal::segment;
use odocal::{ExtraColumn, ExtraValues};

use crate::args::ThetaArg;
use crate::io::{load_drive, print_warnings};
use crate::output::{write_drive, Files};
use crate::progress::Bars;

/// Arguments of `odocal compensate`.
#[derive(Args)]
pub struct CompensateArgs {
    /// The drive: a canonical CSV or a drive manifest (.toml).
    drive: PathBuf,
    /// θ as c_e,c_d,t_r,d (SI), or a parameter file (.yaml, .yml, .json).
    #[arg(long, allow_hyphen_values = true)]
    theta: ThetaArg,
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
    let mut files = Files::default();
    files.drive("the drive being compensated", &a.drive);
    if let Some((p, _)) = &a.theta.file {
        files.input("the --theta parameter file", p);
    }
    files.output("--out", Some(&a.out)).check()?;
    let drive = load_drive(&a.drive)?;
    let segs = segment::cut(&drive, 0, a.segment_length, a.segment_length);
    if segs.is_empty() {
        bail!("{}: too short for one segment of {} steps", a.drive.display(), a.segment_length);
    }
    let cb = |e| bars.event(e);
    let comp = odocal::compensate::compensate_segments(
        &drive,
        &segs,
        &[a.theta.theta],
        &CompensateOptions::default(),
        &QpOptions { solver: a.qp_solver, ..Default::default() },
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
    if is_stdout(&a.out) {
        eprintln!("{summary}");
    } else {
        println!("{summary}");
    }
    Ok(())
}
