//! # odocal-report — pictures of a calibration a person can judge
//!
//! A calibration is deployed by a person who has to decide whether the new
//! parameters are better than the old ones. [`render_html`] writes one
//! self-contained HTML page (inline SVG, no scripts, no network fetches):
//!
//! 1. the verdict and its reasons, then the parameter table (θ_0,
//!    calibrated, 1σ or "held", truth when known) and the method's own
//!    account of the fit (EIV: noise model, σ widening, result);
//! 2. Ē_p of θ_0 and of the calibrated θ (and of the truth), and what data
//!    it was measured on (the calibrated drive, a held-out half, other drives);
//! 3. the drive as a map: the reference, and dead reckoning with θ_0 and
//!    with the calibrated θ on a few validation segments, each named by
//!    its start time (and its drive, when the validation ran on several);
//! 4. E_p,s per validation segment for θ_0 and the calibrated θ;
//! 5. the spread of the step-1 estimates θ_B,I (3-step method);
//! 6. residual time series: the one-step heading residual and the
//!    dead-reckoning position error along the validation segments, one
//!    figure per drive on that drive's own clock;
//! 7. the warnings and notes.
//!
//! [`history::render_history_html`] draws a vehicle's calibration history
//! (each parameter over the recorded calibrations with its σ and the drift
//! flags). [`plots`] holds the small SVG figure kit that the experiment figures use
//! too (plotters with its SVG backend only).
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use odocal::{segment, sim, Theta};
//! use odocal_report::{render_html, ParamRow, ReportInput};
//! let out = sim::simulate(&sim::SimOptions { length_km: 2.0, ..sim::SimOptions::paper(3) })?;
//! let segs = segment::validation_segments(&out.drive, &Default::default())?;
//! let truth = out.sidecar.theta_true;
//! let input = ReportInput {
//!     params: ParamRow::theta_rows(&Theta::PAPER_INITIAL, &truth, None, Some(&truth)),
//!     ..ReportInput::new("demo", &out.drive, &segs, Theta::PAPER_INITIAL, truth)
//! };
//! let html = render_html(&input)?;
//! assert!(html.contains("<section id=\"map\">") && html.contains("<svg"));
//! # Ok(()) }
//! ```

pub mod history;
pub mod plots;
mod sections;

use odocal::model::{Theta, THETA_NAMES};
use odocal::segment::{Segment, SegmentData};
use odocal::{Drive, Extrinsics};

/// Errors of the report renderer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// A figure could not be drawn.
    #[error("report figure: {0}")]
    Draw(String),
    /// Writing the report failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The input cannot be shown (no validation segments, say).
    #[error("report: {0}")]
    Input(String),
}

/// The renderer's result type.
pub type Result<T, E = ReportError> = std::result::Result<T, E>;

/// One row of the parameter table.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamRow {
    /// Parameter name (`c_e`, …).
    pub name: String,
    /// Display unit (`m`, `mm`, `mm/(m/s²)`, `rad`, …).
    pub unit: String,
    /// SI value × `scale` = value in the display unit.
    pub scale: f64,
    /// Initial value, SI.
    pub initial: f64,
    /// Calibrated value, SI.
    pub calibrated: f64,
    /// 1σ, SI; `None` when the parameter has none: shown as "held" when it
    /// did not move from its initial value, else "–".
    pub sigma: Option<f64>,
    /// The truth, SI, when known.
    pub truth: Option<f64>,
    /// The heading of this row's σ when it is not the table's
    /// ([`ReportInput::sigma_label`]): the reference extrinsics' σ is their
    /// cluster-robust or model σ, not θ's σ for the next drive. A row whose
    /// label differs from the one in force starts a block headed "reference
    /// extrinsics" with this label over the σ column.
    pub sigma_label: Option<String>,
    /// The data cannot determine this parameter
    /// ([`odocal::CalibrationReport::observability`]): its σ is shown
    /// marked "not observable" and the table is followed by the line the
    /// text report prints, since value and σ are not to be trusted.
    pub not_observable: bool,
}

impl ParamRow {
    /// Rows for the four θ entries in their usual display units (c_d in mm,
    /// d in mm per m/s²). `sigma[i] = None` marks a held parameter.
    pub fn theta_rows(
        initial: &Theta,
        calibrated: &Theta,
        sigma: Option<[Option<f64>; 4]>,
        truth: Option<&Theta>,
    ) -> Vec<ParamRow> {
        let units = [("m", 1.0), ("mm", 1e3), ("m", 1.0), ("mm/(m/s²)", 1e3)];
        (0..4)
            .map(|i| ParamRow {
                name: THETA_NAMES[i].to_string(),
                unit: units[i].0.to_string(),
                scale: units[i].1,
                initial: <[_; 4]>::from(initial)[i],
                calibrated: <[_; 4]>::from(calibrated)[i],
                sigma: sigma.and_then(|s| s[i]),
                truth: truth.map(|t| <[_; 4]>::from(t)[i]),
                sigma_label: None,
                not_observable: false,
            })
            .collect()
    }
}

impl ParamRow {
    /// Rows for the reference extrinsics (lever arm in m, heading offset in
    /// mrad) with the σ that stands for them
    /// (the cluster-robust σ when it was computed, else the model σ),
    /// labelled `± 1σ (robust)` or `± 1σ (model)` as the text labels it;
    /// held entries have no σ. After a joint calibration with a heading
    /// offset per drive, the row `heading_offset` is their mean and a row
    /// `heading_offset, drive k` follows for each, as the text lists them.
    pub fn extrinsics_rows(x: &odocal::ExtrinsicsEstimate) -> Vec<ParamRow> {
        let sd = x.robust.as_ref().map_or(x.std_dev, |r| r.std_dev);
        let (init, val, sd) = (<[_; 3]>::from(x.initial), <[_; 3]>::from(x.value), <[_; 3]>::from(sd));
        let label = if x.robust.is_some() { "± 1σ (robust)" } else { "± 1σ (model)" };
        let per_drive = heading_offsets_per_drive(x).into_iter().enumerate().map(|(k, (value, sigma))| ParamRow {
            name: format!("heading_offset, drive {}", k + 1),
            unit: "mrad".into(),
            scale: 1e3,
            initial: init[2],
            calibrated: value,
            sigma: Some(sigma),
            truth: None,
            sigma_label: Some(label.to_string()),
            not_observable: false,
        });
        [odocal::Param::LeverX, odocal::Param::LeverY, odocal::Param::HeadingOffset]
            .into_iter()
            .enumerate()
            .map(|(i, p)| {
                let (unit, scale) = if i == 2 { ("mrad", 1e3) } else { ("m", 1.0) };
                ParamRow {
                    name: p.to_string(),
                    unit: unit.to_string(),
                    scale,
                    initial: init[i],
                    calibrated: val[i],
                    sigma: x.free.contains(p).then_some(sd[i]),
                    truth: None,
                    sigma_label: Some(label.to_string()),
                    not_observable: false,
                }
            })
            .chain(per_drive)
            .collect()
    }
}

/// A joint calibration's heading offset of each drive, in drive order, with
/// the 1σ that stands for it (cluster-robust when computed, else the model
/// σ), rad, read from the estimate's JSON `per_drive`; empty for one drive
/// or the heading offset held.
fn heading_offsets_per_drive(x: &odocal::ExtrinsicsEstimate) -> Vec<(f64, f64)> {
    let json = serde_json::to_value(x).unwrap_or_default();
    let Some(drives) = json["per_drive"].as_array() else { return Vec::new() };
    drives
        .iter()
        .filter_map(|d| {
            let sigma = d["robust_std_dev"].as_f64().or(d["std_dev"].as_f64())?;
            Some((d["value"].as_f64()?, sigma))
        })
        .collect()
}

/// Everything the HTML report shows. Build with [`ReportInput::new`] and
/// fill in what is known.
#[derive(Debug, Clone)]
pub struct ReportInput<'a> {
    /// Page title (the input file, usually).
    pub title: String,
    /// Key–value lines shown under the title: method, odocal version, date, input…
    pub provenance: Vec<(String, String)>,
    /// The verdict (`accepted`, `doubtful`, `rejected`) and its reasons.
    pub verdict: Option<(String, Vec<String>)>,
    /// The parameter table.
    pub params: Vec<ParamRow>,
    /// The drive the validation segments come from; joined from several
    /// ([`Drive::concat`]), each drive's segments are named by it and timed
    /// on its own clock ([`Drive::own_time_s`]), and its residuals drawn
    /// apart.
    pub drive: &'a Drive,
    /// The names of the drives [`ReportInput::drive`] was joined from, one
    /// per [`Drive::drive_starts`] (e.g. their files). Empty or short:
    /// `drive 1`, `drive 2`, … for those without one.
    pub drive_names: Vec<String>,
    /// The validation segments.
    pub validation_segments: &'a [Segment],
    /// The initial θ_0.
    pub theta0: Theta,
    /// The calibrated θ.
    pub theta: Theta,
    /// The true θ, when known (simulated drives).
    pub truth: Option<Theta>,
    /// The true reference extrinsics that go with [`ReportInput::truth`]
    /// (a simulated drive's [`odocal::sim::SimOptions::reference_mount`]),
    /// with which the truth's Ē_p and errors are computed, as the text and
    /// JSON reports compute them. Default 0: the reference at the rear-axle
    /// centre, where the simulator puts it unless told otherwise.
    pub truth_extrinsics: Extrinsics,
    /// Step-1 estimates θ_B,I with their Ē_p (3-step method); empty otherwise.
    pub batches: Vec<(Theta, f64)>,
    /// Warnings, one per line.
    pub warnings: Vec<String>,
    /// The method's own account of the fit, one line each (for EIV: the
    /// filter, the noise model at the start and as estimated, the bias
    /// correction, and whether the result is the
    /// EIV estimate or the batch G-N fallback). Shown as text under the
    /// parameter table; the section is left out when empty.
    pub method_details: Vec<String>,
    /// How many validation segments the map shows (default 4).
    pub map_segments: usize,
    /// The reference extrinsics `[θ_0's, θ's]` of each validation segment
    /// (e.g. [`odocal::CalibrationReport::validation_extrinsics`]), so that
    /// the errors and the map are those the calibration's Ē_p is made of.
    /// Empty: the reference at the rear-axle centre for every segment.
    pub segment_extrinsics: Vec<[Extrinsics; 2]>,
    /// The σ column's heading: the σ that stands for the result, labelled
    /// once (e.g. `± 1σ (next drive)`). Default `± 1σ`.
    pub sigma_label: String,
    /// What data Ē_p, the map and the residuals come from, shown at the top
    /// of the validation section: the first line says it (the calibrated
    /// drive, its held-out half, or other drives), each further line one
    /// validation drive. Empty: not said.
    pub validation_data: Vec<String>,
    /// The EIV fit's θ when the default method fell back to batch
    /// Gauss-Newton: the estimate not used, shown beside θ in a column
    /// "EIV (unused)" as the text report shows it. `None`: no column.
    pub eiv_unused: Option<Theta>,
}

impl<'a> ReportInput<'a> {
    /// The minimal input: a title, the drive and its validation segments, θ_0
    /// and the calibrated θ.
    pub fn new(
        title: impl Into<String>,
        drive: &'a Drive,
        validation_segments: &'a [Segment],
        theta0: Theta,
        theta: Theta,
    ) -> Self {
        ReportInput {
            title: title.into(),
            provenance: Vec::new(),
            verdict: None,
            params: ParamRow::theta_rows(&theta0, &theta, None, None),
            drive,
            drive_names: Vec::new(),
            validation_segments,
            theta0,
            theta,
            truth: None,
            truth_extrinsics: Extrinsics::default(),
            batches: Vec::new(),
            warnings: Vec::new(),
            method_details: Vec::new(),
            map_segments: 4,
            segment_extrinsics: Vec::new(),
            sigma_label: "± 1σ".into(),
            validation_data: Vec::new(),
            eiv_unused: None,
        }
    }

    /// The input for a calibration `report` on the drive it was validated
    /// on (`drive`, its validation segments `segments`; `starts`: the first
    /// sample of each drive joined in it), with the true θ when known: the
    /// parameter table with the σ that stands for the result (and the
    /// reference extrinsics when estimated), the verdict, the step-1
    /// estimates, the warnings, the method's account, each segment's
    /// extrinsics and the validation drives' names. The provenance lines
    /// (and the names of a joint calibration's own drives) are the caller's.
    pub fn of_calibration(
        title: impl Into<String>,
        report: &odocal::CalibrationReport,
        (drive, segments, starts): (&'a Drive, &'a [Segment], &[usize]),
        truth: Option<&Theta>,
    ) -> Self {
        let r = report;
        let mut params =
            ParamRow::theta_rows(&r.initial.theta, &r.theta, Some(<[_; 4]>::from(r.result_sigma())), truth);
        params.extend(r.extrinsics.as_ref().map(ParamRow::extrinsics_rows).unwrap_or_default());
        // The free parameters the data cannot determine, as the parameter
        // file marks them (`*_observable: false`).
        let free = r.options.identify.free;
        for p in r.observability.unobservable.into_iter().filter(|p| free.contains(*p)) {
            params.iter_mut().filter(|row| row.name == p.to_string()).for_each(|row| row.not_observable = true);
        }
        let batches = step_one_batches(r);
        ReportInput {
            params,
            truth: truth.copied(),
            verdict: Some((r.verdict.level.to_string(), r.verdict.reasons.iter().map(|x| x.to_string()).collect())),
            batches,
            warnings: r
                .warnings
                .iter()
                .map(|w| if w.is_note() { format!("note: {w}") } else { w.to_string() })
                .collect(),
            method_details: r.method_details().lines().map(str::to_string).collect(),
            segment_extrinsics: r.validation_extrinsics(starts, segments),
            // The σ that stands for the result, labelled once (as the text's column).
            sigma_label: match r.result_sigma().covers {
                odocal::SigmaCovers::NextDrive => "± 1σ (next drive)".into(),
                odocal::SigmaCovers::WithinDrive => "± 1σ (within drive)".into(),
            },
            validation_data: validation_data(r),
            eiv_unused: eiv_unused(r),
            drive_names: r
                .validate_on
                .as_ref()
                .filter(|v| v.drives.len() == drive.drive_starts().len())
                .map(|v| v.drives.iter().map(|d| d.name.clone()).collect())
                .unwrap_or_default(),
            ..ReportInput::new(title, drive, segments, r.initial.theta, r.theta)
        }
    }

    /// The input with the import's warnings (`source: warning`, as the CLI
    /// prints them and the JSON's `import_warnings` holds them) listed
    /// before the calibration's.
    pub fn with_import_warnings(mut self, import: Vec<String>) -> Self {
        self.warnings = import.into_iter().chain(self.warnings).collect();
        self
    }

    /// The extrinsics `[θ_0's, θ's]` of validation segment `i`.
    fn extrinsics_of(&self, i: usize) -> [Extrinsics; 2] {
        self.segment_extrinsics.get(i).copied().unwrap_or([Extrinsics::default(); 2])
    }

    /// How many drives [`ReportInput::drive`] was joined from.
    fn drives(&self) -> usize {
        self.drive.drive_starts().len().max(1)
    }

    /// The name of drive `k` ([`ReportInput::drive_names`]).
    fn drive_name(&self, k: usize) -> String {
        self.drive_names.get(k).cloned().unwrap_or_else(|| format!("drive {}", k + 1))
    }

    /// The name of drive `k` for figures and the lines under them: its
    /// file's name without the folders, unless another drive's is the same.
    fn drive_label(&self, k: usize) -> String {
        let short = |k: usize| -> String {
            let name = self.drive_name(k);
            std::path::Path::new(&name).file_name().and_then(|f| f.to_str()).map_or(name.clone(), str::to_string)
        };
        let mine = short(k);
        if (0..self.drives()).filter(|&j| j != k).any(|j| short(j) == mine) {
            self.drive_name(k)
        } else {
            mine
        }
    }

    /// The index of the drive sample `i` of [`ReportInput::drive`] came from.
    fn drive_of(&self, i: usize) -> usize {
        self.drive.drive_starts().partition_point(|&b| b <= i).saturating_sub(1)
    }

    /// The samples of drive `k` in [`ReportInput::drive`].
    fn drive_samples(&self, k: usize) -> std::ops::Range<usize> {
        let starts = self.drive.drive_starts();
        let start = starts.get(k).copied().unwrap_or(0);
        start..starts.get(k + 1).copied().unwrap_or(self.drive.len())
    }
}

/// What a calibration's Ē_p was measured on ([`ReportInput::validation_data`]),
/// as the text report heads it: held-out data (other drives, one line each,
/// or a held-out half) or the calibrated drive itself.
fn validation_data(r: &odocal::CalibrationReport) -> Vec<String> {
    if let Some(v) = &r.validate_on {
        let mut lines = vec![format!(
            "Held-out data, not used for calibration: {} other drive(s) of the vehicle (Ē_p calibrated / θ_0; \
             each with the reference extrinsics that apply to it on that drive, θ_0's where they differ from θ's):",
            v.drives.len()
        )];
        lines.extend(v.drives.iter().map(|d| {
            let extrinsics =
                d.reference_extrinsics().map(|x| format!("; reference extrinsics: {x}")).unwrap_or_default();
            format!(
                "{}: {:.3} m / {:.3} m ({} segments){extrinsics}",
                d.name, d.mean_position_error_m, d.initial_mean_position_error_m, d.segments
            )
        }));
        if v.drives.len() > 1 {
            // Not the table's Ē_p: there each segment weighs the same.
            lines.push(format!(
                "Mean of the {} drives' Ē_p (each drive weighs the same): {:.3} m / {:.3} m; the table's Ē_p is \
                 over all their segments (each segment weighs the same).",
                v.drives.len(),
                v.mean_over_drives_m,
                v.initial_mean_over_drives_m
            ));
        }
        return lines;
    }
    if r.validation.held_out {
        return vec!["Held-out data, not used for calibration: the half of the drive held out.".into()];
    }
    vec!["The calibrated drive itself: Ē_p there flatters the fit; held-out data (a held-out half, or other \
          drives of the vehicle) is the evidence that counts."
        .into()]
}

/// Step 1's batch results of a 3-step calibration, each θ_B with its Ē_p,
/// read from the report's JSON (`initial_step.batches`); empty for the
/// other methods.
fn step_one_batches(r: &odocal::CalibrationReport) -> Vec<(Theta, f64)> {
    let Ok(v) = serde_json::to_value(r) else { return Vec::new() };
    let Some(batches) = v["initial_step"]["batches"].as_array() else { return Vec::new() };
    batches
        .iter()
        .filter_map(|b| {
            let theta: Theta = serde_json::from_value(b["score"]["theta"].clone()).ok()?;
            Some((theta, b["score"]["mean_position_error_m"].as_f64().unwrap_or(f64::NAN)))
        })
        .collect()
}

/// The EIV fit's θ of a calibration that fell back to batch Gauss-Newton
/// (JSON `eiv_result` `"batch-gn-fallback"`, `eiv.theta`), as the text
/// report's column "EIV (unused)"; `None` otherwise.
fn eiv_unused(r: &odocal::CalibrationReport) -> Option<Theta> {
    let v = serde_json::to_value(r).ok()?;
    if v["eiv_result"] != "batch-gn-fallback" {
        return None;
    }
    serde_json::from_value(v["eiv"]["theta"].clone()).ok()
}

/// Escapes text for HTML.
fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

/// Dead reckoning of one segment from its reference start pose under the
/// extrinsics `e`: the reference point's (x, y) per sample.
fn dead_reckoning(seg: &SegmentData<'_>, theta: &Theta, e: &Extrinsics) -> Vec<(f64, f64)> {
    odocal::dead_reckoning(seg, theta, e).1
}

/// Thins a polyline to at most `max` points (keeps the last).
fn thin(points: Vec<(f64, f64)>, max: usize) -> Vec<(f64, f64)> {
    if points.len() <= max || max < 2 {
        return points;
    }
    let stride = points.len().div_ceil(max - 1);
    let last = points.last().copied();
    let mut out: Vec<(f64, f64)> = points.into_iter().step_by(stride).collect();
    if let Some(l) = last {
        if out.last() != Some(&l) {
            out.push(l);
        }
    }
    out
}

/// Renders the self-contained HTML report.
///
/// # Errors
/// [`ReportError::Input`] without validation segments; [`ReportError::Draw`]
/// when a figure fails.
pub fn render_html(r: &ReportInput<'_>) -> Result<String> {
    if r.validation_segments.is_empty() {
        return Err(ReportError::Input("no validation segments to show".into()));
    }
    let segs: Vec<SegmentData<'_>> = r.validation_segments.iter().map(|s| SegmentData::new(r.drive, s)).collect();
    let errors = sections::SegmentErrors::new(r, &segs);
    let mut h = String::new();
    sections::head(&mut h, r);
    sections::verdict(&mut h, r);
    sections::parameters(&mut h, r);
    sections::validation(&mut h, r, &errors)?;
    sections::map(&mut h, r, &segs, &errors.initial)?;
    sections::batches(&mut h, r)?;
    sections::residuals(&mut h, r, &segs)?;
    sections::warnings(&mut h, r);
    Ok(h)
}

/// Renders the report and writes it to `path`, atomically
/// ([`odocal::output::write_text`]).
///
/// # Errors
/// As [`render_html`], and [`ReportError::Io`].
pub fn write_html(path: &std::path::Path, r: &ReportInput<'_>) -> Result<()> {
    let html = render_html(r)?;
    odocal::output::write_text(path, &html).map_err(write_error)
}

/// The report error of a failed write ([`odocal::output::write_text`]).
pub(crate) fn write_error(e: odocal::Error) -> ReportError {
    match e {
        odocal::Error::Io { path, source } => ReportError::Io { path, source },
        e => ReportError::Io { path: std::path::PathBuf::new(), source: std::io::Error::other(e.to_string()) },
    }
}

const CSS: &str = "body{font-family:sans-serif;max-width:960px;margin:2em auto;color:#222;line-height:1.4}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}\
td:first-child,th:first-child{text-align:left}.prov{color:#555;font-size:.9em}\
.verdict{display:inline-block;padding:.3em .9em;border-radius:.3em;font-weight:bold;font-size:1.2em;text-transform:uppercase}\
.accepted{background:#d4f4dd;color:#0a5c2b}.doubtful{background:#fff2cc;color:#7a5a00}.rejected{background:#fadbd8;color:#8a1c12}\
.none{background:#eee;color:#555}svg{max-width:100%;height:auto;display:block;margin:.5em 0}\
pre{white-space:pre-wrap;font-size:.85em;background:#f7f7f7;padding:.5em}";

#[cfg(test)]
mod tests {
    use super::*;
    use odocal::{segment, sim};

    fn parse_all(xml: &str) {
        let mut r = quick_xml::Reader::from_str(xml);
        loop {
            match r.read_event() {
                Ok(quick_xml::events::Event::Eof) => break,
                Ok(_) => {}
                Err(e) => panic!("not well-formed at {}: {e}", r.buffer_position()),
            }
        }
    }

    #[test]
    fn report_is_well_formed_and_complete() {
        let out = sim::simulate(&sim::SimOptions { length_km: 2.0, ..sim::SimOptions::paper(5) }).expect("sim");
        let segs = segment::validation_segments(&out.drive, &Default::default()).expect("segments");
        let truth = out.sidecar.theta_true;
        let th0 = Theta::PAPER_INITIAL;
        let input = ReportInput {
            params: ParamRow::theta_rows(&th0, &truth, Some([Some(1e-4), None, Some(1e-3), Some(1e-5)]), Some(&truth)),
            verdict: Some(("accepted".into(), vec!["Ē_p 10 m < θ_0's 28 m <&>".into()])),
            truth: Some(truth),
            batches: vec![(th0, 20.0), (truth, 10.0)],
            warnings: vec!["a <warning>".into()],
            method_details: vec!["EIV: 1 window(s)".into(), "  noise, estimated: σ_white <1 %>".into()],
            ..ReportInput::new("sim <2 km>", &out.drive, &segs, th0, truth)
        };
        let html = render_html(&input).expect("render");
        assert!(
            html.contains("<pre>EIV: 1 window(s)\n  noise, estimated: σ_white &lt;1 %&gt;\n</pre>"),
            "method details"
        );
        let plain = render_html(&ReportInput { method_details: Vec::new(), ..input.clone() }).expect("render");
        assert!(!plain.contains("<section id=\"method\">"), "no details, no section");
        for id in ["verdict", "parameters", "method", "validation", "map", "batches", "residuals", "warnings"] {
            assert!(html.contains(&format!("<section id=\"{id}\">")), "section {id}");
        }
        // c_d has no σ and moved: no "held"; a parameter that did not move is held.
        assert!(!html.contains("<td>held</td>") && html.contains("<td>–</td>"));
        let still = ReportInput {
            params: ParamRow::theta_rows(&th0, &th0, Some([Some(1e-4), None, Some(1e-3), Some(1e-5)]), None),
            ..input.clone()
        };
        assert!(render_html(&still).expect("render").contains("<td>held</td>"));
        assert!(html.contains("&lt;warning&gt;") && !html.contains("<warning>"));
        assert!(!html.contains("<script"), "no scripts");
        assert!(!html.contains("src=\"http") && !html.contains("href=\"http"), "no network fetches");
        // Well-formed as XML (the page is XHTML-compatible), SVGs included.
        let body = html.trim_start_matches("<!DOCTYPE html>\n");
        parse_all(body);
        assert!(html.matches("<svg").count() >= 4);
    }

    #[test]
    fn step_one_batches_come_from_the_three_step_report() {
        let out = sim::simulate(&sim::SimOptions { length_km: 3.0, ..sim::SimOptions::paper(2) }).expect("sim");
        let opts =
            odocal::CalibrationOptions { method: odocal::Method::ThreeStep(Default::default()), ..Default::default() };
        let r = odocal::calibrate(&out.drive, &opts).expect("3-step");
        let v = serde_json::to_value(&r).expect("json");
        let want = v["initial_step"]["batches"].as_array().expect("step 1's batches").len();
        let got = step_one_batches(&r);
        assert!(want > 0 && got.len() == want, "{} of {want}", got.len());
        let first = &v["initial_step"]["batches"][0]["score"];
        assert_eq!(got[0].0.c_e.to_bits(), first["theta"]["c_e"].as_f64().expect("c_e").to_bits());
        assert_eq!(got[0].1.to_bits(), first["mean_position_error_m"].as_f64().expect("Ē_p").to_bits());
        let eiv = odocal::calibrate(&out.drive, &odocal::CalibrationOptions::default()).expect("eiv");
        assert!(step_one_batches(&eiv).is_empty(), "EIV has no step 1");
    }

    /// batch-gn and the 3-step method fill the method details with their
    /// account of the fit (as the terminal prints it), not an empty section.
    #[test]
    fn batch_gn_and_three_step_have_method_details() {
        let out = sim::simulate(&sim::SimOptions { length_km: 3.0, ..sim::SimOptions::paper(2) }).expect("sim");
        let segs = segment::validation_segments(&out.drive, &Default::default()).expect("segments");
        for (method, want) in [
            (odocal::Method::BatchGn, ["batch G-N: ", "robust σ: "]),
            (odocal::Method::ThreeStep(Default::default()), ["step 2: ", "step 3: "]),
        ] {
            let opts = odocal::CalibrationOptions { method, ..Default::default() };
            let r = odocal::calibrate(&out.drive, &opts).expect("calibrate");
            let input = ReportInput::of_calibration("d.csv", &r, (&out.drive, &segs, &[0]), None);
            let html = render_html(&input).expect("render");
            let section = html.split("<section id=\"method\">").nth(1).expect("method section");
            let section = section.split("</section>").next().expect("section end");
            for w in want {
                assert!(section.contains(w), "{}: {w} in {section}", r.method);
            }
            assert!(r.render_text(None, None, None).contains(&r.method_details()), "the terminal's lines");
            assert!(!html.contains("EIV (unused)"), "{}: no EIV fit, no column", r.method);
        }
    }

    /// A default-method calibration that fell back to batch Gauss-Newton
    /// (a fixed noise model far below the drive's) shows the EIV fit it
    /// did not use, as the text report's column "EIV (unused)" does.
    #[test]
    fn a_fallback_shows_the_unused_eiv_fit_as_the_text_does() {
        let out = sim::simulate(&sim::SimOptions { length_km: 6.0, ..sim::SimOptions::paper(5) }).expect("sim");
        let segs = segment::validation_segments(&out.drive, &Default::default()).expect("segments");
        let tiny = odocal::eiv::NoiseModel {
            wheel_white_rel_sigma: 1e-4,
            wheel_common_rel_sigma: 1e-5,
            wheel_differential_rel_sigma: 1e-5,
            position_white_sigma_m: 1e-3,
            position_drift_sigma_m: 1e-3,
            heading_drift_sigma_rad: 1e-5,
            ..Default::default()
        };
        let filter = odocal::eiv::EivOptions { noise: tiny, fix_noise: true, ..Default::default() };
        let method = odocal::Method::Eiv(odocal::EivMethodOptions { filter, fallback: true, ..Default::default() });
        let r = odocal::calibrate(&out.drive, &odocal::CalibrationOptions { method, ..Default::default() })
            .expect("calibrate");
        let v = serde_json::to_value(&r).expect("json");
        assert_eq!(v["eiv_result"], "batch-gn-fallback", "the fit falls back");
        let text = r.render_text(None, None, None);
        assert!(text.contains("EIV (unused)"), "{text}");
        let eiv: Theta = serde_json::from_value(v["eiv"]["theta"].clone()).expect("the EIV fit's θ");
        let input = ReportInput::of_calibration("d.csv", &r, (&out.drive, &segs, &[0]), None);
        assert_eq!(input.eiv_unused, Some(eiv));
        let html = render_html(&input).expect("render");
        let table = html.split("<section id=\"parameters\">").nth(1).expect("parameters");
        let table = table.split("</table>").next().expect("table end");
        assert!(table.contains("<th>EIV (unused)</th>"), "{table}");
        // Each θ row ends with the EIV value, in the row's unit (t_r in m, d in mm/(m/s²)).
        for (name, value) in [("t_r", format!("{:.6}", eiv.t_r)), ("d", format!("{:.6}", eiv.d * 1e3))] {
            let row = table.lines().find(|l| l.starts_with(&format!("<tr><td>{name}</td>"))).expect("row");
            assert!(row.ends_with(&format!("<td>{value}</td></tr>")), "{row}");
        }
        parse_all(html.trim_start_matches("<!DOCTYPE html>\n"));
    }

    #[test]
    fn no_segments_is_an_error() {
        let out = sim::simulate(&sim::SimOptions {
            length_km: 1.0,
            noise: "off".parse().expect("the off preset"),
            ..sim::SimOptions::paper(1)
        })
        .expect("sim");
        let input = ReportInput::new("x", &out.drive, &[], Theta::PAPER_INITIAL, Theta::PAPER_INITIAL);
        assert!(matches!(render_html(&input), Err(ReportError::Input(_))));
    }
}
