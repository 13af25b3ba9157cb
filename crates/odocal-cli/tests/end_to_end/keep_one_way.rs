//! `--keep-one-way` and the manifest's `[calibration] keep_one_way`: on a
//! drive whose turning segments all turn one way, `calibrate` adds the
//! straight segments and warns (`one_way_turns`) unless asked to keep the
//! turning-only selection; the flag wins over the manifest.

use crate::common;

use std::path::Path;

use common::{calibrate_json, canonical_manifest, odocal, setting_outcome, text};
use odocal::model::{step, Input, State, Theta};
use odocal::Drive;
use odocal::Signals;

/// A noise-free oval (300 m straights, 40 m radius half circles) driven
/// counter-clockwise at 10 m/s for 1.3 laps at 40 Hz: every turning
/// segment turns left, and some segments lie on a straight.
fn oval() -> Drive {
    let (theta, t_s, v, r, straight) = (Theta { c_d: 0.5e-3, ..Theta::PAPER_NOMINAL }, 0.025, 10.0, 40.0, 300.0);
    let lap = 2.0 * straight + 2.0 * std::f64::consts::PI * r;
    let n = (1.3 * lap / v / t_s) as usize;
    let mut x = State::zeros();
    let mut s = Signals::default();
    for i in 0..n {
        let along = (i as f64 * v * t_s) % lap;
        let omega = if along % (lap / 2.0) < straight { 0.0 } else { v / r };
        let a_y = v * omega;
        // The model's wheel circumferences, solved for the wheel rotations.
        let c_rl = theta.c_e + theta.c_d / 2.0 + theta.d * a_y;
        let c_rr = theta.c_e - theta.c_d / 2.0 - theta.d * a_y;
        let (n_rl, n_rr) = ((v - omega * theta.t_r / 2.0) / c_rl, (v + omega * theta.t_r / 2.0) / c_rr);
        s.extend([[x[0], x[1], x[2], n_rl, n_rr, 0.0, a_y]]);
        x = step(&x, &Input { n_rl, n_rr, beta: 0.0, a_y }, &theta, t_s);
    }
    odocal::DriveBuilder { t: (0..n).map(|i| i as f64 * t_s).collect(), measured: s, ..Default::default() }
        .build()
        .expect("oval")
}

/// A manifest importing the canonical CSV `drive.csv` beside it, with `extra` appended.
fn manifest(extra: &str) -> String {
    canonical_manifest("drive.csv", extra)
}

fn calibrate(input: &Path, extra: &[&str]) -> serde_json::Value {
    calibrate_json(input, &[&["--method", "batch-gn"], extra].concat())
}

fn one_way_warnings(r: &serde_json::Value) -> usize {
    r["warnings"].as_array().expect("warnings").iter().filter(|w| w["kind"] == "one_way_turns").count()
}

#[test]
fn keep_one_way_flag_and_manifest_setting_keep_the_turning_selection() {
    let d = tempfile::tempdir().expect("tmp");
    let csv = d.path().join("drive.csv");
    oval().write_csv(&csv).expect("write csv");

    // Default: the straight segments are added, saying so.
    let r = calibrate(&csv, &[]);
    assert_eq!(one_way_warnings(&r), 1, "{}", r["warnings"]);
    let (cut, selected) = (r["segments"]["cut"].as_u64(), r["segments"]["selected"].as_u64());
    assert!(selected < cut, "{cut:?} cut, {selected:?} selected");
    assert_eq!(r["options"]["keep_one_way_selection"], false);

    // --keep-one-way: the paper's selection, no warning.
    let r = calibrate(&csv, &["--keep-one-way"]);
    assert_eq!(one_way_warnings(&r), 0, "{}", r["warnings"]);
    assert_eq!(r["options"]["keep_one_way_selection"], true);

    // The manifest's [calibration] keep_one_way = true: used.
    let m = d.path().join("keep.toml");
    std::fs::write(&m, manifest("\n[calibration]\nkeep_one_way = true\n")).expect("write");
    let r = calibrate(&m, &[]);
    assert_eq!(one_way_warnings(&r), 0, "{}", r["warnings"]);
    assert_eq!(setting_outcome(&r, "calibration.keep_one_way"), "used");

    // keep_one_way = false in the manifest, --keep-one-way on the command line: the flag wins.
    let m = d.path().join("add.toml");
    std::fs::write(&m, manifest("\n[calibration]\nkeep_one_way = false\n")).expect("write");
    let r = calibrate(&m, &[]);
    assert_eq!(one_way_warnings(&r), 1, "{}", r["warnings"]);
    assert_eq!(setting_outcome(&r, "calibration.keep_one_way"), "used");
    let r = calibrate(&m, &["--keep-one-way"]);
    assert_eq!(one_way_warnings(&r), 0, "{}", r["warnings"]);
    assert_eq!(setting_outcome(&r, "calibration.keep_one_way"), "overridden");

    // The EIV method selects no turning segments: the flag is an error there.
    let o = odocal(&["calibrate", csv.to_str().expect("utf8"), "--method", "eiv", "--keep-one-way"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("--keep-one-way applies to"), "{}", text(&o.stderr));
}
