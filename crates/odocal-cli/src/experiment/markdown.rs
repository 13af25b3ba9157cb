//! `report.md` of `odocal experiment`: the estimates against the truth and
//! the reachable minimum, the Cramér–Rao bound, the paper's Table 1 and the
//! numbers behind the figures.

use std::fmt::Write as _;

use odocal::experiment::{CramerRao, Experiment, Scored};

use super::summary::{summaries, Summary};
use super::Outputs;

/// The report.
pub fn report_md(e: &Experiment, out: &Outputs) -> String {
    let mut o = String::new();
    let e_min = e.reachable_minimum.scored.mean_position_error_m;
    header(&mut o, e, out);
    estimates(&mut o, e, e_min);
    let mut rows = vec![("θ_nom (paper)".to_string(), e.nominal), ("θ_0 (G-N start)".to_string(), e.initial_guess)];
    rows.extend(e.picked.iter().enumerate().map(|(i, p)| (format!("θ_B,I({})", i + 1), *p)));
    rows.push(("**θ_B,F (3-step)**".into(), e.final_estimate));
    rows.push(("reachable minimum".into(), e.reachable_minimum.scored));
    crb_section(&mut o, &e.cramer_rao, &rows, e.timing_s.cramer_rao_bound);
    table1(&mut o, e, e_min);
    per_segment(&mut o, e);
    compensation(&mut o, e);
    figures_and_warnings(&mut o, e, out);
    timing(&mut o, out);
    o
}

/// The title, the drive and how to read the tables.
fn header(o: &mut String, e: &Experiment, out: &Outputs) {
    let _ = writeln!(o, "# odocal experiment — the paper's §6 on one drive\n");
    let _ = writeln!(
        o,
        "Drive: {} — {} samples, {:.2} km, t_s = {} s{}.  \nSegments: {} cut, {} selected, {} validation. QP solver: {}.\n",
        md_text(&out.drive.source),
        out.drive.samples,
        out.drive.distance_km,
        seconds(out.drive.sample_time_s),
        out.drive.wheel_rotation_rel_error_rms.map(|w| format!(", wheel error {:.2} % rms", w * 100.0)).unwrap_or_default(),
        e.segments.cut,
        e.segments.selected,
        e.segments.validation,
        e.qp_solver
    );
    let _ = writeln!(
        o,
        "Ē_p is the mean dead-reckoning position error on the validation segments with the *measured* inputs (docs/method.md §7). \
         Δ columns are θ − θ_true in mm (c_d, d: mm and mm/(m/s²)); Ē_p,min is the reachable minimum.\n"
    );
}

/// A sample time in seconds as a short number: `0.025`, not the
/// `0.025000000000000005` a drive's stamps average to.
fn seconds(t: f64) -> String {
    let s = format!("{t:.9}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// Appends a table heading and [`TABLE_HEAD`] without the blank line after it.
fn table_heading(o: &mut String, heading: &str) {
    let _ = writeln!(o, "{heading}{TABLE_HEAD}");
    o.truncate(o.trim_end().len());
    o.push('\n');
}

/// The estimates table and the final fit's and the search's accounts.
fn estimates(o: &mut String, e: &Experiment, e_min: f64) {
    table_heading(o, "## Estimates\n\n");
    if let Some(t) = &e.truth {
        theta_row(o, "θ_true", t, e_min);
    }
    theta_row(o, "θ_nom (paper)", &e.nominal, e_min);
    theta_row(o, "θ_0 (G-N start)", &e.initial_guess, e_min);
    for (i, p) in e.picked.iter().enumerate() {
        theta_row(o, &format!("θ_B,I({})", i + 1), p, e_min);
    }
    theta_row(o, "**θ_B,F (3-step)**", &e.final_estimate, e_min);
    theta_row(o, "reachable minimum", &e.reachable_minimum.scored, e_min);
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
}

/// The paper's Table 1: one segment and one batch, raw vs compensated inputs.
fn table1(o: &mut String, e: &Experiment, e_min: f64) {
    table_heading(o, "\n## Table 1: one segment and one batch, raw vs compensated inputs\n\n");
    let t1 = &e.table1;
    theta_row(o, &format!("segment @{} raw", t1.segment_start), &t1.segment_raw, e_min);
    theta_row(o, &format!("segment @{} compensated", t1.segment_start), &t1.segment_compensated, e_min);
    theta_row(o, &format!("batch {} raw", t1.batch_index), &t1.batch_raw, e_min);
    theta_row(o, &format!("batch {} compensated", t1.batch_index), &t1.batch_compensated, e_min);
    let _ = writeln!(
        o,
        "\nThe segment is the compensated segment with the highest peak yaw rate; the batch is the middle picked step-1 batch (segments starting at samples {:?}).",
        t1.batch_starts
    );
}

/// The per-segment and per-batch summaries (Fig. 7/8).
fn per_segment(o: &mut String, e: &Experiment) {
    let _ = writeln!(
        o,
        "\n## Per-segment and batch estimates (Fig. 7/8)\n\nPure G-N from θ_0 on each selected segment alone, and on the {} step-1 batches of N = {}, with raw and with compensated inputs. \"median abs Δ\" is the median absolute error against θ_true.\n",
        e.batches.len(),
        e.batch_size
    );
    let _ = writeln!(o, "| | count | min Ē_p (m) | median Ē_p (m) | max Ē_p (m) | median abs Δc_e (mm) | median abs Δc_d (mm) | median abs Δt_r (mm) | median abs Δd (mm/(m/s²)) |");
    let _ = writeln!(o, "|---|---|---|---|---|---|---|---|---|");
    for (_, name, s) in summaries(e) {
        summary_row(o, name, &s);
    }
}

/// The input compensation (step 2) and the Fig. 6 segment.
fn compensation(o: &mut String, e: &Experiment) {
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
}

/// The figures with their captions, and every warning.
fn figures_and_warnings(o: &mut String, e: &Experiment, out: &Outputs) {
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
            let _ = writeln!(o, "- {}", md_text(&w.to_string()));
        }
        o.push('\n');
    }
}

/// The wall time of each stage.
fn timing(o: &mut String, out: &Outputs) {
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
    let s = <[_; 4]>::from(sigma);
    let m = c.sigma_mean_only.map(<[f64; 4]>::from);
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
    if let Some(m) = c.sigma_noise_estimated.map(<[f64; 4]>::from) {
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
        let (d, r) = (<[_; 4]>::from(d), <[_; 4]>::from(r));
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

/// Text from the user (a path, a warning quoting one) as Markdown shows it
/// literally: control characters escaped, HTML's `<`, `>`, `&` as entities
/// (a renderer would run `<img onerror=…>`), and Markdown's punctuation
/// backslash-escaped (no link, emphasis or table cell is started).
fn md_text(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut buf = [0u8; 4];
    for c in text.chars() {
        if let std::borrow::Cow::Owned(escaped) = odocal::output::visible(c.encode_utf8(&mut buf)) {
            out.push_str(&escaped);
            continue;
        }
        match c {
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '&' => out.push_str("&amp;"),
            '\\' | '`' | '*' | '_' | '[' | ']' | '(' | ')' | '#' | '!' | '|' | '{' | '}' => {
                out.push('\\');
                out.push(c);
            }
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use odocal::Theta;

    fn scored(err: Option<Theta>, ratio: Option<Theta>) -> Scored {
        Scored { theta: Theta::PAPER_INITIAL, mean_position_error_m: 1.0, error_vs_true: err, error_over_crb: ratio }
    }

    #[test]
    fn a_sample_time_is_a_short_number() {
        assert_eq!(seconds(0.025000000000000005), "0.025");
        assert_eq!(seconds(0.01), "0.01");
        assert_eq!(seconds(1.0), "1");
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

    #[test]
    fn user_text_cannot_inject_html_or_markdown() {
        let t = super::md_text("x<img src=x onerror=alert(1)>[a](b)\n# h");
        assert_eq!(t, "x&lt;img src=x onerror=alert\\(1\\)&gt;\\[a\\]\\(b\\)\\n\\# h");
    }
}
