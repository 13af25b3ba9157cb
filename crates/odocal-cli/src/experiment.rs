//! `odocal experiment`: the paper's §6 on a simulated (or given) drive in one
//! command — batch calibrations (Fig. 4), picked θ_B,I (Fig. 5), compensated
//! inputs (Fig. 6), per-segment and batch estimates with raw vs compensated
//! inputs (Fig. 7/8, Table 1), θ_nom and the reachable minimum — written as
//! `report.md`, SVG figures and `experiment.json`.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use odocal::model::{step, Theta};
use odocal::pipeline::{
    calibrate_detailed, per_segment_identification, score_batches, BatchResult, CalibrationOptions, CompensationStep,
    DetailedCalibration, SegmentCounts,
};
use odocal::segment::SegmentData;
use odocal::sim::{self, NoiseOptions, SimOptions};
use odocal::{mean_position_error, reachable_minimum, Drive, ReachableOptions};
use serde::Serialize;

use crate::plots::{self, figure, HLine, Panel, Series};
use crate::progress::Bars;
use crate::ExperimentArgs;

/// A θ with its validation error and, when the truth is known, its error.
#[derive(Debug, Clone, Copy, Serialize)]
struct Scored {
    theta: Theta,
    /// Ē_p, m.
    mean_position_error_m: f64,
    /// θ − θ_true, SI units (None without truth).
    error_vs_true: Option<Theta>,
}

#[derive(Debug, Clone, Serialize)]
struct DriveInfo {
    source: String,
    samples: usize,
    distance_km: f64,
    sample_time_s: f64,
    seed: Option<u64>,
    noise: Option<String>,
    wheel_rotation_rel_error_rms: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
struct BatchRow {
    segment_starts: Vec<usize>,
    raw: Scored,
    /// G-N from θ_0 on the same segments with compensated inputs (segments
    /// whose compensation failed are left out).
    compensated: Option<Scored>,
    compensated_segments: usize,
}

#[derive(Debug, Clone, Serialize)]
struct SegmentRow {
    start: usize,
    peak_yaw_rate_rad_per_s: f64,
    raw: Option<Scored>,
    compensated: Option<Scored>,
}

#[derive(Debug, Clone, Serialize)]
struct Table1 {
    segment_start: usize,
    segment_raw: Scored,
    segment_compensated: Scored,
    batch_index: usize,
    batch_starts: Vec<usize>,
    batch_raw: Scored,
    batch_compensated: Scored,
}

/// Summary statistics of a set of estimates.
#[derive(Debug, Clone, Serialize)]
struct Summary {
    count: usize,
    min_mean_position_error_m: f64,
    median_mean_position_error_m: f64,
    max_mean_position_error_m: f64,
    /// Median |θ − θ_true| per parameter, SI.
    median_abs_error_vs_true: Option<Theta>,
}

#[derive(Debug, Clone, Serialize)]
struct Figure6 {
    segment_start: usize,
    /// θ of the dead reckoning (θ_B,F).
    theta: Theta,
    /// RMS of measured − true wheel rotations, rev/s (simulated drives).
    rms_measured_input_error_rev_per_s: Option<f64>,
    /// RMS of compensated − true wheel rotations, rev/s.
    rms_compensated_input_error_rev_per_s: Option<f64>,
    /// Mean position error of dead reckoning with measured inputs, m.
    mean_position_error_measured_m: f64,
    /// Mean position error of dead reckoning with compensated inputs, m.
    mean_position_error_compensated_m: f64,
}

#[derive(Debug, Clone, Default, Serialize)]
struct ExperimentTiming {
    simulate: f64,
    calibrate: f64,
    per_segment: f64,
    compensated_batches: f64,
    reachable_minimum: f64,
    figures: f64,
    total: f64,
}

#[derive(Debug, Clone, Serialize)]
struct ReachableSummary {
    #[serde(flatten)]
    scored: Scored,
    evaluations: usize,
    time_s: f64,
    termination: String,
}

/// Every number of the report.
#[derive(Debug, Clone, Serialize)]
struct Experiment {
    drive: DriveInfo,
    segments: SegmentCounts,
    qp_solver: String,
    truth: Option<Scored>,
    nominal: Scored,
    initial_guess: Scored,
    batch_size: usize,
    batches: Vec<BatchRow>,
    picked_batches: Vec<usize>,
    picked: Vec<Scored>,
    final_estimate: Scored,
    final_identification: String,
    reachable_minimum: ReachableSummary,
    table1: Table1,
    per_segment: Vec<SegmentRow>,
    summary_batches_raw: Summary,
    summary_batches_compensated: Summary,
    summary_segments_raw: Summary,
    summary_segments_compensated: Summary,
    compensation: CompensationStep,
    figure6: Figure6,
    figures: Vec<String>,
    warnings: Vec<String>,
    timing_s: ExperimentTiming,
}

fn diff(a: &Theta, b: &Theta) -> Theta {
    Theta { c_e: a.c_e - b.c_e, c_d: a.c_d - b.c_d, t_r: a.t_r - b.t_r, d: a.d - b.d }
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn summarize<'a>(items: impl Iterator<Item = &'a Scored>) -> Summary {
    let items: Vec<&Scored> = items.collect();
    let mut e: Vec<f64> = items.iter().map(|s| s.mean_position_error_m).collect();
    let med = median(&mut e);
    let err = if items.iter().all(|s| s.error_vs_true.is_some()) && !items.is_empty() {
        let col = |f: fn(&Theta) -> f64| {
            let mut v: Vec<f64> = items.iter().filter_map(|s| s.error_vs_true.as_ref().map(|t| f(t).abs())).collect();
            median(&mut v)
        };
        Some(Theta { c_e: col(|t| t.c_e), c_d: col(|t| t.c_d), t_r: col(|t| t.t_r), d: col(|t| t.d) })
    } else {
        None
    };
    Summary {
        count: items.len(),
        min_mean_position_error_m: e.first().copied().unwrap_or(f64::NAN),
        median_mean_position_error_m: med,
        max_mean_position_error_m: e.last().copied().unwrap_or(f64::NAN),
        median_abs_error_vs_true: err,
    }
}

/// Runs the experiment.
pub fn run(a: ExperimentArgs, bars: &Bars) -> Result<()> {
    let t_total = Instant::now();
    let mut timing = ExperimentTiming::default();
    if a.batches == 0 {
        bail!("--batches must be at least 1");
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;

    // The drive and its truth.
    let t = Instant::now();
    let (drive, theta_true, info) = match &a.drive {
        Some(path) => {
            let drive = Drive::read_csv(path)?;
            let side = sim::sidecar_path(path);
            let sidecar = if side.exists() {
                Some(sim::SimSidecar::read_json(&side).with_context(|| format!("reading {}", side.display()))?)
            } else {
                None
            };
            let info = DriveInfo {
                source: path.display().to_string(),
                samples: drive.len(),
                distance_km: drive.distance_m() / 1e3,
                sample_time_s: drive.sample_time_s(),
                seed: sidecar.as_ref().map(|s| s.settings.seed),
                noise: None,
                wheel_rotation_rel_error_rms: sidecar.as_ref().map(|s| s.stats.wheel_rotation_rel_error_rms),
            };
            (drive, sidecar.map(|s| s.theta_true), info)
        }
        None => {
            let noise = NoiseOptions::by_name(&a.noise)?;
            let o = SimOptions { seed: a.seed, length_km: a.length_km, noise, ..SimOptions::paper(a.seed) };
            bars.stage("simulating");
            let out = sim::simulate(&o)?;
            bars.finish();
            let s = &out.sidecar.stats;
            let info = DriveInfo {
                source: format!("simulated (seed {}, {} km, noise '{}')", a.seed, a.length_km, a.noise),
                samples: s.samples,
                distance_km: s.distance_m / 1e3,
                sample_time_s: out.drive.sample_time_s(),
                seed: Some(a.seed),
                noise: Some(a.noise.clone()),
                wheel_rotation_rel_error_rms: Some(s.wheel_rotation_rel_error_rms),
            };
            (out.drive, Some(out.sidecar.theta_true), info)
        }
    };
    timing.simulate = t.elapsed().as_secs_f64();

    // The 3-step calibration (steps 1–3), keeping the compensated inputs.
    let t = Instant::now();
    let opts =
        CalibrationOptions { seed: a.seed, qp_solver: a.qp_solver, initial_batches: a.batches, ..Default::default() };
    let cb = |e| bars.event(e);
    let det: DetailedCalibration = calibrate_detailed(&drive, None, &opts, Some(&cb))?;
    bars.finish();
    timing.calibrate = t.elapsed().as_secs_f64();
    let r = &det.report;
    let (init, comp) = match (&r.initial_step, &det.compensated) {
        (Some(i), Some(c)) => (i, c),
        _ => bail!("the 3-step calibration returned no step 1/2 results"),
    };
    let validation = &det.validation;
    let score = |theta: &Theta| -> Result<Scored> {
        let v = mean_position_error(&drive, validation, theta)?;
        Ok(Scored {
            theta: *theta,
            mean_position_error_m: v.mean_position_error_m,
            error_vs_true: theta_true.as_ref().map(|t| diff(theta, t)),
        })
    };
    let of = |b: &BatchResult| Scored {
        theta: b.score.theta,
        mean_position_error_m: b.score.mean_position_error_m,
        error_vs_true: theta_true.as_ref().map(|t| diff(&b.score.theta, t)),
    };

    // Per-segment G-N, raw and compensated.
    let t = Instant::now();
    bars.stage("per-segment G-N");
    let raw_data: Vec<SegmentData> = det.selected.iter().map(|s| SegmentData::new(&drive, s)).collect();
    let comp_data = comp.segment_data(&drive);
    let raw_seg = per_segment_identification(&drive, &raw_data, validation, &opts.theta0, &opts.identify);
    let comp_seg = per_segment_identification(&drive, &comp_data, validation, &opts.theta0, &opts.identify);
    let comp_index = |start: usize| comp.segments.iter().position(|s| s.start == start);
    let per_segment: Vec<SegmentRow> = det
        .selected
        .iter()
        .zip(&raw_seg)
        .map(|(s, rr)| SegmentRow {
            start: s.start,
            peak_yaw_rate_rad_per_s: s.peak_yaw_rate_rad_per_s,
            raw: rr.as_ref().ok().map(of),
            compensated: comp_index(s.start).and_then(|i| comp_seg[i].as_ref().ok().map(of)),
        })
        .collect();
    bars.finish();
    timing.per_segment = t.elapsed().as_secs_f64();

    // The step-1 batches again, with compensated inputs.
    let t = Instant::now();
    let comp_batches: Vec<Vec<usize>> =
        init.batches.iter().map(|b| b.segment_starts.iter().filter_map(|&s| comp_index(s)).collect()).collect();
    let comp_results = score_batches(&drive, &comp_data, &comp_batches, validation, &opts.theta0, &opts.identify, None);
    let batches: Vec<BatchRow> = init
        .batches
        .iter()
        .zip(&comp_results)
        .zip(&comp_batches)
        .map(|((b, c), cb)| BatchRow {
            segment_starts: b.segment_starts.clone(),
            raw: of(b),
            compensated: if cb.is_empty() { None } else { c.as_ref().ok().map(of) },
            compensated_segments: cb.len(),
        })
        .collect();
    timing.compensated_batches = t.elapsed().as_secs_f64();

    // Reference points: truth, θ_nom, θ_0, θ_B,F and the reachable minimum.
    let truth = theta_true.as_ref().map(&score).transpose()?;
    let nominal = score(&Theta::PAPER_NOMINAL)?;
    let initial_guess = score(&opts.theta0)?;
    let final_estimate = score(&r.theta)?;
    let picked: Vec<Scored> = init.picked_batches.iter().map(|&i| of(&init.batches[i])).collect();
    let t = Instant::now();
    let mut starts: Vec<Theta> = picked.iter().map(|p| p.theta).collect();
    starts.push(r.theta);
    let ro = ReachableOptions { seed: a.seed, starts, ..ReachableOptions::around(&opts.theta0) };
    bars.stage("reachable minimum");
    let rm = reachable_minimum(&drive, validation, &ro)?;
    bars.finish();
    timing.reachable_minimum = t.elapsed().as_secs_f64();
    let reach = ReachableSummary {
        scored: Scored {
            theta: rm.theta,
            mean_position_error_m: rm.mean_position_error_m,
            error_vs_true: theta_true.as_ref().map(|t| diff(&rm.theta, t)),
        },
        evaluations: rm.evaluations,
        time_s: rm.time_s,
        termination: rm.termination.clone(),
    };

    // Table 1: the compensated segment turning hardest, and the middle picked batch.
    let seg_i = (0..comp.segments.len())
        .filter(|&i| comp_seg[i].is_ok())
        .max_by(|&x, &y| comp.segments[x].peak_yaw_rate_rad_per_s.total_cmp(&comp.segments[y].peak_yaw_rate_rad_per_s))
        .context("no compensated segment could be identified on its own")?;
    let seg = comp.segments[seg_i];
    let raw_i = det.selected.iter().position(|s| s.start == seg.start).context("segment not among the selected")?;
    let batch_index = init
        .picked_batches
        .get(init.picked_batches.len() / 2)
        .copied()
        .filter(|&i| batches[i].compensated.is_some())
        .or_else(|| batches.iter().position(|b| b.compensated.is_some()))
        .context("no batch could be identified with compensated inputs")?;
    let table1 = Table1 {
        segment_start: seg.start,
        segment_raw: raw_seg[raw_i].as_ref().map(of).map_err(|e| anyhow::anyhow!("{e}"))?,
        segment_compensated: comp_seg[seg_i].as_ref().map(of).map_err(|e| anyhow::anyhow!("{e}"))?,
        batch_index,
        batch_starts: batches[batch_index].segment_starts.clone(),
        batch_raw: batches[batch_index].raw,
        batch_compensated: batches[batch_index].compensated.context("batch without compensated result")?,
    };

    // Figure 6 numbers: the Table 1 segment, dead reckoning at θ_B,F.
    let fig6 = figure6_data(&drive, &comp_data[seg_i], &raw_data[raw_i], &r.theta);

    let summary_batches_raw = summarize(batches.iter().map(|b| &b.raw));
    let summary_batches_compensated = summarize(batches.iter().filter_map(|b| b.compensated.as_ref()));
    let summary_segments_raw = summarize(per_segment.iter().filter_map(|s| s.raw.as_ref()));
    let summary_segments_compensated = summarize(per_segment.iter().filter_map(|s| s.compensated.as_ref()));

    let mut exp = Experiment {
        drive: info,
        segments: r.segments,
        qp_solver: a.qp_solver.to_string(),
        truth,
        nominal,
        initial_guess,
        batch_size: opts.initial_batch_size,
        batches,
        picked_batches: init.picked_batches.clone(),
        picked,
        final_estimate,
        final_identification: format!(
            "{} segments, {} iterations, {}, rcond {:.2e}",
            r.identification.segments,
            r.identification.iterations,
            r.identification.termination,
            r.identification.observability.rcond
        ),
        reachable_minimum: reach,
        table1,
        per_segment,
        summary_batches_raw,
        summary_batches_compensated,
        summary_segments_raw,
        summary_segments_compensated,
        compensation: comp.step.clone(),
        figure6: fig6.numbers,
        figures: Vec::new(),
        warnings: r.warnings.clone(),
        timing_s: timing,
    };

    let t = Instant::now();
    exp.figures = write_figures(&a.out, &exp, &fig6.curves)?;
    exp.timing_s.figures = t.elapsed().as_secs_f64();
    exp.timing_s.total = t_total.elapsed().as_secs_f64();

    let json_path = a.out.join("experiment.json");
    let text = serde_json::to_string_pretty(&exp)?;
    std::fs::write(&json_path, text + "\n").with_context(|| format!("writing {}", json_path.display()))?;
    let md_path = a.out.join("report.md");
    std::fs::write(&md_path, report_md(&exp)).with_context(|| format!("writing {}", md_path.display()))?;

    const SHOWN_WARNINGS: usize = 3;
    for w in exp.warnings.iter().take(SHOWN_WARNINGS) {
        eprintln!("warning: {w}");
    }
    if exp.warnings.len() > SHOWN_WARNINGS {
        eprintln!("warning: … and {} more (listed in {})", exp.warnings.len() - SHOWN_WARNINGS, md_path.display());
    }
    println!(
        "θ_B,F Ē_p {:.3} m; reachable minimum {:.3} m; θ_nom {:.3} m{}",
        exp.final_estimate.mean_position_error_m,
        exp.reachable_minimum.scored.mean_position_error_m,
        exp.nominal.mean_position_error_m,
        exp.truth.map(|t| format!("; θ_true {:.3} m", t.mean_position_error_m)).unwrap_or_default()
    );
    println!("wrote {} and {} ({:.1} s)", md_path.display(), json_path.display(), exp.timing_s.total);
    Ok(())
}

/// Curves of Fig. 6 (time in s from the segment start).
struct Fig6Curves {
    n_rl_measured: Vec<(f64, f64)>,
    n_rl_compensated: Vec<(f64, f64)>,
    n_rl_true: Option<Vec<(f64, f64)>>,
    n_rr_measured: Vec<(f64, f64)>,
    n_rr_compensated: Vec<(f64, f64)>,
    n_rr_true: Option<Vec<(f64, f64)>>,
    pos_err_measured: Vec<(f64, f64)>,
    pos_err_compensated: Vec<(f64, f64)>,
}

struct Fig6 {
    numbers: Figure6,
    curves: Fig6Curves,
}

/// Position error along a segment of dead reckoning at θ with the segment's inputs.
fn position_errors(seg: &SegmentData<'_>, theta: &Theta) -> Vec<(f64, f64)> {
    let mut x = seg.reference(0);
    (0..seg.steps())
        .map(|k| {
            x = step(&x, &seg.input(k), theta, seg.sample_time_s);
            ((k + 1) as f64 * seg.sample_time_s, (seg.px[k + 1] - x[0]).hypot(seg.py[k + 1] - x[1]))
        })
        .collect()
}

fn figure6_data(drive: &Drive, comp: &SegmentData<'_>, raw: &SegmentData<'_>, theta: &Theta) -> Fig6 {
    let ts = drive.sample_time_s();
    let series = |v: &[f64]| -> Vec<(f64, f64)> { v.iter().enumerate().map(|(k, &n)| (k as f64 * ts, n)).collect() };
    let (a, k) = (raw.start, raw.steps());
    let truth = drive.truth().filter(|t| t.n_rl.len() >= a + k);
    let rms = |x: &[f64], y: &[f64], tx: &[f64], ty: &[f64]| {
        let s: f64 = (0..x.len()).map(|i| (x[i] - tx[i]).powi(2) + (y[i] - ty[i]).powi(2)).sum();
        (s / (2 * x.len()) as f64).sqrt()
    };
    let (tl, tr) = match truth {
        Some(t) => (Some(&t.n_rl[a..a + k]), Some(&t.n_rr[a..a + k])),
        None => (None, None),
    };
    let pm = position_errors(raw, theta);
    let pc = position_errors(comp, theta);
    let mean = |v: &[(f64, f64)]| v.iter().map(|p| p.1).sum::<f64>() / v.len().max(1) as f64;
    Fig6 {
        numbers: Figure6 {
            segment_start: a,
            theta: *theta,
            rms_measured_input_error_rev_per_s: tl.zip(tr).map(|(l, r)| rms(raw.n_rl, raw.n_rr, l, r)),
            rms_compensated_input_error_rev_per_s: tl.zip(tr).map(|(l, r)| rms(comp.n_rl, comp.n_rr, l, r)),
            mean_position_error_measured_m: mean(&pm),
            mean_position_error_compensated_m: mean(&pc),
        },
        curves: Fig6Curves {
            n_rl_measured: series(raw.n_rl),
            n_rl_compensated: series(comp.n_rl),
            n_rl_true: tl.map(series),
            n_rr_measured: series(raw.n_rr),
            n_rr_compensated: series(comp.n_rr),
            n_rr_true: tr.map(series),
            pos_err_measured: pm,
            pos_err_compensated: pc,
        },
    }
}

/// Parameter accessors with plot units (c_d and d in mm).
/// A parameter's name, plot unit and value in that unit.
type Param = (&'static str, &'static str, fn(&Theta) -> f64);

const PARAMS: [Param; 4] = [
    ("c_e", "m", |t| t.c_e),
    ("c_d", "mm", |t| t.c_d * 1e3),
    ("t_r", "m", |t| t.t_r),
    ("d", "mm/(m/s²)", |t| t.d * 1e3),
];

fn write_figures(dir: &Path, e: &Experiment, c: &Fig6Curves) -> Result<Vec<String>> {
    let mut names = Vec::new();
    let truth_line = |y: f64| HLine { name: "θ_true".into(), y, color: plots::GREEN };
    let ep_lines = || {
        let mut v = vec![
            HLine {
                name: "reachable minimum".into(),
                y: e.reachable_minimum.scored.mean_position_error_m,
                color: plots::GREY,
            },
            HLine { name: "θ_B,F".into(), y: e.final_estimate.mean_position_error_m, color: plots::RED },
        ];
        if let Some(t) = &e.truth {
            v.push(HLine { name: "θ_true".into(), y: t.mean_position_error_m, color: plots::GREEN });
        }
        v
    };

    // Fig. 4: sorted Ē_p of the batch calibrations.
    let mut sorted: Vec<(usize, f64)> =
        e.batches.iter().enumerate().map(|(i, b)| (i, b.raw.mean_position_error_m)).collect();
    sorted.sort_by(|x, y| x.1.total_cmp(&y.1));
    let rank = |i: usize| sorted.iter().position(|s| s.0 == i).map_or(f64::NAN, |r| (r + 1) as f64);
    let name = "fig4_batch_errors.svg";
    figure(
        &dir.join(name),
        &format!("Fig. 4: sorted Ē_p of {} batch G-N calibrations (N = {})", e.batches.len(), e.batch_size),
        (900, 520),
        (1, 1),
        &[Panel {
            title: "raw inputs, from θ_0".into(),
            x_label: "rank of batch result".into(),
            y_label: "Ē_p (m)".into(),
            series: vec![
                Series::line(
                    "batch G-N",
                    sorted.iter().enumerate().map(|(r, s)| ((r + 1) as f64, s.1)).collect(),
                    plots::BLUE,
                ),
                Series::points(
                    "picked θ_B,I",
                    e.picked_batches.iter().map(|&i| (rank(i), e.batches[i].raw.mean_position_error_m)).collect(),
                    plots::ORANGE,
                ),
            ],
            hlines: ep_lines(),
            y_range: None,
        }],
    )?;
    names.push(name.to_string());

    // Fig. 5: the picked θ_B,I.
    let name = "fig5_picked_theta.svg";
    let panels: Vec<Panel> = PARAMS
        .iter()
        .map(|(p, unit, f)| {
            let mut hl = vec![HLine { name: "θ_B,F".into(), y: f(&e.final_estimate.theta), color: plots::RED }];
            if let Some(t) = &e.truth {
                hl.push(truth_line(f(&t.theta)));
            }
            Panel {
                title: p.to_string(),
                x_label: "pick (1 = lowest Ē_p)".into(),
                y_label: format!("{p} ({unit})"),
                series: vec![Series::points(
                    "θ_B,I",
                    e.picked.iter().enumerate().map(|(i, s)| ((i + 1) as f64, f(&s.theta))).collect(),
                    plots::ORANGE,
                )],
                hlines: hl,
                y_range: None,
            }
        })
        .collect();
    figure(&dir.join(name), "Fig. 5: the picked initial estimates θ_B,I", (1000, 760), (2, 2), &panels)?;
    names.push(name.to_string());

    // Fig. 6: wheel rotations and dead-reckoning errors on one segment.
    let name = "fig6_compensation.svg";
    let wheel = |title: &str, m: &[(f64, f64)], cc: &[(f64, f64)], tr: &Option<Vec<(f64, f64)>>| {
        let mut s = vec![
            Series::line("measured", m.to_vec(), plots::BLUE),
            Series::line("compensated", cc.to_vec(), plots::ORANGE),
        ];
        if let Some(t) = tr {
            s.push(Series::line("true", t.clone(), plots::GREEN));
        }
        Panel {
            title: title.into(),
            x_label: "time from segment start (s)".into(),
            y_label: "wheel rotation (rev/s)".into(),
            series: s,
            hlines: vec![],
            y_range: None,
        }
    };
    let diffs = |x: &[(f64, f64)], t: &[(f64, f64)]| -> Vec<(f64, f64)> {
        x.iter().zip(t).map(|(a, b)| (a.0, a.1 - b.1)).collect()
    };
    let mut panels = vec![
        wheel("rear left n_rl", &c.n_rl_measured, &c.n_rl_compensated, &c.n_rl_true),
        wheel("rear right n_rr", &c.n_rr_measured, &c.n_rr_compensated, &c.n_rr_true),
    ];
    if let Some(t) = &c.n_rl_true {
        panels.push(Panel {
            title: "n_rl input error against the truth".into(),
            x_label: "time from segment start (s)".into(),
            y_label: "n_rl − n_rl,true (rev/s)".into(),
            series: vec![
                Series::line("measured", diffs(&c.n_rl_measured, t), plots::BLUE),
                Series::line("compensated", diffs(&c.n_rl_compensated, t), plots::ORANGE),
            ],
            hlines: vec![],
            y_range: None,
        });
    }
    panels.push(Panel {
        title: "dead-reckoning position error at θ_B,F".into(),
        x_label: "time from segment start (s)".into(),
        y_label: "position error (m)".into(),
        series: vec![
            Series::line("measured inputs", c.pos_err_measured.clone(), plots::BLUE),
            Series::line("compensated inputs", c.pos_err_compensated.clone(), plots::ORANGE),
        ],
        hlines: vec![],
        y_range: None,
    });
    let rows = panels.len().div_ceil(2);
    figure(
        &dir.join(name),
        &format!("Fig. 6: input compensation on the segment at sample {}", e.figure6.segment_start),
        (1100, 380 * rows as u32),
        (rows, 2),
        &panels,
    )?;
    names.push(name.to_string());

    // Fig. 7: per-segment θ, raw vs compensated.
    let name = "fig7_segment_theta.svg";
    let panels: Vec<Panel> = PARAMS
        .iter()
        .map(|(p, unit, f)| {
            let raw: Vec<(f64, f64)> =
                e.per_segment.iter().enumerate().filter_map(|(i, s)| s.raw.map(|r| (i as f64, f(&r.theta)))).collect();
            let cmp: Vec<(f64, f64)> = e
                .per_segment
                .iter()
                .enumerate()
                .filter_map(|(i, s)| s.compensated.map(|r| (i as f64, f(&r.theta))))
                .collect();
            let mut hl = vec![HLine { name: "θ_B,F".into(), y: f(&e.final_estimate.theta), color: plots::RED }];
            if let Some(t) = &e.truth {
                hl.push(truth_line(f(&t.theta)));
            }
            let vals: Vec<f64> = raw.iter().chain(&cmp).map(|q| q.1).collect();
            let keep: Vec<f64> = hl.iter().map(|h| h.y).collect();
            Panel {
                title: p.to_string(),
                x_label: "selected segment index".into(),
                y_label: format!("{p} ({unit})"),
                series: vec![
                    Series::points("raw inputs", raw, plots::BLUE),
                    Series::points("compensated inputs", cmp, plots::ORANGE),
                ],
                y_range: plots::robust_range(&vals, &keep),
                hlines: hl,
            }
        })
        .collect();
    figure(
        &dir.join(name),
        "Fig. 7: per-segment G-N estimates, raw vs compensated inputs",
        (1100, 780),
        (2, 2),
        &panels,
    )?;
    names.push(name.to_string());

    // Fig. 8: Ē_p per segment and per batch, raw vs compensated.
    let name = "fig8_errors.svg";
    let seg_raw: Vec<(f64, f64)> = e
        .per_segment
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.raw.map(|r| (i as f64, r.mean_position_error_m)))
        .collect();
    let seg_cmp: Vec<(f64, f64)> = e
        .per_segment
        .iter()
        .enumerate()
        .filter_map(|(i, s)| s.compensated.map(|r| (i as f64, r.mean_position_error_m)))
        .collect();
    let mut b_raw: Vec<f64> = e.batches.iter().map(|b| b.raw.mean_position_error_m).collect();
    let mut b_cmp: Vec<f64> = e.batches.iter().filter_map(|b| b.compensated.map(|c| c.mean_position_error_m)).collect();
    b_raw.sort_by(f64::total_cmp);
    b_cmp.sort_by(f64::total_cmp);
    let ranked = |v: &[f64]| v.iter().enumerate().map(|(i, &y)| ((i + 1) as f64, y)).collect::<Vec<_>>();
    let seg_vals: Vec<f64> = seg_raw.iter().chain(&seg_cmp).map(|q| q.1).collect();
    let keep: Vec<f64> = ep_lines().iter().map(|h| h.y).collect();
    let panels = vec![
        Panel {
            title: "per segment (G-N on one segment)".into(),
            x_label: "selected segment index".into(),
            y_label: "Ē_p (m)".into(),
            series: vec![
                Series::points("raw inputs", seg_raw, plots::BLUE),
                Series::points("compensated inputs", seg_cmp, plots::ORANGE),
            ],
            y_range: plots::robust_range(&seg_vals, &keep),
            hlines: ep_lines(),
        },
        Panel {
            title: format!("per batch (N = {}), sorted", e.batch_size),
            x_label: "rank of batch result".into(),
            y_label: "Ē_p (m)".into(),
            series: vec![
                Series::line("raw inputs", ranked(&b_raw), plots::BLUE),
                Series::line("compensated inputs", ranked(&b_cmp), plots::ORANGE),
            ],
            hlines: ep_lines(),
            y_range: None,
        },
    ];
    figure(&dir.join(name), "Fig. 8: validation error Ē_p, raw vs compensated inputs", (1100, 480), (1, 2), &panels)?;
    names.push(name.to_string());
    Ok(names)
}

fn fmt_opt(v: Option<f64>, scale: f64, prec: usize) -> String {
    v.map_or_else(|| "–".to_string(), |x| format!("{:.*}", prec, x * scale))
}

const TABLE_HEAD: &str = "| | c_e (m) | c_d (mm) | t_r (m) | d (mm/(m/s²)) | Ē_p (m) | Ē_p − Ē_p,min (m) | Δc_e (mm) | Δc_d (mm) | Δt_r (mm) | Δd (mm/(m/s²)) |\n|---|---|---|---|---|---|---|---|---|---|---|\n";

fn theta_row(out: &mut String, name: &str, s: &Scored, e_min: f64) {
    let err = s.error_vs_true;
    let _ = writeln!(
        out,
        "| {name} | {:.5} | {:.3} | {:.4} | {:.3} | {:.3} | {:+.3} | {} | {} | {} | {} |",
        s.theta.c_e,
        s.theta.c_d * 1e3,
        s.theta.t_r,
        s.theta.d * 1e3,
        s.mean_position_error_m,
        s.mean_position_error_m - e_min,
        fmt_opt(err.map(|t| t.c_e), 1e3, 2),
        fmt_opt(err.map(|t| t.c_d), 1e3, 3),
        fmt_opt(err.map(|t| t.t_r), 1e3, 1),
        fmt_opt(err.map(|t| t.d), 1e3, 3),
    );
}

fn summary_row(out: &mut String, name: &str, s: &Summary) {
    let m = s.median_abs_error_vs_true;
    let _ = writeln!(
        out,
        "| {name} | {} | {:.3} | {:.3} | {:.3} | {} | {} | {} | {} |",
        s.count,
        s.min_mean_position_error_m,
        s.median_mean_position_error_m,
        s.max_mean_position_error_m,
        fmt_opt(m.map(|t| t.c_e), 1e3, 2),
        fmt_opt(m.map(|t| t.c_d), 1e3, 3),
        fmt_opt(m.map(|t| t.t_r), 1e3, 1),
        fmt_opt(m.map(|t| t.d), 1e3, 3),
    );
}

fn report_md(e: &Experiment) -> String {
    let mut o = String::new();
    let e_min = e.reachable_minimum.scored.mean_position_error_m;
    let _ = writeln!(o, "# odocal experiment — the paper's §6 on one drive\n");
    let _ = writeln!(
        o,
        "Drive: {} — {} samples, {:.2} km, t_s = {} s{}.  \nSegments: {} cut, {} selected, {} validation. QP solver: {}.\n",
        e.drive.source,
        e.drive.samples,
        e.drive.distance_km,
        e.drive.sample_time_s,
        e.drive.wheel_rotation_rel_error_rms.map(|w| format!(", wheel error {:.2} % rms", w * 100.0)).unwrap_or_default(),
        e.segments.cut,
        e.segments.selected,
        e.segments.validation,
        e.qp_solver
    );
    let _ = writeln!(
        o,
        "Ē_p is the mean dead-reckoning position error on the validation segments with the *measured* inputs (SPEC §7). \
         Δ columns are θ − θ_true in mm (c_d, d: mm and mm/(m/s²)); Ē_p,min is the reachable minimum.\n"
    );
    let _ = writeln!(o, "## Estimates\n\n{TABLE_HEAD}");
    o.truncate(o.trim_end().len());
    o.push('\n');
    if let Some(t) = &e.truth {
        theta_row(&mut o, "θ_true", t, e_min);
    }
    theta_row(&mut o, "θ_nom (paper)", &e.nominal, e_min);
    theta_row(&mut o, "θ_0 (G-N start)", &e.initial_guess, e_min);
    for (i, p) in e.picked.iter().enumerate() {
        theta_row(&mut o, &format!("θ_B,I({})", i + 1), p, e_min);
    }
    theta_row(&mut o, "**θ_B,F (3-step)**", &e.final_estimate, e_min);
    theta_row(&mut o, "reachable minimum", &e.reachable_minimum.scored, e_min);
    let _ = writeln!(
        o,
        "\nFinal identification: {}. Reachable minimum: particle swarm + Nelder-Mead seeded with the θ_B,I and θ_B,F, {} evaluations, {:.1} s ({}).",
        e.final_identification, e.reachable_minimum.evaluations, e.reachable_minimum.time_s, e.reachable_minimum.termination
    );
    if let Some(t) = &e.truth {
        if t.mean_position_error_m < e_min - 1e-9 {
            let _ = writeln!(
                o,
                "\n**Note:** Ē_p of θ_true is below the reachable minimum found: the search missed the minimum."
            );
        }
    }

    let _ = writeln!(o, "\n## Table 1: one segment and one batch, raw vs compensated inputs\n\n{TABLE_HEAD}");
    o.truncate(o.trim_end().len());
    o.push('\n');
    let t1 = &e.table1;
    theta_row(&mut o, &format!("segment @{} raw", t1.segment_start), &t1.segment_raw, e_min);
    theta_row(&mut o, &format!("segment @{} compensated", t1.segment_start), &t1.segment_compensated, e_min);
    theta_row(&mut o, &format!("batch {} raw", t1.batch_index), &t1.batch_raw, e_min);
    theta_row(&mut o, &format!("batch {} compensated", t1.batch_index), &t1.batch_compensated, e_min);
    let _ = writeln!(
        o,
        "\nThe segment is the compensated segment with the highest peak yaw rate; the batch is the middle picked step-1 batch (segments starting at samples {:?}).",
        t1.batch_starts
    );

    let _ = writeln!(
        o,
        "\n## Per-segment and batch estimates (Fig. 7/8)\n\nPure G-N from θ_0 on each selected segment alone, and on the {} step-1 batches of N = {}, with raw and with compensated inputs. \"median abs Δ\" is the median absolute error against θ_true.\n",
        e.batches.len(),
        e.batch_size
    );
    let _ = writeln!(o, "| | count | min Ē_p (m) | median Ē_p (m) | max Ē_p (m) | median abs Δc_e (mm) | median abs Δc_d (mm) | median abs Δt_r (mm) | median abs Δd (mm/(m/s²)) |");
    let _ = writeln!(o, "|---|---|---|---|---|---|---|---|---|");
    summary_row(&mut o, "segments, raw", &e.summary_segments_raw);
    summary_row(&mut o, "segments, compensated", &e.summary_segments_compensated);
    summary_row(&mut o, "batches, raw", &e.summary_batches_raw);
    summary_row(&mut o, "batches, compensated", &e.summary_batches_compensated);

    let c = &e.compensation;
    let _ = writeln!(
        o,
        "\n## Input compensation (step 2, Fig. 6)\n\n{} segments compensated ({} jobs, {} failed, {} unconverged; {} QP solves, {:.1} solver iterations per solve, solver {}); RMS relative input change {:.3} %.\n",
        c.segments,
        c.jobs,
        c.failed_jobs,
        c.unconverged_jobs,
        c.qp_solves,
        c.mean_qp_iterations,
        c.solver,
        c.rms_relative_input_change * 100.0
    );
    let f = &e.figure6;
    let _ = writeln!(o, "Fig. 6 segment (sample {}), dead reckoning at θ_B,F:\n", f.segment_start);
    let _ = writeln!(o, "| inputs | RMS input error vs true (rev/s) | mean position error (m) |\n|---|---|---|");
    let _ = writeln!(
        o,
        "| measured | {} | {:.3} |",
        fmt_opt(f.rms_measured_input_error_rev_per_s, 1.0, 5),
        f.mean_position_error_measured_m
    );
    let _ = writeln!(
        o,
        "| compensated | {} | {:.3} |",
        fmt_opt(f.rms_compensated_input_error_rev_per_s, 1.0, 5),
        f.mean_position_error_compensated_m
    );

    let _ = writeln!(o, "\n## Figures\n");
    let captions = [
        "Fig. 4 — sorted Ē_p of the batch G-N calibrations",
        "Fig. 5 — the picked θ_B,I",
        "Fig. 6 — measured, compensated and true wheel rotations; dead-reckoning error",
        "Fig. 7 — per-segment θ, raw vs compensated inputs",
        "Fig. 8 — per-segment and per-batch Ē_p, raw vs compensated inputs",
    ];
    for (cap, file) in captions.iter().zip(&e.figures) {
        let _ = writeln!(o, "### {cap}\n\n![{cap}]({file})\n");
    }
    if !e.warnings.is_empty() {
        let _ = writeln!(o, "## Warnings\n");
        for w in &e.warnings {
            let _ = writeln!(o, "- {w}");
        }
        o.push('\n');
    }
    let t = &e.timing_s;
    let _ = writeln!(
        o,
        "## Timing\n\n{:.1} s total: simulate {:.1}, calibrate {:.1}, per-segment {:.1}, compensated batches {:.1}, reachable minimum {:.1}, figures {:.1}.",
        t.total, t.simulate, t.calibrate, t.per_segment, t.compensated_batches, t.reachable_minimum, t.figures
    );
    o
}
