//! The calibration report rendered: the text `odocal calibrate` prints
//! ([`CalibrationReport::render_text`]), the validation drives' block
//! (`MultiValidation`'s `Display`) and the JSON report
//! ([`CalibrationReport::to_json`]), each with the account of the
//! calibration's settings when given.

use std::fmt::Write as _;

use crate::assess::pooling::{BetweenDriveSource, PooledDrives, NEXT_DRIVE_SIGMA_LABEL};
use crate::assess::trust::{Verdict, VerdictLevel};
use crate::assess::validate::MultiValidation;
use crate::calibrate::settings::SettingsAccount;
use crate::calibrate::{BatchSpread, CalibrationReport, EivDetail, EivOutcome, Method, MethodDetail, SigmaSource};
use crate::model::extrinsics::ExtrinsicsEstimate;
use crate::model::param::Param;
use crate::model::Theta;

/// Smallest EIV common-mode wheel-scale σ_c (relative) the text names as a
/// part of the σ for the next drive: the smallest that prints as 0.01 %.
const LISTED_COMMON_MODE_REL_SIGMA: f64 = 5e-5;

fn eiv_detail(r: &CalibrationReport) -> Option<&EivDetail> {
    match &r.detail {
        MethodDetail::Eiv(d) => Some(d),
        _ => None,
    }
}

fn row(out: &mut String, name: &str, unit: &str, values: &[Option<f64>], scale: f64, prec: usize) {
    let _ = write!(out, "  {name:<4} {unit:<14}");
    for v in values {
        match v {
            // A σ of NaN marks a parameter held at θ_0 (not estimated); +∞
            // one that moved without a σ from this column's covariance
            // (the EIV filter held it at its start's estimate).
            Some(v) if v.is_nan() => {
                let _ = write!(out, " {:>13}", "held");
            }
            Some(v) if v.is_infinite() && v.is_sign_positive() => {
                let _ = write!(out, " {:>13}", "–");
            }
            Some(v) => {
                let _ = write!(out, " {:>13.*}", prec, v * scale);
            }
            None => {
                let _ = write!(out, " {:>13}", "-");
            }
        }
    }
    out.push('\n');
}

/// A θ table with one column per entry (c_d and d also in mm, as the paper prints them).
fn theta_table(columns: &[(&str, Option<Theta>)]) -> String {
    let mut out = String::new();
    let _ = write!(out, "  {:<4} {:<14}", "", "");
    for (name, _) in columns {
        let _ = write!(out, " {name:>13}");
    }
    out.push('\n');
    let get = |f: fn(&Theta) -> f64| columns.iter().map(|(_, t)| t.as_ref().map(f)).collect::<Vec<_>>();
    row(&mut out, "c_e", "m", &get(|t| t.c_e), 1.0, 6);
    row(&mut out, "c_d", "mm", &get(|t| t.c_d), 1e3, 4);
    row(&mut out, "t_r", "m", &get(|t| t.t_r), 1.0, 6);
    row(&mut out, "d", "mm/(m/s²)", &get(|t| t.d), 1e3, 4);
    out
}

/// The reference extrinsics: initial, calibrated (or held) value, model 1σ
/// and, when computed, the cluster-robust 1σ, under their own column names
/// (the θ table's columns above may differ: truth, spread, EIV).
fn extrinsics_table(x: &ExtrinsicsEstimate) -> String {
    let mut out = String::from("  reference extrinsics (lever arm from the rear-axle centre, x forward, y left):\n");
    let _ = write!(out, "  {:<4} {:<14}", "", "");
    for name in ["initial", "calibrated", "± 1σ (model)", "± 1σ (robust)"] {
        let _ = write!(out, " {name:>13}");
    }
    out.push('\n');
    let (init, val, sd) = (x.initial.to_array(), x.value.to_array(), x.std_dev.to_array());
    for (i, p) in Param::EXTRINSICS.into_iter().enumerate() {
        let sigma = if x.free.contains(p) { sd[i] } else { f64::NAN };
        let (name, unit, scale, prec) = match p {
            Param::HeadingOffset => ("δ", "mrad", 1e3, 4),
            Param::LeverX => ("l_x", "m", 1.0, 4),
            _ => ("l_y", "m", 1.0, 4),
        };
        let robust = x.robust.as_ref().map(|rb| if x.free.contains(p) { rb.std_dev.to_array()[i] } else { f64::NAN });
        row(&mut out, name, unit, &[Some(init[i]), Some(val[i]), Some(sigma), robust], scale, prec);
    }
    if !x.per_drive.is_empty() {
        out.push_str("  heading offset per drive (δ above is their mean, the value carried to other drives):\n");
        for p in &x.per_drive {
            let robust = p.robust_std_dev.map_or(String::new(), |s| format!(", {:.4} robust", s * 1e3));
            let _ = writeln!(
                out,
                "    drive {}: δ = {:.4} mrad ± {:.4} model{robust} (1σ)",
                p.drive + 1,
                p.value * 1e3,
                p.std_dev * 1e3
            );
        }
    }
    out
}

/// Relative error of each parameter against the truth (c_d, d: absolute in mm).
fn error_line(est: &Theta, truth: &Theta) -> String {
    format!(
        "c_e {:+.4} %, c_d {:+.4} mm, t_r {:+.4} %, d {:+.4} mm/(m/s²)",
        (est.c_e / truth.c_e - 1.0) * 100.0,
        (est.c_d - truth.c_d) * 1e3,
        (est.t_r / truth.t_r - 1.0) * 100.0,
        (est.d - truth.d) * 1e3
    )
}

/// The verdict line and one line per reason.
fn verdict(v: &Verdict) -> String {
    let mut out = format!("  verdict: {}", v.level.to_string().to_uppercase());
    if v.reasons.is_empty() {
        out.push_str(" (no reason for doubt found)");
    }
    out.push('\n');
    for r in &v.reasons {
        let _ = writeln!(out, "    - {r}");
    }
    if v.level == VerdictLevel::Rejected {
        out.push_str("    (do not deploy this calibration)\n");
    }
    out
}

impl CalibrationReport {
    /// The JSON report, as `odocal calibrate --json` writes it and the
    /// Python package returns it (the front end adds `schema_version`,
    /// [`REPORT_SCHEMA_VERSION`](crate::REPORT_SCHEMA_VERSION), and its
    /// settings account): the report's fields; `sigma`, the σ that stands for the result
    /// ([`Self::result_sigma`]), and `sigma_within_drive`
    /// (the method's within-drive σ); `drives`, the front end's entries of
    /// the drives (objects with `role`, `path`, `fingerprint`), with a joint
    /// fit's `heading_offset_per_drive`; and, when given, `truth` (a
    /// simulated drive's θ and its mean position error on the validation
    /// segments) and `wheel_scale` (how to read c_e of an imported drive).
    ///
    /// ```
    /// # fn main() -> Result<(), odocal::Error> {
    /// use odocal::{calibrate, CalibrationOptions, Method, sim::{simulate, SimOptions}};
    /// let sim = simulate(&SimOptions { length_km: 4.0, substeps: 1, noise: "off".parse()?, ..SimOptions::paper(1) })?;
    /// let opts = CalibrationOptions { method: "batch-gn".parse::<Method>()?, ..Default::default() };
    /// let json = calibrate(&sim.drive, &opts)?.to_json(Vec::new(), None, None, None)?;
    /// assert_eq!(json["method"], "batch-gn");
    /// assert!(json["sigma"]["c_e"].is_number());
    /// # Ok(()) }
    /// ```
    ///
    /// # Errors
    /// [`Error::Json`](crate::Error::Json) when the report cannot be
    /// written as JSON.
    pub fn to_json(
        &self,
        drives: Vec<serde_json::Value>,
        truth: Option<(&Theta, f64)>,
        wheel_scale: Option<&str>,
        settings: Option<&SettingsAccount>,
    ) -> crate::Result<serde_json::Value> {
        let json = |source| crate::Error::Json { context: "calibration report".into(), source };
        let mut v = serde_json::to_value(self).map_err(json)?;
        let Some(obj) = v.as_object_mut() else { return Ok(v) };
        obj.insert("sigma".into(), serde_json::to_value(self.result_sigma()).map_err(json)?);
        obj.insert("sigma_within_drive".into(), serde_json::to_value(self.within_drive_sigma()).map_err(json)?);
        if let Some((t, e)) = truth {
            obj.insert("truth".into(), serde_json::json!({"theta": t, "mean_position_error_m": e}));
        }
        if let Some(w) = wheel_scale {
            obj.insert("wheel_scale".into(), serde_json::json!(w));
        }
        if let Some(per) = self.heading_offset_per_drive(&drives) {
            obj.insert("heading_offset_per_drive".into(), per);
        }
        obj.insert("drives".into(), serde_json::Value::Array(drives));
        if let Some(s) = settings {
            s.add_to_json(&mut v)?;
        }
        Ok(v)
    }

    /// The report for humans, as `odocal calibrate` prints it: the method
    /// and segments, the method's steps, the θ table (with the truth
    /// column when `truth` gives a simulated drive's θ and its Ē_p), the
    /// extrinsics, the verdict, the σ of the result, the validation and the
    /// times. `wheel_scale` says how to read c_e for an imported drive
    /// (ticks per revolution or nominal circumference); it is printed under
    /// the θ table. With validation drives, their block follows
    /// ([`CalibrationReport::validate_on`]); with `settings`, what became of
    /// the manifests' settings and where the starting noise model came from.
    /// The first line is the heading; the warnings
    /// ([`CalibrationReport::warnings`]) are not included.
    ///
    /// ```
    /// # fn main() -> Result<(), odocal::Error> {
    /// use odocal::{calibrate, CalibrationOptions, Method, sim::{simulate, SimOptions}};
    /// let sim = simulate(&SimOptions { length_km: 4.0, substeps: 1, noise: "off".parse()?, ..SimOptions::paper(1) })?;
    /// let opts = CalibrationOptions { method: "batch-gn".parse::<Method>()?, ..Default::default() };
    /// let text = calibrate(&sim.drive, &opts)?.render_text(None, None, None);
    /// assert!(text.starts_with("odocal calibrate — method batch-gn\n"));
    /// assert!(text.contains("verdict: "));
    /// # Ok(()) }
    /// ```
    pub fn render_text(
        &self,
        truth: Option<(&Theta, f64)>,
        wheel_scale: Option<&str>,
        settings: Option<&SettingsAccount>,
    ) -> String {
        let mut text = calibration(self, truth, wheel_scale);
        if let Some(m) = &self.validate_on {
            let _ = write!(text, "{m}");
        }
        if let Some(s) = settings {
            text.push_str(&s.lines());
        }
        text
    }
}

fn calibration(r: &CalibrationReport, truth: Option<(&Theta, f64)>, wheel_scale: Option<&str>) -> String {
    let mut out = String::new();
    let _ = writeln!(out, "odocal calibrate — method {}", r.method);
    segments_line(&mut out, r);
    if eiv_detail(r).is_some() {
        identification_lines(&mut out, r);
    }
    out.push_str(&r.method_details());
    out.push('\n');
    out.push_str(&theta_table(&theta_columns(r, truth)));
    if let Some(x) = &r.extrinsics {
        out.push_str(&extrinsics_table(x));
    }
    out.push_str(&verdict(&r.verdict));
    result_notes(&mut out, r, wheel_scale);
    out.push('\n');
    validation_lines(&mut out, r, truth);
    let t = &r.timing_s;
    let _ = writeln!(
        out,
        "\ntime: {:.2} s total (setup {:.2}, initial {:.2}, compensation {:.2}, final {:.2}, validation {:.2})",
        t.total, t.setup, t.initial_identification, t.compensation, t.final_identification, t.validation
    );
    out
}

/// The segments cut, selected and used for validation.
fn segments_line(out: &mut String, r: &CalibrationReport) {
    let used = r.identification().map(|id| id.segments);
    if used == Some(r.segments.cut) && (r.segments.selected < r.segments.cut || eiv_detail(r).is_some()) {
        // --auto-fix on a drive without turns, or --min-yaw-rate 0: no selection happened.
        let _ = writeln!(
            out,
            "segments: {} cut, all used (no yaw-rate selection), {} validation",
            r.segments.cut, r.segments.validation
        );
    } else {
        let _ = writeln!(
            out,
            "segments: {} cut, {} selected (peak yaw rate ≥ {} rad/s), {} validation",
            r.segments.cut, r.segments.selected, r.options.segments.min_peak_yaw_rate_rad_per_s, r.segments.validation
        );
    }
}

/// The three-step method's first two steps: the batch fits and the input
/// compensation.
fn three_step_lines(out: &mut String, r: &CalibrationReport) {
    if let (Some(s), Method::ThreeStep(o)) = (r.initial_step(), &r.options.method) {
        let _ = writeln!(
            out,
            "step 1: {} batch G-N runs of {} segments; picked θ_B,I (Ē_p, m): {}",
            s.batches.len(),
            o.initial_batch_size,
            s.picked.iter().map(|p| format!("{:.3}", p.mean_position_error_m)).collect::<Vec<_>>().join(", ")
        );
    }
    if let Some(c) = r.compensation() {
        let _ = writeln!(
            out,
            "step 2: {} segments compensated ({} QP jobs, {} failed, {} solves, {} by the Clarabel fallback, {:.1} solver it/solve, {}), rms input change {:.3} %",
            c.segments,
            c.jobs,
            c.failed_jobs,
            c.qp_solves,
            c.fallback_solves,
            c.mean_qp_iterations,
            c.solver,
            c.rms_relative_input_change * 100.0
        );
    }
}

/// The account of a batch G-N or 3-step fit ([`CalibrationReport::method_details`]):
/// the 3-step's steps 1 and 2, then the Gauss-Newton fit and its σ.
pub(super) fn fit_lines(r: &CalibrationReport) -> String {
    let mut out = String::new();
    three_step_lines(&mut out, r);
    identification_lines(&mut out, r);
    out
}

/// The Gauss-Newton fit (the three-step's step 3, EIV's start or batch
/// G-N) and which σ stands beside the model σ.
fn identification_lines(out: &mut String, r: &CalibrationReport) {
    let Some(id) = r.identification() else { return };
    let _ = writeln!(
        out,
        "{}: {} segments, {} it, {}; rcond {:.2e}",
        if r.initial_step().is_some() {
            "step 3"
        } else if eiv_detail(r).is_some() {
            "EIV start, batch G-N"
        } else {
            "batch G-N"
        },
        id.segments,
        id.iterations,
        id.termination,
        id.observability.rcond
    );
    if let Some(b) = three_step_spread(r) {
        let _ = writeln!(
            out,
            "batch-spread σ: the spread of {} plausible step-1 batch estimates (of {} segments) scaled to \
             {:.0} independent segment lengths; the model σ (step 3's) understates the uncertainty 100–1000×",
            b.batches, b.batch_size, b.effective_segments
        );
    } else if r.initial_step().is_some() {
        let _ = writeln!(
            out,
            "σ: model only (too few plausible step-1 batches for a batch-spread σ); it understates the spread \
             of 3-step estimates about 100–1000× on simulated paper-noise drives"
        );
    } else if eiv_detail(r).is_none() {
        let o = &r.options.identify;
        let _ = match &id.robust {
            Some(rb) => writeln!(
                out,
                "robust σ: cluster-robust over {} clusters of {} samples (the model σ assumes independent residuals)",
                rb.clusters, rb.block_steps
            ),
            None => writeln!(
                out,
                "robust σ: not computed (fewer than {} clusters of {} samples); the model σ assumes independent \
                 residuals and understates the uncertainty under input noise",
                o.robust_min_clusters, o.robust_block_steps
            ),
        };
    }
}

/// The θ table's columns: θ_0, the calibrated θ, each σ the method has,
/// the truth when known and an EIV estimate the fallback replaced.
fn theta_columns(r: &CalibrationReport, truth: Option<(&Theta, f64)>) -> Vec<(&'static str, Option<Theta>)> {
    let mut cols = vec![("θ_0", Some(r.initial.theta)), ("calibrated", Some(r.theta))];
    // Held parameters print "held", not a σ of 0: those not free and those
    // the method held itself (EIV holds what it cannot observe at its start;
    // a zero covariance row), by the rule of the JSON `sigma_within_drive`.
    // "held" only for a parameter that did not move from θ_0.
    let sd = r.std_dev().to_array();
    let estimated = r.within_drive_sigma().to_array();
    let (start, value) = (r.initial.theta.to_array(), r.theta.to_array());
    let sigma: [f64; 4] = std::array::from_fn(|i| match estimated[i] {
        Some(_) => sd[i],
        None if value[i].to_bits() != start[i].to_bits() => f64::INFINITY,
        None => f64::NAN,
    });
    cols.push(("± 1σ (model)", Some(Theta { c_e: sigma[0], c_d: sigma[1], t_r: sigma[2], d: sigma[3] })));
    // The cluster-robust σ (residuals correlated along and across segments):
    // batch-gn's, or that of the default's batch G-N fallback, whose
    // within-drive σ it is.
    let fallback = eiv_detail(r).filter(|d| d.eiv_result == EivOutcome::BatchGnFallback);
    if let Some(rb) = r.robust().or_else(|| fallback.and_then(|d| d.identification.robust.as_ref())) {
        let sd = rb.std_dev().to_array();
        let s: [f64; 4] = std::array::from_fn(|i| if sigma[i].is_finite() { sd[i] } else { sigma[i] });
        cols.push(("± 1σ (robust)", Some(Theta { c_e: s[0], c_d: s[1], t_r: s[2], d: s[3] })));
    }
    // The 3-step's step-1 batch spread.
    if let Some(b) = three_step_spread(r) {
        let sd = b.std_dev().to_array();
        let s: [f64; 4] = std::array::from_fn(|i| if sigma[i].is_finite() { sd[i] } else { sigma[i] });
        cols.push(("± 1σ (spread)", Some(Theta { c_e: s[0], c_d: s[1], t_r: s[2], d: s[3] })));
    }
    // The σ that stands for the result: for the next drive.
    if r.next_drive_sigma.is_some() {
        let s: [f64; 4] = std::array::from_fn(|i| r.result_sigma().to_array()[i].unwrap_or(sigma[i]));
        cols.push(("± 1σ (next drive)", Some(Theta::from_array(s))));
    }
    if let Some((t, _)) = truth {
        cols.push(("truth", Some(*t)));
    }
    if let Some(d) = eiv_detail(r).filter(|d| d.eiv_result == EivOutcome::BatchGnFallback) {
        if let Some(e) = &d.eiv {
            cols.push(("EIV (unused)", Some(e.theta)));
        }
    }
    cols
}

/// Under the tables: which σ stands for the result, how to read c_e, what
/// was held and what the data cannot determine.
fn result_notes(out: &mut String, r: &CalibrationReport, wheel_scale: Option<&str>) {
    let column = match r.result_sigma().source {
        SigmaSource::ClusterRobust => "robust",
        SigmaSource::BatchSpread => "spread",
        SigmaSource::Model => "model",
    };
    match &r.next_drive_sigma {
        Some(n) => {
            let between = match n.between_source {
                BetweenDriveSource::Prior => "the documented prior".to_string(),
                BetweenDriveSource::RandomEffects => {
                    format!("{} drives pooled", n.pooled.as_ref().map_or(0, |p| p.theta.len()))
                }
            };
            let gap = if n.fallback_gap.iter().any(|g| *g > 0.0) { " ⊕ gap to EIV's own estimate" } else { "" };
            let above = if n.t_r_above_start.iter().any(|a| *a > 0.0) {
                " ⊕ EIV's t_r above its batch G-N start"
            } else {
                ""
            };
            let floor = if n.heading_drift_floor_gap.iter().any(|g| *g > 0.0) {
                " ⊕ gap to the fit without the heading drift's floor"
            } else {
                ""
            };
            let raised: Vec<&str> = (0..4)
                .filter(|i| n.within_from_start[*i] > 0.0)
                .filter_map(|i| Param::from_index(i).map(|p| p.name()))
                .collect();
            let raised = if raised.is_empty() {
                String::new()
            } else {
                format!("; {}: its batch G-N start's larger cluster-robust σ", raised.join(", "))
            };
            // A σ_c that prints as 0.00 % adds less than 0.2 % of the
            // within-drive σ (`common_mode` is within · σ_c / 2.5 %): not listed.
            let common = match n.wheel_common_rel_sigma {
                Some(s) if s >= LISTED_COMMON_MODE_REL_SIGMA && n.common_mode.iter().any(|h| *h > 0.0) => {
                    format!(" ⊕ common-mode wheel noise (EIV's σ_c {:.2} %)", s * 100.0)
                }
                _ => String::new(),
            };
            let _ = writeln!(
                out,
                "  σ of the result (verdict, --params-out, --report, JSON `sigma`): ± 1σ (next drive) = {}\n    \
                 within-drive ± 1σ ({column}, JSON `sigma_within_drive`{raised}){common}{gap}{floor}{above} ⊕ between-drive \
                 ({between})",
                NEXT_DRIVE_SIGMA_LABEL
            );
        }
        None => {
            let _ = writeln!(out, "  σ of the result (verdict, --params-out, --report, JSON `sigma`): ± 1σ ({column})");
        }
    }
    if let Some(p) = r.next_drive_sigma.as_ref().and_then(|n| n.pooled.as_ref()) {
        pooled_lines(out, p);
    }
    if let Some(w) = wheel_scale {
        let _ = writeln!(out, "  wheels: {w}");
    }
    if !r.auto_fixed.is_empty() {
        let held: Vec<&str> = r.auto_fixed.iter().map(|p| p.name()).collect();
        let _ = writeln!(out, "  held at θ_0 (--auto-fix, not observable): {}", held.join(", "));
    }
    let unobs = r.observability.unobservable;
    if !unobs.is_empty() {
        let _ = writeln!(out, "  NOT OBSERVABLE from these data (estimates not to be trusted): {unobs}");
    }
}

/// The block of a several-drive calibration: each drive fitted alone, the
/// random-effects pooling per parameter.
fn pooled_lines(out: &mut String, p: &PooledDrives) {
    let _ = writeln!(
        out,
        "  between drives ({} drives, each fitted alone with {}; random effects, DerSimonian–Laird):",
        p.theta.len(),
        p.method
    );
    let _ = writeln!(out, "    {:<18} {:>12} {:>18} {:>18}", "", "pooled", "σ of pooled mean", "τ between-drive");
    let rows = [("c_e  m", 1.0), ("c_d  mm", 1e3), ("t_r  m", 1.0), ("d    mm/(m/s²)", 1e3)];
    for (i, (name, scale)) in rows.iter().enumerate() {
        match p.params[i] {
            Some(e) => {
                let (m, s, t) = (e.mean * scale, e.mean_sigma * scale, e.tau * scale);
                let _ = writeln!(out, "    {name:<18} {m:>12.6} {s:>18.3e} {t:>18.3e}");
            }
            None => {
                let _ = writeln!(out, "    {name:<18} {:>12}", "held");
            }
        }
    }
}

/// Ē_p of θ_0, of the calibrated θ and of the truth, and the error against the truth.
fn validation_lines(out: &mut String, r: &CalibrationReport, truth: Option<(&Theta, f64)>) {
    let _ = writeln!(
        out,
        "mean position error Ē_p on {} validation segments{}:",
        r.validation.segments,
        if r.validation.held_out { " of held-out data (not used for calibration)" } else { "" }
    );
    let _ = writeln!(out, "  θ_0          {:>9.3} m", r.initial.mean_position_error_m);
    let _ = writeln!(out, "  calibrated   {:>9.3} m", r.validation.mean_position_error_m);
    if let Some((t, e)) = truth {
        let _ = writeln!(out, "  truth        {e:>9.3} m");
        let _ = writeln!(out, "error against truth: {}", error_line(&r.theta, t));
    }
}

/// Ē_p of the calibrated θ and of θ_0 on each validation drive (`odocal
/// calibrate --validate-on`) and their mean over the drives, as the tool
/// prints them.
impl std::fmt::Display for MultiValidation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&validate_on(self))
    }
}

fn validate_on(m: &MultiValidation) -> String {
    let mut out = String::from("validation drives (Ē_p calibrated / θ_0, m):\n");
    for d in &m.drives {
        let worse = if d.mean_position_error_m > d.initial_mean_position_error_m { "  worse than θ_0" } else { "" };
        let _ = writeln!(
            out,
            "  {}: {:.3} / {:.3} ({} segment{}){worse}",
            d.name,
            d.mean_position_error_m,
            d.initial_mean_position_error_m,
            d.segments,
            if d.segments == 1 { "" } else { "s" }
        );
        if let Some(x) = &d.extrinsics {
            let _ = writeln!(out, "    reference extrinsics: {x}");
            for c in &x.conflicts {
                let _ = writeln!(out, "    CONFLICT: {c}");
            }
        }
    }
    // Two means of several drives, each labelled by what weighs the same:
    // the drives' (a short drive counts as much as a long one) and the
    // segments' (the report's Ē_p on the held-out data). One drive's line
    // is both.
    if m.drives.len() > 1 {
        let n = m.drives.len();
        let _ = writeln!(
            out,
            "  mean of the {n} drives' Ē_p (each drive weighs the same): {:.3} / {:.3}",
            m.mean_over_drives_m, m.initial_mean_over_drives_m
        );
        let (segments, calibrated, initial) = m.mean_over_segments();
        let _ = writeln!(
            out,
            "  mean over their {segments} segments (each segment weighs the same; the Ē_p of the report): \
             {calibrated:.3} / {initial:.3}"
        );
    }
    out
}

/// The 3-step method's step-1 batch-spread σ, when it has one.
fn three_step_spread(r: &CalibrationReport) -> Option<&BatchSpread> {
    match &r.detail {
        MethodDetail::ThreeStep(d) => d.uncertainty.batch_spread.as_ref(),
        _ => None,
    }
}

/// The lines on the noise scales at their lower clamp: those the data show
/// none of, and those released from it at the end of the fit.
pub(super) fn clamp_lines(out: &mut String, e: &crate::eiv::EivReport) {
    // A scale at its lower clamp (below 0, without a σ) is a source the data
    // show none of, but for the heading's white noise where its readings'
    // own noise is its floor: then the level above is that floor's.
    let heading = crate::eiv::NoiseSource::HeadingWhite.index();
    let floored = |j: usize| j == heading && e.heading_noise_floor.is_some();
    let clamped = |j: usize| e.eta[j] < 0.0 && e.eta_sigma[j] == 0.0;
    let absent: Vec<&str> =
        (0..e.eta.len()).filter(|&j| clamped(j) && !floored(j)).map(|j| crate::eiv::NOISE_SOURCES[j].name()).collect();
    if !absent.is_empty() {
        let _ = writeln!(
            out,
            "  at the lower clamp (the data show none of it, so its level above reads 0): {}",
            absent.join(", ")
        );
    }
    if let Some(floor) = e.heading_noise_floor.filter(|_| clamped(heading)) {
        let _ = writeln!(
            out,
            "  at the lower clamp, the heading's white noise is its readings' own ({:.3} mrad, its level above): heading_white",
            floor * 1e3
        );
    }
    if !e.released.is_empty() {
        let names: Vec<&str> = e.released.iter().map(|s| s.name()).collect();
        let outcome = if e.release_kept {
            "the fit from there is the estimate (lower M)"
        } else {
            "the fit from there was not better; the estimate stays"
        };
        let _ = writeln!(
            out,
            "  released from the lower clamp (its score says the data hold it): {}; {outcome}",
            names.join(", ")
        );
    }
}
