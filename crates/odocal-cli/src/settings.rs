//! The manifest's calibration settings (`[noise]`, `[reference]`, `[calibration]`) in
//! `calibrate`: which flags override them, and what the report says about
//! them. The library applies them (`odocal::calibrate::settings::ManifestSettings::apply`).

use std::fmt::Write as _;

use anyhow::Result;
use odocal::calibrate::settings::{GivenSettings, SettingUse};
use odocal::{Param, ParamSet};

use crate::args::CalibrationArgs;

/// The settings the command line gives itself (they win over the manifest's).
pub fn given(a: &CalibrationArgs) -> GivenSettings {
    GivenSettings {
        noise_model: a.noise_model.is_some(),
        lever_arm: a.lever_arm.is_some(),
        heading_offset: a.heading_offset.is_some(),
        estimate: a.estimate.is_some(),
        keep_one_way: a.keep_one_way,
        lateral_noise: a.lateral_noise.is_some(),
    }
}

/// The extrinsic parameters the command line gives (`--lever-arm`,
/// `--heading-offset`): they apply to every validation drive.
pub fn given_extrinsics(a: &CalibrationArgs) -> ParamSet {
    let mut s = ParamSet::EMPTY;
    if a.lever_arm.is_some() {
        s = s.union(ParamSet::LEVER_ARM);
    }
    if a.heading_offset.is_some() {
        s = s.with(Param::HeadingOffset);
    }
    s
}

/// Which starting noise model `--method eiv` used; `None` for other methods.
pub fn noise_origin(a: &CalibrationArgs, uses: &[SettingUse]) -> Option<String> {
    odocal::calibrate::settings::noise_model_origin(&a.method, a.noise_model.as_deref(), uses)
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
