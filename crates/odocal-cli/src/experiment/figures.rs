//! The SVG figures of `odocal experiment`: the paper's Fig. 4–8.

use anyhow::Result;
use odocal::experiment::Experiment;
use odocal_report::plots::{self, figure_svg, HLine, Panel, Series};

use super::PARAMS;

/// The file names of Fig. 4–8.
pub const FIGURES: [&str; 5] = [
    "fig4_batch_errors.svg",
    "fig5_picked_theta.svg",
    "fig6_compensation.svg",
    "fig7_segment_theta.svg",
    "fig8_errors.svg",
];

/// A figure's file name and its SVG text.
pub type Figure = (&'static str, String);

/// Fig. 4–8: their file names and SVG texts (written with the report's
/// other files, as one).
pub fn render_figures(e: &Experiment) -> Result<Vec<Figure>> {
    Ok(vec![fig4(e)?, fig5(e)?, fig6(e)?, fig7(e)?, fig8(e)?])
}

/// The θ_true line of a parameter panel.
fn truth_line(y: f64) -> HLine {
    HLine { name: "θ_true".into(), y, color: plots::GREEN }
}

/// The reference lines of an Ē_p panel: the reachable minimum, θ_B,F and θ_true.
fn ep_lines(e: &Experiment) -> Vec<HLine> {
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
}

/// The θ_B,F line of a parameter panel and, when known, the θ_true line.
fn final_and_truth_lines(e: &Experiment, f: fn(&odocal::Theta) -> f64) -> Vec<HLine> {
    let mut hl = vec![HLine { name: "θ_B,F".into(), y: f(&e.final_estimate.theta), color: plots::RED }];
    if let Some(t) = &e.truth {
        hl.push(truth_line(f(&t.theta)));
    }
    hl
}

/// Fig. 4: sorted Ē_p of the batch calibrations.
fn fig4(e: &Experiment) -> Result<Figure> {
    let mut sorted: Vec<(usize, f64)> =
        e.batches.iter().enumerate().map(|(i, b)| (i, b.raw.mean_position_error_m)).collect();
    sorted.sort_by(|x, y| x.1.total_cmp(&y.1));
    let rank = |i: usize| sorted.iter().position(|s| s.0 == i).map_or(f64::NAN, |r| (r + 1) as f64);
    let name = FIGURES[0];
    let svg = figure_svg(
        &format!("Fig. 4: sorted Ē_p of {} batch G-N calibrations (N = {})", e.batches.len(), e.batch_size),
        (900, 520),
        (1, 1),
        &[Panel {
            equal_aspect: false,
            labels: Vec::new(),
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
            hlines: ep_lines(e),
            y_range: None,
        }],
    )?;
    Ok((name, svg))
}

/// Fig. 5: the picked θ_B,I.
fn fig5(e: &Experiment) -> Result<Figure> {
    let name = FIGURES[1];
    let panels: Vec<Panel> = PARAMS
        .iter()
        .map(|(p, unit, f)| Panel {
            equal_aspect: false,
            labels: Vec::new(),
            title: p.to_string(),
            x_label: "pick (1 = lowest Ē_p)".into(),
            y_label: format!("{p} ({unit})"),
            series: vec![Series::points(
                "θ_B,I",
                e.picked.iter().enumerate().map(|(i, s)| ((i + 1) as f64, f(&s.theta))).collect(),
                plots::ORANGE,
            )],
            hlines: final_and_truth_lines(e, *f),
            y_range: None,
        })
        .collect();
    let svg = figure_svg("Fig. 5: the picked initial estimates θ_B,I", (1000, 760), (2, 2), &panels)?;
    Ok((name, svg))
}

/// A Fig. 6 panel of one wheel's rotations: measured, compensated and true.
fn wheel_panel(title: &str, m: &[(f64, f64)], cc: &[(f64, f64)], tr: &Option<Vec<(f64, f64)>>) -> Panel {
    let mut s = vec![
        Series::line("measured", m.to_vec(), plots::BLUE),
        Series::line("compensated", cc.to_vec(), plots::ORANGE),
    ];
    if let Some(t) = tr {
        s.push(Series::line("true", t.clone(), plots::GREEN));
    }
    Panel {
        equal_aspect: false,
        labels: Vec::new(),
        title: title.into(),
        x_label: "time from segment start (s)".into(),
        y_label: "wheel rotation (rev/s)".into(),
        series: s,
        hlines: vec![],
        y_range: None,
    }
}

/// Fig. 6: wheel rotations and dead-reckoning errors on one segment.
fn fig6(e: &Experiment) -> Result<Figure> {
    let (name, c) = (FIGURES[2], &e.figure6);
    let diffs = |x: &[(f64, f64)], t: &[(f64, f64)]| -> Vec<(f64, f64)> {
        x.iter().zip(t).map(|(a, b)| (a.0, a.1 - b.1)).collect()
    };
    let mut panels = vec![
        wheel_panel("rear left n_rl", &c.n_rl_measured, &c.n_rl_compensated, &c.n_rl_true),
        wheel_panel("rear right n_rr", &c.n_rr_measured, &c.n_rr_compensated, &c.n_rr_true),
    ];
    if let Some(t) = &c.n_rl_true {
        panels.push(Panel {
            equal_aspect: false,
            labels: Vec::new(),
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
        labels: Vec::new(),
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
    let svg = figure_svg(
        &format!("Fig. 6: input compensation on the segment at sample {}", e.figure6.segment_start),
        (1100, 380 * rows as u32),
        (rows, 2),
        &panels,
    )?;
    Ok((name, svg))
}

/// Fig. 7: per-segment θ, raw vs compensated.
fn fig7(e: &Experiment) -> Result<Figure> {
    let name = FIGURES[3];
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
            let hl = final_and_truth_lines(e, *f);
            let vals: Vec<f64> = raw.iter().chain(&cmp).map(|q| q.1).collect();
            let keep: Vec<f64> = hl.iter().map(|h| h.y).collect();
            Panel {
                equal_aspect: false,
                labels: Vec::new(),
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
    let svg = figure_svg("Fig. 7: per-segment G-N estimates, raw vs compensated inputs", (1100, 780), (2, 2), &panels)?;
    Ok((name, svg))
}

/// Fig. 8: Ē_p per segment and per batch, raw vs compensated.
fn fig8(e: &Experiment) -> Result<Figure> {
    let name = FIGURES[4];
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
    let keep: Vec<f64> = ep_lines(e).iter().map(|h| h.y).collect();
    let panels = vec![
        Panel {
            equal_aspect: false,
            labels: Vec::new(),
            title: "per segment (G-N on one segment)".into(),
            x_label: "selected segment index".into(),
            y_label: "Ē_p (m)".into(),
            series: vec![
                Series::points("raw inputs", seg_raw, plots::BLUE),
                Series::points("compensated inputs", seg_cmp, plots::ORANGE),
            ],
            y_range: plots::robust_range(&seg_vals, &keep),
            hlines: ep_lines(e),
        },
        Panel {
            equal_aspect: false,
            labels: Vec::new(),
            title: format!("per batch (N = {}), sorted", e.batch_size),
            x_label: "rank of batch result".into(),
            y_label: "Ē_p (m)".into(),
            series: vec![
                Series::line("raw inputs", ranked(&b_raw), plots::BLUE),
                Series::line("compensated inputs", ranked(&b_cmp), plots::ORANGE),
            ],
            hlines: ep_lines(e),
            y_range: None,
        },
    ];
    let svg = figure_svg("Fig. 8: validation error Ē_p, raw vs compensated inputs", (1100, 480), (1, 2), &panels)?;
    Ok((name, svg))
}
