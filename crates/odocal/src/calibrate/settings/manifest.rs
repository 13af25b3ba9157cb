//! The calibration settings a manifest states beside its streams:
//! `[calibration]` (any key of [`Settings`] but the noise model and the
//! extrinsics), `[reference]` (the pose reference's extrinsics) and
//! `[noise]` (the starting noise model of method eiv). The importer carries
//! them as plain data ([`crate::io::import::ImportReport`]);
//! [`ManifestSettings`] reads them into one [`Settings`], which
//! [`Settings::resolve`] puts under the caller's.

use std::path::{Path, PathBuf};

use super::{NoiseModelSetting, Settings};
use crate::calibrate::eiv::{noise_model_from_table, NoiseSpec};
use crate::error::{Error, Result};
use crate::io::import::{CalibrationTable, ImportReport, Manifest, NoiseTable, ReferenceSpec};

/// The calibration settings of one manifest.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ManifestSettings {
    /// The manifest that states them.
    pub manifest: PathBuf,
    /// Every setting its tables state: `[calibration]`'s keys,
    /// `[reference]`'s (`lever_arm`, `heading_offset`, `estimate`) and
    /// `[noise]` as `noise_model`.
    pub settings: Settings,
    /// `[reference]` as stated: also the drive's own mount where it is a
    /// validation drive (docs/guide.md, "Several drives of one vehicle").
    pub reference: Option<ReferenceSpec>,
}

/// The calibration settings a parsed manifest states.
///
/// # Errors
/// [`Error::Manifest`] for a bad `[noise]` or `[calibration]` table.
impl TryFrom<&Manifest> for ManifestSettings {
    type Error = Error;
    fn try_from(m: &Manifest) -> Result<Self> {
        ManifestSettings::of_manifest(m)
    }
}

/// The calibration settings of an imported manifest.
///
/// # Errors
/// [`Error::Manifest`] for a bad `[noise]` or `[calibration]` table.
impl TryFrom<&ImportReport> for ManifestSettings {
    type Error = Error;
    fn try_from(r: &ImportReport) -> Result<Self> {
        ManifestSettings::of_report(r)
    }
}

/// The calibration settings of an imported manifest from its import
/// report as JSON ([`import_report_json`]; the Python package keeps a
/// drive's import report so, and a pickled drive carries it).
///
/// # Errors
/// [`Error::Json`] when the value is not an import report's JSON;
/// [`Error::Manifest`] for a bad `[noise]` or `[calibration]` table.
impl TryFrom<&serde_json::Value> for ManifestSettings {
    type Error = Error;
    fn try_from(report: &serde_json::Value) -> Result<Self> {
        ManifestSettings::of_report_json(report)
    }
}

/// The keys of [`Settings`] a manifest states in `[reference]`.
const REFERENCE_KEYS: [&str; 3] = ["lever_arm", "heading_offset", "estimate"];

/// The noise model of a manifest's `[noise]` table, parsed by the same
/// function as a `--noise-model` file ([`noise_model_from_table`]).
///
/// # Errors
/// [`Error::Manifest`] naming `noise`, the bad field and the table's line.
pub(crate) fn read_noise_table(manifest: &Path, noise: &NoiseTable) -> Result<NoiseSpec> {
    noise_model_from_table(noise.table.clone()).map_err(|reason| Error::Manifest {
        path: manifest.to_path_buf(),
        reason: format!("noise: {reason}{}", noise.line.map(|l| format!(" (line {l})")).unwrap_or_default()),
    })
}

/// The settings of a manifest's `[calibration]` table.
///
/// # Errors
/// [`Error::Manifest`] naming `calibration.KEY` (an unknown key, a bad
/// value, a key that belongs in `[reference]` or `[noise]`) and its line.
fn read_calibration_table(manifest: &Path, calibration: &CalibrationTable) -> Result<Settings> {
    let err = |key: &str, reason: String| {
        let line = calibration.lines.get(key).map(|l| format!(" (line {l})")).unwrap_or_default();
        Error::Manifest { path: manifest.to_path_buf(), reason: format!("calibration.{key}: {reason}{line}") }
    };
    let settings: Settings =
        serde_path_to_error::deserialize(toml::Value::Table(calibration.table.clone())).map_err(|e| {
            let key = e.path().iter().next().map(|s| s.to_string()).unwrap_or_default();
            err(&key, e.into_inner().message().to_string())
        })?;
    if let Some((key, what)) = settings.value_problem() {
        return Err(err(key, format!("{key} {what}")));
    }
    for key in settings.stated() {
        if REFERENCE_KEYS.contains(&key) {
            return Err(err(key, "the reference extrinsics belong in [reference]".into()));
        }
        if key == "noise_model" {
            return Err(err(key, "a manifest states its noise model as the [noise] table".into()));
        }
    }
    Ok(settings)
}

/// The import report as JSON, its `[noise]` read as the noise model it
/// states (`read_noise_table`: every field, the defaults filled in, with
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
    /// The settings `manifest` states in its tables, read and checked.
    ///
    /// # Errors
    /// [`Error::Manifest`] for a bad `[noise]` or `[calibration]` table.
    pub(crate) fn new(
        manifest: PathBuf,
        noise: Option<&NoiseTable>,
        reference: Option<ReferenceSpec>,
        calibration: Option<&CalibrationTable>,
    ) -> Result<Self> {
        let mut settings = calibration.map(|c| read_calibration_table(&manifest, c)).transpose()?.unwrap_or_default();
        settings.noise_model =
            noise.map(|n| read_noise_table(&manifest, n).map(NoiseModelSetting::Stated)).transpose()?;
        if let Some(r) = &reference {
            settings.lever_arm = r.lever_arm;
            settings.heading_offset = r.heading_offset;
            // Checked by the importer; an unchecked bad entry estimates nothing.
            settings.estimate = (!r.estimate.is_empty()).then(|| r.estimate_set().unwrap_or_default());
        }
        Ok(ManifestSettings { manifest, settings, reference })
    }

    /// The calibration settings a parsed manifest states (outside the
    /// crate: `ManifestSettings::try_from(&manifest)`).
    pub(crate) fn of_manifest(m: &Manifest) -> Result<Self> {
        Self::new(m.path.clone(), m.noise.as_ref(), m.reference.clone(), m.calibration.as_ref())
    }

    /// The calibration settings of an imported manifest (outside the
    /// crate: `ManifestSettings::try_from(&import_report)`).
    pub(crate) fn of_report(r: &ImportReport) -> Result<Self> {
        Self::new(r.manifest.clone(), r.noise.as_ref(), r.reference.clone(), r.calibration.as_ref())
    }

    /// The calibration settings of an imported manifest from its import
    /// report as JSON (outside the crate:
    /// `ManifestSettings::try_from(&json)`).
    pub(crate) fn of_report_json(report: &serde_json::Value) -> Result<Self> {
        let bad = |source| Error::Json { context: "import report".into(), source };
        let field = |k: &str| report.get(k).filter(|x| !x.is_null()).cloned();
        let manifest: PathBuf = match field("manifest") {
            Some(m) => serde_json::from_value(m).map_err(bad)?,
            None => PathBuf::new(),
        };
        let noise: Option<NoiseTable> = field("noise").map(serde_json::from_value).transpose().map_err(bad)?;
        let calibration: Option<CalibrationTable> =
            field("calibration").map(serde_json::from_value).transpose().map_err(bad)?;
        let reference = field("reference").map(serde_json::from_value).transpose().map_err(bad)?;
        Self::new(manifest, noise.as_ref(), reference, calibration.as_ref())
    }

    /// True when the manifest states none.
    pub(crate) fn is_empty(&self) -> bool {
        self.settings.is_empty() && self.reference.is_none()
    }

    /// The manifest key of a [`Settings`] key: `noise` for the noise model,
    /// `reference.KEY` for the extrinsics, else `calibration.KEY`.
    pub(crate) fn key(&self, key: &str) -> String {
        match key {
            "noise_model" => "noise".into(),
            k if REFERENCE_KEYS.contains(&k) => format!("reference.{k}"),
            k => format!("calibration.{k}"),
        }
    }

    /// The settings of several drives fitted jointly: they must agree
    /// (drives without settings agree with any). `None` when none states any.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the two manifests that differ.
    pub(crate) fn merge<'a>(all: impl IntoIterator<Item = &'a ManifestSettings>) -> Result<Option<ManifestSettings>> {
        let mut out: Option<ManifestSettings> = None;
        for s in all.into_iter().filter(|s| !s.is_empty()) {
            match &out {
                None => out = Some(s.clone()),
                Some(o) if o.settings == s.settings && o.reference == s.reference => {}
                Some(o) => {
                    return Err(Error::InvalidOption {
                        field: "manifest settings",
                        reason: format!(
                            "{} and {} state different [noise], [reference] or [calibration] tables; drives fitted \
                             jointly share one setting: make them agree or give it on the command line",
                            o.manifest.display(),
                            s.manifest.display()
                        ),
                    })
                }
            }
        }
        Ok(out)
    }
}
