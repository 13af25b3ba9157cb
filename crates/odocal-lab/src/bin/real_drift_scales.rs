//! The reference-noise scales the default fits on the shipped real drives
//! (the six test-track runs and the highway van's halves), with the heading
//! drift's floor under the tie at each of `--floors` (log-variance scales,
//! `heading_drift_min_eta`; default: the default's, and −20, the tie all
//! the way): per drive
//! the EIV fit's η, its noise model's position and heading drift, the
//! heading-drift test, t_r and the verdict (docs/validation.md, "The
//! default's t_r bias").
//!
//! Run: `cargo run --release --manifest-path crates/odocal-lab/Cargo.toml
//! --bin real_drift_scales`.

use odocal::settings::{Caller, ManifestSettings, Settings};
use odocal::{Calibration, CalibrationOptions, Drive, Holdout};
use odocal_lab::{repo_path, testtrack_manifest, Args, Res, TESTTRACK_RUNS, VAN_MANIFEST};

const USAGE: &str = "real_drift_scales [--floors -2.197,-20]";

/// A manifest imported, with the calibration options `odocal calibrate` resolves for it.
fn load_with_options(rel: &str) -> Res<(Drive, CalibrationOptions)> {
    let path = repo_path(rel);
    let (drive, report) = odocal::load_drive(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let manifest = report.as_ref().map(ManifestSettings::try_from).transpose()?;
    Ok((drive, Settings::default().resolve(manifest.as_slice(), Caller::CommandLine)?.options))
}

/// One line per floor of the heading drift's scale for `drive`.
fn show(name: &str, drive: &Drive, opts: &CalibrationOptions, floors: &[f64]) -> Res<()> {
    for &floor in floors {
        let mut o = opts.clone();
        if let odocal::Method::Eiv(e) = &mut o.method {
            e.filter.research.heading_drift_min_eta = floor;
        }
        let r = Calibration::new(drive, &o).run()?;
        let part = odocal_lab::report_json::eiv_part(&r);
        let Some(e) = part.as_ref().and_then(|p| p.eiv.as_ref()) else {
            println!("{name} (floor {floor}): no EIV fit");
            continue;
        };
        let eta: Vec<String> = e.eta.iter().map(|x| format!("{x:+.2}")).collect();
        let hd = e.heading_drift.as_ref().map(|h| format!("score {:.1}, r {:+.2}", h.score_statistic, h.log_ratio));
        println!(
            "{name} (floor {floor}): η [{}]; drift {:.3} m / {:.2} mrad; heading test {:?}; \
             EIV t_r {:.5}, result t_r {:.5} ({}), verdict {}; Ē_p {:.3} m",
            eta.join(", "),
            e.noise.position_drift_sigma_m,
            e.noise.heading_drift_sigma_rad * 1e3,
            hd,
            e.theta.t_r,
            r.theta.t_r,
            part.as_ref().map_or("", |p| p.eiv_result.as_str()),
            r.verdict.level,
            r.validation.mean_position_error_m
        );
    }
    Ok(())
}

fn main() {
    odocal_lab::main_with(|| {
        let mut a = Args::parse(USAGE, &[])?;
        let floors: Vec<f64> =
            a.list("floors", &["-2.197", "-20"]).iter().map(|f| f.parse()).collect::<Result<_, _>>()?;
        a.finish()?;
        for (name, _) in TESTTRACK_RUNS {
            let (drive, opts) = load_with_options(&testtrack_manifest(name))?;
            show(name, &drive, &opts, &floors)?;
        }
        let (drive, opts) = load_with_options(VAN_MANIFEST)?;
        for (name, h) in [("van first half", Holdout::SecondHalf), ("van second half", Holdout::FirstHalf)] {
            let (fit, _) = h.split(&drive)?;
            show(name, &fit, &opts, &floors)?;
        }
        Ok(())
    });
}
