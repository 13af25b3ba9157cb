#![allow(clippy::float_cmp)] // parsed and copied values are exact

use std::path::Path;

use serde_json::json;

use super::resolve::SettingOutcome;
use super::*;
use crate::calibrate::eiv::NoiseSpec;
use crate::calibrate::CalibrationOptions;
use crate::eiv::{NoiseModel, NoiseSource};
use crate::io::import::tests::small_case;
use crate::io::import::{load_drive, Manifest, ReferenceSpec};
use crate::model::extrinsics::Extrinsics;

/// The small manifest of the import tests with `extra` appended, parsed
/// and its settings read.
fn parsed(extra: &str) -> Result<(Manifest, ManifestSettings)> {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text = std::fs::read_to_string(&path).expect("read") + extra;
    let m = Manifest::parse(&text, &path)?;
    let s = ManifestSettings::of_manifest(&m)?;
    Ok((m, s))
}

/// The message of a bad setting, without the manifest's (temporary) path.
fn error(extra: &str) -> String {
    let e = parsed(extra).expect_err("a bad setting").to_string();
    e.split_once("m.toml: ").map_or(e.clone(), |(_, m)| m.to_string())
}

/// The settings of a JSON object.
fn json_settings(v: serde_json::Value) -> Settings {
    Settings::from_json(v).expect("settings")
}

#[test]
fn every_key_is_a_field_and_the_precedence_is_key_by_key() {
    let all = json_settings(json!({
        "method": "eiv", "theta0": [2.0, 0.0, 1.6, 0.0], "fix": "d", "auto_fix": true, "seed": 3,
        "max_iterations": 7, "min_yaw_rate": 0.1, "keep_one_way": false, "segment_length": 400,
        "segment_stride": 50, "validation_length": 800, "estimate": ["lever-arm"], "lever_arm": [1.0, 0.5],
        "heading_offset": 0.01, "batches": 9, "batch_size": 8, "picks": 3, "final_segments": 5,
        "qp_solver": "clarabel", "noise_model": {"wheel_white_rel_sigma": 0.02}, "known_noise": "pose_white",
        "fix_noise": true, "fallback": false, "eiv_window": 1500, "quantisation": "process",
        "quantisation_level": "given", "lateral_noise": "stated", "heading_noise": "tied", "bootstrap": 10,
        "bootstrap_seed": 4, "correct_bias": 2, "correct_bias_of": "c_e,t_r"
    }));
    assert_eq!(all.stated(), Settings::KEYS, "every key deserializes into its field");
    let none = Settings::default();
    assert_eq!(all.clone().over(none.clone()), all);
    assert_eq!(none.clone().over(all.clone()), all);
    let seed = Settings { seed: Some(1), ..Default::default() };
    let over = seed.over(all.clone());
    assert_eq!((over.seed, over.batches), (Some(1), Some(9)), "the upper value wins, the lower fills the rest");
    assert_eq!(all.without("seed").seed, None);
}

#[test]
fn values_take_the_command_lines_text_and_lists_alike() {
    let a =
        json_settings(json!({"fix": "c_d, t_r", "known_noise": "heading-white,pose_white", "final_segments": "all"}));
    let b = json_settings(json!({"fix": ["c_d", "t_r"], "known_noise": ["heading_white", "pose-white"]}));
    assert_eq!((a.fix, &a.known_noise), (b.fix, &b.known_noise));
    assert_eq!(a.final_segments, Some(FinalSegments::All));
    let t = json_settings(json!({"theta0": "2.0,0,1.6,0"})).theta0;
    assert_eq!(t, json_settings(json!({"theta0": {"c_e": 2.0, "c_d": 0.0, "t_r": 1.6, "d": 0.0}})).theta0);
    assert_eq!(t, Some(Theta::PAPER_INITIAL));
    let toml_settings: Settings = toml::from_str("estimate = [\"heading-offset\"]\nseed = 2").expect("toml");
    assert_eq!(toml_settings.estimate, Some(ParamSet::EMPTY.with(Param::HeadingOffset)));
}

#[test]
fn bad_values_and_keys_name_the_key() {
    let e = |v| Settings::from_json(v).expect_err("bad").to_string();
    assert_eq!(
        e(json!({"method": "newton"})),
        "invalid option `method`: invalid method 'newton': use three-step, batch-gn or eiv"
    );
    assert_eq!(e(json!({"lever_arm": [1.0]})), "invalid option `lever_arm`: expected 2 values x, y, got 1");
    assert_eq!(e(json!({"lever_arm": [1.0, 0.0, 7.0]})), "invalid option `lever_arm`: expected 2 values x, y, got 3");
    assert!(e(json!({"batches": "x"})).starts_with("invalid option `batches`: invalid type: string"));
    assert!(e(json!({"theta0": [1, 2]})).contains("expected 4 values c_e, c_d, t_r, d, got 2"));
    assert!(e(json!({"batchez": 3})).starts_with("invalid option `settings`: unknown field `batchez`, expected one of"));
    assert_eq!(Theta::try_from(json!("2.0,0,1.6,0")).expect("θ"), Theta::PAPER_INITIAL);
    assert!(Theta::try_from(json!([2.0, 0.0, -1.0, 0.0])).is_err(), "checked");
    assert!(Theta::try_from(json!(true)).expect_err("form").to_string().contains("give θ as"));
}

#[test]
fn a_theta_table_is_checked_as_the_other_forms() {
    let e = |v| Settings::from_json(v).expect_err("bad").to_string();
    let paper = json!({"c_e": 2.0, "c_d": 0.0, "t_r": 1.6, "d": 0.0});
    assert_eq!(Theta::try_from(paper.clone()).expect("θ"), Theta::PAPER_INITIAL);
    let mut typo = paper.clone();
    typo["x"] = json!(1.0);
    let m = Theta::try_from(typo.clone()).expect_err("unknown key").to_string();
    assert!(m.contains("unknown key 'x'"), "{m}");
    assert!(e(json!({ "theta0": typo })).contains("unknown key 'x'"), "the setting alike");
    let toml_typo: std::result::Result<Settings, _> =
        toml::from_str("theta0 = {c_e = 2.0, c_d = 0, t_r = 1.6, d = 0, x = 1}");
    assert!(toml_typo.expect_err("manifest").to_string().contains("unknown key 'x'"));
    let missing = json!({"c_e": 2.0, "c_d": 0.0, "t_r": 1.6});
    assert!(Theta::try_from(missing).expect_err("missing").to_string().contains("missing d"));
    // The physical limits, as for "c_e,c_d,t_r,d" and four numbers.
    let huge = json!({"c_e": 2000.0, "c_d": 0.0, "t_r": 1.6, "d": 0.0});
    let m = Theta::try_from(huge.clone()).expect_err("c_e 2000 m").to_string();
    assert!(m.contains("c_e = 2000 m is outside 0.05 … 20 m"), "{m}");
    assert!(e(json!({ "theta0": huge })).contains("is outside 0.05 … 20 m"), "the setting alike");
}

#[test]
fn a_seed_is_an_integer_of_64_bits() {
    let e = |v| Settings::from_json(v).expect_err("bad").to_string();
    let s = json_settings(json!({"seed": u64::MAX, "bootstrap_seed": 7}));
    assert_eq!((s.seed, s.bootstrap_seed), (Some(u64::MAX), Some(7)));
    for (v, got) in [(json!(-1), "-1"), (json!(1.8446744073709552e19), "1.8446744073709552e19"), (json!(0.5), "0.5")] {
        for key in ["seed", "bootstrap_seed"] {
            let m = e(json!({ key: v.clone() }));
            assert_eq!(
                m,
                format!("invalid option `{key}`: {got} is not a seed, an integer 0 … 2^64 − 1 (18446744073709551615)")
            );
        }
    }
    let toml_negative: std::result::Result<Settings, _> = toml::from_str("seed = -3");
    assert!(toml_negative.expect_err("negative").to_string().contains("-3 is not a seed"));
}

#[test]
fn the_mapping_matches_the_options_each_key_names() {
    let s = json_settings(json!({
        "method": "three-step", "batches": 9, "batch_size": 8, "picks": 3, "final_segments": 5, "qp_solver": "clarabel",
        "validation_length": 801, "fix": "d", "seed": 3, "lever_arm": [1.0, 0.5], "estimate": "lever-arm"
    }));
    let o = s.to_options(Caller::Python).expect("options");
    let Method::ThreeStep(t) = &o.method else { panic!("three-step") };
    assert_eq!((t.initial_batches, t.initial_batch_size, t.picks), (9, 8, 3));
    assert_eq!(t.final_segments, FinalSegments::Random(5));
    assert_eq!((o.validation.length_steps, o.validation.stride_steps, o.seed), (801, 400, 3));
    assert_eq!(o.identify.free, ParamSet::THETA.without(Param::D).union(ParamSet::LEVER_ARM));
    assert_eq!((o.identify.extrinsics.lever_x, o.identify.extrinsics.lever_y), (1.0, 0.5));

    let s = json_settings(json!({"correct_bias": 0, "fallback": false, "known_noise": "pose_white", "bootstrap": 6}));
    let o = s.to_options(Caller::Python).expect("options");
    let Method::Eiv(e) = &o.method else { panic!("eiv") };
    assert_eq!((e.correct_bias, e.fallback), (None, false));
    assert_eq!(e.filter.known_sources(), [NoiseSource::PoseWhite]);
    assert_eq!(e.bootstrap.as_ref().map(|b| b.replicates), Some(6));
    let o = json_settings(json!({"bootstrap_seed": 5})).to_options(Caller::Python).expect("options");
    let Method::Eiv(e) = &o.method else { panic!("eiv") };
    assert_eq!(e.correct_bias.map(|c| (c.replicates, c.seed)), Some((4, 5)), "the default correction, seeded");
    let c_e: ParamSet = [Param::CE].into_iter().collect();
    let c_e_c_d = c_e.with(Param::CD);
    assert_eq!(e.correct_bias.map(|c| c.parameters), Some(c_e_c_d), "the default correction is of c_e and c_d");
    // The parameters and the replicates are set apart; either keeps the other's default.
    let c_e_t_r = c_e.with(Param::TR);
    for (s, want) in [
        (json!({"correct_bias_of": "c_e,t_r"}), (4, c_e_t_r)),
        (json!({"correct_bias_of": ["c_e", "c_d", "t_r", "d"]}), (4, ParamSet::THETA)),
        (json!({"correct_bias": 6}), (6, c_e_c_d)),
        (json!({"correct_bias": 6, "correct_bias_of": "t_r"}), (6, c_e_t_r.without(Param::CE))),
    ] {
        let o = json_settings(s.clone()).to_options(Caller::Python).expect("options");
        let Method::Eiv(e) = &o.method else { panic!("eiv") };
        assert_eq!(e.correct_bias.map(|c| (c.replicates, c.parameters)), Some(want), "{s}");
    }
    assert_eq!(Settings::default().to_options(Caller::CommandLine).expect("defaults"), CalibrationOptions::default());
}

#[test]
fn misplaced_keys_are_named_as_the_caller_gave_them() {
    let s = json_settings(json!({"method": "batch-gn", "batches": 3, "picks": 2}));
    let cli = s.to_options(Caller::CommandLine).expect_err("three-step keys").to_string();
    assert_eq!(cli, "--batches, --picks apply to --method three-step only, not to --method batch-gn");
    let py = s.to_options(Caller::Python).expect_err("three-step keys").to_string();
    assert_eq!(py, "invalid option `batches`: batches, picks apply to method three-step only, not to batch-gn");
    let s = json_settings(json!({"min_yaw_rate": 0.1}));
    let py = s.to_options(Caller::Python).expect_err("eiv selects no segments").to_string();
    assert!(py.starts_with("invalid option `min_yaw_rate`: min_yaw_rate applies to the segment-selecting"), "{py}");
    let s = json_settings(json!({"method": "batch-gn", "fix_noise": true, "fallback": false, "correct_bias": 0}));
    let cli = s.to_options(Caller::CommandLine).expect_err("eiv keys").to_string();
    assert_eq!(
        cli,
        "--fix-noise, --no-fallback, --no-bias-correction apply to --method eiv only, not to --method batch-gn"
    );
    let s = json_settings(json!({"keep_one_way": true}));
    let cli = s.to_options(Caller::CommandLine).expect_err("eiv selects no segments").to_string();
    assert_eq!(
        cli,
        "--keep-one-way applies to the segment-selecting methods (three-step, batch-gn), not to --method eiv"
    );
    let s = json_settings(json!({"estimate": "t_r"}));
    let cli = s.to_options(Caller::CommandLine).expect_err("θ").to_string();
    assert!(cli.starts_with("--estimate takes lever-arm, heading-offset"), "{cli}");
    let py = s.to_options(Caller::Python).expect_err("θ").to_string();
    assert!(py.starts_with("invalid option `estimate`: takes lever-arm") && py.ends_with("with fix=)"), "{py}");
    let s = json_settings(json!({"correct_bias": 0, "bootstrap_seed": 5}));
    let py = s.to_options(Caller::Python).expect_err("seed of nothing").to_string();
    assert_eq!(
        py,
        "invalid option `bootstrap_seed`: is the seed of the bias correction, which correct_bias=0 turns off"
    );
    let s = json_settings(json!({"correct_bias": 3}));
    assert!(s.to_options(Caller::Python).expect_err("odd").to_string().contains("`correct_bias`: = 3: must be 0"));
    for (key, v, want) in [
        ("segment_length", 1, "--segment-length = 1: must be at least 2 samples"),
        ("validation_length", 0, "--validation-length = 0: must be at least 2 samples"),
        ("segment_stride", 0, "--segment-stride = 0: must be at least 1 sample"),
    ] {
        let s = json_settings(json!({ key: v }));
        assert_eq!(s.to_options(Caller::CommandLine).expect_err(key).to_string(), want);
    }
    let s = json_settings(json!({"correct_bias": 0, "correct_bias_of": "t_r"}));
    let cli = s.to_options(Caller::CommandLine).expect_err("parameters of nothing").to_string();
    assert_eq!(
        cli,
        "--correct-bias-of names the parameters of the bias correction, which --no-bias-correction turns off"
    );
    let s = json_settings(json!({"correct_bias_of": "c_e,heading_offset"}));
    let py = s.to_options(Caller::Python).expect_err("an extrinsic").to_string();
    assert_eq!(py, "invalid option `correct_bias_of`: corrects parameters of θ (c_e, c_d, t_r, d), not heading_offset");
    let s = json_settings(json!({"correct_bias_of": ""}));
    let cli = s.to_options(Caller::CommandLine).expect_err("no parameter").to_string();
    assert_eq!(cli, "--correct-bias-of names no parameter to correct (give c_e, c_d, t_r or d)");
    // The EIV window's and the bootstrap's floors are named as given, not
    // by the library's fields (window_samples, replicates).
    let s = json_settings(json!({"eiv_window": 1}));
    let cli = s.to_options(Caller::CommandLine).expect_err("window").to_string();
    assert_eq!(cli, "--eiv-window = 1: must be at least 10 samples");
    let s = json_settings(json!({"max_iterations": 0}));
    let cli = s.to_options(Caller::CommandLine).expect_err("no iteration").to_string();
    assert_eq!(cli, "--max-iterations = 0: must be at least 1");
    let s = json_settings(json!({"method": "three-step", "final_segments": 0}));
    let cli = s.to_options(Caller::CommandLine).expect_err("no final segment").to_string();
    assert_eq!(cli, "--final-segments = 0: must be at least 1 (or all)");
    let s = json_settings(json!({"bootstrap": 1}));
    let py = s.to_options(Caller::Python).expect_err("one replicate").to_string();
    assert_eq!(py, "invalid option `bootstrap`: = 1: must be at least 2 replicates");
    // A lever arm or heading offset beyond its plausible range is named as given.
    let s = json_settings(json!({"lever_arm": [1e300, 0.0]}));
    let cli = s.to_options(Caller::CommandLine).expect_err("lever arm").to_string();
    assert_eq!(cli, "--lever-arm = 1e300 m is not within ±20 m (the lever arm is in metres)");
    let s = json_settings(json!({"heading_offset": 90.0}));
    let py = s.to_options(Caller::Python).expect_err("degrees").to_string();
    assert!(py.starts_with("invalid option `heading_offset`: = 90 rad is not within ±π rad"), "{py}");
    // A negative minimum yaw rate is named as given, not by the library's field.
    let s = json_settings(json!({"method": "batch-gn", "min_yaw_rate": -1.0}));
    let cli = s.to_options(Caller::CommandLine).expect_err("negative").to_string();
    assert!(cli.starts_with("--min-yaw-rate = -1: must be a non-negative number"), "{cli}");
    let py = s.to_options(Caller::Python).expect_err("negative").to_string();
    assert!(py.starts_with("invalid option `min_yaw_rate`: = -1: must be") && !py.contains("peak"), "{py}");
}

#[test]
fn noise_and_reference_tables_parse_and_are_carried_on_the_import_report() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let extra = "\n[noise]\nwheel_white_rel_sigma = 0.012\nposition_white_sigma_m = 0.05\nknown = [\"pose_white\"]\n\n[reference]\n\
                 lever_arm = [-0.9, 0.1]\nheading_offset = -0.0099\nestimate = [\"lever-arm\"]\n\n[calibration]\n\
                 method = \"batch-gn\"\nmin_yaw_rate = 0.1\n";
    let text = std::fs::read_to_string(&path).expect("read") + extra;
    std::fs::write(&path, text).expect("write");
    let (_, report) = load_drive(&path).expect("import");
    let report = report.expect("a manifest's report");
    let text = report.to_string();
    assert!(
        text.contains(
            "[noise] (start of --method eiv): known = [\"pose_white\"], position_white_sigma_m = 0.05, \
             wheel_white_rel_sigma = 0.012\n"
        ),
        "{text}"
    );
    assert!(text.contains("[reference]: lever arm (-0.900, +0.100) m, heading offset -9.90 mrad, estimate lever-arm"));
    assert!(text.contains("[calibration]: method = \"batch-gn\", min_yaw_rate = 0.1\n"), "{text}");
    let s = ManifestSettings::of_report(&report).expect("settings");
    let Some(NoiseModelSetting::Stated(n)) = &s.settings.noise_model else { panic!("[noise]") };
    assert_eq!(n.known, [NoiseSource::PoseWhite]);
    assert_eq!((n.model.wheel_white_rel_sigma, n.model.position_white_sigma_m), (0.012, 0.05));
    assert_eq!(n.model.wheel_common_rel_sigma, NoiseModel::PRODUCTION_CAR.wheel_common_rel_sigma, "default kept");
    assert_eq!(s.settings.lever_arm, Some([-0.9, 0.1]));
    assert_eq!(s.settings.heading_offset, Some(-0.0099));
    assert_eq!(s.settings.estimate, Some(ParamSet::LEVER_ARM));
    assert_eq!(s.settings.min_yaw_rate, Some(0.1));
    assert_eq!(s.settings.method.as_ref().map(Method::name), Some("batch-gn"));
    assert_eq!(s.reference.as_ref().map(|r| r.lever_arm), Some(Some([-0.9, 0.1])));
    let m = Manifest::from_path(&path).expect("parse");
    let from_manifest = ManifestSettings::of_manifest(&m).expect("settings");
    assert_eq!(from_manifest, ManifestSettings { manifest: path.clone(), ..s.clone() });
    // The parsed manifest serialises and parses back the same.
    let back = Manifest::parse(&toml::to_string(&m).expect("toml"), &path).expect("round trip");
    assert_eq!(ManifestSettings::of_manifest(&back).expect("settings"), from_manifest);
    // The import report's JSON reads back the same (Python keeps the settings so).
    let json = serde_json::to_value(&report).expect("json");
    let again: crate::io::import::CalibrationTable =
        serde_json::from_value(json["calibration"].clone()).expect("calibration");
    let noise = serde_json::from_value(json["noise"].clone()).expect("noise");
    let reference = serde_json::from_value(json["reference"].clone()).expect("reference");
    let s2 = ManifestSettings::new(path.clone(), Some(&noise), Some(reference), Some(&again)).expect("settings");
    assert_eq!(s2, from_manifest);
    // So does the JSON the Python package keeps (`import_report_json`).
    let kept = import_report_json(&report).expect("json");
    assert_eq!(ManifestSettings::of_report_json(&kept).expect("settings"), s);
    let e = ManifestSettings::of_report_json(&json!({"noise": 3})).expect_err("not a table").to_string();
    assert!(e.contains("import report"), "{e}");
}

#[test]
fn bad_settings_are_errors_naming_the_key() {
    let e = error("\n[noise]\nwheel_whte_rel_sigma = 0.01\n");
    assert!(e.contains("noise: unknown field(s) wheel_whte_rel_sigma"), "{e}");
    let e = error("\n[noise]\nlateral = \"free\"\n");
    assert!(e.contains("noise: lateral: invalid lateral noise 'free': use tied or stated"), "{e}");
    let e = error("\n[noise]\nlateral = 1\n");
    assert!(e.contains("noise: lateral: 1 must be \"tied\" or \"stated\""), "{e}");
    let e = error("\n[noise]\nposition_white_sigma_m = -0.5\n");
    assert!(e.contains("noise") && e.contains("noise.position_white_sigma_m"), "{e}");
    let e = error("\n[noise]\nsideslip_sigma_rad = \"small\"\n");
    assert!(e.contains("noise: sideslip_sigma_rad: invalid type"), "{e}");
    let e = error("\n[reference]\nlever_arm = [1.0]\n");
    assert!(e.contains("reference.lever_arm"), "{e}");
    let e = error("\n[reference]\nlever_arm = [1.0, 1e9]\n");
    assert!(e.contains("reference.lever_arm: [1, 1e9] must be finite metres"), "{e}");
    let e = error("\n[reference]\nheading_offset = 7.0\n");
    assert!(e.contains("reference.heading_offset: 7 must be finite radians within ±π"), "{e}");
    let e = error("\n[reference]\nestimate = [\"t_r\"]\n");
    assert!(e.contains("reference.estimate: 't_r' is not an extrinsic parameter"), "{e}");
    let e = error("\n[reference]\nestimate = [\"lever-arms\"]\n");
    assert!(e.contains("reference.estimate: 'lever-arms' is not"), "{e}");
    let e = error("\n[reference]\nlever = [0.0, 0.0]\n");
    assert!(e.contains("reference.lever: unknown field"), "{e}");
    let e = error("\n[calibration]\nkeep_one_wya = true\n");
    assert!(e.starts_with("calibration.keep_one_wya: unknown field `keep_one_wya`, expected one of"), "{e}");
    assert!(e.ends_with("(line 25)"), "{e}");
    let e = error("\n[calibration]\nlever_arm = [0.0, 0.0]\n");
    assert_eq!(e, "calibration.lever_arm: the reference extrinsics belong in [reference] (line 25)");
    let e = error("\n[calibration]\nnoise_model = \"n.toml\"\n");
    assert_eq!(e, "calibration.noise_model: a manifest states its noise model as the [noise] table (line 25)");
    // Values out of range are named by the manifest's key, not a flag, and
    // before the import.
    let e = error("\n[calibration]\nsegment_length = 1000000000\n");
    assert_eq!(e, "calibration.segment_length: segment_length = 1000000000 is above its ceiling of 10000000 (line 25)");
    let e = error("\n[calibration]\nmin_yaw_rate = -1.0\n");
    assert!(
        e.starts_with("calibration.min_yaw_rate: min_yaw_rate = -1: must be a non-negative number of rad/s"),
        "{e}"
    );
    let e = error("\n[calibration]\ncorrect_bias = 3\n");
    assert!(e.starts_with("calibration.correct_bias: correct_bias = 3: must be 0 (no correction) or an even"), "{e}");
    assert!(e.ends_with("(line 25)"), "{e}");
    let e = error("\n[calibration]\nsegment_length = 0\n");
    assert_eq!(e, "calibration.segment_length: segment_length = 0: must be at least 2 samples (line 25)");
    let e = error("\n[calibration]\nseed = 1\nmethod = \"newton\"\n");
    assert_eq!(e, "calibration.method: invalid method 'newton': use three-step, batch-gn or eiv (line 26)");
    // A count written as a float is named, saying a whole number is wanted.
    let e = error("\n[calibration]\nbatches = 1e3\n");
    assert_eq!(
        e,
        "calibration.batches: 1000 is written as a float (with a decimal point or an exponent): a whole number \
         (0, 1, 2, …) is wanted, write it as 1000 (line 25)"
    );
    let e = error("\n[calibration]\nfinal_segments = 2.5\n");
    assert_eq!(e, "calibration.final_segments: 2.5 is not a whole number (0, 1, 2, …) (line 25)");
}

/// Every count of the settings takes a whole number and refuses a float
/// or a negative number by its key, saying a whole number is wanted.
#[test]
fn a_count_is_a_whole_number() {
    let e = |v| Settings::from_json(v).expect_err("bad").to_string();
    for key in [
        "max_iterations",
        "segment_length",
        "segment_stride",
        "validation_length",
        "batches",
        "batch_size",
        "picks",
        "eiv_window",
        "bootstrap",
        "correct_bias",
        "final_segments",
    ] {
        assert_eq!(
            e(json!({ key: 1e3 })),
            format!(
                "invalid option `{key}`: 1000 is written as a float (with a decimal point or an exponent): a whole \
                 number (0, 1, 2, …) is wanted, write it as 1000"
            )
        );
        if key != "final_segments" {
            assert_eq!(e(json!({ key: -2 })), format!("invalid option `{key}`: -2 is not a whole number (0, 1, 2, …)"));
        }
        let toml_settings: Settings = toml::from_str(&format!("{key} = 4")).expect("a whole number");
        assert_ne!(toml_settings, Settings::default(), "{key}");
    }
    assert!(e(json!({"batches": "x"})).starts_with("invalid option `batches`: invalid type: string"));
}

#[test]
fn noise_errors_name_the_key_and_the_tables_line() {
    // Each message names the key and the line the table starts on.
    let cases = [
        ("\n[noise]\nwheel_whte_rel_sigma = 0.01\n",
         "noise: unknown field(s) wheel_whte_rel_sigma; the fields are drift_time_constant_s, heading_drift_sigma_rad, heading_white_sigma_rad, known, lateral, lateral_acceleration_sigma_m_per_s2, position_drift_sigma_m, position_white_sigma_m, quantisation_step_rev_per_s, sideslip_sigma_rad, sideslip_time_constant_s, wheel_common_rel_sigma, wheel_common_time_constant_s, wheel_differential_rel_sigma, wheel_differential_time_constant_s, wheel_white_rel_sigma (line 24)"),
        ("\n[noise]\nlateral = \"free\"\n",
         "noise: lateral: invalid lateral noise 'free': use tied or stated (line 24)"),
        ("\n[noise]\nlateral = 1\n",
         "noise: lateral: 1 must be \"tied\" or \"stated\" (line 24)"),
        ("\n[noise]\nposition_white_sigma_m = -0.5\n",
         "noise: invalid option `noise.position_white_sigma_m`: must be finite and >= 0, got -0.5 (line 24)"),
        ("\n[noise]\nwheel_white_rel_sigma = 1e300\n",
         "noise: invalid option `noise.wheel_white_rel_sigma`: must be at most 1, got 1e300 (a unit or a typo?) (line 24)"),
        ("\n[noise]\nheading_drift_sigma_rad = 5.0\n",
         "noise: invalid option `noise.heading_drift_sigma_rad`: must be at most π, got 5 (a unit or a typo?) (line 24)"),
        ("\n[noise]\ndrift_time_constant_s = 1e6\n",
         "noise: invalid option `noise.drift_time_constant_s`: must be at most a day (86400 s), got 1000000 s (line 24)"),
        ("\n[noise]\nsideslip_sigma_rad = \"small\"\n",
         "noise: sideslip_sigma_rad: invalid type: string \"small\", expected f64 (line 24)"),
        ("\n[noise]\nknown = [\"x\"]\n",
         "noise: known: invalid noise source 'x': use wheel_white, wheel_common, wheel_differential, pose_white, pose_drift or heading_white (line 24)"),
        ("\n[noise]\nknown = 3\n",
         "noise: known: 3 must be a list of source names, e.g. [\"heading_white\"] (line 24)"),
        ("\n[noise]\nwheel_white_rel_sigma = 0.01\nknown = [\"pose_white\"]\n[calibration]\nkeep_one_way = 3\n",
         "calibration.keep_one_way: invalid type: integer `3`, expected a boolean (line 28)"),
    ];
    for (extra, message) in cases {
        assert_eq!(error(extra), message, "{extra}");
    }
}

/// A manifest's noise model and extrinsics.
/// The methods that use each key: every method, or the ones named.
fn users(key: &str) -> &'static [&'static str] {
    const ALL: &[&str] = &["eiv", "batch-gn", "three-step"];
    match key {
        "seed" | "batches" | "batch_size" | "picks" | "final_segments" | "qp_solver" => &["three-step"],
        // Method eiv, its batch G-N start and fallback fit every segment.
        "min_yaw_rate" | "keep_one_way" => &["batch-gn", "three-step"],
        "noise_model" | "known_noise" | "fix_noise" | "fallback" | "eiv_window" | "quantisation"
        | "quantisation_level" | "lateral_noise" | "heading_noise" | "bootstrap" | "bootstrap_seed"
        | "correct_bias" | "correct_bias_of" => &["eiv"],
        "method" | "theta0" | "fix" | "auto_fix" | "max_iterations" | "segment_length" | "segment_stride"
        | "validation_length" | "estimate" | "lever_arm" | "heading_offset" => ALL,
        _ => panic!("key {key}: say which methods use it"),
    }
}

/// Every key, given with a method that does not use it, is a usage error
/// naming the flag (the keyword in Python) and the methods that use it; in
/// a manifest it is reported ignored. Given with a method that uses it, it
/// is taken, and a manifest's is reported used.
#[test]
fn a_key_is_refused_or_ignored_exactly_where_its_method_does_not_use_it() {
    let values = json!({
        "theta0": [2.0, 0.0, 1.6, 0.0], "fix": "d", "auto_fix": true, "seed": 3, "max_iterations": 7,
        "min_yaw_rate": 0.1, "keep_one_way": true, "segment_length": 400, "segment_stride": 50,
        "validation_length": 800, "estimate": ["lever-arm"], "lever_arm": [1.0, 0.5], "heading_offset": 0.01,
        "batches": 9, "batch_size": 8, "picks": 3, "final_segments": 5, "qp_solver": "clarabel",
        "noise_model": {"wheel_white_rel_sigma": 0.02}, "known_noise": "pose_white", "fix_noise": true,
        "fallback": false, "eiv_window": 1500, "quantisation": "process", "quantisation_level": "given",
        "lateral_noise": "stated", "heading_noise": "tied", "bootstrap": 10, "bootstrap_seed": 4,
        "correct_bias": 2, "correct_bias_of": "c_e,t_r"
    });
    for key in Settings::KEYS.iter().filter(|k| **k != "method") {
        let value = values.get(*key).unwrap_or_else(|| panic!("a value for {key}")).clone();
        let stated = json_settings(json!({ *key: value }));
        let m = ManifestSettings { manifest: "m.toml".into(), settings: stated.clone(), reference: None };
        for method in ["eiv", "batch-gn", "three-step"] {
            let caller = Settings { method: Some(method.parse().expect("method")), ..stated.clone() };
            let flag = Caller::CommandLine.name(key, &caller);
            let cli = caller.resolve(&[], Caller::CommandLine);
            let py = caller.resolve(&[], Caller::Python);
            let from_manifest = json_settings(json!({ "method": method }))
                .resolve(std::slice::from_ref(&m), Caller::CommandLine)
                .expect("a manifest's key never fails");
            let outcome = &from_manifest.account.uses[0].outcome;
            if users(key).contains(&method) {
                assert!(cli.is_ok() && py.is_ok(), "{method} uses {key}: {:?}", cli.err());
                assert_eq!(outcome, &SettingOutcome::Used, "{method}, manifest {key}");
            } else {
                let cli = cli.map(|_| ()).expect_err("a usage error").to_string();
                let owners = users(key).join(", ");
                assert!(cli.starts_with(&format!("{flag} appl")), "{method}, {key}: {cli}");
                assert!(users(key).iter().all(|u| cli.contains(u)), "{method}, {key} names {owners}: {cli}");
                assert!(matches!(cli_error(&caller), Error::InvalidFlags(_)), "{method}, {key}");
                let py = py.map(|_| ()).expect_err("an error").to_string();
                assert!(py.starts_with(&format!("invalid option `{key}`: {key} appl")), "{method}, {key}: {py}");
                assert!(matches!(outcome, SettingOutcome::Ignored { .. }), "{method}, manifest {key}: {outcome:?}");
                assert_eq!(
                    from_manifest.options,
                    json_settings(json!({ "method": method })).to_options(Caller::Python).expect("defaults"),
                    "{method} ignores the manifest's {key}"
                );
            }
        }
    }
}

/// The error the command line's settings resolve to.
fn cli_error(s: &Settings) -> Error {
    s.resolve(&[], Caller::CommandLine).map(|_| ()).expect_err("an error")
}

fn manifest() -> ManifestSettings {
    let settings = Settings {
        noise_model: Some(NoiseModelSetting::Stated(NoiseSpec {
            model: NoiseModel { wheel_white_rel_sigma: 0.02, ..NoiseModel::PRODUCTION_CAR },
            known: vec![NoiseSource::PoseWhite],
            lateral: None,
        })),
        lever_arm: Some([-0.9, 0.0]),
        heading_offset: Some(-0.01),
        estimate: Some(ParamSet::EMPTY.with(Param::HeadingOffset)),
        ..Default::default()
    };
    let reference = ReferenceSpec {
        lever_arm: Some([-0.9, 0.0]),
        heading_offset: Some(-0.01),
        estimate: vec!["heading-offset".into()],
    };
    ManifestSettings { manifest: "m.toml".into(), settings, reference: Some(reference) }
}

fn outcomes(r: &Resolved) -> Vec<(&str, SettingOutcome)> {
    r.account.uses.iter().map(|u| (u.key.as_str(), u.outcome.clone())).collect()
}

fn resolve(caller: serde_json::Value, m: &ManifestSettings) -> Resolved {
    json_settings(caller).resolve(std::slice::from_ref(m), Caller::CommandLine).expect("resolves")
}

#[test]
fn the_manifest_fills_what_the_caller_does_not_give() {
    let m = manifest();
    // Batch G-N: the extrinsics are used, the noise model is not.
    let r = resolve(json!({"method": "batch-gn"}), &m);
    assert_eq!(r.options.identify.extrinsics, Extrinsics { lever_x: -0.9, lever_y: 0.0, heading_offset: -0.01 });
    assert_eq!(r.options.identify.free, ParamSet::THETA.with(Param::HeadingOffset));
    let o = outcomes(&r);
    assert!(matches!(&o[3], ("noise", SettingOutcome::Ignored { .. })), "{o:?}");
    assert_eq!(
        o[..3],
        [
            ("reference.estimate", SettingOutcome::Used),
            ("reference.lever_arm", SettingOutcome::Used),
            ("reference.heading_offset", SettingOutcome::Used),
        ]
    );
    assert_eq!(r.account.noise_model_origin, None);
    assert!(r.account.lines().contains("manifest setting reference.lever_arm from m.toml: used\n"));
    assert!(r.account.lines().contains("noise from m.toml: ignored (method batch-gn does not use a noise model)\n"));

    // The caller's lever arm and estimate win; the rest is still the manifest's.
    let r = resolve(json!({"method": "batch-gn", "lever_arm": [0.0, 0.0], "estimate": ""}), &m);
    assert_eq!(r.options.identify.extrinsics, Extrinsics { lever_x: 0.0, lever_y: 0.0, heading_offset: -0.01 });
    assert_eq!(r.options.identify.free, ParamSet::THETA);
    assert_eq!(
        outcomes(&r)[..3],
        [
            ("reference.estimate", SettingOutcome::Overridden),
            ("reference.lever_arm", SettingOutcome::Overridden),
            ("reference.heading_offset", SettingOutcome::Used),
        ]
    );
    assert!(r.account.lines().contains("reference.lever_arm from m.toml: overridden by the command line\n"));

    // EIV: the noise model is the start unless the caller gives one; the
    // extrinsics are used (its batch G-N start estimates them, the filter
    // holds them).
    let r = resolve(json!({}), &m);
    let Method::Eiv(e) = &r.options.method else { panic!("eiv") };
    assert_eq!(e.filter.noise.wheel_white_rel_sigma, 0.02);
    assert_eq!(e.filter.known_sources(), [NoiseSource::PoseWhite], "[noise] known");
    assert_eq!(r.options.identify.free, ParamSet::THETA.with(Param::HeadingOffset));
    assert!(outcomes(&r).iter().all(|u| u.1 == SettingOutcome::Used), "{:?}", outcomes(&r));
    assert_eq!(r.account.noise_model_origin.as_deref(), Some("[noise] of m.toml"));
    let file = tempfile::NamedTempFile::new().expect("file");
    std::fs::write(file.path(), "wheel_white_rel_sigma = 0.009\n").expect("write");
    let r = resolve(json!({"noise_model": file.path()}), &m);
    let Method::Eiv(e) = &r.options.method else { panic!("eiv") };
    assert_eq!(e.filter.noise, NoiseModel { wheel_white_rel_sigma: 0.009, ..NoiseModel::PRODUCTION_CAR });
    assert!(e.filter.known_sources().is_empty(), "the caller's model replaces the manifest's known sources too");
    assert_eq!(outcomes(&r)[3], ("noise", SettingOutcome::Overridden));
    assert_eq!(r.account.noise_model_origin, Some(format!("--noise-model {}", file.path().display())));
    assert_eq!(
        resolve(json!({}), &ManifestSettings::default()).account.noise_model_origin.as_deref(),
        Some("the production-car defaults (no --noise-model, no manifest [noise])")
    );
}

#[test]
fn the_lateral_noise_and_the_heading_offset_follow_who_states_them() {
    // `[noise] lateral = "stated"` sets the lateral noise with the model,
    // unless the caller gives its own (`lateral_noise`).
    let mut lateral = manifest();
    if let Some(NoiseModelSetting::Stated(n)) = &mut lateral.settings.noise_model {
        n.lateral = Some(crate::eiv::LateralNoise::Stated);
    }
    let r = resolve(json!({}), &lateral);
    assert!(matches!(&r.options.method, Method::Eiv(e) if e.filter.lateral_noise == crate::eiv::LateralNoise::Stated));
    let r = resolve(json!({"lateral_noise": "tied"}), &lateral);
    let Method::Eiv(e) = &r.options.method else { panic!("eiv") };
    assert_eq!(e.filter.lateral_noise, crate::eiv::LateralNoise::TiedToWheelWhite);
    let o = outcomes(&r);
    assert!(o.contains(&("noise", SettingOutcome::Used)) && o.contains(&("noise.lateral", SettingOutcome::Overridden)));
    // A stated heading offset is held by EIV's start (which estimates one
    // by default) unless the manifest frees it; the caller's own
    // `heading_offset` is held too.
    let mut held = manifest();
    held.settings.estimate = None;
    held.settings.lever_arm = None;
    let r = resolve(json!({}), &held);
    assert!(matches!(&r.options.method, Method::Eiv(m) if !m.estimate_heading_offset));
    let r = resolve(json!({"heading_offset": 0.02}), &ManifestSettings::default());
    assert_eq!(r.given_extrinsics, ParamSet::EMPTY.with(Param::HeadingOffset), "the caller's apply to every drive");
    assert!(matches!(&r.options.method, Method::Eiv(m) if !m.estimate_heading_offset));
    let r = resolve(json!({}), &ManifestSettings::default());
    assert!(matches!(&r.options.method, Method::Eiv(m) if m.estimate_heading_offset));
}

#[test]
fn keep_one_way_and_other_keys_of_a_method_are_used_overridden_or_ignored() {
    let (_, m) = parsed("\n[calibration]\nkeep_one_way = true\nbatches = 7\n").expect("parses");
    assert_eq!((m.settings.keep_one_way, m.settings.batches), (Some(true), Some(7)));

    let r = resolve(json!({"method": "three-step"}), &m);
    assert!(r.options.keep_one_way_selection);
    assert!(matches!(&r.options.method, Method::ThreeStep(t) if t.initial_batches == 7));
    let o = outcomes(&r);
    assert_eq!(o, [("calibration.keep_one_way", SettingOutcome::Used), ("calibration.batches", SettingOutcome::Used)]);
    // The caller's value stands.
    let r = resolve(json!({"method": "three-step", "keep_one_way": false}), &m);
    assert!(!r.options.keep_one_way_selection);
    assert_eq!(outcomes(&r)[0], ("calibration.keep_one_way", SettingOutcome::Overridden));
    // EIV selects no turning segments, and has no batches: both ignored.
    let r = resolve(json!({}), &m);
    assert!(!r.options.keep_one_way_selection);
    let o = outcomes(&r);
    assert!(o.iter().all(|(_, u)| matches!(u, SettingOutcome::Ignored { .. })), "{o:?}");
    assert!(r.account.lines().contains("batches from"), "{}", r.account.lines());
    // A manifest's method is used unless the caller gives one.
    let (_, m) = parsed("\n[calibration]\nmethod = \"batch-gn\"\n").expect("parses");
    assert_eq!(resolve(json!({}), &m).options.method.name(), "batch-gn");
    assert_eq!(resolve(json!({"method": "eiv"}), &m).options.method.name(), "eiv");
    let mut v = serde_json::json!({});
    resolve(json!({"method": "eiv"}), &m).account.add_to_json(&mut v).expect("json");
    assert_eq!(
        v["manifest_settings"][0],
        json!({"key": "calibration.method", "manifest": m.manifest, "outcome": "overridden"})
    );
    assert!(v["noise_model_origin"].is_string());
}

/// The `[reference]` example the shipped van manifests carry commented
/// out is a valid table once uncommented.
#[test]
fn the_shipped_commented_reference_example_parses() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples");
    for f in ["psu-mapping-van/manifest.toml", "psu-mapping-van-testtrack/run-14-45-26.toml"] {
        let path = root.join(f);
        let text = std::fs::read_to_string(&path).expect("read");
        let i = text.find("\n# [reference]\n").expect("the commented example");
        let tail: Vec<&str> = text[i..].lines().map(|l| l.strip_prefix("# ").unwrap_or(l)).collect();
        let m = Manifest::parse(&(text[..i].to_string() + &tail.join("\n")), &path).expect("parses");
        let r = m.reference.expect("[reference]");
        assert_eq!((r.lever_arm, r.heading_offset), (Some([-0.9, 0.0]), Some(-0.0099)), "{f}");
        assert_eq!(r.estimate_set(), Ok(ParamSet::EXTRINSICS), "{f}");
        assert_eq!(Manifest::from_path(&path).expect("as shipped").reference, None, "{f}: commented out");
    }
}

#[test]
fn drives_fitted_jointly_must_agree() {
    let a = manifest();
    let none = ManifestSettings { manifest: "n.toml".into(), ..Default::default() };
    let same = ManifestSettings { manifest: "b.toml".into(), ..a.clone() };
    let merged = ManifestSettings::merge([&none, &a, &same]).expect("agree").expect("some");
    assert_eq!(merged.manifest, Path::new("m.toml"));
    assert_eq!(ManifestSettings::merge([&none]).expect("none"), None);
    let other = ManifestSettings {
        manifest: "c.toml".into(),
        settings: a.settings.clone().without("noise_model"),
        ..a.clone()
    };
    let e = ManifestSettings::merge([&a, &other]).expect_err("differ").to_string();
    assert!(e.contains("m.toml and c.toml state different"), "{e}");
    let e = Settings::default().resolve(&[a.clone(), other], Caller::Python).expect_err("differ").to_string();
    assert!(e.contains("m.toml and c.toml state different"), "resolve merges them: {e}");
    let r = Settings::default().resolve(&[none, a.clone(), same], Caller::Python).expect("agree");
    assert_eq!(r, Settings::default().resolve(std::slice::from_ref(&a), Caller::Python).expect("one"));
    let keep = ManifestSettings { settings: Settings { keep_one_way: Some(false), ..a.settings.clone() }, ..a.clone() };
    assert!(ManifestSettings::merge([&a, &keep]).is_err(), "[calibration] too");
}
