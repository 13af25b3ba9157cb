//! The manifest's calibration settings (`[noise]`, `[reference]`) in
//! `calibrate`: which flags override them, and what the report says about
//! them. The library applies them (`odocal::import::ManifestSettings::apply`).

use std::fmt::Write as _;

use anyhow::Result;
use odocal::import::{GivenSettings, SettingOutcome, SettingUse};
use odocal::Method;

use crate::CalibrationArgs;

/// The settings the command line gives itself (they win over the manifest's).
pub fn given(a: &CalibrationArgs) -> GivenSettings {
    GivenSettings {
        noise_model: a.noise_model.is_some(),
        lever_arm: a.lever_arm.is_some(),
        heading_offset: a.heading_offset.is_some(),
        estimate: a.estimate.is_some(),
    }
}

/// Which starting noise model `--method eiv` used; `None` for other methods.
pub fn noise_origin(a: &CalibrationArgs, uses: &[SettingUse]) -> Option<String> {
    if !matches!(a.method, Method::Eiv(_)) {
        return None;
    }
    if let Some(p) = &a.noise_model {
        return Some(format!("--noise-model {}", p.display()));
    }
    Some(match uses.iter().find(|u| u.key == "noise" && u.outcome == SettingOutcome::Used) {
        Some(u) => format!("[noise] of {}", u.manifest.display()),
        None => "the production-car defaults (no --noise-model, no manifest [noise])".into(),
    })
}

/// The report's lines on the settings ("" when there is nothing to say).
pub fn report(uses: &[SettingUse], noise_origin: Option<&str>) -> String {
    let mut o = String::new();
    if let Some(n) = noise_origin {
        let _ = writeln!(o, "starting noise model: {n}");
    }
    for u in uses {
        let _ = writeln!(o, "manifest setting {u}");
    }
    o
}

/// Adds `manifest_settings` (what became of each) and `noise_model_origin`
/// to the JSON report.
pub fn add_to_json(v: &mut serde_json::Value, uses: &[SettingUse], noise_origin: Option<&str>) -> Result<()> {
    if let Some(obj) = v.as_object_mut() {
        if !uses.is_empty() {
            obj.insert("manifest_settings".into(), serde_json::to_value(uses)?);
        }
        if let Some(n) = noise_origin {
            obj.insert("noise_model_origin".into(), n.into());
        }
    }
    Ok(())
}
