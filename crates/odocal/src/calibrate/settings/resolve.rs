//! From settings to calibration options: which keys a method uses, the
//! caller's settings over a manifest's, the one mapping to
//! [`CalibrationOptions`], and the account of what became of each
//! manifest setting.

use std::fmt::Write as _;
use std::path::PathBuf;

use serde::Serialize;

use super::{ManifestSettings, NoiseModelSetting, Settings};
use crate::calibrate::eiv::{CorrectBias, EivMethodOptions};
use crate::calibrate::three_step::{FinalSegments, ThreeStepOptions};
use crate::calibrate::{CalibrationOptions, Method};
use crate::eiv::correctable_problem;
use crate::eiv::BootstrapOptions;
use crate::error::{Error, Result};
use crate::model::param::{Param, ParamSet};

/// Who gives the caller's settings, for the words of messages and of the
/// account.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Caller {
    /// The `odocal` command line: a key is named by its flag (`--min-yaw-rate`).
    CommandLine,
    /// Python's keyword arguments (`min_yaw_rate`).
    Python,
}

impl Caller {
    /// How this caller names `key` as `settings` state it: the keyword, or
    /// the flag (`--no-fallback` for `fallback`, `--no-bias-correction`
    /// for `correct_bias` 0).
    pub(crate) fn name(self, key: &str, settings: &Settings) -> String {
        match self {
            Caller::Python => key.to_string(),
            Caller::CommandLine => match key {
                "fallback" => "--no-fallback".into(),
                "correct_bias" if settings.correct_bias == Some(0) => "--no-bias-correction".into(),
                _ => format!("--{}", key.replace('_', "-")),
            },
        }
    }

    /// The method `name` in a message: the one a key belongs to (`owner`)
    /// or the one chosen.
    fn method(self, name: &str, owner: bool) -> String {
        match (self, owner) {
            (Caller::CommandLine, _) => format!("--method {name}"),
            (Caller::Python, true) => format!("method {name}"),
            (Caller::Python, false) => name.to_string(),
        }
    }

    /// The error for the caller's `key`: `what` is wrong with it.
    fn invalid(self, key: &'static str, settings: &Settings, what: String) -> Error {
        match self {
            Caller::CommandLine => Error::InvalidFlags(format!("{} {what}", self.name(key, settings))),
            Caller::Python => Error::InvalidOption { field: key, reason: what },
        }
    }

    /// The error for the caller's `keys`, which the chosen method does not
    /// use: `what` says which methods do. Python's names the first key as
    /// the option at fault (the method is the caller's choice, the key the
    /// mistake).
    fn misplaced(self, keys: &[&'static str], settings: &Settings, what: String) -> Error {
        let names: Vec<String> = keys.iter().map(|k| self.name(k, settings)).collect();
        let text = format!("{} appl{} to {what}", names.join(", "), if keys.len() == 1 { "ies" } else { "y" });
        match (self, keys.first()) {
            (Caller::Python, Some(first)) => Error::InvalidOption { field: first, reason: text },
            _ => Error::InvalidFlags(text),
        }
    }

    /// Who gave a setting that won over a manifest's, in words.
    fn words(self) -> &'static str {
        match self {
            Caller::CommandLine => "the command line",
            Caller::Python => "a keyword",
        }
    }
}

/// Keys only some methods use.
struct MethodKeys {
    keys: &'static [&'static str],
    /// Whether the method uses them.
    uses: fn(&Method) -> bool,
    /// The methods that use them, as `caller` names them.
    owner: fn(Caller) -> String,
    /// Why a manifest's key is ignored by `method`.
    ignored: fn(key: &str, method: &Method) -> String,
}

/// Every key that only some methods use, by the methods that use them.
static METHOD_KEYS: [MethodKeys; 4] = [
    MethodKeys {
        keys: &[
            "noise_model",
            "known_noise",
            "fix_noise",
            "fallback",
            "eiv_window",
            "quantisation",
            "quantisation_level",
            "lateral_noise",
            "heading_noise",
            "bootstrap",
            "bootstrap_seed",
            "correct_bias",
            "correct_bias_of",
        ],
        uses: |m| matches!(m, Method::Eiv(_)),
        owner: |c| format!("{} only", c.method("eiv", true)),
        ignored: |key, m| match key {
            "noise_model" => format!("method {m} does not use a noise model"),
            _ => format!("applies to method eiv only, not to {m}"),
        },
    },
    MethodKeys {
        keys: &["seed", "batches", "batch_size", "picks", "final_segments", "qp_solver"],
        uses: |m| matches!(m, Method::ThreeStep(_)),
        owner: |c| format!("{} only", c.method("three-step", true)),
        ignored: |_, m| format!("applies to method three-step only, not to {m}"),
    },
    MethodKeys {
        keys: &["min_yaw_rate", "keep_one_way"],
        uses: |m| !matches!(m, Method::Eiv(_)),
        owner: |_| "the segment-selecting methods (three-step, batch-gn)".into(),
        ignored: |_, _| "method eiv fits every segment, it does not select turning ones".into(),
    },
    MethodKeys {
        keys: &["estimate", "lever_arm", "heading_offset"],
        uses: |m| m.estimator().supports_extrinsics(),
        owner: |_| "the methods that model the reference extrinsics".into(),
        ignored: |_, m| format!("method {m} does not model the reference extrinsics"),
    },
];

/// The keys-of-some-methods that `method` does not use, if `key` is one.
fn unused_by(key: &str, method: &Method) -> Option<&'static MethodKeys> {
    METHOD_KEYS.iter().find(|g| g.keys.contains(&key) && !(g.uses)(method))
}

/// What became of one manifest setting.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case", tag = "outcome")]
pub(crate) enum SettingOutcome {
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
pub(crate) struct SettingUse {
    /// The manifest key (`noise`, `reference.lever_arm`,
    /// `calibration.keep_one_way`, …; `noise.lateral` when the caller's
    /// `lateral_noise` wins over the `[noise]` table's `lateral`).
    pub key: String,
    /// The manifest it comes from.
    pub manifest: PathBuf,
    /// What became of it.
    #[serde(flatten)]
    pub outcome: SettingOutcome,
}

/// Where a calibration's settings came from: what became of each manifest
/// setting and which starting noise model method eiv used. The text report
/// prints it ([`crate::CalibrationReport::render_text`]); the JSON report
/// has the same as `manifest_settings` and `noise_model_origin`
/// ([`crate::CalibrationReport::to_json`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SettingsAccount {
    /// Who gave the settings that win over the manifest's.
    #[serde(skip)]
    pub caller: Caller,
    /// Each manifest setting and what became of it.
    #[serde(rename = "manifest_settings", skip_serializing_if = "Vec::is_empty")]
    pub(crate) uses: Vec<SettingUse>,
    /// Where method eiv's starting noise model came from, in words; `None`
    /// for another method.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise_model_origin: Option<String>,
}

impl SettingsAccount {
    /// The report's lines on the settings, each ending in a newline ("" when
    /// there is nothing to say).
    pub(crate) fn lines(&self) -> String {
        let mut o = String::new();
        if let Some(n) = &self.noise_model_origin {
            let _ = writeln!(o, "starting noise model: {n}");
        }
        for u in &self.uses {
            let _ = write!(o, "manifest setting {} from {}: ", u.key, u.manifest.display());
            let _ = match &u.outcome {
                SettingOutcome::Used => writeln!(o, "used"),
                SettingOutcome::Overridden => writeln!(o, "overridden by {}", self.caller.words()),
                SettingOutcome::Ignored { reason } => writeln!(o, "ignored ({reason})"),
            };
        }
        o
    }

    /// Adds `manifest_settings` (when a manifest states any) and
    /// `noise_model_origin` (method eiv) to a JSON report.
    ///
    /// # Errors
    /// [`Error::Json`] if the account does not serialise (it always does).
    pub(crate) fn add_to_json(&self, report: &mut serde_json::Value) -> Result<()> {
        let json = |source| Error::Json { context: "settings account".into(), source };
        if let (serde_json::Value::Object(fields), Some(obj)) =
            (serde_json::to_value(self).map_err(json)?, report.as_object_mut())
        {
            obj.extend(fields);
        }
        Ok(())
    }
}

/// Calibration options and where their settings came from.
#[derive(Debug, Clone, PartialEq)]
pub struct Resolved {
    /// The options to calibrate with.
    pub options: CalibrationOptions,
    /// What became of the manifest's settings.
    pub account: SettingsAccount,
    /// The extrinsic parameters the caller's settings state values of
    /// (`lever_arm`: lever_x and lever_y, `heading_offset`): they apply to
    /// every validation drive too (docs/guide.md, "Several drives of one
    /// vehicle"), where a manifest's apply to its own drive only.
    pub given_extrinsics: ParamSet,
}

impl Settings {
    /// The calibration options of these settings, the caller's, over the
    /// `manifests`' (those of the drives fitted jointly, which must agree;
    /// a manifest that states none agrees with any), over the defaults, and what became of
    /// each manifest setting. A key the method does not use is an error
    /// when the caller gives it and ignored (saying so) when the manifest
    /// does.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming two manifests that state different
    /// settings; [`Error::InvalidFlags`] (command line) or
    /// [`Error::InvalidOption`] (Python) naming the caller's key of another
    /// method; the errors of `Settings::to_options`.
    pub fn resolve(&self, manifests: &[ManifestSettings], caller: Caller) -> Result<Resolved> {
        let merged = ManifestSettings::merge(manifests)?;
        let manifest = merged.as_ref();
        let stated = manifest.map(|m| m.settings.clone()).unwrap_or_default();
        let method = self.method.clone().or_else(|| stated.method.clone()).unwrap_or_default();
        self.check_method_keys(&method, caller)?;
        let mut uses = Vec::new();
        let mut used = stated.clone();
        if let Some(m) = manifest {
            let caller_keys = self.stated();
            for key in stated.stated() {
                let outcome = match unused_by(key, &method) {
                    _ if caller_keys.contains(&key) => SettingOutcome::Overridden,
                    Some(g) => {
                        used = used.without(key);
                        SettingOutcome::Ignored { reason: (g.ignored)(key, &method) }
                    }
                    None => SettingOutcome::Used,
                };
                let lateral_overridden = key == "noise_model"
                    && outcome == SettingOutcome::Used
                    && self.lateral_noise.is_some()
                    && matches!(&stated.noise_model, Some(NoiseModelSetting::Stated(n)) if n.lateral.is_some());
                uses.push(SettingUse { key: m.key(key), manifest: m.manifest.clone(), outcome });
                if lateral_overridden {
                    let key = "noise.lateral".into();
                    uses.push(SettingUse { key, manifest: m.manifest.clone(), outcome: SettingOutcome::Overridden });
                }
            }
        }
        let noise_model_origin = matches!(method, Method::Eiv(_)).then(|| match (&self.noise_model, manifest) {
            (Some(NoiseModelSetting::File(p)), _) => format!("--noise-model {}", p.display()),
            (Some(NoiseModelSetting::Stated(_)), _) => "the noise_model table given".into(),
            (None, Some(m)) if used.noise_model.is_some() => format!("[noise] of {}", m.manifest.display()),
            (None, _) => "the production-car defaults (no --noise-model, no manifest [noise])".into(),
        });
        let options = self.clone().over(used).to_options(caller)?;
        let account = SettingsAccount { caller, uses, noise_model_origin };
        Ok(Resolved { options, account, given_extrinsics: self.stated_extrinsics() })
    }

    /// The error for the first set of keys these settings state that
    /// `method` does not use.
    fn check_method_keys(&self, method: &Method, caller: Caller) -> Result<()> {
        let stated = self.stated();
        for g in METHOD_KEYS.iter().filter(|g| !(g.uses)(method)) {
            let given: Vec<&'static str> = g.keys.iter().copied().filter(|k| stated.contains(k)).collect();
            if !given.is_empty() {
                let what = format!("{}, not to {}", (g.owner)(caller), caller.method(method.name(), false));
                return Err(caller.misplaced(&given, self, what));
            }
        }
        Ok(())
    }

    /// The calibration options of these settings over the defaults: the
    /// one mapping of settings to [`CalibrationOptions`]. `caller` names
    /// the keys in messages. `fix` applies last, so it holds an extrinsic
    /// `estimate` frees too.
    ///
    /// # Errors
    /// [`Error::InvalidFlags`] or [`Error::InvalidOption`] naming the key:
    /// of another method, `estimate` naming θ, an odd `correct_bias`, a
    /// `bootstrap_seed` that seeds nothing; a noise-model file's errors;
    /// the options' check ([`CalibrationOptions::validate`]).
    pub(crate) fn to_options(&self, caller: Caller) -> Result<CalibrationOptions> {
        self.check_ceilings(caller)?;
        let mut o = CalibrationOptions { method: self.method.clone().unwrap_or_default(), ..Default::default() };
        self.check_method_keys(&o.method, caller)?;
        set(&mut o.theta0, &self.theta0);
        set(&mut o.seed, &self.seed);
        set(&mut o.auto_fix, &self.auto_fix);
        match &mut o.method {
            Method::ThreeStep(t) => self.three_step_options(t),
            Method::Eiv(e) => self.eiv_options(e, caller)?,
            Method::BatchGn => {}
        }
        self.extrinsics(&mut o, caller)?;
        let fix = self.fix.unwrap_or_default();
        if Param::THETA.iter().all(|p| fix.contains(*p)) {
            let validate = if caller == Caller::CommandLine { "odocal validate --theta" } else { "odocal.validate" };
            return Err(caller.invalid(
                "fix",
                self,
                format!("holds every parameter of θ: leave at least one free ({validate} judges a θ as it is)"),
            ));
        }
        for p in fix.iter() {
            o.hold(p);
        }
        set(&mut o.identify.max_iterations, &self.max_iterations);
        set(&mut o.segments.min_peak_yaw_rate_rad_per_s, &self.min_yaw_rate);
        set(&mut o.keep_one_way_selection, &self.keep_one_way);
        set(&mut o.segments.length_steps, &self.segment_length);
        set(&mut o.segments.stride_steps, &self.segment_stride);
        if let Some(k) = self.validation_length {
            o.validation.length_steps = k;
            o.validation.stride_steps = (k / 2).max(1);
        }
        o.validate()?;
        Ok(o)
    }

    /// Every count setting at most its ceiling ([`super::COUNT_CEILINGS`]),
    /// the three-step counts (final segments too) at least 1, the minimum yaw rate a
    /// non-negative number.
    fn check_ceilings(&self, caller: Caller) -> Result<()> {
        match self.value_problem() {
            Some((key, what)) => Err(caller.invalid(key, self, what)),
            None => Ok(()),
        }
    }

    /// The first value out of its range (as `check_ceilings` checks them):
    /// the key and what is wrong (`= 0: must be at least 1`), for the
    /// caller's or a manifest's words.
    pub(crate) fn value_problem(&self) -> Option<(&'static str, String)> {
        let counts: [Option<usize>; 10] = [
            self.max_iterations,
            self.segment_length,
            self.segment_stride,
            self.validation_length,
            self.eiv_window,
            self.batches,
            self.batch_size,
            self.picks,
            self.bootstrap,
            self.correct_bias,
        ];
        for ((key, max), v) in super::COUNT_CEILINGS.iter().zip(counts) {
            if let Some(v) = v.filter(|v| v > max) {
                return Some((key, format!("= {v} is above its ceiling of {max}")));
            }
        }
        // Gauss-Newton and the counts of the 3-step method's step 1 need at
        // least one (no iteration is no calibration); the floors of the EIV
        // window and of a bootstrap (eiv::options and eiv::bootstrap check
        // them again, naming their own fields).
        for (key, v) in [
            ("max_iterations", self.max_iterations),
            ("batches", self.batches),
            ("batch_size", self.batch_size),
            ("picks", self.picks),
        ] {
            if v == Some(0) {
                return Some((key, "= 0: must be at least 1".into()));
            }
        }
        if self.final_segments == Some(FinalSegments::Random(0)) {
            return Some(("final_segments", "= 0: must be at least 1 (or all)".into()));
        }
        // The floors of `drive::segment`, whose options' check refuses these
        // again, naming no source.
        use crate::drive::segment::{MIN_LENGTH_STEPS, MIN_STRIDE_STEPS};
        for (key, v, min) in [
            ("segment_length", self.segment_length, MIN_LENGTH_STEPS),
            ("validation_length", self.validation_length, MIN_LENGTH_STEPS),
            ("segment_stride", self.segment_stride, MIN_STRIDE_STEPS),
        ] {
            if let Some(v) = v.filter(|v| *v < min) {
                let unit = if min == 1 { "sample" } else { "samples" };
                return Some((key, format!("= {v}: must be at least {min} {unit}")));
            }
        }
        if let Some(b) = self.correct_bias.filter(|b| !b.is_multiple_of(2)) {
            return Some((
                "correct_bias",
                format!(
                    "= {b}: must be 0 (no correction) or an even number of at least 2 (the replicates come in \
                     antithetic pairs)"
                ),
            ));
        }
        for (key, v, min, unit) in
            [("eiv_window", self.eiv_window, 10, "samples"), ("bootstrap", self.bootstrap, 2, "replicates")]
        {
            if let Some(v) = v.filter(|v| *v < min) {
                return Some((key, format!("= {v}: must be at least {min} {unit}")));
            }
        }
        // The extrinsics a manifest's [reference] states are checked by the
        // importer alike; a lever arm in millimetres or a heading offset in
        // degrees is caught here for the command line and Python.
        let [lever_x, lever_y] = self.lever_arm.unwrap_or_default();
        let heading_offset = self.heading_offset.unwrap_or_default();
        let stated = crate::model::extrinsics::Extrinsics { lever_x, lever_y, heading_offset };
        if let Err((key, why)) = crate::model::limits::check_extrinsics(&stated) {
            return Some((if key == "heading_offset" { key } else { "lever_arm" }, format!("= {why}")));
        }
        match self.min_yaw_rate {
            Some(r) if !(r.is_finite() && r >= 0.0) => {
                let r = crate::drive::echo_num(r);
                Some((
                    "min_yaw_rate",
                    format!("= {r}: must be a non-negative number of rad/s (0 selects every segment)"),
                ))
            }
            _ => None,
        }
    }

    /// The lever arm and heading offset (a stated heading offset is held
    /// by method eiv's start), and the extrinsics to estimate.
    fn extrinsics(&self, o: &mut CalibrationOptions, caller: Caller) -> Result<()> {
        if let Some([x, y]) = self.lever_arm {
            (o.identify.extrinsics.lever_x, o.identify.extrinsics.lever_y) = (x, y);
        }
        if let Some(h) = self.heading_offset {
            o.identify.extrinsics.heading_offset = h;
            o.hold_stated_heading_offset();
        }
        if let Some(e) = self.estimate {
            let theta = e.intersection(ParamSet::THETA);
            if !theta.is_empty() {
                let fix = if caller == Caller::CommandLine { "--fix" } else { "fix=" };
                let what = format!(
                    "takes lever-arm, heading-offset (or lever_x, lever_y, heading_offset), not {theta}: θ is \
                     estimated by default (hold parameters with {fix})"
                );
                return Err(caller.invalid("estimate", self, what));
            }
            o.identify.free = o.identify.free.union(e);
        }
        Ok(())
    }

    /// The three-step method's settings.
    fn three_step_options(&self, t: &mut ThreeStepOptions) {
        set(&mut t.initial_batches, &self.batches);
        set(&mut t.initial_batch_size, &self.batch_size);
        set(&mut t.picks, &self.picks);
        set(&mut t.final_segments, &self.final_segments);
        set(&mut t.qp.solver, &self.qp_solver);
    }

    /// Method eiv's settings: the starting noise model (then the sources
    /// held and the lateral noise, which win over the model's), the
    /// filter's settings, the bias correction and the bootstrap.
    fn eiv_options(&self, e: &mut EivMethodOptions, caller: Caller) -> Result<()> {
        if let Some(n) = &self.noise_model {
            n.spec()?.apply(&mut e.filter);
        }
        e.filter.hold_known(self.known_noise.as_deref().unwrap_or_default());
        set(&mut e.filter.fix_noise, &self.fix_noise);
        set(&mut e.fallback, &self.fallback);
        set(&mut e.filter.window_samples, &self.eiv_window);
        set(&mut e.filter.quantisation, &self.quantisation);
        set(&mut e.filter.quantisation_level, &self.quantisation_level);
        set(&mut e.filter.lateral_noise, &self.lateral_noise);
        set(&mut e.filter.heading_scale, &self.heading_noise);
        if e.filter.heading_known_but_tied() {
            let tied = caller.name("heading_noise", self);
            let what = format!(
                "names heading_white, whose scale {tied} tied shares with pose_white: give the heading its own \
                 scale (separate) or name pose_white as known too"
            );
            return Err(caller.invalid("known_noise", self, what));
        }
        let seed = self.bootstrap_seed.unwrap_or(0);
        self.bias_correction(e, caller, seed)?;
        if let Some(b) = self.bootstrap {
            e.bootstrap = Some(BootstrapOptions { replicates: b, seed, ..Default::default() });
        }
        Ok(())
    }

    /// The bias correction's settings (`correct_bias`, `correct_bias_of`,
    /// the seed) applied to `e`.
    fn bias_correction(&self, e: &mut EivMethodOptions, caller: Caller, seed: u64) -> Result<()> {
        let off = if caller == Caller::CommandLine { "--no-bias-correction" } else { "correct_bias=0" };
        if let Some(parameters) = self.correct_bias_of {
            if self.correct_bias == Some(0) {
                let what = format!("names the parameters of the bias correction, which {off} turns off");
                return Err(caller.invalid("correct_bias_of", self, what));
            }
            if let Some(problem) = correctable_problem(parameters) {
                return Err(caller.invalid("correct_bias_of", self, problem));
            }
        }
        match self.correct_bias {
            Some(0) if self.bootstrap_seed.is_some() && self.bootstrap.is_none() => {
                let what = format!("is the seed of the bias correction, which {off} turns off");
                return Err(caller.invalid("bootstrap_seed", self, what));
            }
            Some(0) => e.correct_bias = None,
            Some(b) if !b.is_multiple_of(2) => {
                return Err(Error::InvalidOption {
                    field: "correct_bias",
                    reason: format!(
                        "must be 0 (no correction) or an even number of at least 2 (the replicates come in \
                         antithetic pairs), got {b}"
                    ),
                })
            }
            Some(b) => e.correct_bias.get_or_insert_with(CorrectBias::default).replicates = b,
            None => {}
        }
        // The seed and the parameters apply to the correction that stands.
        if let Some(c) = &mut e.correct_bias {
            c.seed = seed;
            c.parameters = self.correct_bias_of.unwrap_or(c.parameters);
        }
        Ok(())
    }
}

/// `target = value` when a value is stated.
fn set<T: Clone>(target: &mut T, value: &Option<T>) {
    if let Some(v) = value {
        *target = v.clone();
    }
}
