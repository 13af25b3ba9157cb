//! End-to-end tests of the help screens and of `--threads`.

use crate::common;

use common::{odocal, simulated_drive, stderr, stdout};

/// The options `calibrate --help` lists: those most runs need.
const COMMON: [&str; 13] = [
    "--method <METHOD>",
    "--theta0 <THETA0>",
    "--fix <FIX>",
    "--holdout <HOLDOUT>",
    "--validate-on <VALIDATE_ON>",
    "--auto-fix",
    "--params-out <PARAMS_OUT>",
    "--report <REPORT>",
    "--json <JSON>",
    "--quiet",
    "--threads <N>",
    "--help",
    "--help-all",
];

/// The options only `--help-all` lists, each under its heading.
const EXPERT: [(&str, &[&str]); 6] = [
    (
        "Segments and Gauss-Newton:",
        &[
            "--min-yaw-rate",
            "--keep-one-way",
            "--segment-length",
            "--segment-stride",
            "--validation-length",
            "--max-iterations",
        ],
    ),
    ("Reference extrinsics:", &["--estimate", "--lever-arm", "--heading-offset"]),
    (
        "Three-step method (--method three-step):",
        &["--seed", "--qp-solver", "--batches", "--batch-size", "--picks", "--final-segments"],
    ),
    (
        "EIV noise model (--method eiv):",
        &[
            "--noise-model",
            "--known-noise",
            "--fix-noise",
            "--no-fallback",
            "--eiv-window",
            "--quantisation",
            "--quantisation-level",
            "--lateral-noise",
            "--heading-noise",
        ],
    ),
    (
        "EIV bias correction and bootstrap (--method eiv):",
        &["--bootstrap", "--bootstrap-seed", "--correct-bias", "--correct-bias-of", "--no-bias-correction"],
    ),
    ("Parameter file (--params-out):", &["--params-node", "--params-mapping"]),
];

/// Whether `help` has an option line for `flag` (not a longer flag it is a
/// prefix of).
fn lists(help: &str, flag: &str) -> bool {
    help.lines().any(|l| {
        let l = l.trim_start().trim_start_matches("-q, ").trim_start_matches("-h, ");
        l == flag || l.starts_with(&format!("{flag} ")) || l.starts_with(&format!("{flag}\t"))
    })
}

#[test]
fn calibrate_help_lists_the_common_options_on_one_screen() {
    for args in [["calibrate", "--help"], ["calibrate", "-h"]] {
        let o = odocal(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        let help = stdout(&o);
        assert!(help.lines().count() <= 30, "more than a screen:\n{help}");
        assert!(help.contains("a drive CSV or a manifest (TOML)"), "{help}");
        assert!(help.contains("three-step, batch-gn or eiv"), "{help}");
        for flag in COMMON {
            assert!(lists(&help, flag), "{flag} missing:\n{help}");
        }
        for (_, flags) in EXPERT {
            for flag in flags.iter() {
                assert!(!lists(&help, flag), "{flag} is an expert option:\n{help}");
            }
        }
        assert!(help.contains("More options (--help-all)"), "{help}");
    }
}

#[test]
fn calibrate_help_all_lists_every_option_under_its_heading() {
    let o = odocal(&["calibrate", "--help-all"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let help = stdout(&o);
    for flag in COMMON {
        assert!(lists(&help, flag), "{flag} missing:\n{help}");
    }
    // Each heading in this order, followed by its options before the next.
    let mut from = 0;
    for (heading, flags) in EXPERT {
        let at = from + help[from..].find(heading).unwrap_or_else(|| panic!("{heading} missing or out of order"));
        // The section ends at the next line that is not indented (the next heading).
        let lines = help[at + heading.len()..].lines().skip(1);
        let section = lines.take_while(|l| l.is_empty() || l.starts_with(' ')).collect::<Vec<_>>().join("\n");
        for flag in flags.iter() {
            assert!(lists(&section, flag), "{flag} not under {heading}:\n{section}");
        }
        from = at + heading.len();
    }
    assert!(help.contains("Exit codes: 0 done, 1 error, 2 usage error, 3 calibration rejected"), "{help}");
}

#[test]
fn demo_shares_the_calibration_help() {
    let o = odocal(&["demo", "--help"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let help = stdout(&o);
    for flag in ["--sim-seed <SIM_SEED>", "--length-km <LENGTH_KM>", "--method <METHOD>", "--help-all"] {
        assert!(lists(&help, flag), "{flag} missing:\n{help}");
    }
    assert!(!lists(&help, "--fix-noise"), "{help}");
    let all = stdout(&odocal(&["demo", "--help-all"]));
    assert!(lists(&all, "--fix-noise") && lists(&all, "--sim-seed <SIM_SEED>"), "{all}");
}

/// `follow --help` fits a screen, as `-h`; `--help-all` adds the online
/// calibrator's and the gates' expert settings under their headings.
#[test]
fn follow_help_fits_a_screen_and_help_all_has_the_rest() {
    for flag in ["-h", "--help"] {
        let help = stdout(&odocal(&["follow", flag]));
        assert!(help.lines().count() <= 30, "more than a screen:\n{help}");
        for f in ["--vehicle <ID>", "--db <FILE>", "--params-out <FILE>", "--steady-s <S>"] {
            assert!(lists(&help, f), "{f} missing:\n{help}");
        }
        assert!(!lists(&help, "--max-sigma <CE,CD,TR,D>"), "{help}");
        assert!(help.contains("More options (--help-all)"), "{help}");
    }
    let all = stdout(&odocal(&["follow", "--help-all"]));
    for (heading, flag) in
        [("Online calibrator:", "--random-walk <CE,CD,TR,D>"), ("Write-back gates:", "--max-sigma <CE,CD,TR,D>")]
    {
        let at = all.find(heading).unwrap_or_else(|| panic!("{heading} missing:\n{all}"));
        let section = all[at + heading.len()..].lines().skip(1).take_while(|l| l.is_empty() || l.starts_with(' '));
        assert!(lists(&section.collect::<Vec<_>>().join("\n"), flag), "{flag} not under {heading}:\n{all}");
    }
}

#[test]
fn top_level_help_lists_every_subcommand() {
    let o = odocal(&["--help"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let help = stdout(&o);
    for cmd in [
        "simulate",
        "calibrate",
        "validate",
        "compensate",
        "demo",
        "experiment",
        "import",
        "inspect",
        "follow",
        "history",
    ] {
        assert!(help.lines().any(|l| l.trim_start().starts_with(&format!("{cmd} "))), "{cmd} missing:\n{help}");
    }
}

/// The help texts point only to documents a clone holds (docs/…), never to
/// a specification outside the repository.
#[test]
fn help_texts_cite_only_the_repository_s_documents() {
    for cmd in ["simulate", "calibrate", "validate", "compensate", "demo", "experiment", "import", "inspect", "follow"]
    {
        let o = odocal(&[cmd, "--help-all"]);
        let o = if o.status.success() { o } else { odocal(&[cmd, "--help"]) };
        assert!(o.status.success(), "{cmd}: {}", stderr(&o));
        let help = stdout(&o);
        assert!(!help.contains("SPEC"), "{cmd} --help cites SPEC, which is not in the repository:\n{help}");
    }
}

#[test]
fn a_usage_error_still_points_to_help() {
    let o = odocal(&["calibrate", "x.csv", "--no-such-flag"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("For more information, try '--help'."), "{}", stderr(&o));
}

/// The results do not depend on the number of worker threads.
#[test]
fn threads_do_not_change_the_result() {
    let d = tempfile::tempdir().expect("tmp");
    let csv = simulated_drive(d.path(), "d.csv", &["--seed", "2", "--length-km", "2"]);
    let run = |extra: &[&str]| {
        let o = odocal(&[&["calibrate", &csv, "--method", "batch-gn", "--json", "-"][..], extra].concat());
        assert!(o.status.success(), "{}", stderr(&o));
        let mut v: serde_json::Value = serde_json::from_str(&stdout(&o)).expect("json");
        v.as_object_mut().expect("object").remove("timing_s");
        v
    };
    assert_eq!(run(&["--threads", "1"]), run(&[]));
    assert_eq!(run(&["--threads", "3"]), run(&[]));
}
