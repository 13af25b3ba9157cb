//! The library used as a Rust user uses it: options, θ and drives out of
//! their range are refused with an error naming what is wrong, never a
//! panic or a silently wrong result.

use odocal::{
    calibrate,
    sim::{simulate, SimOptions},
    validate, CalibrationOptions, Drive, Error, Theta, ValidateOptions,
};

fn drive() -> Drive {
    simulate(&SimOptions { length_km: 1.0, noise: "off".parse().expect("the off preset"), ..SimOptions::paper(1) })
        .expect("simulate")
        .drive
}

/// A segment offset or length too large for any drive is refused naming
/// the field, in `calibrate` and in `validate`, instead of overflowing.
#[test]
fn segment_counts_above_their_ceiling_are_refused() {
    let d = drive();
    let mut o = CalibrationOptions::default();
    o.segments.offset_steps = usize::MAX;
    assert!(matches!(calibrate(&d, &o), Err(Error::InvalidOption { field: "segment_offset", .. })));
    let mut o = CalibrationOptions::default();
    o.segments.length_steps = usize::MAX;
    assert!(matches!(calibrate(&d, &o), Err(Error::InvalidOption { field: "segment_length", .. })));
    let mut o = CalibrationOptions::default();
    o.validation.offset_steps = usize::MAX;
    assert!(matches!(calibrate(&d, &o), Err(Error::InvalidOption { field: "validation_offset", .. })));
    let mut v = ValidateOptions::default();
    v.segments.offset_steps = usize::MAX;
    let theta = Theta::PAPER_NOMINAL;
    assert!(matches!(validate(&d, &theta, &v, None), Err(Error::InvalidOption { field: "validation_offset", .. })));
    assert_eq!(odocal::segment::cut(&d, usize::MAX, 650, 100).len(), 0);
}

/// `validate` checks θ before the drive (`InvalidTheta`, as `calibrate`
/// checks θ_0), and its messages on the drive call the θ it judges at θ.
#[test]
fn validate_checks_theta_first_and_calls_it_theta() {
    let d = drive();
    let o = ValidateOptions::default();
    let nominal = Theta::PAPER_NOMINAL;
    for bad in [Theta { d: f64::NAN, ..nominal }, Theta { c_e: -2.0, ..nominal }] {
        match validate(&d, &bad, &o, None) {
            Err(Error::InvalidTheta(m)) => assert!(!m.contains("θ_0"), "{m}"),
            other => panic!("{bad:?}: {other:?}"),
        }
    }
    match validate(&d, &Theta { c_e: 10.0, ..nominal }, &o, None) {
        Err(e @ Error::InvalidDrive { .. }) => {
            let m = e.to_string();
            assert!(m.contains("wheel speed at θ is") && !m.contains("θ_0"), "{m}");
        }
        other => panic!("{other:?}"),
    }
}

/// A θ_0 outside the physical limits is refused naming `theta0`, before
/// the drive's checks (which would blame the drive).
#[test]
fn theta0_outside_the_physical_limits_is_refused() {
    let d = drive();
    for theta0 in [Theta { c_e: 1e6, ..Theta::PAPER_INITIAL }, Theta { d: 1.0, ..Theta::PAPER_INITIAL }] {
        let o = CalibrationOptions { theta0, ..Default::default() };
        match calibrate(&d, &o) {
            Err(Error::InvalidTheta(m)) => assert!(m.contains("theta0"), "{m}"),
            other => panic!("{theta0:?}: {:?}", other.map(|r| r.theta)),
        }
    }
}

/// Gauss-Newton's counts and tolerances out of their range are refused
/// naming the field, as its weights and resolutions are.
#[test]
fn identify_options_out_of_range_are_refused() {
    let d = drive();
    type Set = fn(&mut odocal::identify::IdentifyOptions);
    let cases: [(&str, Set); 7] = [
        ("max_iterations", |o| o.max_iterations = 0),
        ("max_iterations", |o| o.max_iterations = 100_001),
        ("step_tolerance", |o| o.step_tolerance = f64::NAN),
        ("cost_tolerance", |o| o.cost_tolerance = -1.0),
        ("cost_tolerance", |o| o.cost_tolerance = f64::NAN),
        ("min_sensitivity_m", |o| o.min_sensitivity_m = -0.01),
        ("min_sensitivity_m", |o| o.min_sensitivity_m = f64::INFINITY),
    ];
    for (field, set) in cases {
        let mut o = CalibrationOptions { method: "batch-gn".parse().expect("method"), ..Default::default() };
        set(&mut o.identify);
        match calibrate(&d, &o) {
            Err(Error::InvalidOption { field: f, .. }) => assert_eq!(f, field),
            other => panic!("{field}: {:?}", other.map(|r| r.theta)),
        }
    }
}

/// The guide's recipe for a manifest's calibration settings: the import
/// report's `[calibration]` and `[reference]`, resolved over the defaults,
/// reach the options `calibrate` is given.
#[test]
fn a_manifests_settings_reach_the_options_through_resolve() {
    use odocal::settings::{Caller, ManifestSettings, Settings};
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/comma2k19-rav4");
    let dir = tempfile::tempdir().expect("tmp");
    for e in std::fs::read_dir(&src).expect("data") {
        let e = e.expect("entry");
        std::fs::copy(e.path(), dir.path().join(e.file_name())).expect("copy");
    }
    let manifest = dir.path().join("manifest.toml");
    let mut text = std::fs::read_to_string(&manifest).expect("manifest");
    text.push_str(
        "\n[reference]\nlever_arm = [0.5, 0.0]\n\n[calibration]\nmethod = \"batch-gn\"\nsegment_length = 400\n",
    );
    std::fs::write(&manifest, text).expect("write");
    let (_, import_report) = odocal::load_drive(&manifest).expect("load");
    let manifests: Vec<ManifestSettings> =
        import_report.as_ref().map(ManifestSettings::try_from).transpose().expect("settings").into_iter().collect();
    let opts = Settings::default().resolve(&manifests, Caller::CommandLine).expect("resolve").options;
    assert_eq!(opts.method.to_string(), "batch-gn");
    assert_eq!(opts.segments.length_steps, 400);
    assert!((opts.identify.extrinsics.lever_x - 0.5).abs() < 1e-12, "{:?}", opts.identify.extrinsics);
    assert_ne!(opts, CalibrationOptions::default());
}
