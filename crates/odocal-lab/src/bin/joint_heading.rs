//! Joint calibrations of the six test-track runs with one heading offset δ
//! per drive against one δ for all (docs/validation.md, "Test track: joint
//! fits with a heading offset per drive").
//!
//! Groups: each counter-clockwise run with each clockwise one (nine pairs)
//! and every five runs (leave one out, six groups). Each group is joined
//! with `Drive::concat` (each drive its own δ) and, for the comparison,
//! rebuilt as one drive whose parts are the runs' (`with_signals`: no drive
//! boundaries, so one δ for all: what a joint calibration did before drives
//! had their own). Both are calibrated with the first run's manifest
//! settings and the method (`--method`, default the default) and validated
//! on every run outside the group with that run's δ re-estimated (θ and
//! lever arm held). Printed per group: the δ fitted, own Ē_p, held-out Ē_p;
//! then the means.
//!
//! Run: `cargo run --release --manifest-path crates/odocal-lab/Cargo.toml
//! --bin joint_heading [-- --method batch-gn]`.

use odocal::settings::{Caller, ManifestSettings, Settings};
use odocal::{Calibration, CalibrationOptions, CalibrationReport, Drive, Method, Param, ValidationDrive};
use odocal_lab::{repo_path, testtrack_manifest, with_signals, Args, Res, Table, TESTTRACK_RUNS};

const USAGE: &str = "joint_heading [--method eiv|batch-gn|three-step]";

fn main() {
    odocal_lab::main_with(run)
}

fn load_with_options(rel: &str) -> Res<(Drive, CalibrationOptions)> {
    let path = repo_path(rel);
    let (drive, report) = odocal::load_drive(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let manifest = report.as_ref().map(ManifestSettings::try_from).transpose()?;
    let options = Settings::default().resolve(manifest.as_slice(), Caller::CommandLine)?.options;
    Ok((drive, options))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

/// Mean Ē_p of `r` on `others`, each with its own δ re-estimated.
fn held_out(r: &CalibrationReport, others: &[(&str, &Drive)]) -> Res<f64> {
    let v: Vec<ValidationDrive> =
        others.iter().map(|(name, drive)| ValidationDrive { name, drive, reference: None }).collect();
    let m = r.validate_on_drives(&v, false)?;
    Ok(mean(&m.drives.iter().map(|d| d.mean_position_error_m).collect::<Vec<_>>()))
}

fn deltas(r: &CalibrationReport) -> String {
    match &r.extrinsics {
        Some(x) if !x.per_drive().is_empty() => {
            x.per_drive().iter().map(|p| format!("{:.1}", p.value * 1e3)).collect::<Vec<_>>().join(", ")
        }
        Some(x) => format!("{:.1}", x.value.heading_offset * 1e3),
        None => "–".into(),
    }
}

fn run() -> Res<()> {
    let mut a = Args::parse(USAGE, &[])?;
    let method: String = a.get("method", "eiv".to_string())?;
    a.finish()?;
    let runs: Vec<(&str, Drive, CalibrationOptions)> = TESTTRACK_RUNS
        .iter()
        .map(|(n, _)| load_with_options(&testtrack_manifest(n)).map(|(d, o)| (*n, d, o)))
        .collect::<Res<_>>()?;
    let mut groups: Vec<Vec<usize>> = (0..3).flat_map(|i| (3..6).map(move |j| vec![i, j])).collect();
    groups.extend((0..6).map(|out| (0..6).filter(|&i| i != out).collect()));
    let mut t = Table::new(&[
        "group",
        "δ per drive, mrad",
        ">own Ē_p m",
        ">held-out Ē_p m",
        "one δ, mrad",
        ">own Ē_p m",
        ">held-out Ē_p m",
    ]);
    let (mut per_pairs, mut one_pairs, mut per_loo, mut one_loo) = (vec![], vec![], vec![], vec![]);
    for g in &groups {
        let members: Vec<&Drive> = g.iter().map(|&i| &runs[i].1).collect();
        let joined = Drive::concat(&members)?;
        let shared = with_signals(&joined, joined.measured().clone())?;
        let mut opts = runs[g[0]].2.clone();
        opts.method = method.parse::<Method>()?;
        if method != "eiv" {
            opts.identify.free = opts.identify.free.with(Param::HeadingOffset);
        }
        let others: Vec<(&str, &Drive)> = (0..6).filter(|i| !g.contains(i)).map(|i| (runs[i].0, &runs[i].1)).collect();
        let per = Calibration::new(&joined, &opts).run()?;
        let one = Calibration::new(&shared, &opts).run()?;
        let (hp, ho) = (held_out(&per, &others)?, held_out(&one, &others)?);
        let name = g.iter().map(|&i| runs[i].0).collect::<Vec<_>>().join("+");
        eprintln!("{name}: per-drive {hp:.3} m, one δ {ho:.3} m");
        t.row([
            name,
            deltas(&per),
            format!("{:.3}", per.validation.mean_position_error_m),
            format!("{hp:.3}"),
            deltas(&one),
            format!("{:.3}", one.validation.mean_position_error_m),
            format!("{ho:.3}"),
        ]);
        if g.len() == 2 {
            per_pairs.push(hp);
            one_pairs.push(ho);
        } else {
            per_loo.push(hp);
            one_loo.push(ho);
        }
    }
    println!("Test track, joint fits, method {method}; held-out runs' δ re-estimated:\n\n{t}");
    println!(
        "mean held-out Ē_p: pairs (9) per-drive δ {:.3} m, one δ {:.3} m; five runs (6) per-drive δ {:.3} m, one δ {:.3} m",
        mean(&per_pairs),
        mean(&one_pairs),
        mean(&per_loo),
        mean(&one_loo)
    );
    Ok(())
}
