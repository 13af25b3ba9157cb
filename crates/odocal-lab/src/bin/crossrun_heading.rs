//! Test-track cross-run and the highway van's halves with the reference's
//! heading offset δ carried from the calibration and re-estimated on the
//! validation drive (docs/validation.md, "Test track: cross-run").
//!
//! Each of the six test-track runs is calibrated with the settings the CLI
//! uses (`odocal calibrate RUN.toml`: its manifest's settings, the default
//! method); its own fit is the report's Ē_p on the run itself. Its θ and
//! extrinsics are then validated on each of the other five runs as
//! `odocal validate OTHER.toml --theta RUN.yaml` does, once with δ carried
//! (`--carry-heading-offset`) and once with each run's own δ re-estimated
//! with θ and the lever arm held (the default). Cross-run is the mean over
//! the 30 pairs; θ_0's Ē_p on the same pairs (its δ treated alike) is the
//! floor nobody should fall below. Then the van (2024-07-11): calibrated
//! on one half, validated on the other, against the other half's own fit,
//! in both directions.
//!
//! Run: `cargo run --release --manifest-path crates/odocal-lab/Cargo.toml
//! --bin crossrun_heading [-- --skip-van]`.

use odocal::settings::{Caller, ManifestSettings, Settings};
use odocal::{Calibration, CalibrationOptions, CalibrationReport, Drive, Holdout, ValidationDrive};
use odocal_lab::{repo_path, testtrack_manifest, Args, ReadingsNoise, Res, Table, TESTTRACK_RUNS, VAN_MANIFEST};

const USAGE: &str = concat!(
    "crossrun_heading [--skip-van] [--heading-drift-lr T] [--untied-drift] [--no-clamp-refit]
    [--no-bias-correction] [--tau-drift S] [--lateral-from-readings] [--a-y-held-from-readings]

--untied-drift: the default with the reference drift untied (position_drift_own_scale, the position drift's
    τ 20 s, heading_drift_two_sided).
--no-clamp-refit: the default without the refit, after a fit that fails with a noise scale at its upper clamp, with
    c_e held at the batch G-N start's (clamp_refit_hold_scale off).
--no-bias-correction: the default without its bias correction (`--no-bias-correction`).
--tau-drift: the default with the noise model's drift correlation time (position and heading) S s instead of 100.
",
    odocal_lab::readings_noise_usage!()
);

/// `--tau-drift`: the noise model's `drift_time_constant_s` (None: the default's).
static TAU_DRIFT: std::sync::OnceLock<Option<f64>> = std::sync::OnceLock::new();

/// `--lateral-from-readings`, `--a-y-held-from-readings`: applied to every calibration.
static READINGS_NOISE: std::sync::OnceLock<ReadingsNoise> = std::sync::OnceLock::new();

/// `--no-bias-correction`: the default method's bias correction off.
static NO_BIAS_CORRECTION: std::sync::OnceLock<bool> = std::sync::OnceLock::new();

/// `--no-clamp-refit`: `ResearchOptions::clamp_refit_hold_scale` off.
static NO_CLAMP_REFIT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();

/// `--untied-drift`: the default's research options of the untied reference drift.
static UNTIED_DRIFT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();

/// The default's heading-drift likelihood-ratio threshold (`--heading-drift-lr`; None: the default).
static HEADING_DRIFT_LR: std::sync::OnceLock<Option<f64>> = std::sync::OnceLock::new();

/// The heading-drift test of `r`'s EIV fit, its verdict, θ and σ on stderr.
fn note_heading_drift(name: &str, r: &CalibrationReport) {
    if let Some(p) = odocal_lab::report_json::eiv_part(r) {
        let start = p.identification.theta.t_r;
        if let Some(e) = &p.eiv {
            eprintln!("{name}: heading drift {:?}", e.heading_drift);
            eprintln!(
                "{name}: {} (refit {}); EIV's t_r {} (free {}), its start's {start}",
                p.eiv_result, p.refit, e.theta.t_r, e.free[2]
            );
        }
    }
    let reasons: Vec<String> = r.verdict.reasons.iter().map(|x| x.to_string()).collect();
    eprintln!("{name}: verdict {} [{}]", r.verdict.level, reasons.join(" | "));
    eprintln!("{name}: θ {:?} σ {:?}", <[_; 4]>::from(r.theta), <[_; 4]>::from(r.result_sigma()));
}

fn main() {
    odocal_lab::main_with(run)
}

/// A manifest imported, with the calibration options `odocal calibrate` resolves for it.
fn load_with_options(rel: &str) -> Res<(Drive, CalibrationOptions)> {
    let path = repo_path(rel);
    let (drive, report) = odocal::load_drive(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let manifest = report.as_ref().map(ManifestSettings::try_from).transpose()?;
    let mut options = Settings::default().resolve(manifest.as_slice(), Caller::CommandLine)?.options;
    if let (Some(t), odocal::Method::Eiv(e)) = (HEADING_DRIFT_LR.get().copied().flatten(), &mut options.method) {
        e.filter.research.heading_drift_lr_threshold = t;
    }
    if let (Some(true), odocal::Method::Eiv(e)) = (UNTIED_DRIFT.get().copied(), &mut options.method) {
        let r = &mut e.filter.research;
        (r.position_drift_own_scale, r.position_drift_time_constant_s, r.heading_drift_two_sided) =
            (true, Some(20.0), true);
    }
    if let (Some(t), odocal::Method::Eiv(e)) = (TAU_DRIFT.get().copied().flatten(), &mut options.method) {
        e.filter.noise.drift_time_constant_s = t;
    }
    if let (Some(true), odocal::Method::Eiv(e)) = (NO_CLAMP_REFIT.get().copied(), &mut options.method) {
        e.filter.research.clamp_refit_hold_scale = false;
    }
    if let Some(r) = READINGS_NOISE.get() {
        r.apply(&mut options, &drive);
    }
    if let (Some(true), odocal::Method::Eiv(e)) = (NO_BIAS_CORRECTION.get().copied(), &mut options.method) {
        e.correct_bias = None;
        e.filter.research.bias_correction = odocal::eiv::BiasCorrection::None;
    }
    Ok((drive, options))
}

/// Ē_p of the calibration `r` and of θ_0 on `drive`, δ carried or re-estimated.
fn judge(r: &CalibrationReport, drive: &Drive, carry: bool) -> Res<(f64, f64, f64)> {
    let others = [ValidationDrive { name: "other", drive, reference: None }];
    let v = r.validate_on_drives(&others, carry)?;
    let row = &v.drives[0];
    let delta = row.heading_offset_rad();
    Ok((row.mean_position_error_m, row.initial_mean_position_error_m, delta))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn testtrack() -> Res<()> {
    let mut runs = Vec::new();
    for (name, _) in TESTTRACK_RUNS {
        let (drive, opts) = load_with_options(&testtrack_manifest(name))?;
        let r = Calibration::new(&drive, &opts).run()?;
        note_heading_drift(name, &r);
        runs.push((name, drive, opts, r));
    }
    let mut t = Table::new(&[
        "calibrated on",
        "δ mrad",
        "own Ē_p m",
        "cross, δ carried m",
        "cross, δ re-estimated m",
        "θ_0 cross, re-estimated m",
        "re-estimated δ on the others, mrad",
    ]);
    let (mut own, mut carried, mut reest, mut init) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut worse = 0;
    for (name, _, _, r) in &runs {
        let (mut c, mut e, mut i, mut deltas) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for (other, drive, _, _) in &runs {
            if other == name {
                continue;
            }
            c.push(judge(r, drive, true)?.0);
            let (ep, ep0, delta) = judge(r, drive, false)?;
            worse += usize::from(ep > ep0);
            e.push(ep);
            i.push(ep0);
            deltas.push(format!("{:.1}", delta * 1e3));
        }
        let delta = r.extrinsics.as_ref().map_or(0.0, |x| x.value.heading_offset);
        own.push(r.validation.mean_position_error_m);
        t.row([
            name.to_string(),
            format!("{:.1}", delta * 1e3),
            format!("{:.3}", r.validation.mean_position_error_m),
            format!("{:.3}", mean(&c)),
            format!("{:.3}", mean(&e)),
            format!("{:.3}", mean(&i)),
            deltas.join(", "),
        ]);
        carried.extend(c);
        reest.extend(e);
        init.extend(i);
    }
    println!("Test track, six runs, 30 pairs:\n\n{t}");
    let m = mean(&own);
    println!(
        "mean own fit {m:.3} m; cross-run δ carried {:.3} m ({:.2}×), δ re-estimated {:.3} m ({:.2}×); \
         θ_0 {:.3} m; pairs worse than θ_0 (re-estimated): {worse} of {}\n",
        mean(&carried),
        mean(&carried) / m,
        mean(&reest),
        mean(&reest) / m,
        mean(&init),
        reest.len()
    );
    Ok(())
}

fn van() -> Res<()> {
    let (drive, opts) = load_with_options(VAN_MANIFEST)?;
    let mut t = Table::new(&[
        "calibrated on",
        "validated on",
        "its own fit m",
        "δ carried m",
        "δ re-estimated m",
        "ratio (re-estimated)",
        "θ_0 m",
    ]);
    for (fit_half, held_half, h) in
        [("first half", "second half", Holdout::SecondHalf), ("second half", "first half", Holdout::FirstHalf)]
    {
        let (fit, held) = h.split(&drive)?;
        let r = Calibration::new(&fit, &opts).run()?;
        note_heading_drift("van half", &r);
        let own = Calibration::new(&held, &opts).run()?.validation.mean_position_error_m;
        let carried = judge(&r, &held, true)?.0;
        let (reest, initial, _) = judge(&r, &held, false)?;
        t.row([
            fit_half.to_string(),
            held_half.to_string(),
            format!("{own:.3}"),
            format!("{carried:.3}"),
            format!("{reest:.3}"),
            format!("{:.2}", reest / own),
            format!("{initial:.3}"),
        ]);
    }
    println!("Highway van (2024-07-11), halves:\n\n{t}");
    Ok(())
}

fn run() -> Res<()> {
    let [lateral, a_y_held] = ReadingsNoise::SWITCHES;
    let mut a =
        Args::parse(USAGE, &["skip-van", "untied-drift", "no-clamp-refit", "no-bias-correction", lateral, a_y_held])?;
    let skip_van = a.flag("skip-van");
    let _ = HEADING_DRIFT_LR.set(a.opt("heading-drift-lr")?);
    let _ = UNTIED_DRIFT.set(a.flag("untied-drift"));
    let _ = NO_CLAMP_REFIT.set(a.flag("no-clamp-refit"));
    let _ = NO_BIAS_CORRECTION.set(a.flag("no-bias-correction"));
    let _ = TAU_DRIFT.set(a.opt("tau-drift")?);
    let _ = READINGS_NOISE.set(ReadingsNoise::from_args(&a));
    a.finish()?;
    testtrack()?;
    if !skip_van {
        van()?;
    }
    Ok(())
}
