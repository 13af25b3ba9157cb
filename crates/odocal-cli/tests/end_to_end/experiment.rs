//! End-to-end test of `odocal experiment` on a small simulated drive: the
//! run succeeds, every SVG is well-formed XML with axis labels, report.md
//! links every figure, experiment.json holds the key numbers.

use std::path::Path;
use std::process::Command;

use quick_xml::events::Event;
use quick_xml::Reader;

/// Parses an SVG to the end; returns the text content of its `<text>` elements.
fn svg_texts(path: &Path) -> Vec<String> {
    let xml = std::fs::read_to_string(path).expect("read svg");
    let mut reader = Reader::from_str(&xml);
    let (mut texts, mut in_text, mut saw_svg) = (Vec::new(), false, false);
    loop {
        match reader.read_event() {
            Ok(Event::Start(e)) => {
                saw_svg |= e.name().as_ref() == b"svg";
                in_text = e.name().as_ref() == b"text";
            }
            Ok(Event::Text(t)) if in_text => {
                texts.push(t.decode().expect("utf8 text").trim().to_string());
            }
            Ok(Event::End(_)) => in_text = false,
            Ok(Event::Eof) => break,
            Err(e) => panic!("{}: not well-formed XML at {}: {e}", path.display(), reader.buffer_position()),
            Ok(_) => {}
        }
    }
    assert!(saw_svg, "{}: no <svg> root", path.display());
    texts
}

fn number(v: &serde_json::Value, pointer: &str) -> f64 {
    v.pointer(pointer).and_then(serde_json::Value::as_f64).unwrap_or_else(|| panic!("experiment.json lacks {pointer}"))
}

#[test]
fn experiment_runs_end_to_end() {
    let dir = tempfile::tempdir().expect("tmp");
    let out = dir.path().join("exp");
    let o = Command::new(env!("CARGO_BIN_EXE_odocal"))
        .args(["experiment", "--seed", "3", "--length-km", "3", "--batches", "6", "--noise", "paper", "--quiet"])
        .arg("--out")
        .arg(&out)
        .output()
        .expect("run odocal");
    assert!(o.status.success(), "stderr: {}", String::from_utf8_lossy(&o.stderr));

    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md");
    let figures = [
        "fig4_batch_errors.svg",
        "fig5_picked_theta.svg",
        "fig6_compensation.svg",
        "fig7_segment_theta.svg",
        "fig8_errors.svg",
    ];
    for (i, f) in figures.iter().enumerate() {
        assert!(report.contains(&format!("]({f})")), "report.md does not link {f}");
        assert!(report.contains(&format!("Fig. {}", i + 4)), "report.md does not mention Fig. {}", i + 4);
        let texts = svg_texts(&out.join(f));
        assert!(texts.iter().any(|t| t.starts_with(&format!("Fig. {}", i + 4))), "{f}: no title in {texts:?}");
        assert!(texts.iter().any(|t| t.contains('(') && t.contains(')')), "{f}: no axis label with unit");
    }
    for needle in
        ["Table 1", "θ_true", "θ_nom", "reachable minimum", "θ_B,F", "θ_B,I(5)", "Cramér–Rao bound", "| σ_CRB |"]
    {
        assert!(report.contains(needle), "report.md lacks '{needle}'");
    }

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("experiment.json")).expect("json")).expect("valid json");
    let e_min = number(&json, "/reachable_minimum/mean_position_error_m");
    for p in [
        "/truth/mean_position_error_m",
        "/nominal/mean_position_error_m",
        "/final_estimate/mean_position_error_m",
        "/table1/segment_raw/mean_position_error_m",
        "/table1/segment_compensated/mean_position_error_m",
        "/table1/batch_raw/mean_position_error_m",
        "/table1/batch_compensated/mean_position_error_m",
    ] {
        let e = number(&json, p);
        assert!(e.is_finite() && e > 0.0, "{p} = {e}");
        // The reachable minimum is seeded with the estimates; θ_true and θ_nom are not, but
        // a global search over the default box should not miss them by more than rounding.
        assert!(e >= e_min - 1e-6, "{p} = {e} is below the reachable minimum {e_min}");
    }
    assert!((number(&json, "/truth/theta/c_e") - 1.95).abs() < 1e-12);
    assert_eq!(json["batches"].as_array().map(Vec::len), Some(6));
    assert_eq!(json["picked"].as_array().map(Vec::len), Some(5));
    assert!(number(&json, "/final_estimate/error_vs_true/c_e").abs() < 0.05, "c_e within 5 cm of the truth");
    assert!(json["per_segment"].as_array().is_some_and(|a| !a.is_empty()));
    // The Cramér–Rao column: σ_CRB > 0 and error/σ_CRB beside every error.
    for p in ["c_e", "c_d", "t_r", "d"] {
        let sigma = number(&json, &format!("/cramer_rao/sigma/{p}"));
        assert!(sigma > 0.0, "σ_CRB {p} = {sigma}");
        let err = number(&json, &format!("/final_estimate/error_vs_true/{p}"));
        let ratio = number(&json, &format!("/final_estimate/error_over_crb/{p}"));
        assert!((ratio * sigma - err).abs() <= 1e-9 * err.abs().max(1e-9), "{p}: {ratio} × {sigma} ≠ {err}");
    }
    assert!(json["cramer_rao"]["unavailable"].is_null());
    assert!(number(&json, "/timing_s/cramer_rao_bound") >= 0.0);
}
