//! `odocal experiment`: the paper's §6 on a simulated (or given) drive in one
//! command. The numbers come from [`odocal::experiment::run`]; this module
//! loads or simulates the drive and writes them as `report.md`, SVG figures
//! and `experiment.json`.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use odocal::eiv::NoiseModel;
use odocal::experiment::{
    self, CramerRao, Experiment, ExperimentOptions, ExperimentTiming, Figure6Curves, Scored, Summary,
};
use odocal::sim::{self, NoiseOptions, SimOptions};
use odocal::{CalibrationOptions, Drive, Method, QpOptions, ReachableOptions, Theta, ThreeStepOptions};
use serde::Serialize;

use crate::progress::Bars;
use crate::ExperimentArgs;
use odocal_report::plots::{self, figure, HLine, Panel, Series};

/// Where the drive came from.
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

/// Wall time, s: the library's stages plus simulation and figures.
#[derive(Debug, Clone, Default, Serialize)]
struct Timing {
    simulate: f64,
    #[serde(flatten)]
    stages: ExperimentTiming,
    figures: f64,
    total: f64,
}

/// What the command adds to the library's numbers.
struct Outputs {
    drive: DriveInfo,
    figures: Vec<String>,
    timing: Timing,
}

/// Runs the experiment.
pub fn run(a: ExperimentArgs, bars: &Bars) -> Result<()> {
    let t_total = Instant::now();
    let mut timing = Timing::default();
    if a.batches == 0 {
        bail!("--batches must be at least 1");
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;

    // The drive and its truth.
    let t = Instant::now();
    let (drive, theta_true, noise, info) = match &a.drive {
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
            let noise = sidecar.as_ref().map(|s| NoiseModel::from_sim(&s.settings.noise, drive.sample_time_s()));
            (drive, sidecar.map(|s| s.theta_true), noise, info)
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
            let noise = NoiseModel::from_sim(&out.sidecar.settings.noise, out.drive.sample_time_s());
            (out.drive, Some(out.sidecar.theta_true), Some(noise), info)
        }
    };
    timing.simulate = t.elapsed().as_secs_f64();

    let method = Method::ThreeStep(ThreeStepOptions {
        initial_batches: a.batches,
        qp: QpOptions { solver: a.qp_solver, ..Default::default() },
        ..Default::default()
    });
    let calibration = CalibrationOptions { method, seed: a.seed, ..Default::default() };
    let reachable = ReachableOptions { seed: a.seed, ..ReachableOptions::around(&calibration.theta0) };
    let cb = |e| bars.event(e);
    let opts = ExperimentOptions { calibration, reachable, noise };
    let exp = experiment::run(&drive, theta_true.as_ref(), &opts, Some(&cb))?;
    bars.finish();
    timing.stages = exp.timing_s.clone();

    let t = Instant::now();
    let figures = write_figures(&a.out, &exp, &exp.figure6_curves)?;
    timing.figures = t.elapsed().as_secs_f64();
    timing.total = t_total.elapsed().as_secs_f64();
    let outputs = Outputs { drive: info, figures, timing };

    let json_path = a.out.join("experiment.json");
    let mut json = serde_json::to_value(&exp)?;
    if let Some(obj) = json.as_object_mut() {
        obj.insert("schema_version".into(), odocal::REPORT_SCHEMA_VERSION.into());
        obj.insert("drive".into(), serde_json::to_value(&outputs.drive)?);
        obj.insert("figures".into(), serde_json::to_value(&outputs.figures)?);
        obj.insert("timing_s".into(), serde_json::to_value(&outputs.timing)?);
    }
    let text = serde_json::to_string_pretty(&json)?;
    std::fs::write(&json_path, text + "\n").with_context(|| format!("writing {}", json_path.display()))?;
    let md_path = a.out.join("report.md");
    std::fs::write(&md_path, report_md(&exp, &outputs)).with_context(|| format!("writing {}", md_path.display()))?;

    for l in odocal::assess::warning::summarize(&exp.warnings, SHOWN_WARNINGS) {
        eprintln!("warning: {l}");
    }
    println!(
        "θ_B,F Ē_p {:.3} m; reachable minimum {:.3} m; θ_nom {:.3} m{}",
        exp.final_estimate.mean_position_error_m,
        exp.reachable_minimum.scored.mean_position_error_m,
        exp.nominal.mean_position_error_m,
        exp.truth.map(|t| format!("; θ_true {:.3} m", t.mean_position_error_m)).unwrap_or_default()
    );
    println!("wrote {} and {} ({:.1} s)", md_path.display(), json_path.display(), outputs.timing.total);
    Ok(())
}

/// Warnings of one kind printed on stderr (report.md lists all).
const SHOWN_WARNINGS: usize = 3;

/// Parameter accessors with plot units (c_d and d in mm).
/// A parameter's name, plot unit and value in that unit.
type Param = (&'static str, &'static str, fn(&Theta) -> f64);

const PARAMS: [Param; 4] = [
    ("c_e", "m", |t| t.c_e),
    ("c_d", "mm", |t| t.c_d * 1e3),
    ("t_r", "m", |t| t.t_r),
    ("d", "mm/(m/s²)", |t| t.d * 1e3),
];

fn write_figures(dir: &Path, e: &Experiment, c: &Figure6Curves) -> Result<Vec<String>> {
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
            equal_aspect: false,
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
                equal_aspect: false,
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
            equal_aspect: false,
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
            equal_aspect: false,
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
        equal_aspect: false,
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
                equal_aspect: false,
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
            equal_aspect: false,
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
            equal_aspect: false,
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

/// The Cramér–Rao section: σ_CRB and, next to each estimate's error, error/σ_CRB.
fn crb_section(o: &mut String, c: &CramerRao, rows: &[(String, Scored)], time_s: f64) {
    let _ = writeln!(o, "\n## Against the Cramér–Rao bound\n");
    let (Some(sigma), None) = (c.sigma, &c.unavailable) else {
        let _ = writeln!(
            o,
            "Not available: {}. The bound needs θ_true and the drive's true noise model, which only a simulated drive \
             (or a CSV with its simulator sidecar) has.",
            c.unavailable.as_deref().unwrap_or("no bound")
        );
        return;
    };
    let _ = writeln!(
        o,
        "σ_CRB is the smallest standard deviation an unbiased estimator that knows the noise model can have on this \
         drive (`odocal::eiv::cramer_rao_bound` at θ_true with the simulator's noise model in the EIV filter's form, \
         linearised along the drive's true inputs; wheel slip is not in that form). Δ is θ − θ_true; Δ/σ_CRB of a \
         single estimate is one draw: over seeds, an efficient unbiased estimator has RMS(Δ/σ_CRB) ≈ 1. The row \
         \"noise scales unknown too\" is the bound of an estimator that estimates the noise levels with θ (EIV's \
         default): the size of the innovations then no longer measures θ.\n"
    );
    let _ = writeln!(
        o,
        "| | Δc_e (mm) | Δc_e/σ | Δc_d (mm) | Δc_d/σ | Δt_r (mm) | Δt_r/σ | Δd (mm/(m/s²)) | Δd/σ |\n|---|---|---|---|---|---|---|---|---|"
    );
    let s = sigma.to_array();
    let m = c.sigma_mean_only.map(|m| m.to_array());
    let _ = writeln!(
        o,
        "| σ_CRB | {:.3} | | {:.4} | | {:.2} | | {:.4} | |",
        s[0] * 1e3,
        s[1] * 1e3,
        s[2] * 1e3,
        s[3] * 1e3
    );
    if let Some(m) = m {
        let _ = writeln!(
            o,
            "| σ_CRB, mean-only information | {:.3} | | {:.4} | | {:.2} | | {:.4} | |",
            m[0] * 1e3,
            m[1] * 1e3,
            m[2] * 1e3,
            m[3] * 1e3
        );
    }
    if let Some(m) = c.sigma_noise_estimated.map(|m| m.to_array()) {
        let _ = writeln!(
            o,
            "| σ_CRB, noise scales unknown too | {:.3} | | {:.4} | | {:.2} | | {:.4} | |",
            m[0] * 1e3,
            m[1] * 1e3,
            m[2] * 1e3,
            m[3] * 1e3
        );
    }
    for (name, sc) in rows {
        let (Some(d), Some(r)) = (sc.error_vs_true, sc.error_over_crb) else { continue };
        let (d, r) = (d.to_array(), r.to_array());
        let _ = writeln!(
            o,
            "| {name} | {:+.3} | {:+.2} | {:+.4} | {:+.2} | {:+.2} | {:+.2} | {:+.4} | {:+.2} |",
            d[0] * 1e3,
            r[0],
            d[1] * 1e3,
            r[1],
            d[2] * 1e3,
            r[2],
            d[3] * 1e3,
            r[3]
        );
    }
    let _ = writeln!(o, "\nComputed in {time_s:.2} s (one filter pass with derivatives).");
}

fn report_md(e: &Experiment, out: &Outputs) -> String {
    let mut o = String::new();
    let e_min = e.reachable_minimum.scored.mean_position_error_m;
    let _ = writeln!(o, "# odocal experiment — the paper's §6 on one drive\n");
    let _ = writeln!(
        o,
        "Drive: {} — {} samples, {:.2} km, t_s = {} s{}.  \nSegments: {} cut, {} selected, {} validation. QP solver: {}.\n",
        out.drive.source,
        out.drive.samples,
        out.drive.distance_km,
        out.drive.sample_time_s,
        out.drive.wheel_rotation_rel_error_rms.map(|w| format!(", wheel error {:.2} % rms", w * 100.0)).unwrap_or_default(),
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

    let mut rows = vec![("θ_nom (paper)".to_string(), e.nominal), ("θ_0 (G-N start)".to_string(), e.initial_guess)];
    rows.extend(e.picked.iter().enumerate().map(|(i, p)| (format!("θ_B,I({})", i + 1), *p)));
    rows.push(("**θ_B,F (3-step)**".into(), e.final_estimate));
    rows.push(("reachable minimum".into(), e.reachable_minimum.scored));
    crb_section(&mut o, &e.cramer_rao, &rows, e.timing_s.cramer_rao_bound);

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
    for (cap, file) in captions.iter().zip(&out.figures) {
        let _ = writeln!(o, "### {cap}\n\n![{cap}]({file})\n");
    }
    if !e.warnings.is_empty() {
        let _ = writeln!(o, "## Warnings\n");
        for w in &e.warnings {
            let _ = writeln!(o, "- {w}");
        }
        o.push('\n');
    }
    let (t, st) = (&out.timing, &out.timing.stages);
    let _ = writeln!(
        o,
        "## Timing\n\n{:.1} s total: simulate {:.1}, Cramér–Rao bound {:.2}, calibrate {:.1}, per-segment {:.1}, compensated batches {:.1}, reachable minimum {:.1}, figures {:.1}.",
        t.total,
        t.simulate,
        st.cramer_rao_bound,
        st.calibrate,
        st.per_segment,
        st.compensated_batches,
        st.reachable_minimum,
        t.figures
    );
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scored(err: Option<Theta>, ratio: Option<Theta>) -> Scored {
        Scored { theta: Theta::PAPER_INITIAL, mean_position_error_m: 1.0, error_vs_true: err, error_over_crb: ratio }
    }

    #[test]
    fn the_crb_section_shows_the_ratio_beside_the_error_or_says_why_not() {
        let sigma = Theta { c_e: 1e-4, c_d: 2e-5, t_r: 2e-3, d: 1e-4 };
        let err = Theta { c_e: 2e-4, c_d: -2e-5, t_r: 1e-3, d: 0.0 };
        let ratio = Theta { c_e: 2.0, c_d: -1.0, t_r: 0.5, d: 0.0 };
        let c = CramerRao {
            sigma: Some(sigma),
            sigma_mean_only: Some(sigma),
            sigma_noise_estimated: Some(sigma),
            noise: None,
            unavailable: None,
        };
        let mut o = String::new();
        crb_section(&mut o, &c, &[("θ_B,F".into(), scored(Some(err), Some(ratio)))], 0.25);
        assert!(o.contains("| σ_CRB | 0.100 | | 0.0200 | | 2.00 | | 0.1000 | |"), "{o}");
        assert!(o.contains("| θ_B,F | +0.200 | +2.00 | -0.0200 | -1.00 | +1.00 | +0.50 | +0.0000 | +0.00 |"), "{o}");
        assert!(o.contains("0.25 s"), "{o}");
        assert!(o.contains("| σ_CRB, noise scales unknown too | 0.100 |"), "{o}");

        let none = CramerRao {
            sigma: None,
            sigma_mean_only: None,
            sigma_noise_estimated: None,
            noise: None,
            unavailable: Some("the true θ is not known".into()),
        };
        let mut o = String::new();
        crb_section(&mut o, &none, &[("θ_B,F".into(), scored(None, None))], 0.0);
        assert!(o.contains("Not available: the true θ is not known"), "{o}");
        assert!(!o.contains("| θ_B,F |"), "{o}");
    }
}
