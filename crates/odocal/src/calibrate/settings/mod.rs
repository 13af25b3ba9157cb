//! The calibration settings, one type for every interface.
//!
//! Expert API: for front ends that take settings from users (the CLI, the
//! Python package); a Rust program usually fills [`crate::CalibrationOptions`].
//!
//! A manifest's calibration tables, the command line's flags and Python's
//! keywords all become a [`Settings`]: every key optional, named like the
//! manifest key and the Python keyword (`min_yaw_rate`) and, in kebab case,
//! the command-line flag (`--min-yaw-rate`).
//!
//! - A manifest states them in three tables ([`ManifestSettings`]):
//!   `[calibration]` any key but the noise model and the extrinsics,
//!   `[reference]` the extrinsics (`lever_arm`, `heading_offset`,
//!   `estimate`), `[noise]` the noise model in place (the `noise_model`
//!   key).
//! - One function, [`Settings::resolve`], puts the sources together by one
//!   precedence rule, the caller's settings (flags, keywords) over the
//!   manifest's over the defaults, and maps them to
//!   [`CalibrationOptions`]. A key of another method is an error when the
//!   caller gives it and ignored, saying so, when a manifest does.
//! - One account says what became of each manifest setting and where the
//!   starting noise model came from ([`SettingsAccount`]), for the text and
//!   the JSON report alike.
//!
//! [`CalibrationOptions`]: super::CalibrationOptions

use std::path::PathBuf;

use serde::Deserialize;

use super::eiv::{read_noise_model, NoiseSpec};
use super::{FinalSegments, Method};
use crate::compensate::SolverKind;
use crate::eiv::{HeadingScale, LateralNoise, NoiseSource, QuantisationLevel, QuantisationModel};
use crate::error::{Error, Result};
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

mod de;
mod manifest;
mod resolve;

/// The ceilings of the count settings, checked before anything is
/// allocated from them (the command line, Python and a manifest's
/// `[calibration]` alike): `(key, largest value)`.
///
/// | key | ceiling |
/// |---|---|
/// | `max_iterations` | 100,000 |
/// | `segment_length`, `segment_stride`, `validation_length`, `eiv_window` | 10,000,000 samples |
/// | `batches`, `batch_size`, `picks` | 100,000 |
/// | `bootstrap`, `correct_bias` | 100,000 replicates |
pub(crate) const COUNT_CEILINGS: [(&str, usize); 10] = [
    ("max_iterations", crate::identify::MAX_ITERATIONS),
    ("segment_length", crate::drive::segment::MAX_STEPS),
    ("segment_stride", crate::drive::segment::MAX_STEPS),
    ("validation_length", crate::drive::segment::MAX_STEPS),
    ("eiv_window", 10_000_000),
    ("batches", 100_000),
    ("batch_size", 100_000),
    ("picks", 100_000),
    ("bootstrap", 100_000),
    ("correct_bias", 100_000),
];

/// Most worker threads a caller may ask for (`--threads`, Python `threads=`).
pub const MAX_THREADS: usize = 1024;
#[cfg(test)]
mod tests;

pub use manifest::{import_report_json, ManifestSettings};
pub use resolve::{Caller, Resolved, SettingsAccount};

/// Declares [`Settings`] and the methods that visit every key, so that a
/// key is named once: its field.
macro_rules! settings {
    (
        $(#[$meta:meta])*
        $vis:vis struct Settings {
            $( $(#[$field_meta:meta])* pub $key:ident : Option<$ty:ty>, )*
        }
    ) => {
        $(#[$meta])*
        $vis struct Settings {
            $( $(#[$field_meta])* pub $key: Option<$ty>, )*
        }

        impl Settings {
            /// Every key, in the order of the fields.
            pub const KEYS: &'static [&'static str] = &[$(stringify!($key)),*];

            /// These settings over `lower`: each key these state, else
            /// `lower`'s. The one precedence rule: the caller's settings
            /// over a manifest's over the defaults.
            pub(crate) fn over(self, lower: Settings) -> Settings {
                Settings { $( $key: self.$key.or(lower.$key), )* }
            }

            /// The keys these settings state, in the order of [`Settings::KEYS`].
            pub(crate) fn stated(&self) -> Vec<&'static str> {
                let mut keys = Vec::new();
                $( if self.$key.is_some() { keys.push(stringify!($key)); } )*
                keys
            }

            /// These settings without `key` (the same when they do not state it).
            pub(crate) fn without(mut self, key: &str) -> Settings {
                match key {
                    $( stringify!($key) => self.$key = None, )*
                    _ => {}
                }
                self
            }
        }
    };
}

settings! {
    /// Calibration settings as a manifest, the command line or Python
    /// states them. Every key is optional; `None` means "not stated", and
    /// the next source's value, else the default, applies ([`Settings::resolve`]).
    /// The key is the manifest key and the Python keyword; the flag is the
    /// key in kebab case (`min_yaw_rate`, `--min-yaw-rate`) unless noted.
    ///
    /// Values deserialize from TOML and JSON as each field says; a text
    /// value is parsed like the flag's (`"c_d,t_r,d"`, `"from-readings"`),
    /// and a bad one is an error naming the key. [`Settings::resolve`] maps
    /// them to the calibration options.
    ///
    /// ```
    /// # fn main() -> Result<(), odocal::Error> {
    /// use odocal::settings::{Caller, ManifestSettings, Settings};
    /// use odocal::Param;
    /// let caller = Settings::try_from(serde_json::json!({"method": "batch-gn", "fix": "d"}))?;
    /// let stated: Settings = toml::from_str("segment_length = 400\nfix = [\"t_r\"]").expect("toml");
    /// let manifest = ManifestSettings { manifest: "drive.toml".into(), settings: stated, reference: None };
    /// let options = caller.resolve(&[manifest], Caller::Python)?.options;
    /// assert_eq!(options.segments.length_steps, 400); // the manifest's
    /// // The caller's `fix` wins: d is held, t_r free.
    /// assert!(!options.identify.free.contains(Param::D) && options.identify.free.contains(Param::TR));
    /// # Ok(()) }
    /// ```
    #[derive(Debug, Clone, PartialEq, Default, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Settings {
        /// `method`: `"eiv"` (the errors-in-variables filter, started from
        /// batch G-N and falling back to it), `"three-step"` (the paper's)
        /// or `"batch-gn"`. Default eiv.
        #[serde(default, deserialize_with = "de::parsed")]
        pub method: Option<Method>,
        /// `theta0`: the initial guess θ_0, as `"c_e,c_d,t_r,d"` (SI),
        /// `[c_e, c_d, t_r, d]`, `{c_e = …, c_d = …, t_r = …, d = …}` or the
        /// path of a parameter file (`.yaml`, `.yml`, `.json`, as
        /// `--params-out` writes it). Default the paper's `2.0,0,1.6,0`.
        #[serde(default, deserialize_with = "de::theta")]
        pub theta0: Option<Theta>,
        /// `fix`: parameters held at θ_0, `"c_d,t_r,d"` or a list; also
        /// `lever_x`, `lever_y`, `heading_offset` (held even when
        /// `estimate` frees them). Default none.
        #[serde(default, deserialize_with = "de::param_set")]
        pub fix: Option<ParamSet>,
        /// `auto_fix`: hold the parameters the data cannot determine
        /// instead of estimating them. Default false.
        #[serde(default)]
        pub auto_fix: Option<bool>,
        /// `seed`: seed of the three-step method's random choices (its
        /// batches and the final fit's segments; three-step only: method
        /// eiv's bootstrap and bias correction take `bootstrap_seed`).
        /// Default 0.
        #[serde(default, deserialize_with = "de::seed")]
        pub seed: Option<u64>,
        /// `max_iterations`: Gauss-Newton iterations. Default 5.
        #[serde(default, deserialize_with = "de::whole")]
        pub max_iterations: Option<usize>,
        /// `min_yaw_rate`: peak yaw rate for a segment to be selected,
        /// rad/s (batch-gn, three-step only: method eiv, its batch G-N
        /// start and fallback fit every segment). Default 0.15.
        #[serde(default)]
        pub min_yaw_rate: Option<f64>,
        /// `keep_one_way`: keep the turning-only selection when every
        /// selected segment turns the same way (batch-gn, three-step only).
        /// Default false: the straight segments are added, with a warning.
        #[serde(default)]
        pub keep_one_way: Option<bool>,
        /// `segment_length`: calibration segment length K, samples. Default 650.
        #[serde(default, deserialize_with = "de::whole")]
        pub segment_length: Option<usize>,
        /// `segment_stride`: calibration segment stride, samples. Default 100.
        #[serde(default, deserialize_with = "de::whole")]
        pub segment_stride: Option<usize>,
        /// `validation_length`: validation segment length K_v, samples
        /// (stride K_v/2). Default 1300.
        #[serde(default, deserialize_with = "de::whole")]
        pub validation_length: Option<usize>,
        /// `estimate`: reference extrinsics estimated with θ, starting from
        /// `lever_arm` and `heading_offset`: `"lever-arm"`,
        /// `"heading-offset"` (or `lever_x`, `lever_y`, `heading_offset`),
        /// as text with commas or a list. A manifest states it in
        /// `[reference]`. Default none (held).
        #[serde(default, deserialize_with = "de::param_set")]
        pub estimate: Option<ParamSet>,
        /// `lever_arm`: `[x, y]` of the pose reference from the rear-axle
        /// centre, m, x forward, y left (flag: `--lever-arm X,Y`): held, or
        /// the start of `estimate`. A manifest states it in `[reference]`.
        /// Default `[0, 0]`.
        #[serde(default, deserialize_with = "crate::io::exact::lever_arm")]
        pub lever_arm: Option<[f64; 2]>,
        /// `heading_offset`: reference heading minus vehicle heading, rad:
        /// held, or the start of `estimate` (method eiv then holds it
        /// instead of estimating it by default). A manifest states it in
        /// `[reference]`. Default 0.
        #[serde(default)]
        pub heading_offset: Option<f64>,
        /// `batches`: step 1's random batches (three-step only). Default 50.
        #[serde(default, deserialize_with = "de::whole")]
        pub batches: Option<usize>,
        /// `batch_size`: segments per batch of step 1 (three-step only). Default 10.
        #[serde(default, deserialize_with = "de::whole")]
        pub batch_size: Option<usize>,
        /// `picks`: batch estimates θ_B,I picked to start the compensation
        /// from (three-step only). Default 5.
        #[serde(default, deserialize_with = "de::whole")]
        pub picks: Option<usize>,
        /// `final_segments`: segments of step 3, `"all"` or a number of
        /// random ones (three-step only). Default all.
        #[serde(default, deserialize_with = "de::final_segments")]
        pub final_segments: Option<FinalSegments>,
        /// `qp_solver`: the compensation QP's solver, `"structured"` or
        /// `"clarabel"` (three-step only). Default structured.
        #[serde(default, deserialize_with = "de::parsed")]
        pub qp_solver: Option<SolverKind>,
        /// `noise_model`: the starting noise model (eiv only): the path of
        /// a noise-model TOML file or, in place, a table of its fields. A
        /// manifest states it as its `[noise]` table. Default the
        /// production-car model.
        #[serde(default, deserialize_with = "de::noise_model")]
        pub noise_model: Option<NoiseModelSetting>,
        /// `known_noise`: noise sources whose level in the starting model
        /// is known and held (adds to the model's `known`; eiv only):
        /// `wheel_white`, `wheel_common`, `wheel_differential`,
        /// `pose_white`, `pose_drift`, `heading_white` (or with hyphens),
        /// as text with commas or a list. Default none.
        #[serde(default, deserialize_with = "de::noise_sources")]
        pub known_noise: Option<Vec<NoiseSource>>,
        /// `fix_noise`: use the starting noise model as is instead of
        /// estimating its levels (eiv only). Default false.
        #[serde(default)]
        pub fix_noise: Option<bool>,
        /// `fallback`: fall back to batch G-N when the EIV consistency
        /// checks fail (eiv only; flag: `--no-fallback` is `false`).
        /// Default true.
        #[serde(default)]
        pub fallback: Option<bool>,
        /// `eiv_window`: filter window, samples (eiv only). Default 6000.
        #[serde(default, deserialize_with = "de::whole")]
        pub eiv_window: Option<usize>,
        /// `quantisation`: how encoder quantisation enters the noise model,
        /// `"process"`, `"measurement"` or `"counting"` (eiv only). Default counting.
        #[serde(default, deserialize_with = "de::parsed")]
        pub quantisation: Option<QuantisationModel>,
        /// `quantisation_level`: the quantisation step, `"scaled"`,
        /// `"given"` or `"from-readings"` (eiv only). Default from-readings.
        #[serde(default, deserialize_with = "de::parsed")]
        pub quantisation_level: Option<QuantisationLevel>,
        /// `lateral_noise`: the a_y and β noise `"tied"` to the white wheel
        /// noise or `"stated"` (held at the noise model's σ; eiv only).
        /// Wins over the noise model's `lateral`. Default tied.
        #[serde(default, deserialize_with = "de::parsed")]
        pub lateral_noise: Option<LateralNoise>,
        /// `heading_noise`: the reference heading's white noise scaled on
        /// its own (`"separate"`) or with the position noise (`"tied"`;
        /// eiv only). Default separate.
        #[serde(default, deserialize_with = "de::parsed")]
        pub heading_noise: Option<HeadingScale>,
        /// `bootstrap`: also run a parametric bootstrap with this many
        /// replicates, for percentile intervals and the estimator's bias
        /// (eiv only). Default none.
        #[serde(default, deserialize_with = "de::whole")]
        pub bootstrap: Option<usize>,
        /// `bootstrap_seed`: seed of the bootstrap and of the bias
        /// correction (eiv only). Default 0.
        #[serde(default, deserialize_with = "de::seed")]
        pub bootstrap_seed: Option<u64>,
        /// `correct_bias`: replicates B of the bias correction, an even
        /// number; 0 turns it off (flag: `--correct-bias B`,
        /// `--no-bias-correction` is 0; eiv only). Default 4.
        #[serde(default, deserialize_with = "de::whole")]
        pub correct_bias: Option<usize>,
        /// `correct_bias_of`: the parameters of θ the bias correction
        /// subtracts its bias from, `"c_e,t_r"` or a list (eiv only).
        /// Default c_e and c_d.
        #[serde(default, deserialize_with = "de::param_set")]
        pub correct_bias_of: Option<ParamSet>,
    }
}

/// A starting noise model as a setting states it.
#[derive(Debug, Clone, PartialEq)]
pub enum NoiseModelSetting {
    /// A noise-model file (`--noise-model`; `read_noise_model`), read
    /// when the settings are resolved.
    File(PathBuf),
    /// A model stated in place (a manifest's `[noise]`, a table).
    Stated(NoiseSpec),
}

/// Settings from a JSON object of keys and values (Python's keywords).
///
/// # Errors
/// [`Error::InvalidOption`] naming the key of a bad value, or (field
/// `settings`) an unknown key, with the known ones.
impl TryFrom<serde_json::Value> for Settings {
    type Error = Error;
    fn try_from(value: serde_json::Value) -> Result<Settings> {
        Settings::from_json(value)
    }
}

impl NoiseModelSetting {
    /// The noise model, read from its file when it names one.
    ///
    /// # Errors
    /// The file's: [`Error::Io`], or [`Error::InvalidOption`] naming the bad field.
    pub(crate) fn spec(&self) -> Result<NoiseSpec> {
        match self {
            NoiseModelSetting::File(p) => read_noise_model(p),
            NoiseModelSetting::Stated(s) => Ok(s.clone()),
        }
    }
}

impl Settings {
    /// True when no key is stated.
    pub(crate) fn is_empty(&self) -> bool {
        self.stated().is_empty()
    }

    /// Settings from a JSON object of keys and values (outside the crate:
    /// `Settings::try_from(json)`).
    pub(crate) fn from_json(value: serde_json::Value) -> Result<Settings> {
        serde_path_to_error::deserialize(value).map_err(|e| {
            let key = e.path().iter().next().map(|s| s.to_string()).unwrap_or_default();
            let field = Settings::KEYS.iter().find(|k| **k == key).copied().unwrap_or("settings");
            Error::InvalidOption { field, reason: e.into_inner().to_string() }
        })
    }

    /// The extrinsic parameters these settings state values of
    /// (`lever_arm`: lever_x and lever_y, `heading_offset`;
    /// [`Resolved::given_extrinsics`]).
    pub(crate) fn stated_extrinsics(&self) -> ParamSet {
        let mut s = ParamSet::EMPTY;
        if self.lever_arm.is_some() {
            s = s.union(ParamSet::LEVER_ARM);
        }
        if self.heading_offset.is_some() {
            s = s.with(Param::HeadingOffset);
        }
        s
    }
}
