//! `odocal calibrate --method eiv`: JSON (noise model, termination, which
//! estimate), terminal section, flags of other methods rejected.

use crate::common;

use common::{odocal, simulated_drive, text};

#[test]
fn eiv_on_a_small_simulated_drive() {
    let d = tempfile::tempdir().expect("tmp");
    let dstr: &str = &simulated_drive(d.path(), "drive.csv", &["--seed", "4", "--length-km", "3", "--noise", "white"]);

    let o = odocal(&["calibrate", dstr, "--method", "eiv", "--eiv-window", "1500", "--json", "-"]);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(r["method"], "eiv");
    assert_eq!(r["options"]["method"]["name"], "eiv");
    assert!(r["eiv"]["noise"]["wheel_white_rel_sigma"].is_f64(), "{}", r["eiv"]);
    assert!(r["eiv"]["noise"]["position_drift_sigma_m"].is_f64());
    assert!(r["noise_start"]["wheel_common_time_constant_s"].is_f64());
    assert!(r["eiv"]["termination"]["reason"].is_string(), "{}", r["eiv"]["termination"]);
    assert!(r["eiv"]["windows"].as_array().is_some_and(|w| !w.is_empty()));
    assert!(["eiv", "batch-gn-fallback"].contains(&r["eiv_result"].as_str().expect("eiv_result")));
    // The start: batch G-N over every cut segment.
    assert_eq!(r["identification"]["segments"], r["segments"]["cut"]);
    for k in ["c_e", "c_d", "t_r", "d"] {
        assert!(r["theta"][k].is_f64());
    }

    // Terminal: the EIV section with the noise model in physical units.
    let model = d.path().join("noise.toml");
    std::fs::write(&model, "wheel_white_rel_sigma = 0.008\nwheel_common_rel_sigma = 0.0001\n").expect("write");
    let o = odocal(&[
        "calibrate",
        dstr,
        "--method",
        "eiv",
        "--eiv-window",
        "1500",
        "--fix-noise",
        "--noise-model",
        model.to_str().expect("utf8"),
        "--no-fallback",
        "--bootstrap",
        "3",
    ]);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
    let out = text(&o.stdout);
    assert!(out.starts_with("odocal calibrate — method eiv"), "{out}");
    assert!(out.contains("all used (no yaw-rate selection)"), "{out}");
    assert!(out.contains("EIV start, batch G-N:"), "{out}");
    assert!(out.contains("noise, fixed    : σ_white 0.800 %"), "{out}");
    assert!(!out.contains("σ widened"), "a fixed noise model adds no η term: {out}");
    assert!(out.contains("σ_c 0.010 %"), "{out}");
    assert!(out.contains("  result: EIV estimate"), "{out}");
    assert!(out.contains("  bootstrap: 3 replicates (0 failed), 95 % basic intervals"), "{out}");
    assert!(out.contains("    t_r  ["), "{out}");
}

/// `--known-noise` and a noise model's `known`: the stated levels are held
/// (reported as the start's), the others estimated; the terminal names them.
#[test]
fn known_noise_sources_are_held_at_the_stated_level() {
    let d = tempfile::tempdir().expect("tmp");
    let dstr: &str = &simulated_drive(d.path(), "drive.csv", &["--seed", "4", "--length-km", "2", "--noise", "paper"]);
    let model = d.path().join("noise.toml");
    std::fs::write(&model, "heading_white_sigma_rad = 0.0002\nknown = [\"heading_white\"]\n").expect("write");
    let mstr = model.to_str().expect("utf8");
    let runs =
        [vec!["--known-noise", "heading-white,pose-white"], vec!["--noise-model", mstr, "--known-noise", "pose_white"]];
    let json = d.path().join("r.json");
    let jstr = json.to_str().expect("utf8");
    let html = d.path().join("r.html");
    let hstr = html.to_str().expect("utf8");
    for flags in runs {
        let args = [
            &["calibrate", dstr, "--eiv-window", "1500", "--no-fallback", "--json", jstr, "--report", hstr][..],
            &flags[..],
        ];
        let o = odocal(&args.concat());
        assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).expect("report")).expect("json");
        let held = &r["options"]["method"]["filter"]["eta_held"];
        assert_eq!(held, &serde_json::json!([false, false, false, true, false, true]), "{flags:?}");
        for k in ["heading_white_sigma_rad", "position_white_sigma_m"] {
            assert_eq!(r["eiv"]["noise"][k], r["noise_start"][k], "{flags:?}: {k} held");
        }
        assert_ne!(r["eiv"]["noise"]["wheel_white_rel_sigma"], r["noise_start"]["wheel_white_rel_sigma"], "estimated");
        assert!(
            text(&o.stdout).contains("  known (held at the start): pose_white, heading_white"),
            "{}",
            text(&o.stdout)
        );
        // The default σ leaves out the noise-estimate term, and the terminal
        // does not claim a widening.
        let widened = r["eiv"]["sigma_noise_estimate"].as_array().expect("sigma_noise_estimate");
        assert!(widened.iter().all(|x| x.as_f64() == Some(0.0)), "{widened:?}");
        assert!(!text(&o.stdout).contains("σ widened for the estimated noise levels"), "{}", text(&o.stdout));
        // The HTML report carries the same account of the EIV fit.
        let page = std::fs::read_to_string(&html).expect("html");
        assert!(page.contains("<section id=\"method\">"), "{flags:?}");
        assert!(page.contains("  known (held at the start): pose_white, heading_white"), "{flags:?}");
    }
    let o = odocal(&["calibrate", dstr, "--known-noise", "heading"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("heading_white"), "{}", text(&o.stderr));
    let o = odocal(&["calibrate", dstr, "--method", "batch-gn", "--known-noise", "heading-white"]);
    assert!(text(&o.stderr).contains("--known-noise applies to --method eiv only"), "{}", text(&o.stderr));
    // A known heading noise whose scale is tied to the position noise's is a
    // usage error naming the flags; with the position noise known too it holds.
    let o = odocal(&["calibrate", dstr, "--known-noise", "heading-white", "--heading-noise", "tied"]);
    let e = text(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("--known-noise names heading_white") && e.contains("--heading-noise tied"), "{e}");
    assert!(!e.contains("eta_held"), "{e}");
    let o = odocal(&["calibrate", dstr, "--known-noise", "heading-white,pose-white", "--heading-noise", "tied"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
}

#[test]
fn eiv_noise_model_shape_flags_reach_the_options() {
    let d = tempfile::tempdir().expect("tmp");
    let dstr: &str = &simulated_drive(d.path(), "drive.csv", &["--seed", "4", "--length-km", "1", "--noise", "white"]);
    for (q, h, l, a, q_json, h_json, l_json, a_json) in [
        ("counting", "separate", "given", "stated", "counting", "separate", "given", "stated"),
        (
            "process",
            "tied",
            "scaled",
            "tied",
            "process_noise",
            "tied_to_position",
            "scaled_with_white",
            "tied_to_wheel_white",
        ),
    ] {
        let args = ["calibrate", dstr, "--method", "eiv", "--eiv-window", "1500", "--fix-noise"];
        let shape =
            ["--quantisation", q, "--heading-noise", h, "--quantisation-level", l, "--lateral-noise", a, "--json", "-"];
        let o = odocal(&[&args[..], &shape[..]].concat());
        assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
        let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        let f = &r["options"]["method"]["filter"];
        assert_eq!(f["quantisation"], q_json, "{f}");
        assert_eq!(f["heading_scale"], h_json, "{f}");
        assert_eq!(f["quantisation_level"], l_json, "{f}");
        assert_eq!(f["lateral_noise"], a_json, "{f}");
    }
    // Stated with the noise estimated: the reported a_y and β σ are the
    // starting model's, whatever η_0 became.
    let args =
        ["calibrate", dstr, "--method", "eiv", "--eiv-window", "1500", "--lateral-noise", "stated", "--json", "-"];
    let o = odocal(&args);
    assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    let (start, end) = (&r["noise_start"], &r["eiv"]["noise"]);
    assert_ne!(r["eiv"]["eta"][0].as_f64(), Some(0.0), "η_0 was estimated: {}", r["eiv"]["eta"]);
    for k in ["lateral_acceleration_sigma_m_per_s2", "sideslip_sigma_rad"] {
        assert_eq!(start[k], end[k], "{k}");
    }
    assert_ne!(start["wheel_white_rel_sigma"], end["wheel_white_rel_sigma"]);
    // From the readings: the simulator's paper encoder (2048 ticks at
    // 40 Hz) is found through the CSV; the white preset has no encoder.
    let pstr: &str = &simulated_drive(d.path(), "paper.csv", &["--seed", "4", "--length-km", "1", "--noise", "paper"]);
    for (file, expected) in [(pstr, Some(1.0 / (2048.0 * 0.025))), (dstr, None)] {
        let args = ["calibrate", file, "--method", "eiv", "--eiv-window", "1500", "--fix-noise"];
        let o = odocal(&[&args[..], &["--quantisation-level", "from-readings", "--json", "-"]].concat());
        assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
        let r: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
        assert_eq!(r["eiv"]["quantisation_step_from_readings"].as_f64(), expected, "{file}");
    }
    let o = odocal(&["calibrate", dstr, "--method", "eiv", "--quantisation", "ticks"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("possible values: process, measurement, counting"), "{}", text(&o.stderr));
}

/// The default bias correction (B = 4, of c_e and c_d), `--correct-bias B` and
/// `--correct-bias-of`: the named parameters corrected by a bootstrap in
/// antithetic pairs on the smoothed trajectory whose replicates hold the
/// fitted noise model; their σ carries the correction's Monte Carlo error,
/// the others' are the uncorrected fit's; `--no-bias-correction` returns
/// the uncorrected fit; B must be even; neither with another method.
#[test]
fn correct_bias_corrects_the_named_parameters_with_held_noise() {
    let d = tempfile::tempdir().expect("tmp");
    let dstr: &str = &simulated_drive(d.path(), "drive.csv", &["--seed", "6", "--length-km", "2", "--noise", "paper"]);
    let base = ["calibrate", dstr, "--method", "eiv", "--no-fallback", "--json", "-"];
    let run = |extra: &[&str]| {
        let o = odocal(&[&base[..], extra].concat());
        assert!(o.status.code() == Some(0) || o.status.code() == Some(3), "{}", text(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).expect("json")
    };
    let plain = run(&["--no-bias-correction"]);
    assert!(plain["options"]["method"]["correct_bias"].is_null(), "{}", plain["options"]["method"]);
    assert_eq!(plain["eiv"]["bias_subtracted"], serde_json::json!([0.0, 0.0, 0.0, 0.0]));
    let default = run(&[]);
    let want = serde_json::json!({"replicates": 4, "seed": 0, "parameters": ["c_e", "c_d"]});
    assert_eq!(default["options"]["method"]["correct_bias"], want);
    assert_eq!(default["eiv"]["theta_uncorrected"], plain["eiv"]["theta"]);
    let r = run(&["--correct-bias", "2", "--bootstrap-seed", "7", "--correct-bias-of", "c_e,c_d,t_r,d"]);
    let want = serde_json::json!({"replicates": 2, "seed": 7, "parameters": ["c_e", "c_d", "t_r", "d"]});
    assert_eq!(r["options"]["method"]["correct_bias"], want);
    assert_eq!(r["eiv"]["theta_uncorrected"], plain["eiv"]["theta"]);
    for (name, c, corrected) in [("default", &default, [true, true, false, false]), ("every parameter", &r, [true; 4])]
    {
        let (e, p) = (&c["eiv"], &plain["eiv"]);
        for i in 0..4 {
            let on = corrected[i] && e["free"][i].as_bool().expect("free");
            let mc = e["sigma_bias_correction"][i].as_f64().expect("mc σ");
            let (s, s0) = (e["sigma"][i].as_f64().expect("σ"), p["sigma"][i].as_f64().expect("σ"));
            let name_i = ["c_e", "c_d", "t_r", "d"][i];
            let (t, t0) = (e["theta"][name_i].as_f64().expect("θ"), p["theta"][name_i].as_f64().expect("θ"));
            if on {
                assert!(mc > 0.0 && (s * s - s0 * s0 - mc * mc).abs() <= 1e-9 * s * s, "{name} {i}: {s} {s0} {mc}");
                assert_ne!(e["bias_subtracted"][i].as_f64(), Some(0.0), "{name} {i}: {}", e["bias_subtracted"]);
            } else {
                assert_eq!(mc.to_bits(), 0.0f64.to_bits(), "{name} {i}: an uncorrected parameter has no Monte Carlo σ");
                assert_eq!((t.to_bits(), s.to_bits()), (t0.to_bits(), s0.to_bits()), "{name} {i}: the fit's θ and σ");
            }
        }
    }
    assert_ne!(default["eiv"]["bias_subtracted"], r["eiv"]["bias_subtracted"]);
    for (extra, want) in [
        (&["--correct-bias", "2", "--no-bias-correction"][..], "cannot be used with"),
        (&["--correct-bias-of", "t_r", "--no-bias-correction"][..], "cannot be used with"),
        (
            &["--correct-bias-of", "lever_x"][..],
            "--correct-bias-of corrects parameters of θ (c_e, c_d, t_r, d), not lever_x",
        ),
        (
            &["--correct-bias", "3"][..],
            "B must be an even number of at least 2 (the replicates come in antithetic pairs), got 3",
        ),
    ] {
        let o = odocal(&[&base[..], extra].concat());
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", text(&o.stderr));
        assert!(text(&o.stderr).contains(want), "{extra:?}: {}", text(&o.stderr));
    }
    let o = odocal(&["calibrate", dstr, "--method", "batch-gn", "--correct-bias", "2"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("--correct-bias applies to --method eiv only"), "{}", text(&o.stderr));
    let o = odocal(&["calibrate", dstr, "--method", "batch-gn", "--no-bias-correction"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("--no-bias-correction applies to --method eiv only"), "{}", text(&o.stderr));
    // Terminal: the correction and its Monte Carlo σ are named (by default).
    let o = odocal(&["calibrate", dstr, "--method", "eiv", "--no-fallback"]);
    let out = text(&o.stdout);
    assert!(out.contains("  bias correction: subtracted c_e "), "{out}");
    assert!(out.contains("  σ includes the correction's Monte Carlo error: c_e "), "{out}");
    // Only the parameters it corrects (c_e and c_d by default) are listed.
    let line = |start: &str| out.lines().find(|l| l.starts_with(start)).unwrap_or_default().to_owned();
    let subtracted = line("  bias correction: subtracted ");
    assert!(subtracted.split(';').next().is_some_and(|s| s.contains("c_d") && !s.contains("t_r")), "{out}");
    let mc = line("  σ includes the correction's Monte Carlo error: ");
    assert!(mc.contains("c_d") && !mc.contains("t_r") && !mc.contains(", d "), "{out}");
    let o = odocal(&["calibrate", dstr, "--method", "eiv", "--no-fallback", "--no-bias-correction"]);
    assert!(!text(&o.stdout).contains("bias correction"), "{}", text(&o.stdout));
}

#[test]
fn eiv_flags_belong_to_eiv() {
    let d = tempfile::tempdir().expect("tmp");
    let p = d.path().join("d.csv");
    let mut rows = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
    for i in 0..10 {
        rows.push_str(&format!("{},{},0,0,5,5,0,0\n", i as f64 * 0.025, i as f64 * 0.25));
    }
    std::fs::write(&p, rows).expect("write");
    let csv = p.to_str().expect("utf8");
    let o = odocal(&["calibrate", csv, "--method", "batch-gn", "--fix-noise", "--no-fallback"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o.stderr).contains("--fix-noise, --no-fallback apply to --method eiv only, not to --method batch-gn"),
        "{}",
        text(&o.stderr)
    );
    let shape = [
        "--quantisation",
        "counting",
        "--quantisation-level",
        "given",
        "--lateral-noise",
        "stated",
        "--heading-noise",
        "tied",
    ];
    let o = odocal(&[&["calibrate", csv, "--method", "batch-gn"][..], &shape[..]].concat());
    assert!(
        text(&o.stderr).contains(
            "--quantisation, --quantisation-level, --lateral-noise, --heading-noise apply to --method eiv only"
        ),
        "{}",
        text(&o.stderr)
    );
    let o = odocal(&["calibrate", csv, "--method", "three-step", "--noise-model", "n.toml"]);
    assert!(text(&o.stderr).contains("--noise-model applies to --method eiv only, not to --method three-step"));
    let o = odocal(&["calibrate", csv, "--method", "eiv", "--batches", "4"]);
    assert!(text(&o.stderr).contains("--batches applies to --method three-step only, not to --method eiv"));
    let o = odocal(&["calibrate", csv, "--method", "eiv", "--noise-model", "/nonexistent/n.toml"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(text(&o.stderr).contains("/nonexistent/n.toml"), "{}", text(&o.stderr));
    let o = odocal(&["calibrate", "--help-all"]);
    let help = text(&o.stdout);
    assert!(help.contains("three-step, batch-gn or eiv") && help.contains("--fix-noise"), "{help}");
}

/// The text names the noise sources at their lower clamp (those the JSON's
/// η puts below 0 without a σ): on the `white` preset, a perfect reference
/// and only white wheel noise, every source but the white wheel noise and
/// the heading's white noise, which is its readings' own (none: R's floor,
/// 1e-5 rad) and named so.
#[test]
fn the_text_names_the_noise_sources_the_data_show_none_of() {
    let d = tempfile::tempdir().expect("tmp");
    let drive =
        crate::common::simulated_drive(d.path(), "w.csv", &["--seed", "2", "--length-km", "3", "--noise", "white"]);
    let json = d.path().join("r.json");
    let o = odocal(&["calibrate", &drive, "--json", json.to_str().expect("utf8")]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).expect("json")).expect("json");
    let (eta, sigma) = (&r["eiv"]["eta"], &r["eiv"]["eta_sigma"]);
    let names = ["wheel_white", "wheel_common", "wheel_differential", "pose_white", "pose_drift", "heading_white"];
    let absent: Vec<&str> = (0..6)
        .filter(|&j| eta[j].as_f64().expect("η") < 0.0 && sigma[j].as_f64().expect("σ") == 0.0)
        .map(|j| names[j])
        .collect();
    assert_eq!(absent, &names[1..5], "{eta} {sigma}");
    let line =
        format!("at the lower clamp (the data show none of it, so its level above reads 0): {}", absent.join(", "));
    assert!(text(&o.stdout).contains(&line), "{}", text(&o.stdout));
    assert_eq!(r["eiv"]["heading_white_at_floor"], true);
    let heading = "heading white noise: its readings' own (0.010 mrad), no level above it fitted";
    assert!(text(&o.stdout).contains(heading), "{}", text(&o.stdout));
}
