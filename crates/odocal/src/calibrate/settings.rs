//! The calibration settings a manifest states beside its streams: the
//! sensor's noise (`[noise]`, the starting noise model of `--method eiv`),
//! the reference sensor's extrinsics (`[reference]`) and calibration
//! choices (`[calibration]`). The importer carries them as plain data
//! ([`crate::io::import::ImportReport`]); [`ManifestSettings`] reads the
//! noise model and [`ManifestSettings::apply`] puts them into
//! [`CalibrationOptions`] where the caller did not give its own value (a
//! command-line flag wins).

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::eiv::{noise_model_from_table, NoiseSpec};
use super::{CalibrationOptions, Method};
use crate::error::{Error, Result};
use crate::io::import::{CalibrationSpec, ImportReport, Manifest, NoiseTable, ReferenceSpec};
use crate::model::param::ParamSet;

/// The calibration settings of one manifest.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct ManifestSettings {
    /// The manifest that states them.
    pub manifest: PathBuf,
    /// `[noise]`: the sensor's noise model and which levels are known.
    pub noise: Option<NoiseSpec>,
    /// `[reference]`: the reference sensor's extrinsics.
    pub reference: Option<ReferenceSpec>,
    /// `[calibration]`: calibration choices.
    pub calibration: Option<CalibrationSpec>,
}

/// Which settings the caller gives itself (they win over the manifest's).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GivenSettings {
    /// A noise model (`--noise-model`).
    pub noise_model: bool,
    /// A lever arm (`--lever-arm`).
    pub lever_arm: bool,
    /// A heading offset (`--heading-offset`).
    pub heading_offset: bool,
    /// The extrinsics to estimate (`--estimate`).
    pub estimate: bool,
    /// Keep the one-way turning selection (`--keep-one-way`).
    pub keep_one_way: bool,
    /// How the a_y and β noise is scaled (`--lateral-noise`): wins over the
    /// manifest's `[noise] lateral`.
    pub lateral_noise: bool,
}

/// What became of one manifest setting.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case", tag = "outcome")]
pub enum SettingOutcome {
    /// Put into the calibration options.
    Used,
    /// The caller gave its own value, which was used instead.
    Overridden,
    /// Not used, for the reason given.
    Ignored {
        /// Why.
        reason: String,
    },
}

/// One manifest setting and what became of it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct SettingUse {
    /// The manifest key (`noise`, `reference.lever_arm`,
    /// `reference.heading_offset`, `reference.estimate`,
    /// `calibration.keep_one_way`).
    pub key: &'static str,
    /// The manifest it comes from.
    pub manifest: PathBuf,
    /// What became of it.
    #[serde(flatten)]
    pub outcome: SettingOutcome,
}

impl std::fmt::Display for SettingUse {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let m = self.manifest.display();
        match &self.outcome {
            SettingOutcome::Used => write!(f, "{} from {m}: used", self.key),
            SettingOutcome::Overridden => write!(f, "{} from {m}: overridden by the command line", self.key),
            SettingOutcome::Ignored { reason } => write!(f, "{} from {m}: ignored ({reason})", self.key),
        }
    }
}

/// The noise model of a manifest's `[noise]` table, parsed by the same
/// function as a `--noise-model` file ([`noise_model_from_table`]).
///
/// # Errors
/// [`Error::Manifest`] naming `noise`, the bad field and the table's line.
pub fn read_noise_table(manifest: &Path, noise: &NoiseTable) -> Result<NoiseSpec> {
    noise_model_from_table(noise.table.clone()).map_err(|reason| Error::Manifest {
        path: manifest.to_path_buf(),
        reason: format!("noise: {reason}{}", noise.line.map(|l| format!(" (line {l})")).unwrap_or_default()),
    })
}

/// The import report as JSON, its `[noise]` read as the noise model it
/// states ([`read_noise_table`]: every field, the defaults filled in, with
/// `known` and `lateral`), as the `odocal import` report and the Python
/// package show it.
///
/// # Errors
/// [`Error::Manifest`] for a bad `[noise]` table.
pub fn import_report_json(report: &ImportReport) -> Result<serde_json::Value> {
    let json = |source| Error::Json { context: format!("import report of {}", report.manifest.display()), source };
    let mut v = serde_json::to_value(report).map_err(json)?;
    if let (Some(n), Some(obj)) = (&report.noise, v.as_object_mut()) {
        obj.insert("noise".into(), serde_json::to_value(read_noise_table(&report.manifest, n)?).map_err(json)?);
    }
    Ok(v)
}

impl ManifestSettings {
    /// The settings `manifest` states, its `[noise]` table read as a noise
    /// model ([`read_noise_table`]).
    ///
    /// # Errors
    /// [`Error::Manifest`] for a bad `[noise]` table.
    pub fn new(
        manifest: PathBuf,
        noise: Option<&NoiseTable>,
        reference: Option<ReferenceSpec>,
        calibration: Option<CalibrationSpec>,
    ) -> Result<Self> {
        let noise = noise.map(|n| read_noise_table(&manifest, n)).transpose()?;
        Ok(ManifestSettings { manifest, noise, reference, calibration })
    }

    /// The calibration settings a parsed manifest states.
    ///
    /// # Errors
    /// [`Error::Manifest`] for a bad `[noise]` table.
    pub fn of_manifest(m: &Manifest) -> Result<Self> {
        Self::new(m.path.clone(), m.noise.as_ref(), m.reference.clone(), m.calibration)
    }

    /// The calibration settings of an imported manifest.
    ///
    /// # Errors
    /// [`Error::Manifest`] for a bad `[noise]` table.
    pub fn of_report(r: &ImportReport) -> Result<Self> {
        Self::new(r.manifest.clone(), r.noise.as_ref(), r.reference.clone(), r.calibration)
    }

    /// True when the manifest states none.
    pub fn is_empty(&self) -> bool {
        self.noise.is_none() && self.reference.is_none() && self.calibration.is_none()
    }

    /// The settings of several drives fitted jointly: they must agree
    /// (drives without settings agree with any). `None` when none states any.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the two manifests that differ.
    pub fn merge<'a>(all: impl IntoIterator<Item = &'a ManifestSettings>) -> Result<Option<ManifestSettings>> {
        let mut out: Option<ManifestSettings> = None;
        for s in all.into_iter().filter(|s| !s.is_empty()) {
            match &out {
                None => out = Some(s.clone()),
                Some(o) if o.noise == s.noise && o.reference == s.reference && o.calibration == s.calibration => {}
                Some(o) => {
                    return Err(Error::InvalidOption {
                        field: "manifest settings",
                        reason: format!(
                            "{} and {} state different [noise], [reference] or [calibration] tables; drives fitted \
                             jointly share \
                             one setting: make them agree or give it on the command line",
                            o.manifest.display(),
                            s.manifest.display()
                        ),
                    })
                }
            }
        }
        Ok(out)
    }

    /// Puts the settings into `opts` where `given` says the caller has no
    /// value of its own, and says what became of each: the noise model is
    /// the starting model of `--method eiv` (ignored by the other methods);
    /// the extrinsics are held at, or estimated from, the stated values
    /// (ignored, saying so, by a method that does not model them). Call it
    /// before applying the caller's `--fix`, so that holds an estimated
    /// extrinsic again.
    pub fn apply(&self, opts: &mut CalibrationOptions, given: GivenSettings) -> Vec<SettingUse> {
        let mut out = Vec::new();
        let mut note = |key: &'static str, outcome: SettingOutcome| {
            out.push(SettingUse { key, manifest: self.manifest.clone(), outcome });
        };
        if let Some(n) = &self.noise {
            match &mut opts.method {
                _ if given.noise_model => note("noise", SettingOutcome::Overridden),
                Method::Eiv(o) => {
                    let caller_lateral = o.filter.lateral_noise;
                    n.apply(&mut o.filter);
                    note("noise", SettingOutcome::Used);
                    if n.lateral.is_some() && given.lateral_noise {
                        o.filter.lateral_noise = caller_lateral;
                        note("noise.lateral", SettingOutcome::Overridden);
                    }
                }
                other => note(
                    "noise",
                    SettingOutcome::Ignored { reason: format!("method {other} does not use a noise model") },
                ),
            }
        }
        if let Some(k) = self.calibration.and_then(|c| c.keep_one_way) {
            match &opts.method {
                _ if given.keep_one_way => note("calibration.keep_one_way", SettingOutcome::Overridden),
                Method::Eiv(_) => note(
                    "calibration.keep_one_way",
                    SettingOutcome::Ignored {
                        reason: "method eiv fits every segment, it does not select turning ones".into(),
                    },
                ),
                _ => {
                    opts.keep_one_way_selection = k;
                    note("calibration.keep_one_way", SettingOutcome::Used);
                }
            }
        }
        let Some(r) = &self.reference else { return out };
        let supported = opts.method.estimator().supports_extrinsics();
        let ignored = || SettingOutcome::Ignored {
            reason: format!("method {} does not model the reference extrinsics", opts.method),
        };
        let mut x = opts.identify.extrinsics;
        let mut free = opts.identify.free;
        let mut notes = Vec::new();
        if let Some(l) = r.lever_arm {
            notes.push(("reference.lever_arm", given.lever_arm));
            if !given.lever_arm {
                (x.lever_x, x.lever_y) = (l[0], l[1]);
            }
        }
        if let Some(h) = r.heading_offset {
            notes.push(("reference.heading_offset", given.heading_offset));
            if !given.heading_offset {
                x.heading_offset = h;
            }
        }
        if !r.estimate.is_empty() {
            notes.push(("reference.estimate", given.estimate));
            if !given.estimate {
                // Checked by the importer; an unchecked bad entry estimates nothing.
                free = free.union(r.estimate_set().unwrap_or(ParamSet::EMPTY));
            }
        }
        for (key, overridden) in notes {
            note(
                key,
                match (overridden, supported) {
                    (true, _) => SettingOutcome::Overridden,
                    (false, true) => SettingOutcome::Used,
                    (false, false) => ignored(),
                },
            );
        }
        if supported {
            opts.identify.extrinsics = x;
            opts.identify.free = free;
            if r.heading_offset.is_some() && !given.heading_offset {
                opts.hold_stated_heading_offset();
            }
        }
        out
    }
}

/// Which starting noise model `--method eiv` uses, in words: the
/// caller's file (`noise_model_file`, e.g. `--noise-model`), a manifest's
/// `[noise]` (a `noise` entry of `uses` that was used), or the
/// production-car defaults. `None` for a method without a noise model.
pub fn noise_model_origin(
    method: &Method,
    noise_model_file: Option<&std::path::Path>,
    uses: &[SettingUse],
) -> Option<String> {
    if !matches!(method, Method::Eiv(_)) {
        return None;
    }
    if let Some(p) = noise_model_file {
        return Some(format!("--noise-model {}", p.display()));
    }
    Some(match uses.iter().find(|u| u.key == "noise" && u.outcome == SettingOutcome::Used) {
        Some(u) => format!("[noise] of {}", u.manifest.display()),
        None => "the production-car defaults (no --noise-model, no manifest [noise])".into(),
    })
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // parsed and copied values are exact
mod tests {
    use std::path::Path;

    use super::*;
    use crate::calibrate::eiv::EivMethodOptions;
    use crate::eiv::NoiseModel;
    use crate::io::import::load_drive;
    use crate::io::import::tests::small_case;
    use crate::model::extrinsics::Extrinsics;
    use crate::model::param::Param;

    /// The small manifest of the import tests with `extra` appended, parsed
    /// and its settings read.
    fn parsed(extra: &str) -> Result<(Manifest, ManifestSettings)> {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = small_case(dir.path());
        let text = std::fs::read_to_string(&path).expect("read") + extra;
        let m = Manifest::parse(&text, &path)?;
        let s = ManifestSettings::of_manifest(&m)?;
        Ok((m, s))
    }

    /// The message of a bad setting, without the manifest's (temporary) path.
    fn error(extra: &str) -> String {
        let e = parsed(extra).expect_err("a bad setting").to_string();
        e.split_once("m.toml: ").map_or(e.clone(), |(_, m)| m.to_string())
    }

    #[test]
    fn noise_and_reference_tables_parse_and_are_carried_on_the_import_report() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = small_case(dir.path());
        let extra = "\n[noise]\nwheel_white_rel_sigma = 0.012\nposition_white_sigma_m = 0.05\nknown = [\"pose_white\"]\n\n[reference]\n\
                     lever_arm = [-0.9, 0.1]\nheading_offset = -0.0099\nestimate = [\"lever-arm\"]\n";
        let text = std::fs::read_to_string(&path).expect("read") + extra;
        std::fs::write(&path, text).expect("write");
        let (_, report) = load_drive(&path).expect("import");
        let report = report.expect("a manifest's report");
        let text = report.to_string();
        assert!(
            text.contains(
                "[noise] (start of --method eiv): known = [\"pose_white\"], position_white_sigma_m = 0.05, \
                 wheel_white_rel_sigma = 0.012\n"
            ),
            "{text}"
        );
        assert!(
            text.contains("[reference]: lever arm (-0.900, +0.100) m, heading offset -9.90 mrad, estimate lever-arm")
        );
        let s = ManifestSettings::of_report(&report).expect("settings");
        assert_eq!(s.noise.as_ref().map(|n| n.known.clone()), Some(vec![crate::eiv::NoiseSource::PoseWhite]));
        let n = s.noise.clone().expect("[noise]").model;
        assert_eq!(n.wheel_white_rel_sigma, 0.012);
        assert_eq!(n.position_white_sigma_m, 0.05);
        assert_eq!(n.wheel_common_rel_sigma, NoiseModel::PRODUCTION_CAR.wheel_common_rel_sigma, "default kept");
        let r = s.reference.clone().expect("[reference]");
        assert_eq!(r.lever_arm, Some([-0.9, 0.1]));
        assert_eq!(r.heading_offset, Some(-0.0099));
        assert_eq!(r.estimate_set(), Ok(ParamSet::LEVER_ARM));
        let m = Manifest::from_path(&path).expect("parse");
        let from_manifest = ManifestSettings::of_manifest(&m).expect("settings");
        assert_eq!(from_manifest, ManifestSettings { manifest: path.clone(), ..s.clone() });
        // The parsed manifest serialises and parses back the same.
        let back = Manifest::parse(&toml::to_string(&m).expect("toml"), &path).expect("round trip");
        assert_eq!(ManifestSettings::of_manifest(&back).expect("settings"), from_manifest);
    }

    #[test]
    fn bad_settings_are_errors_naming_the_key() {
        let e = error("\n[noise]\nwheel_whte_rel_sigma = 0.01\n");
        assert!(e.contains("noise: unknown field(s) wheel_whte_rel_sigma"), "{e}");
        let e = error("\n[noise]\nlateral = \"free\"\n");
        assert!(e.contains("noise: lateral: invalid lateral noise 'free': use tied or stated"), "{e}");
        let e = error("\n[noise]\nlateral = 1\n");
        assert!(e.contains("noise: lateral: 1 must be \"tied\" or \"stated\""), "{e}");
        let e = error("\n[noise]\nposition_white_sigma_m = -0.5\n");
        assert!(e.contains("noise") && e.contains("noise.position_white_sigma_m"), "{e}");
        let e = error("\n[noise]\nsideslip_sigma_rad = \"small\"\n");
        assert!(e.contains("noise: sideslip_sigma_rad: invalid type"), "{e}");
        let e = error("\n[reference]\nlever_arm = [1.0]\n");
        assert!(e.contains("reference.lever_arm"), "{e}");
        let e = error("\n[reference]\nlever_arm = [1.0, 1e9]\n");
        assert!(e.contains("reference.lever_arm: [1, 1000000000] must be finite metres"), "{e}");
        let e = error("\n[reference]\nheading_offset = 7.0\n");
        assert!(e.contains("reference.heading_offset: 7 must be finite radians within ±π"), "{e}");
        let e = error("\n[reference]\nestimate = [\"t_r\"]\n");
        assert!(e.contains("reference.estimate: 't_r' is not an extrinsic parameter"), "{e}");
        let e = error("\n[reference]\nestimate = [\"lever-arms\"]\n");
        assert!(e.contains("reference.estimate: 'lever-arms' is not"), "{e}");
        let e = error("\n[reference]\nlever = [0.0, 0.0]\n");
        assert!(e.contains("reference.lever: unknown field"), "{e}");
    }

    #[test]
    fn noise_errors_name_the_key_and_the_tables_line() {
        // Each message names the key and the line the table starts on.
        let cases = [
            ("\n[noise]\nwheel_whte_rel_sigma = 0.01\n",
             "noise: unknown field(s) wheel_whte_rel_sigma; the fields are drift_time_constant_s, heading_drift_sigma_rad, heading_white_sigma_rad, known, lateral, lateral_acceleration_sigma_m_per_s2, position_drift_sigma_m, position_white_sigma_m, quantisation_step_rev_per_s, sideslip_sigma_rad, sideslip_time_constant_s, wheel_common_rel_sigma, wheel_common_time_constant_s, wheel_differential_rel_sigma, wheel_differential_time_constant_s, wheel_white_rel_sigma (line 24)"),
            ("\n[noise]\nlateral = \"free\"\n",
             "noise: lateral: invalid lateral noise 'free': use tied or stated (line 24)"),
            ("\n[noise]\nlateral = 1\n",
             "noise: lateral: 1 must be \"tied\" or \"stated\" (line 24)"),
            ("\n[noise]\nposition_white_sigma_m = -0.5\n",
             "noise: invalid option `noise.position_white_sigma_m`: must be finite and >= 0, got -0.5 (line 24)"),
            ("\n[noise]\nsideslip_sigma_rad = \"small\"\n",
             "noise: sideslip_sigma_rad: invalid type: string \"small\", expected f64 (line 24)"),
            ("\n[noise]\nknown = [\"x\"]\n",
             "noise: known: invalid noise source 'x': use wheel_white, wheel_common, wheel_differential, pose_white, pose_drift or heading_white (line 24)"),
            ("\n[noise]\nknown = 3\n",
             "noise: known: 3 must be a list of source names, e.g. [\"heading_white\"] (line 24)"),
            ("\n[noise]\nwheel_white_rel_sigma = 0.01\nknown = [\"pose_white\"]\n[calibration]\nkeep_one_way = 3\n",
             "calibration.keep_one_way: invalid type: integer `3`, expected a boolean (line 28)"),
        ];
        for (extra, message) in cases {
            assert_eq!(error(extra), message, "{extra}");
        }
    }

    fn settings() -> ManifestSettings {
        ManifestSettings {
            manifest: "m.toml".into(),
            noise: Some(NoiseSpec {
                model: NoiseModel { wheel_white_rel_sigma: 0.02, ..NoiseModel::PRODUCTION_CAR },
                known: vec![crate::eiv::NoiseSource::PoseWhite],
                lateral: None,
            }),
            reference: Some(ReferenceSpec {
                lever_arm: Some([-0.9, 0.0]),
                heading_offset: Some(-0.01),
                estimate: vec!["heading-offset".into()],
            }),
            calibration: None,
        }
    }

    fn outcomes(uses: &[SettingUse]) -> Vec<(&'static str, SettingOutcome)> {
        uses.iter().map(|u| (u.key, u.outcome.clone())).collect()
    }

    #[test]
    fn apply_fills_what_the_caller_did_not_give() {
        let s = settings();
        // Batch G-N: the extrinsics are used, the noise model is not.
        let mut o = CalibrationOptions { method: Method::BatchGn(Default::default()), ..Default::default() };
        let uses = s.apply(&mut o, GivenSettings::default());
        assert_eq!(o.identify.extrinsics, Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: -0.01 });
        assert_eq!(o.identify.free, ParamSet::THETA.with(Param::HeadingOffset));
        let o_uses = outcomes(&uses);
        assert!(matches!(&o_uses[0], ("noise", SettingOutcome::Ignored { .. })), "{o_uses:?}");
        assert_eq!(
            o_uses[1..],
            [
                ("reference.lever_arm", SettingOutcome::Used),
                ("reference.heading_offset", SettingOutcome::Used),
                ("reference.estimate", SettingOutcome::Used),
            ]
        );
        assert!(uses[1].to_string().contains("reference.lever_arm from m.toml: used"), "{}", uses[1]);

        // The caller's lever arm and estimate win; the rest is still the manifest's.
        let mut o = CalibrationOptions { method: Method::BatchGn(Default::default()), ..Default::default() };
        let given = GivenSettings { lever_arm: true, estimate: true, ..Default::default() };
        let uses = s.apply(&mut o, given);
        assert_eq!(o.identify.extrinsics, Extrinsics { lever_x: 0.0, lever_y: 0.0, heading_offset: -0.01 });
        assert_eq!(o.identify.free, ParamSet::THETA);
        assert_eq!(
            outcomes(&uses)[1..],
            [
                ("reference.lever_arm", SettingOutcome::Overridden),
                ("reference.heading_offset", SettingOutcome::Used),
                ("reference.estimate", SettingOutcome::Overridden),
            ]
        );

        // EIV: the noise model is the start unless the caller gives one; the
        // extrinsics are used (its batch G-N start estimates them, the
        // filter holds them).
        let eiv = || CalibrationOptions { method: Method::Eiv(EivMethodOptions::default()), ..Default::default() };
        let mut o = eiv();
        let uses = s.apply(&mut o, GivenSettings::default());
        let Method::Eiv(m) = &o.method else { panic!("eiv") };
        assert_eq!(m.filter.noise.wheel_white_rel_sigma, 0.02);
        assert_eq!(m.filter.known_sources(), [crate::eiv::NoiseSource::PoseWhite], "[noise] known");
        assert_eq!(o.identify.extrinsics, Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: -0.01 });
        assert_eq!(o.identify.free, ParamSet::THETA.with(Param::HeadingOffset));
        assert_eq!(outcomes(&uses)[0], ("noise", SettingOutcome::Used));
        assert!(outcomes(&uses)[1..].iter().all(|u| u.1 == SettingOutcome::Used), "{uses:?}");
        let mut o = eiv();
        let uses = s.apply(&mut o, GivenSettings { noise_model: true, ..Default::default() });
        let Method::Eiv(m) = &o.method else { panic!("eiv") };
        assert_eq!(m.filter.noise, NoiseModel::PRODUCTION_CAR);
        assert!(m.filter.known_sources().is_empty(), "the caller's model replaces the manifest's known sources too");
        assert_eq!(outcomes(&uses)[0], ("noise", SettingOutcome::Overridden));
        // `[noise] lateral = "stated"` sets the lateral noise with the model,
        // unless the caller gave its own (`--lateral-noise`).
        let mut lat = s.clone();
        if let Some(n) = lat.noise.as_mut() {
            n.lateral = Some(crate::eiv::LateralNoise::Stated);
        }
        let mut o = eiv();
        lat.apply(&mut o, GivenSettings::default());
        let Method::Eiv(m) = &o.method else { panic!("eiv") };
        assert_eq!(m.filter.lateral_noise, crate::eiv::LateralNoise::Stated);
        let mut o = eiv();
        let uses = lat.apply(&mut o, GivenSettings { lateral_noise: true, ..Default::default() });
        let Method::Eiv(m) = &o.method else { panic!("eiv") };
        assert_eq!(m.filter.lateral_noise, crate::eiv::LateralNoise::TiedToWheelWhite);
        assert_eq!(
            outcomes(&uses)[..2],
            [("noise", SettingOutcome::Used), ("noise.lateral", SettingOutcome::Overridden)]
        );
        // A stated heading offset is held by EIV's start (which estimates
        // one by default) unless the manifest frees it; the caller's own
        // `--heading-offset` leaves that to the caller.
        let held = ManifestSettings {
            reference: Some(ReferenceSpec { heading_offset: Some(-0.01), lever_arm: None, estimate: vec![] }),
            ..settings()
        };
        let mut o = eiv();
        held.apply(&mut o, GivenSettings::default());
        assert!(matches!(&o.method, Method::Eiv(m) if !m.estimate_heading_offset));
        let mut o = eiv();
        held.apply(&mut o, GivenSettings { heading_offset: true, ..Default::default() });
        assert!(matches!(&o.method, Method::Eiv(m) if m.estimate_heading_offset));
    }

    #[test]
    fn keep_one_way_is_used_overridden_or_ignored() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = small_case(dir.path());
        let text = std::fs::read_to_string(&path).expect("read") + "\n[calibration]\nkeep_one_way = true\n";
        let m = Manifest::parse(&text, &path).expect("parses");
        let s = ManifestSettings::of_manifest(&m).expect("settings");
        assert_eq!(s.calibration, Some(CalibrationSpec { keep_one_way: Some(true) }));
        let e = error("\n[calibration]\nkeep_one_wya = true\n");
        assert!(e.contains("calibration.keep_one_wya: unknown field"), "{e}");

        let three_step = || CalibrationOptions { method: Method::ThreeStep(Default::default()), ..Default::default() };
        let mut o = three_step();
        let uses = s.apply(&mut o, GivenSettings::default());
        assert!(o.keep_one_way_selection);
        assert_eq!(outcomes(&uses), [("calibration.keep_one_way", SettingOutcome::Used)]);
        // `--keep-one-way` given: the command line's value stands
        let mut o = three_step();
        let uses = s.apply(&mut o, GivenSettings { keep_one_way: true, ..Default::default() });
        assert!(!o.keep_one_way_selection, "apply leaves the caller's own value to the caller");
        assert_eq!(outcomes(&uses), [("calibration.keep_one_way", SettingOutcome::Overridden)]);
        // EIV selects no turning segments
        let mut o = CalibrationOptions { method: Method::Eiv(EivMethodOptions::default()), ..Default::default() };
        let uses = s.apply(&mut o, GivenSettings::default());
        assert!(!o.keep_one_way_selection);
        assert!(matches!(outcomes(&uses)[0], ("calibration.keep_one_way", SettingOutcome::Ignored { .. })));
        // jointly fitted drives must agree on it too
        let other = ManifestSettings { manifest: "o.toml".into(), calibration: None, ..s.clone() };
        let none = ManifestSettings { manifest: "n.toml".into(), ..Default::default() };
        assert!(ManifestSettings::merge([&s, &none]).is_ok());
        let other = ManifestSettings { calibration: Some(CalibrationSpec { keep_one_way: Some(false) }), ..other };
        assert!(ManifestSettings::merge([&s, &other]).is_err());
    }

    /// The `[reference]` example the shipped van manifests carry commented
    /// out is a valid table once uncommented.
    #[test]
    fn the_shipped_commented_reference_example_parses() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
        for f in ["psu-mapping-van/manifest.toml", "psu-mapping-van-testtrack/run-14-45-26.toml"] {
            let path = root.join(f);
            let text = std::fs::read_to_string(&path).expect("read");
            let i = text.find("\n# [reference]\n").expect("the commented example");
            let tail: Vec<&str> = text[i..].lines().map(|l| l.strip_prefix("# ").unwrap_or(l)).collect();
            let m = Manifest::parse(&(text[..i].to_string() + &tail.join("\n")), &path).expect("parses");
            let r = m.reference.expect("[reference]");
            assert_eq!((r.lever_arm, r.heading_offset), (Some([-0.9, 0.0]), Some(-0.0099)), "{f}");
            assert_eq!(r.estimate_set(), Ok(ParamSet::EXTRINSICS), "{f}");
            assert_eq!(Manifest::from_path(&path).expect("as shipped").reference, None, "{f}: commented out");
        }
    }

    #[test]
    fn drives_fitted_jointly_must_agree() {
        let a = settings();
        let none = ManifestSettings { manifest: "n.toml".into(), ..Default::default() };
        let same = ManifestSettings { manifest: "b.toml".into(), ..a.clone() };
        let merged = ManifestSettings::merge([&none, &a, &same]).expect("agree").expect("some");
        assert_eq!(merged.manifest, Path::new("m.toml"));
        assert_eq!(ManifestSettings::merge([&none]).expect("none"), None);
        let other = ManifestSettings { manifest: "c.toml".into(), noise: None, ..a.clone() };
        let e = ManifestSettings::merge([&a, &other]).expect_err("differ").to_string();
        assert!(e.contains("m.toml and c.toml state different"), "{e}");
    }
}
