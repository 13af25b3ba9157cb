//! Calibration settings a manifest states beside its streams, as plain
//! data: the reference sensor's extrinsics (`[reference]`), calibration
//! settings (`[calibration]`) and the sensor's noise (`[noise]`), the last
//! two kept as the TOML tables they are. The importer parses and checks
//! `[reference]` and carries all three on [`super::ImportReport`];
//! [`crate::calibrate::settings`] reads `[noise]` and `[calibration]` and
//! puts the settings into the calibration options.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::model::extrinsics::Extrinsics;
use crate::model::param::ParamSet;

/// The reference sensor's extrinsics (`[reference]`): where the pose
/// reference sits on the vehicle and whether to estimate that with θ
/// (see [`Extrinsics`]). Every key is optional.
///
/// ```toml
/// [reference]
/// lever_arm = [-0.9, 0.0]      # x forward, y left, m, from the rear-axle centre
/// heading_offset = -0.0099     # reference heading minus vehicle heading, rad
/// estimate = ["lever-arm", "heading-offset"]   # start from the values above
/// ```
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSpec {
    /// Lever arm `[x, y]` of the reference point from the rear-axle centre,
    /// m (x forward, y left): held at this value, or the start of the
    /// estimate. Default none (0, 0).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "crate::io::exact::lever_arm")]
    pub lever_arm: Option<[f64; 2]>,
    /// Reference heading minus vehicle heading, rad: held, or the start of
    /// the estimate. Default none (0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heading_offset: Option<f64>,
    /// Extrinsics to estimate with θ: `"lever-arm"`, `"heading-offset"`
    /// (or `"lever_x"`, `"lever_y"`, `"heading_offset"`). Default none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub estimate: Vec<String>,
}

/// The stated lever arm and heading offset (0 where not stated).
impl From<&ReferenceSpec> for Extrinsics {
    fn from(r: &ReferenceSpec) -> Extrinsics {
        r.extrinsics()
    }
}

impl ReferenceSpec {
    /// The parameters of `estimate`, or the error naming the bad entry.
    pub(crate) fn estimate_set(&self) -> std::result::Result<ParamSet, String> {
        let mut set = ParamSet::EMPTY;
        for name in &self.estimate {
            let not_extrinsic = || {
                format!("'{name}' is not an extrinsic parameter (lever-arm, heading-offset, lever_x, lever_y, heading_offset)")
            };
            let s: ParamSet = name.parse().map_err(|_| not_extrinsic())?;
            if s.is_empty() || !s.intersection(ParamSet::THETA).is_empty() {
                return Err(format!("{}: θ is estimated by default", not_extrinsic()));
            }
            set = set.union(s);
        }
        Ok(set)
    }

    /// The stated lever arm and heading offset, 0 where not stated
    /// (outside the crate: `Extrinsics::from(&reference)`).
    pub(crate) fn extrinsics(&self) -> Extrinsics {
        let l = self.lever_arm.unwrap_or_default();
        Extrinsics { lever_x: l[0], lever_y: l[1], heading_offset: self.heading_offset.unwrap_or(0.0) }
    }

    /// Checks the values: `(key, reason)` of the first bad one.
    pub(crate) fn check(&self) -> std::result::Result<(), (&'static str, String)> {
        if let Some(l) = self.lever_arm {
            if !l.iter().all(|v| v.is_finite() && v.abs() <= MAX_LEVER_ARM_M) {
                return Err((
                    "reference.lever_arm",
                    format!(
                        "[{}, {}] must be finite metres within ±{MAX_LEVER_ARM_M} m",
                        crate::drive::echo_num(l[0]),
                        crate::drive::echo_num(l[1])
                    ),
                ));
            }
        }
        if let Some(h) = self.heading_offset {
            if !(h.is_finite() && h.abs() <= std::f64::consts::PI) {
                return Err((
                    "reference.heading_offset",
                    format!("{} must be finite radians within ±π", crate::drive::echo_num(h)),
                ));
            }
        }
        self.estimate_set().map(|_| ()).map_err(|r| ("reference.estimate", r))
    }
}

/// A manifest's `[calibration]` table as written: calibration settings,
/// any key of [`crate::calibrate::settings::Settings`] but the noise model
/// and the reference extrinsics (those are `[noise]` and `[reference]`).
/// The importer keeps it uninterpreted, with the line of each key for
/// messages; the calibration reads it.
///
/// ```toml
/// [calibration]
/// keep_one_way = true     # keep the turning-only selection on one-way turns
/// min_yaw_rate = 0.1
/// ```
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct CalibrationTable {
    /// The table's keys and values.
    pub(crate) table: toml::Table,
    /// The manifest line (1-based) of each key's value, when read from a
    /// manifest's text.
    pub(crate) lines: BTreeMap<String, usize>,
}

impl Serialize for CalibrationTable {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        self.table.serialize(s)
    }
}

impl<'de> Deserialize<'de> for CalibrationTable {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        Ok(CalibrationTable { table: toml::Table::deserialize(d)?, lines: BTreeMap::new() })
    }
}

/// `[calibration]` with the byte offset of each value in `lines` (the
/// manifest parser turns them into line numbers).
pub(crate) fn calibration_table<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Option<CalibrationTable>, D::Error> {
    let spanned = BTreeMap::<String, toml::Spanned<toml::Value>>::deserialize(d)?;
    let mut out = CalibrationTable::default();
    for (key, value) in spanned {
        out.lines.insert(key.clone(), value.span().start);
        out.table.insert(key, value.into_inner());
    }
    Ok(Some(out))
}

/// Largest lever arm a manifest may state, m (a vehicle's length).
pub(crate) use crate::model::limits::MAX_LEVER_ARM_M;

/// A manifest's `[noise]` table as written: the sensor's noise model, the
/// start of `--method eiv`, read by the calibration
/// ([`crate::calibrate::settings`], like a `--noise-model` file). The
/// importer keeps it uninterpreted, with the line it starts on for messages.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct NoiseTable {
    /// The table's keys and values.
    pub(crate) table: toml::Table,
    /// The manifest line the table starts on (1-based), when read from a
    /// manifest's text.
    pub(crate) line: Option<usize>,
}

impl Serialize for NoiseTable {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        self.table.serialize(s)
    }
}

impl<'de> Deserialize<'de> for NoiseTable {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        Ok(NoiseTable { table: toml::Table::deserialize(d)?, line: None })
    }
}

/// `[noise]` with the byte offset it starts at in `line` (the manifest
/// parser turns it into a line number).
pub(crate) fn noise_table<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Option<NoiseTable>, D::Error> {
    let t = toml::Spanned::<toml::Table>::deserialize(d)?;
    let offset = t.span().start;
    Ok(Some(NoiseTable { table: t.into_inner(), line: Some(offset) }))
}
