//! The real-drive slices in `tests/data/` import and calibrate to plausible
//! values (fast: batch Gauss-Newton on ~2 min and 20 s of data).

use odocal::segment::{SegmentOptions, ValidationSegmentOptions};
use odocal::{calibrate, CalibrationOptions, Method, Param};
use odocal::{import, Manifest};

fn manifest(name: &str) -> Manifest {
    let p = format!("{}/tests/data/{name}/manifest.toml", env!("CARGO_MANIFEST_DIR"));
    Manifest::from_path(std::path::Path::new(&p)).expect("manifest")
}

/// All segments of 400 steps (10 s), validation segments of 400 steps.
fn options() -> CalibrationOptions {
    CalibrationOptions {
        method: Method::BatchGn,
        segments: SegmentOptions { length_steps: 400, min_peak_yaw_rate_rad_per_s: 0.0, ..Default::default() },
        validation: ValidationSegmentOptions { length_steps: 400, stride_steps: 200, ..Default::default() },
        ..Default::default()
    }
}

#[test]
fn van_slice_imports_and_calibrates_c_e_near_the_tick_scale() {
    let (drive, report) = import(&manifest("psu-mapping-van")).expect("import");
    assert!(report.wheel_scale.contains("40360 ticks"), "{}", report.wheel_scale);
    let r = calibrate(&drive, &options()).expect("calibrate");
    // ~20,180 ticks per metre (data README): 40,360 ticks ≈ 2.0 m; the full
    // drive's halves give 1.9945–1.9963 m.
    assert!((1.99..2.005).contains(&r.theta.c_e), "c_e = {}", r.theta.c_e);
    assert!(r.validation.mean_position_error_m < r.initial.mean_position_error_m, "{:?}", r.validation);
    // 130 s of highway cannot separate t_r and d from c_d.
    let unobs = r.observability.unobservable;
    assert!(unobs.contains(Param::TR) && unobs.contains(Param::D), "{unobs:?}");
}

#[test]
fn van_slice_auto_fix_holds_what_the_check_names() {
    let (drive, _) = import(&manifest("psu-mapping-van")).expect("import");
    let r = calibrate(&drive, &CalibrationOptions { auto_fix: true, ..options() }).expect("calibrate");
    assert!(!r.auto_fixed.is_empty());
    assert!(r.observability.unobservable.is_empty(), "{:?}", r.observability);
    for p in &r.auto_fixed {
        assert!(!r.options.identify.free.contains(*p), "{p} is held");
    }
}

#[test]
fn rav4_slice_without_turns_is_an_error_naming_the_parameters() {
    let (drive, _) = import(&manifest("comma2k19-rav4")).expect("import");
    let opts = CalibrationOptions { segments: SegmentOptions { length_steps: 400, ..Default::default() }, ..options() };
    let e = calibrate(&drive, &opts).expect_err("not observable");
    assert!(e.to_string().contains("c_d, t_r, d not observable"), "{e}");
    let r = calibrate(&drive, &CalibrationOptions { auto_fix: true, ..opts.clone() }).expect("c_e alone");
    assert_eq!(r.auto_fixed, vec![Param::CD, Param::TR, Param::D]);
    assert!((2.0 * 1.005..2.0 * 1.015).contains(&r.theta.c_e), "c_e = {}", r.theta.c_e);
}
