//! Tests of the import: a synthetic multi-stream drive imported back against
//! its truth, the manifest errors, and slices of the two real drives.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use rand::{Rng, SeedableRng};

use super::manifest::{SourceSpec, WheelColumn, WheelSignal};
use super::report::StreamReport;
use super::source::Stream;
use super::wheels::wheel_revolutions;
use super::*;
use crate::model::{step, Input, State};

/// Pose interpolation of 10 Hz samples on a 40 m circle at ≤ 13 m/s: chord
/// error v²·Δt²/(8R) ≈ 5 mm; 2 cm leaves room for the ENU round trip.
const POSITION_TOL_M: f64 = 0.02;
/// Linear interpolation of 10 Hz heading where the yaw rate steps by up to
/// 13 m/s / 40 m = 0.33 rad/s (circle entry/exit): 0.33 × 0.1 s / 4 = 8 mrad.
const HEADING_TOL_RAD: f64 = 0.01;
/// Tick quantization (1/4096 rev per interval end over 25 ms: 0.01 rev/s) plus
/// the residual stamp error after de-jittering (~0.1 ms × 6 rev/s / 25 ms).
const WHEEL_TOL_REV_PER_S: f64 = 0.05;
/// IMU interval means vs truth: exact up to linear interpolation between
/// 100 Hz samples where a_y steps by v²/R ≈ 4 m/s² at the circle's ends
/// (measured 0.05 m/s² there, ~1e-3 elsewhere).
const A_Y_TOL: f64 = 0.1;

const TRUE_CLOCK_OFFSET_S: f64 = 0.137;
const TICKS_PER_REV: f64 = 4096.0;

/// The noise-free truth on a fine time grid (1 ms).
struct Truth {
    dt: f64,
    x: Vec<f64>,
    y: Vec<f64>,
    psi: Vec<f64>,
    rev_l: Vec<f64>,
    rev_r: Vec<f64>,
    a_y: Vec<f64>,
}

impl Truth {
    /// Straight, a 40 m circle, straight; speed 10 ± 3 m/s (period 15 s).
    fn new(duration_s: f64) -> Truth {
        let theta = Theta { c_e: 1.95, c_d: -0.002, t_r: 1.53, d: 0.0008 };
        let dt = 1e-3;
        let n = (duration_s / dt).round() as usize + 1;
        let mut tr = Truth {
            dt,
            x: vec![0.0; n],
            y: vec![0.0; n],
            psi: vec![0.0; n],
            rev_l: vec![0.0; n],
            rev_r: vec![0.0; n],
            a_y: vec![0.0; n],
        };
        let mut x = State::new(0.0, 0.0, 0.3);
        for i in 0..n {
            let t = i as f64 * dt;
            let v = 10.0 + 3.0 * (2.0 * std::f64::consts::PI * t / 15.0).sin();
            let kappa = if (15.0..45.0).contains(&t) { 1.0 / 40.0 } else { 0.0 };
            let om = v * kappa;
            let a_y = v * om;
            let (n_rl, n_rr) = crate::model::wheel_rotations(v, om, a_y, &theta);
            let u = Input { n_rl, n_rr, beta: 0.0, a_y };
            tr.x[i] = x[0];
            tr.y[i] = x[1];
            tr.psi[i] = x[2];
            tr.a_y[i] = a_y;
            if i + 1 < n {
                tr.rev_l[i + 1] = tr.rev_l[i] + u.n_rl * dt;
                tr.rev_r[i + 1] = tr.rev_r[i] + u.n_rr * dt;
            }
            x = step(&x, &u, &theta, dt);
        }
        tr
    }

    fn at(&self, v: &[f64], t: f64) -> f64 {
        let f = (t / self.dt).clamp(0.0, (v.len() - 2) as f64);
        let i = f.floor() as usize;
        let w = f - i as f64;
        v[i] + w * (v[i + 1] - v[i])
    }
}

/// Writes the streams and a manifest into `dir`; returns the manifest path.
/// Wheels at 100 Hz with ±1.5 ms stamp jitter in ns (left cumulative ticks,
/// right a 16-bit raw counter counting down), lat/lon pose at 10 Hz on a clock
/// `TRUE_CLOCK_OFFSET_S` behind with NED heading in degrees and a dropout at
/// pose time 30–32 s, IMU at 100 Hz (lateral axis to the right).
fn write_synthetic(dir: &Path, tr: &Truth, duration_s: f64) -> PathBuf {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut s = String::from("stamp_ns,left,right\n");
    let mut i = 0;
    while i as f64 * 0.01 <= duration_s - 0.01 {
        let t = i as f64 * 0.01;
        let stamp = t + 1.0 + rng.random_range(-0.0015..0.0015);
        let left = (tr.at(&tr.rev_l, t) * TICKS_PER_REV).floor();
        let down = 60_000.0 - (tr.at(&tr.rev_r, t) * TICKS_PER_REV).floor();
        let raw = down.rem_euclid(65536.0);
        writeln!(s, "{},{left},{raw}", (stamp * 1e9).round() as i64).expect("write");
        i += 1;
    }
    std::fs::write(dir.join("wheels.csv"), s).expect("write");

    let enu = geodesy::Enu::new(47.0, 19.0, 100.0);
    let mut s = String::from("time,lat,lon,alt,heading_deg,fix\n");
    let mut j = 0;
    loop {
        let ps = j as f64 * 0.1; // pose clock
        let t = ps + TRUE_CLOCK_OFFSET_S - 1.0; // truth time (the wheel clock is truth + 1 s)
        j += 1;
        if t < 0.0 {
            continue;
        }
        if t > duration_s {
            break;
        }
        if (30.0..32.0).contains(&ps) {
            continue;
        }
        let p = Vector3::new(tr.at(&tr.x, t), tr.at(&tr.y, t), 0.0);
        let (lat, lon, alt) = enu.geodetic_of(&p);
        let ned = (std::f64::consts::FRAC_PI_2 - tr.at(&tr.psi, t)).to_degrees();
        writeln!(s, "{ps:.3},{lat:.10},{lon:.10},{alt:.4},{ned:.9},4").expect("write");
    }
    std::fs::write(dir.join("pose.csv"), s).expect("write");

    let mut s = String::from("t,acc_right\n");
    for i in 0..((duration_s / 0.01) as usize) {
        let t = 0.005 + i as f64 * 0.01;
        writeln!(s, "{:.6},{:.9}", t + 1.0, -tr.at(&tr.a_y, t)).expect("write");
    }
    std::fs::write(dir.join("imu.csv"), s).expect("write");

    let manifest = format!(
        r#"
[output]
min_part_s = 10.0

[streams.wheels]
file = "wheels.csv"
time_column = "stamp_ns"
time_unit = "ns"
nominal_rate_hz = 100.0

[streams.gnss]
file = "pose.csv"
time_column = "time"

[streams.imu]
file = "imu.csv"
time_column = "t"

[wheels]
stream = "wheels"
signal = "ticks_raw"
ticks_per_rev = {TICKS_PER_REV}
counter_bits = 16
rear_left = {{ column = "left" }}
rear_right = {{ column = "right", sign = -1 }}

[pose]
stream = "gnss"
position = {{ kind = "lat_lon", lat = "lat", lon = "lon", alt = "alt", origin = [47.0, 19.0, 100.0] }}
heading = {{ column = "heading_deg", convention = "ned", unit = "deg" }}
quality = {{ column = "fix", accept = [4] }}

[lateral_acceleration]
source = "imu"
stream = "imu"
column = "acc_right"
sign = -1
"#
    );
    let path = dir.join("manifest.toml");
    std::fs::write(&path, manifest).expect("write");
    path
}

#[test]
fn synthetic_round_trip() {
    let duration = 70.0;
    let tr = Truth::new(duration);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = write_synthetic(dir.path(), &tr, duration);
    let (drive, report) = load_drive(&path).expect("import");
    let report = report.expect("a manifest gives a report");

    // The offset is recovered within one output sample (it is far better).
    let off = report.clock_offset.applied_s;
    assert!((off - TRUE_CLOCK_OFFSET_S).abs() < drive.sample_time_s(), "offset {off}");
    // The dropout (pose clock 30–32 s) splits the drive into two parts.
    assert_eq!(drive.parts().len(), 2, "{report}");
    assert!(report.gaps.iter().any(|g| g.reasons.iter().any(|r| r.contains("pose gap"))), "{report}");
    let gap = &report.gaps[0];
    let gap_truth = 30.0 + TRUE_CLOCK_OFFSET_S - 1.0; // in truth time
    assert!((report.time_origin_s + gap.t_start_s - 1.0 - gap_truth).abs() < 0.2, "{report}");
    // De-jittering makes the wheel speeds quieter.
    let j = report.jitter.as_ref().expect("jitter report");
    assert!(j.wheel_speed_noise_dejittered_pct < 0.5 * j.wheel_speed_noise_raw_pct, "{j:?}");

    let h = drive.sample_time_s();
    let shift = TRUE_CLOCK_OFFSET_S - off; // the pose is placed with the estimated offset
    let (mut ep, mut eh, mut en, mut ea) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for k in 0..drive.len() {
        let t = report.time_origin_s + drive.t()[k] - 1.0; // truth time
        let tp = t + shift;
        ep = ep.max((drive.px()[k] - tr.at(&tr.x, tp)).hypot(drive.py()[k] - tr.at(&tr.y, tp)));
        eh = eh.max((drive.psi()[k] - tr.at(&tr.psi, tp)).abs());
        let nl = (tr.at(&tr.rev_l, t + h) - tr.at(&tr.rev_l, t)) / h;
        let nr = (tr.at(&tr.rev_r, t + h) - tr.at(&tr.rev_r, t)) / h;
        en = en.max((drive.n_rl()[k] - nl).abs()).max((drive.n_rr()[k] - nr).abs());
        // a_y truth: mean over the interval.
        let m: f64 = (0..25).map(|q| tr.at(&tr.a_y, t + (q as f64 + 0.5) * h / 25.0)).sum::<f64>() / 25.0;
        ea = ea.max((drive.a_y()[k] - m).abs());
    }
    eprintln!("offset {off:.4} s (true {TRUE_CLOCK_OFFSET_S}); max errors: position {ep:.4} m, heading {eh:.5} rad, wheels {en:.4} rev/s, a_y {ea:.4} m/s²");
    assert!(ep < POSITION_TOL_M + 13.0 * shift.abs(), "position error {ep} m (offset error {shift} s)");
    assert!(eh < HEADING_TOL_RAD + 0.33 * shift.abs(), "heading error {eh} rad");
    assert!(en < WHEEL_TOL_REV_PER_S, "wheel error {en} rev/s");
    assert!(ea < A_Y_TOL, "a_y error {ea} m/s²");
    // Written and read back as canonical CSV with the part column.
    let mut buf = Vec::new();
    drive.write_csv_to(&mut buf).expect("write");
    let back = Drive::parse_csv(&buf, Path::new("x.csv")).expect("read back");
    assert_eq!(back.parts(), drive.parts());
}

#[test]
fn fixed_offset_and_raw_stamps_are_used_as_given() {
    let duration = 40.0;
    let tr = Truth::new(duration);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = write_synthetic(dir.path(), &tr, duration);
    let text = std::fs::read_to_string(&path).expect("read");
    let text = text.replace("min_part_s = 10.0", "min_part_s = 10.0\nclock_offset = 0.5");
    let m = Manifest::parse(&text, &path).expect("manifest");
    let r = import_drive(&m).expect("import").report;
    assert!((r.clock_offset.applied_s - 0.5).abs() < 1e-12);
    assert_eq!(r.clock_offset.mode, "fixed");
    // Still estimated and reported.
    let e = r.clock_offset.estimated_s.expect("estimate");
    assert!((e - TRUE_CLOCK_OFFSET_S).abs() < 0.025, "{e}");
}

/// A minimal valid manifest over small stream files in `dir`.
pub(crate) fn small_case(dir: &Path) -> PathBuf {
    let mut w = String::from("t,left,right\n");
    let mut p = String::from("t,x,y,q\n");
    for i in 0..400 {
        writeln!(w, "{},5,5", i as f64 / 100.0).expect("write");
    }
    for i in 0..40 {
        writeln!(p, "{},{i},0,1", i as f64 / 10.0).expect("write");
    }
    std::fs::write(dir.join("w.csv"), w).expect("write");
    std::fs::write(dir.join("p.csv"), p).expect("write");
    small_case_manifest(dir)
}

/// The manifest of [`small_case`] over the stream files `w.csv` and
/// `p.csv` in `dir` (`t,left,right` and `t,x,y,q`).
fn small_case_manifest(dir: &Path) -> PathBuf {
    let m = r#"
[output]
min_part_s = 1.0
clock_offset = 0.0

[streams.wheels]
file = "w.csv"
time_column = "t"

[streams.pose]
file = "p.csv"
time_column = "t"

[wheels]
stream = "wheels"
signal = "rev_per_s"
rear_left = { column = "left" }
rear_right = { column = "right" }

[pose]
stream = "pose"
position = { kind = "local", x = "x", y = "y" }
"#;
    let path = dir.join("m.toml");
    std::fs::write(&path, m).expect("write");
    path
}

fn error_of(dir: &Path, edit: impl Fn(String) -> String) -> String {
    let path = small_case(dir);
    let text = edit(std::fs::read_to_string(&path).expect("read"));
    std::fs::write(&path, text).expect("write");
    match load_drive(&path) {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn small_case_imports_and_derives_heading() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (d, r) = load_drive(small_case(dir.path())).expect("import");
    assert_eq!(d.parts().len(), 1);
    assert!(d.psi().iter().all(|p| p.abs() < 1e-9), "heading along +x is 0");
    assert!(d.n_rl().iter().all(|n| (n - 5.0).abs() < 1e-9));
    let r = r.expect("report");
    assert!(r.to_string().contains("1 of 1 parts kept"), "{r}");
}

/// `"auto"` does not apply a low or flat correlation peak (a false peak
/// from an offset beyond the search: correlation 0.776, ± 2.4 s), and
/// applies the shipped examples' (the highway van's ± 0.50 s, a test-track
/// run's ± 0.65 s at 0.9947).
#[test]
fn auto_refuses_a_low_or_flat_correlation_peak() {
    let c =
        |offset_s, peak, curvature| super::signal::Correlation { offset_s, peak, pairs: 2000, curvature, second: None };
    let d = |c| super::clock::doubt(Some(c), None, 0.025);
    let false_peak = d(c(2.7753, 0.7759, 0.081)).expect("low correlation");
    assert!(false_peak.contains("the speed correlation 0.776 is below 0.9"), "{false_peak}");
    let flat = d(c(2.7753, 0.95, 0.081)).expect("flat peak");
    assert!(flat.contains("too flat: ± 1.111 s is wider than 1 s"), "{flat}");
    assert_eq!(d(c(0.1408, 0.9998, 0.0016)), None);
    assert_eq!(d(c(-0.0996, 0.9947, 0.025)), None);
    // The yaw-rate cross-check counts from a correlation of 0.8.
    let yaw = |peak| super::clock::doubt(Some(c(0.0, 0.9998, 0.09)), Some(c(0.5, peak, 0.09)), 0.025);
    assert_eq!(yaw(0.79), None);
    assert!(yaw(0.8).expect("cross-check").contains("yaw-rate cross-check gives +0.5000 s"));
}

/// Rows repeating a stamp with other values are named (stream, file, first
/// line); more than 10 % of a stream's rows repeating a stamp is warned
/// about; identical repeats below that are only counted.
#[test]
fn repeated_stamps_with_other_values_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let w = dir.path().join("w.csv");
    let clean = std::fs::read_to_string(&w).expect("read");
    let repeats =
        |r: &ImportReport| r.warnings.iter().filter(|w| w.contains("repeat the stamp")).cloned().collect::<Vec<_>>();
    // One identical repeat: counted, no warning.
    std::fs::write(&w, clean.replacen("\n2,5,5\n", "\n2,5,5\n2,5,5\n", 1)).expect("write");
    let r = load_drive(&path).expect("import").1.expect("report");
    assert_eq!(r.streams.iter().map(|s| s.repeated_stamps_dropped).sum::<usize>(), 1);
    assert!(repeats(&r).is_empty(), "{:?}", r.warnings);
    // One repeat with other values: named.
    std::fs::write(&w, clean.replacen("\n2,5,5\n", "\n2,5,5\n2,15,15\n", 1)).expect("write");
    let r = load_drive(&path).expect("import").1.expect("report");
    let found = repeats(&r);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].starts_with("streams.wheels: 1 row(s) of") && found[0].contains("w.csv"), "{found:?}");
    assert!(found[0].contains("first: line 203 at 2 s, column 'left' = 15 against 5 at line 202"), "{found:?}");
    // Every second row doubled: a third of the rows dropped.
    let doubled: String = clean
        .lines()
        .enumerate()
        .map(|(i, l)| if i % 2 == 1 { format!("{l}\n{l}\n") } else { format!("{l}\n") })
        .collect();
    std::fs::write(&w, doubled).expect("write");
    let r = load_drive(&path).expect("import").1.expect("report");
    let found = repeats(&r);
    assert!(found.iter().any(|w| w.contains("200 of the 600 rows") && w.contains("(33 %)")), "{found:?}");
}

/// A one-sample wheel-speed glitch, which averages out below the output
/// speed check, is named with its stream, file and line.
#[test]
fn an_impossible_wheel_speed_sample_is_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    // a_y from the straight pose: the wheels' yaw rate at the glitch is not judged.
    let manifest = std::fs::read_to_string(&path).expect("read");
    std::fs::write(&path, manifest + "\n[lateral_acceleration]\nsource = \"from_pose\"\n").expect("write");
    let (_, r) = load_drive(&path).expect("clean");
    assert!(!r.expect("report").warnings.iter().any(|w| w.contains("impossible wheel speed")));
    let w = dir.path().join("w.csv");
    let clean = std::fs::read_to_string(&w).expect("read");
    // One wheel 30 m/s from the other; both above limits.max_speed_m_per_s.
    for (bad, what) in [("2,5,20", "rear_right ('right') 40.00 m/s"), ("2,60,60", "rear_left ('left') 120.00 m/s")] {
        std::fs::write(&w, clean.replacen("\n2,5,5\n", &format!("\n{bad}\n"), 1)).expect("write");
        let (_, r) = load_drive(&path).expect("a glitch warns");
        let r = r.expect("report");
        let found = r.warnings.iter().find(|w| w.contains("impossible wheel speed"));
        let found = found.unwrap_or_else(|| panic!("{:?}", r.warnings));
        assert!(found.starts_with("streams.wheels: 1 row(s) of") && found.contains("w.csv"), "{found}");
        assert!(found.contains("first line 202 (t = 2.000 s)") && found.contains(what), "{found}");
    }
}

/// A heading in radians declared in degrees, on a drive too straight for
/// the yaw-rate checks, gets the warning calibrate's refusal would give.
#[test]
fn a_heading_in_the_wrong_unit_is_warned_at_import() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let (mut w, mut p) = (String::from("t,left,right\n"), String::from("t,x,y,q,h\n"));
    for i in 0..1000 {
        writeln!(w, "{},5,5", i as f64 / 100.0).expect("write");
    }
    for i in 0..100 {
        writeln!(p, "{},0,{i},1,{}", i as f64 / 10.0, std::f64::consts::FRAC_PI_2).expect("write");
    }
    std::fs::write(dir.path().join("w.csv"), w).expect("write");
    std::fs::write(dir.path().join("p.csv"), p).expect("write");
    let text = std::fs::read_to_string(&path).expect("read");
    let with_unit = |unit: &str| {
        let heading = format!("[pose.heading]\ncolumn = \"h\"\nconvention = \"enu\"\nunit = \"{unit}\"\n");
        std::fs::write(&path, format!("{text}\n{heading}")).expect("write");
        let (_, r) = load_drive(&path).expect("import");
        r.expect("report").warnings
    };
    let refused = |w: &Vec<String>| w.iter().any(|w| w.contains("calibrate and validate will refuse this drive"));
    assert!(!refused(&with_unit("rad")), "{:?}", with_unit("rad"));
    let w = with_unit("deg");
    assert!(refused(&w) && w.iter().any(|w| w.contains("the heading differs from the direction of travel")), "{w:?}");
}

/// [`small_case`]'s manifest over a walk along x at 2 m/s for 60 s: wheels
/// at 100 Hz, positions at 20 Hz with 2 cm of white noise on each axis, no
/// heading column; `pose` holds extra `[pose]` keys. Output at 40 Hz.
fn noisy_walk(dir: &Path, pose: &str) -> PathBuf {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let noise = rand_distr::Normal::new(0.0, 0.02).expect("normal");
    let mut sample = || rand_distr::Distribution::sample(&noise, &mut rng);
    let (mut w, mut p) = (String::from("t,left,right\n"), String::from("t,x,y,q\n"));
    for i in 0..6000 {
        writeln!(w, "{},1,1", i as f64 / 100.0).expect("write");
    }
    for i in 0..1200 {
        let t = i as f64 / 20.0;
        writeln!(p, "{t},{},{},1", 2.0 * t + sample(), sample()).expect("write");
    }
    std::fs::write(dir.join("w.csv"), w).expect("write");
    std::fs::write(dir.join("p.csv"), p).expect("write");
    let path = small_case_manifest(dir);
    let text = std::fs::read_to_string(&path).expect("read");
    let text = text
        .replace("min_part_s = 1.0", "min_part_s = 1.0\nrate_hz = 40.0")
        .replace("[pose]\nstream = \"pose\"\n", &format!("[pose]\nstream = \"pose\"\n{pose}\n"));
    std::fs::write(&path, text).expect("write");
    path
}

/// The noisy walk of [`noisy_walk`] imports with the derived heading's
/// default chord (2 m): its error is about 0.01 rad RMS. A chord shorter
/// than the steps (5 cm: the direction between consecutive samples) is
/// the noise, and the drive's check refuses it, naming the heading as
/// derived from the positions with the settings that help, not as a
/// heading column in degrees.
#[test]
fn a_noisy_track_gives_a_derived_heading_that_passes_the_check() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (d, _) = load_drive(noisy_walk(dir.path(), "")).expect("the default chord");
    let psi = &d.measured().psi;
    let rms = (psi.iter().map(|p| p * p).sum::<f64>() / psi.len() as f64).sqrt();
    assert!(rms < 0.02, "heading error RMS {rms} rad");
    let short = noisy_walk(dir.path(), "derive_heading_baseline_m = 0.05");
    let e = load_drive(&short).expect_err("a heading of noise").to_string();
    assert!(e.contains("psi at t = ") && e.contains("the heading derived from the positions"), "{e}");
    assert!(e.contains("[pose.heading]") && e.contains("derive_heading_min_speed_m_per_s (here 1 m/s)"), "{e}");
    assert!(e.contains("lengthen pose.derive_heading_baseline_m (here 0.05 m)"), "{e}");
    assert!(!e.contains("degrees"), "{e}");
}

/// `pose.derive_heading_baseline_m` must be a positive length up to the
/// limit; the error names the key.
#[test]
fn a_derived_heading_baseline_out_of_range_is_refused_with_the_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (value, says) in [
        ("0", "must be a positive number"),
        ("-1.5", "must be a positive number"),
        ("nan", "must be a positive number"),
        ("inf", "must be a positive number"),
        ("500.0", "above the limit of 50"),
        ("\"2\"", "invalid type"),
    ] {
        let e =
            error_of(dir.path(), |t| t.replace("[pose]\n", &format!("[pose]\nderive_heading_baseline_m = {value}\n")));
        assert!(e.contains("pose.derive_heading_baseline_m") && e.contains(says), "{value}: {e}");
    }
}

/// A fixed clock offset's estimate, only reported, is skipped with a note
/// when its search would exceed the correlation budget; `"auto"` is still
/// refused there.
#[test]
fn a_fixed_offset_skips_an_estimate_beyond_the_budget() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    // 100 s at 500 Hz: a ±60 s search is 6·10⁹ multiply-adds.
    let (mut w, mut p) = (String::from("t,left,right\n"), String::from("t,x,y,q\n"));
    for i in 0..10_000 {
        writeln!(w, "{},5,5", i as f64 / 100.0).expect("write");
    }
    for i in 0..1000 {
        writeln!(p, "{},{i},0,1", i as f64 / 10.0).expect("write");
    }
    std::fs::write(dir.path().join("w.csv"), w).expect("write");
    std::fs::write(dir.path().join("p.csv"), p).expect("write");
    let text = std::fs::read_to_string(&path)
        .expect("read")
        .replace("min_part_s = 1.0", "min_part_s = 1.0\nrate_hz = 500.0\nmax_clock_offset_s = 60.0");
    std::fs::write(&path, &text).expect("write");
    let (_, r) = load_drive(&path).expect("a fixed offset imports");
    let t = r.expect("report").to_string();
    assert!(t.contains("clock offset: not estimated, applied +0.0000 s (fixed)"), "{t}");
    assert!(t.contains("clock offset estimate skipped: searching ±60 s at 500 Hz"), "{t}");
    std::fs::write(&path, text.replace("clock_offset = 0.0", "clock_offset = \"auto\"")).expect("write");
    let e = load_drive(&path).expect_err("auto over budget").to_string();
    assert!(e.contains("output.max_clock_offset_s") && e.contains("above the budget"), "{e}");
}

/// Every fixed-length array refuses more values as it refuses fewer,
/// naming the key.
#[test]
fn fixed_length_arrays_refuse_extra_values() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    for (theta0, got) in [("[2.0, 0.0, 1.6, 0.0, 5.0]", 5), ("[2.0, 0.0, 1.6]", 3)] {
        let m = error_of(d, |t| t.replace("clock_offset = 0.0", &format!("clock_offset = 0.0\ntheta0 = {theta0}")));
        assert!(m.contains(&format!("output.theta0: expected 4 values c_e, c_d, t_r, d, got {got}")), "{m}");
    }
    let m = error_of(d, |t| t + "\n[reference]\nlever_arm = [0.5, 0.0, 7.0]\n");
    assert!(m.contains("reference.lever_arm: expected 2 values x, y, got 3"), "{m}");
    let origin = "position = { kind = \"lat_lon\", lat = \"x\", lon = \"y\", origin = [0.0, 0.0, 0.0, 1.0] }";
    let m = error_of(d, |t| t.replace("position = { kind = \"local\", x = \"x\", y = \"y\" }", origin));
    assert!(m.contains("pose.position") && m.contains("expected 3 values lat_deg, lon_deg, h_m, got 4"), "{m}");
}

#[test]
fn manifest_errors_name_key_and_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let m = error_of(d, |t| t.replacen("file = \"w.csv\"\n", "", 1));
    assert!(m.contains("m.toml") && m.contains("streams.wheels.file: missing"), "{m}");
    let m = error_of(d, |t| t.replacen("time_column = \"t\"", "time_column = \"t\"\ntime_unit = \"minutes\"", 1));
    assert!(m.contains("streams.wheels.time_unit") && m.contains("minutes"), "{m}");
    let m = error_of(d, |t| t.replacen("stream = \"wheels\"", "stream = \"wheel\"", 1));
    assert!(m.contains("wheels.stream: no stream named 'wheel' (streams: pose, wheels)"), "{m}");
    let m = error_of(d, |t| t.replace("signal = \"rev_per_s\"", "signal = \"ticks_raw\""));
    assert!(m.contains("wheels.ticks_per_rev: required"), "{m}");
    let m = error_of(d, |t| t.replace("[pose]", "[pose]\nspeed = 3"));
    assert!(m.contains("pose.speed: unknown field `speed`, expected one of `stream`"), "{m}");
    let m = error_of(d, |t| t.replace("clock_offset = 0.0", "clock_offset = \"soon\""));
    assert!(m.contains("output.clock_offset") && m.contains("\"auto\""), "{m}");
}

#[test]
fn missing_file_and_column_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let m = error_of(d, |t| t.replace("\"p.csv\"", "\"nope.csv\""));
    assert!(m.contains("streams.pose.file: cannot read") && m.contains("nope.csv"), "{m}");
    let m = error_of(d, |t| t.replace("column = \"left\"", "column = \"lft\""));
    assert!(
        m.contains("wheels.rear_left.column: column 'lft' not found in")
            && m.contains("w.csv; columns found: t, left, right"),
        "{m}"
    );
}

/// A stream file's header: empty, separated by `;`, or naming a column the
/// manifest reads twice (which of the two to read would be a guess) is an
/// error naming the file, in the whole import and the streamed one alike.
#[test]
fn empty_ambiguous_and_misseparated_headers_are_named() {
    type Edit<'a> = &'a dyn Fn(String) -> String;
    let cases: [(Edit, &[&str]); 3] = [
        (&|_| String::new(), &["w.csv is empty: a stream file starts with a header row"]),
        (&|w| w.replace(',', ";"), &["column 't' not found", "looks separated by ';'"]),
        (&|w| w.replacen("t,left,right", "t,left,left", 1), &["column 'left' is named 2 times", "(columns 2, 3)"]),
    ];
    for (edit, needles) in cases {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = small_case(dir.path());
        let w = dir.path().join("w.csv");
        std::fs::write(&w, edit(std::fs::read_to_string(&w).expect("read"))).expect("write");
        let whole = load_drive(&path).map(|_| ()).expect_err("bad header").to_string();
        let m = Manifest::from_path(&path).expect("manifest");
        let opened = stream::reader::ManifestStream::open(&m, stream::StreamOptions { warm_up_s: 20.0 });
        let streamed = opened.map(|_| ()).expect_err("bad header").to_string();
        for e in [whole, streamed] {
            assert!(needles.iter().all(|n| e.contains(n)), "{needles:?} in: {e}");
        }
    }
}

#[test]
fn backwards_time_names_file_and_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let p = std::fs::read_to_string(dir.path().join("p.csv")).expect("read");
    std::fs::write(dir.path().join("p.csv"), p.replacen("\n0.5,", "\n0.25,", 1)).expect("write");
    let m = load_drive(&path).map(|_| ()).expect_err("backwards").to_string();
    assert!(m.contains("p.csv: line 7, column 't'") && m.contains("time goes backwards (0.25 after 0.4 s)"), "{m}");
    // One stamp ahead of both neighbours: its own line is named, not the next one's.
    std::fs::write(dir.path().join("p.csv"), p.replacen("\n0.5,", "\n5.5,", 1)).expect("write");
    let m = load_drive(&path).map(|_| ()).expect_err("a jump").to_string();
    assert!(m.contains("p.csv: line 7, column 't'") && m.contains("time jumps ahead to 5.5 s, 5.1 s after"), "{m}");
}

/// The errors of the small case with `p.csv` and `w.csv` edited, converted
/// to CRLF when asked: the whole import's, then the streamed import's.
fn whole_and_streamed_errors(
    crlf: bool,
    edit_p: impl Fn(String) -> String,
    edit_w: impl Fn(String) -> String,
) -> [String; 2] {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    for (file, edit) in [("p.csv", &edit_p as &dyn Fn(String) -> String), ("w.csv", &edit_w)] {
        let text = edit(std::fs::read_to_string(dir.path().join(file)).expect("read"));
        let text = if crlf { text.replace('\n', "\r\n") } else { text };
        std::fs::write(dir.path().join(file), text).expect("write");
    }
    let whole = load_drive(&path).map(|_| ()).expect_err("bad row").to_string();
    let m = Manifest::from_path(&path).expect("manifest");
    let mut s = stream::reader::ManifestStream::open(&m, stream::StreamOptions { warm_up_s: 20.0 }).expect("open");
    let streamed = loop {
        match s.next_chunk(400) {
            Ok(Some(_)) => {}
            Ok(None) => panic!("the streamed import took the bad row"),
            Err(e) => break e.to_string(),
        }
    };
    [whole, streamed]
}

#[test]
fn stream_csv_errors_name_the_line_for_lf_and_crlf() {
    for crlf in [false, true] {
        for m in whole_and_streamed_errors(crlf, |p| p.replacen("\n0.5,5,", "\n0.5,abc,", 1), |w| w) {
            assert!(m.contains("p.csv: line 7, column 'x': 'abc' is not a number"), "crlf {crlf}: {m}");
        }
        for m in whole_and_streamed_errors(crlf, |p| p, |w| w.replacen("\n0.1,5,5\n", "\n0.1,5\n", 1)) {
            assert!(m.contains("w.csv: line 12") && m.contains("2 fields, the header has 3"), "crlf {crlf}: {m}");
        }
    }
}

#[test]
fn no_overlap_is_an_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let m =
        error_of(dir.path(), |t| t.replacen("time_column = \"t\"", "time_column = \"t\"\ntime_offset_s = 100.0", 1));
    assert!(m.contains("no time overlap") && m.contains("streams.pose") && m.contains("streams.wheels"), "{m}");
}

#[test]
fn quality_rejection_splits_and_short_parts_are_dropped() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let p = std::fs::read_to_string(dir.path().join("p.csv")).expect("read");
    // Samples at 1.0 s and 3.6 s rejected: parts 0–0.9 s and 3.7–3.9 s are
    // shorter than min_part_s = 1 s and dropped, 1.1–3.5 s is kept.
    let p = p.replace("\n1,10,0,1", "\n1,10,0,0").replace("\n3.6,36,0,1", "\n3.6,36,0,0");
    std::fs::write(dir.path().join("p.csv"), p).expect("write");
    let text = std::fs::read_to_string(&path).expect("read");
    std::fs::write(&path, text.replace("[pose]", "[pose]\nquality = { column = \"q\", accept = [1] }")).expect("write");
    let (d, r) = load_drive(&path).expect("import");
    let r = r.expect("report");
    assert_eq!(r.gaps.len(), 2, "{r}");
    assert!(r.gaps[0].reasons[0].contains("pose quality rejected (q = [0.0], 1 samples)"), "{r}");
    assert!(
        r.parts.iter().any(|p| !p.kept && p.dropped_because.as_deref().is_some_and(|w| w.contains("min_part_s"))),
        "{r}"
    );
    assert_eq!(d.parts().len(), r.parts.iter().filter(|p| p.kept).count());
    // No sample of the drive lies within a rejected stretch.
    assert!(d.t().iter().all(|t| !(0.9..1.1).contains(t)));
    spans_agree_with_durations(&r);
}

/// Every part's span is its samples × the output step, the duration its
/// drop reason and the kept total state; parts and gaps tile the time
/// axis (each ends where the next starts).
fn spans_agree_with_durations(r: &ImportReport) {
    let h = 1.0 / r.output_rate_hz;
    for p in &r.parts {
        let span = p.t_end_s - p.t_start_s;
        assert!((span - p.samples as f64 * h).abs() < 1e-9, "{span} s against {} samples: {r}", p.samples);
        if let Some(why) = &p.dropped_because {
            assert!(why.starts_with(&format!("{span:.3} s is shorter")), "{why} against {span} s: {r}");
        }
    }
    let kept: f64 = r.parts.iter().filter(|p| p.kept).map(|p| p.t_end_s - p.t_start_s).sum();
    assert!((kept - r.duration_s).abs() < 1e-6, "{kept} against {}: {r}", r.duration_s);
    let mut spans: Vec<[f64; 2]> = r.parts.iter().map(|p| [p.t_start_s, p.t_end_s]).collect();
    spans.extend(r.gaps.iter().map(|g| [g.t_start_s, g.t_end_s]));
    spans.sort_by(|a, b| a[0].total_cmp(&b[0]));
    for w in spans.windows(2) {
        assert_eq!(w[0][1].to_bits(), w[1][0].to_bits(), "{w:?}: {r}");
    }
}

#[test]
fn raw_counter_wraps() {
    // A 12-bit counter counting down through zero, +5 ticks per sample.
    let s = Stream {
        path: PathBuf::from("x.csv"),
        t: (0..100).map(|i| i as f64 * 0.01).collect(),
        t_raw: vec![],
        cols: [("c".to_string(), (0..100).map(|i| ((100 - 5 * i) as i64).rem_euclid(4096) as f64).collect())]
            .into_iter()
            .collect(),
        lines: None,
        report: StreamReport {
            name: "w".into(),
            file: PathBuf::new(),
            rows: 100,
            repeated_stamps_dropped: 0,
            corrupt_rows_dropped: 0,
            time_span_s: [0.0, 1.0],
            mean_rate_hz: 100.0,
            dejitter: None,
        },
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(small_case(dir.path())).expect("read");
    let text = text.replace("signal = \"rev_per_s\"", "signal = \"ticks_raw\"\nticks_per_rev = 10\ncounter_bits = 12");
    let m = Manifest::parse(&text, Path::new("m.toml")).expect("manifest");
    let rev = wheel_revolutions(&m, &s, &WheelColumn { column: "c".into(), sign: -1.0 }, "k").expect("revs");
    assert!((rev[99] - 99.0 * 5.0 / 10.0).abs() < 1e-9, "{}", rev[99]);
}

#[test]
fn module_doc_example_manifest_parses() {
    let src = include_str!("mod.rs");
    let start = src.find("//! ```toml\n").expect("toml block") + "//! ```toml\n".len();
    let end = start + src[start..].find("//! ```\n").expect("end");
    let text: String = src[start..end]
        .lines()
        .map(|l| l.strip_prefix("//!").unwrap_or(l).trim_start_matches(' '))
        .collect::<Vec<_>>()
        .join("\n");
    let m = Manifest::parse(&text, Path::new("doc.toml")).expect("doc example");
    assert_eq!(m.wheels.signal, WheelSignal::TicksRaw);
    assert!(matches!(m.lateral_acceleration, LateralAccelerationSpec::Imu { .. }));
}

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name).join("manifest.toml")
}

#[test]
fn van_slice_imports() {
    let (d, r) = load_drive(data("psu-mapping-van")).expect("van slice");
    let r = r.expect("report");
    // Two RTK-fixed losses in the slice split it.
    assert!(d.parts().len() >= 2 && r.gaps.iter().any(|g| g.reasons[0].contains("both_fix6")), "{r}");
    // Highway: ~30 m/s over most of 130 s.
    assert!(r.distance_m > 2000.0, "{r}");
    // On top of the README's 0.105 s, the full drive's speed correlation gives
    // +0.14 s, this slice +0.08 s: highway speed carries little timing
    // information. Check the estimate is applied and plausible.
    let off = r.clock_offset.applied_s;
    assert!((0.0..0.25).contains(&off), "{r}");
    assert_eq!(r.clock_offset.estimated_s, Some(off));
    let j = r.jitter.as_ref().expect("de-jittered");
    assert!(j.wheel_speed_noise_dejittered_pct < 0.5 * j.wheel_speed_noise_raw_pct, "{r}");
    assert!(r.wheel_scale.contains("40360 ticks"), "{r}");
    // c_e ≈ 2 m per 40360 ticks: wheel speed at θ_0 ≈ reference speed.
    let (mut sw, mut sp) = (0.0f64, 0.0f64);
    for p in d.parts() {
        for k in p.start..p.end - 1 {
            sw += (d.n_rl()[k] + d.n_rr()[k]) * 0.5 * 2.0 * d.sample_time_s();
            sp += (d.px()[k + 1] - d.px()[k]).hypot(d.py()[k + 1] - d.py()[k]);
        }
    }
    assert!((sw / sp - 1.0).abs() < 0.02, "wheel/pose distance {}", sw / sp);
}

#[test]
fn van_raw_counters_match_cumulative_columns() {
    let path = data("psu-mapping-van");
    let text = std::fs::read_to_string(&path).expect("read");
    let raw = text
        .replace("signal = \"ticks_cumulative\"", "signal = \"ticks_raw\"\ncounter_bits = 32")
        .replace("{ column = \"left_ticks_cum\" }", "{ column = \"c1_raw\", sign = -1 }")
        .replace("{ column = \"right_ticks_cum\" }", "{ column = \"c2_raw\" }");
    let a = import_drive(&Manifest::parse(&text, &path).expect("m")).expect("cum").drive;
    let b = import_drive(&Manifest::parse(&raw, &path).expect("m")).expect("raw").drive;
    assert_eq!(a.len(), b.len());
    let worst = a
        .n_rl()
        .iter()
        .zip(b.n_rl())
        .chain(a.n_rr().iter().zip(b.n_rr()))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-9, "{worst}");
}

#[test]
fn rav4_slice_imports() {
    let (d, r) = load_drive(data("comma2k19-rav4")).expect("rav4 slice");
    let r = r.expect("report");
    assert_eq!(d.parts().len(), 1, "{r}");
    assert!((18.0..20.5).contains(&r.duration_s), "{r}");
    assert!(r.clock_offset.applied_s.abs() < 0.1, "{r}");
    // Nearly straight: |a_y| stays small, and is left-positive on average ~0.
    let mean_ay = d.a_y().iter().sum::<f64>() / d.len() as f64;
    assert!(mean_ay.abs() < 1.0, "{mean_ay}");
    // Too straight for the heading check; its yaw rates correlate well
    // enough, and the warning names only what failed.
    let w = r.warnings.iter().find(|w| w.starts_with("heading unit and convention not checked")).expect("{r}");
    assert!(w.contains("the drive turns too little (RMS wheel yaw rate 0.00"), "{w}");
    assert!(!w.contains("correlate"), "{w}");
}

#[test]
fn stream_format_is_tagged_with_csv_by_default() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text = std::fs::read_to_string(&path).expect("read");
    let m = Manifest::parse(&text, &path).expect("manifest");
    assert_eq!(m.streams["wheels"].source, SourceSpec::Csv { file: "w.csv".into() });
    let explicit = text.replacen("file = \"w.csv\"", "format = \"csv\"\nfile = \"w.csv\"", 1);
    assert_eq!(Manifest::parse(&explicit, &path).expect("explicit csv").streams, m.streams);
    // MCAP needs a topic; the topic is only for MCAP.
    // (A bag stream takes its time from the messages: no time_column.)
    let mcap = text.replacen("file = \"w.csv\"\ntime_column = \"t\"", "format = \"mcap\"\nfile = \"w.mcap\"", 1);
    let e = Manifest::parse(&mcap, &path).expect_err("no topic").to_string();
    assert!(e.contains("streams.wheels") && e.contains("`topic` is required for format = \"mcap\""), "{e}");
    let e = Manifest::parse(&text.replacen("file = \"w.csv\"", "file = \"w.csv\"\ntopic = \"/w\"", 1), &path)
        .expect_err("topic on csv")
        .to_string();
    assert!(e.contains("`topic` is only for format = \"mcap\""), "{e}");
    let e = Manifest::parse(&text.replacen("file = \"w.csv\"", "format = \"hdf5\"\nfile = \"w.csv\"", 1), &path)
        .expect_err("unknown format")
        .to_string();
    assert!(e.contains("streams.wheels.format") && e.contains("hdf5"), "{e}");
    // A parsed MCAP stream goes to the bag reader (here: no such file).
    let mcap = mcap.replacen("format = \"mcap\"", "format = \"mcap\"\ntopic = \"/wheels\"", 1);
    let m = Manifest::parse(&mcap, &path).expect("mcap manifest");
    let time = crate::io::import::manifest::BagTime::Header;
    assert_eq!(m.streams["wheels"].source, SourceSpec::Mcap { file: "w.mcap".into(), topic: "/wheels".into(), time });
    let e = import_drive(&m).map(|_| ()).expect_err("no such bag").to_string();
    #[cfg(feature = "mcap")]
    assert!(e.contains("streams.wheels.file: ") && e.contains("w.mcap"), "{e}");
    #[cfg(not(feature = "mcap"))]
    assert!(e.contains("streams.wheels.format: \"mcap\" streams need odocal built with the cargo feature"), "{e}");
}

#[test]
fn reference_measured_marks_the_sample_nearest_each_pose_sample() {
    let duration = 40.0;
    let tr = Truth::new(duration);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = write_synthetic(dir.path(), &tr, duration);
    let ImportedDrive { drive, report } = import_drive(&Manifest::from_path(&path).expect("m")).expect("import");
    let mask = drive.reference_measured().expect("an imported drive has the mask");
    let h = drive.sample_time_s();
    // Pose times on the drive's clock: 10 Hz on the pose clock, shifted.
    let shift = report.clock_offset.applied_s - report.time_origin_s;
    let pose_t: Vec<f64> = (0..1000).map(|j| j as f64 * 0.1 + shift).collect();
    for (k, &m) in mask.iter().enumerate() {
        let t = drive.t()[k];
        let nearest = pose_t.iter().map(|p| (p - t).abs()).fold(f64::INFINITY, f64::min);
        assert_eq!(m, nearest <= 0.5 * h + 1e-9, "sample {k} t = {t}: nearest pose sample {nearest} s away");
    }
    // 40 Hz output, 10 Hz pose: one in four.
    let frac = mask.iter().filter(|m| **m).count() as f64 / mask.len() as f64;
    assert!((frac - 0.25).abs() < 0.01, "{frac}");
}

// ---- Bounded resources and physical plausibility. ----

/// Imports the small case after `edit` of the manifest and `edit_w` of the
/// wheel CSV; returns the error text and the largest grid allocated.
fn small_case_error(edit: impl Fn(String) -> String, edit_w: impl Fn(String) -> String) -> (String, usize) {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text = edit(std::fs::read_to_string(&path).expect("read"));
    let w = edit_w(std::fs::read_to_string(dir.path().join("w.csv")).expect("read"));
    std::fs::write(dir.path().join("w.csv"), w).expect("write");
    limits::LARGEST_GRID.with(|c| c.set(0));
    let e = Manifest::parse(&text, &path).and_then(|m| import_drive(&m)).map(|_| ()).expect_err("an error").to_string();
    (e, limits::LARGEST_GRID.with(|c| c.get()))
}

fn manifest_error(edit: impl Fn(String) -> String) -> String {
    small_case_error(edit, |w| w).0
}

#[test]
fn absurd_output_rates_are_rejected_naming_the_key() {
    for rate in ["9223372036854775807", "1e9", "1e6", "0.001"] {
        let e = manifest_error(|t| t.replace("min_part_s = 1.0", &format!("min_part_s = 1.0\nrate_hz = {rate}")));
        assert!(e.contains("output.rate_hz"), "{rate}: {e}");
        assert!(e.len() < 400, "{e}");
    }
    // Within the rate limit but beyond the sample budget for the span: a
    // 1 kHz output of a 20,000 s log.
    let (e, largest) = small_case_error(
        |t| t.replace("min_part_s = 1.0", "min_part_s = 1.0\nrate_hz = 1000"),
        |w| w.replace("\n3.99,", "\n20000,"),
    );
    assert!(e.contains("output.rate_hz") && e.contains("budget"), "{e}");
    assert_eq!(largest, 0, "nothing allocated before the budget check");
}

/// The output rate's limit is the drive's sample-time limit: every rate the
/// manifest accepts gives a drive whose sample time passes the drive
/// checks, and a faster one is refused naming the key, before any stream
/// is read.
#[test]
fn the_output_rate_limit_is_the_drives_sample_time_limit() {
    let drive_limits = crate::model::limits::PhysicalLimits::default();
    assert!((limits::MAX_OUTPUT_RATE_HZ * drive_limits.min_sample_time_s - 1.0).abs() < 1e-12);
    assert!((limits::MIN_OUTPUT_RATE_HZ * drive_limits.max_sample_time_s - 1.0).abs() < 1e-12);
    let (e, largest) = small_case_error(|t| t.replace("min_part_s = 1.0", "min_part_s = 1.0\nrate_hz = 2000.0"), |w| w);
    assert!(e.contains("output.rate_hz: 2000 is above the limit of 1000"), "{e}");
    assert_eq!(largest, 0, "refused before any grid");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text =
        std::fs::read_to_string(&path).expect("read").replace("min_part_s = 1.0", "min_part_s = 1.0\nrate_hz = 1000.0");
    let m = Manifest::parse(&text, &path).expect("manifest");
    let d = import_drive(&m).expect("a 1 kHz import").drive;
    assert!((d.sample_time_s() - 1e-3).abs() < 1e-12, "{}", d.sample_time_s());
}

/// A stream in seconds read with `time_unit = "ms"` spans a thousandth
/// of the drive: the error that no part is long enough names the unit, the
/// span and the rate it gives.
#[test]
fn a_stream_in_seconds_read_as_ms_is_named_with_its_unit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut w = String::from("t,left,right\n");
    let mut p = String::from("t,x,y,q\n");
    for i in 0..20_000 {
        writeln!(w, "{},5,5", i as f64 / 100.0).expect("write");
    }
    for i in 0..2_000 {
        writeln!(p, "{},{i},0,1", i as f64 / 10.0).expect("write");
    }
    std::fs::write(dir.path().join("w.csv"), w).expect("write");
    std::fs::write(dir.path().join("p.csv"), p).expect("write");
    let path = small_case_manifest(dir.path());
    let text = std::fs::read_to_string(&path).expect("read").replace("min_part_s = 1.0", "min_part_s = 10.0").replacen(
        "time_column = \"t\"",
        "time_column = \"t\"\ntime_unit = \"ms\"",
        1,
    );
    let e = Manifest::parse(&text, &path).and_then(|m| import_drive(&m)).map(|_| ()).expect_err("short").to_string();
    assert!(e.contains("no continuous part of at least output.min_part_s = 10 s"), "{e}");
    assert!(e.contains("streams.wheels reads its times in ms (time_unit = \"ms\"): 0.19999 s at 100000 Hz"), "{e}");
    assert!(e.contains("are the times in seconds already?"), "{e}");
}

/// `output.max_gap_s` has an upper limit, named when exceeded.
#[test]
fn max_gap_beyond_its_limit_is_refused_naming_the_key() {
    for gap in ["1e9", "10.5"] {
        let e = manifest_error(|t| t.replace("min_part_s = 1.0", &format!("min_part_s = 1.0\nmax_gap_s = {gap}")));
        assert!(e.contains("output.max_gap_s") && e.contains("above the limit of 10"), "{gap}: {e}");
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text =
        std::fs::read_to_string(&path).expect("read").replace("min_part_s = 1.0", "min_part_s = 1.0\nmax_gap_s = 10");
    Manifest::parse(&text, &path).expect("10 s is within the limit");
}

/// Two rows each a long time apart: the output would be millions of
/// samples interpolated between them, within the sample budget but far
/// beyond what the streams hold. Refused naming the streams and their rows
/// before any grid is allocated.
#[test]
fn an_output_far_beyond_the_wheel_streams_rows_is_refused_before_allocating() {
    let dir = tempfile::tempdir().expect("tempdir");
    std::fs::write(dir.path().join("w.csv"), "t,rl,rr\n0,1,1\n9990000,1,1\n").expect("write");
    std::fs::write(dir.path().join("p.csv"), "t,x,y\n0,0,0\n9990000,1,0\n").expect("write");
    let text = r#"
[output]
rate_hz = 1.0
max_gap_s = 10
min_part_s = 0.0
clock_offset = 0.0
[streams.w]
file = "w.csv"
time_column = "t"
[streams.p]
file = "p.csv"
time_column = "t"
[wheels]
stream = "w"
signal = "rev_per_s"
rear_left = { column = "rl" }
rear_right = { column = "rr" }
[pose]
stream = "p"
position = { kind = "local", x = "x", y = "y" }
"#;
    let path = dir.path().join("m.toml");
    limits::LARGEST_GRID.with(|c| c.set(0));
    let e = Manifest::parse(text, &path).and_then(|m| import_drive(&m)).map(|_| ()).expect_err("refused").to_string();
    assert!(e.contains("streams.w spans 9990000 s") && e.contains("9990000 output samples"), "{e}");
    assert!(e.contains("streams.w holds 2 rows") && e.contains("streams.p (pose): 2"), "{e}");
    assert_eq!(limits::LARGEST_GRID.with(|c| c.get()), 0, "nothing allocated before the check");
    // The same streams a million seconds shorter fit the samples any import
    // may have.
    let short = |f: &str| f.replace("9990000", "900000");
    for f in ["w.csv", "p.csv"] {
        let p = dir.path().join(f);
        std::fs::write(&p, short(&std::fs::read_to_string(&p).expect("read"))).expect("write");
    }
    let e = Manifest::parse(text, &path).and_then(|m| import_drive(&m)).map(|_| ()).err().map(|e| e.to_string());
    assert!(e.as_ref().is_none_or(|e| !e.contains("rows")), "{e:?}");
}

#[test]
fn search_and_dejitter_settings_beyond_their_limits_are_rejected() {
    let e = manifest_error(|t| t.replace("clock_offset = 0.0", "clock_offset = \"auto\"\nmax_clock_offset_s = 1e5"));
    assert!(e.contains("output.max_clock_offset_s") && e.contains("above the limit of 60"), "{e}");
    let e = manifest_error(|t| t.replacen("time_column = \"t\"", "time_column = \"t\"\ndejitter_window_s = 1e9", 1));
    assert!(e.contains("streams.wheels.dejitter_window_s"), "{e}");
    let e = manifest_error(|t| t.replacen("time_column = \"t\"", "time_column = \"t\"\nnominal_rate_hz = 1e7", 1));
    assert!(e.contains("streams.wheels.nominal_rate_hz"), "{e}");
    // Below the absolute limit but far above the stream's own rate (100 Hz).
    let e = manifest_error(|t| t.replacen("time_column = \"t\"", "time_column = \"t\"\nnominal_rate_hz = 5e3", 1));
    assert!(e.contains("streams.wheels.nominal_rate_hz") && e.contains("mean rate of 100"), "{e}");
    // Far below it: a sensor does not sample slower than its samples arrive.
    let e = manifest_error(|t| t.replacen("time_column = \"t\"", "time_column = \"t\"\nnominal_rate_hz = 0.0001", 1));
    assert!(
        e.contains("streams.wheels.nominal_rate_hz") && e.contains("less than 0.5 × the stream's mean rate"),
        "{e}"
    );
    // An offset beyond any two epochs is named as the offset, not as stamps that do not advance.
    let e = manifest_error(|t| t.replacen("time_column = \"t\"", "time_column = \"t\"\ntime_offset_s = 1e20", 1));
    assert!(e.contains("streams.wheels.time_offset_s") && e.contains("above the limit of 10000000000"), "{e}");
    // A smoothing of a derived a_y over more than a minute.
    let e = manifest_error(|t| t + "\n[lateral_acceleration]\nsource = \"from_pose\"\nsmoothing_s = 1e9\n");
    assert!(e.contains("lateral_acceleration.smoothing_s") && e.contains("above the limit of 60"), "{e}");
}

#[test]
fn a_time_unit_mistake_is_a_no_overlap_error_before_any_grid() {
    // Wheel stamps in µs, declared as seconds, against the pose in seconds.
    let (e, largest) = small_case_error(
        |t| t.replace("clock_offset = 0.0", "clock_offset = \"auto\""),
        |w| {
            let mut out = String::from("t,left,right\n");
            for l in w.lines().skip(1) {
                let (t, rest) = l.split_once(',').expect("row");
                let t: f64 = t.parse().expect("t");
                out.push_str(&format!("{},{rest}\n", (t * 1e6 + 1.7e15).round()));
            }
            out
        },
    );
    assert!(e.contains("the streams do not overlap in time"), "{e}");
    assert!(e.contains("streams.wheels") && e.contains("streams.pose"), "{e}");
    assert!(e.contains("time_unit"), "{e}");
    assert_eq!(largest, 0, "the overlap is checked before the clock grid: {largest} samples allocated");
    // Encoder stamps × 1000 (ms read as s): same error, with the hint.
    let (e, largest) = small_case_error(
        |t| t,
        |w| {
            let mut out = String::from("t,left,right\n");
            for l in w.lines().skip(1) {
                let (t, rest) = l.split_once(',').expect("row");
                let t: f64 = t.parse().expect("t");
                out.push_str(&format!("{},{rest}\n", 1000.0 * (t + 1000.0)));
            }
            out
        },
    );
    assert!(e.contains("do not overlap") && e.contains("time_unit"), "{e}");
    assert_eq!(largest, 0);
}

#[test]
fn wheel_speed_beyond_the_limit_names_the_wheel_and_time() {
    // 60 rev/s = 120 m/s at θ_0 (the pose moves at 10 m/s).
    let fast = |w: String| w.replace(",5,5", ",60,60");
    let (e, _) = small_case_error(|t| t, fast);
    assert!(e.contains("wheels.rear_left") && e.contains("at t = 0.000 s") && e.contains("max_speed_m_per_s"), "{e}");
    // The limit is a setting: a vehicle that is that fast raises it (the
    // wheel/pose mismatch is then a warning).
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let w = fast(std::fs::read_to_string(dir.path().join("w.csv")).expect("read"));
    std::fs::write(dir.path().join("w.csv"), w).expect("write");
    let text = std::fs::read_to_string(&path).expect("read") + "\n[limits]\nmax_speed_m_per_s = 150.0\n";
    let r = import_drive(&Manifest::parse(&text, &path).expect("m")).expect("raised limit").report;
    assert!(r.warnings.iter().any(|w| w.contains("wheels.rear_left: the wheel's speed at θ_0 is 12")), "{r}");
    // Cumulative ticks declared as rev/s.
    let (e, _) = small_case_error(
        |t| t,
        |w| {
            let mut out = String::from("t,left,right\n");
            for (i, l) in w.lines().skip(1).enumerate() {
                let t = l.split(',').next().expect("t");
                out.push_str(&format!("{t},{},{}\n", 2000 * i, 2000 * i));
            }
            out
        },
    );
    assert!(e.contains("wheels.rear_left") && e.contains("ticks_cumulative"), "{e}");
}

#[test]
fn pose_columns_holding_ecef_or_metres_are_named() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text = std::fs::read_to_string(&path).expect("read");
    let latlon = text.replace(
        "position = { kind = \"local\", x = \"x\", y = \"y\" }",
        "position = { kind = \"lat_lon\", lat = \"x\", lon = \"y\" }",
    );
    // Metres in the lat column (0 … 39, all within ±90): 111 km per step.
    let e = Manifest::parse(&latlon, &path).and_then(|m| import_drive(&m)).map(|_| ()).expect_err("metres").to_string();
    assert!(e.contains("pose.position.lat") && e.contains("max_speed_m_per_s"), "{e}");
    // ECEF metres: outside ±90.
    let p = std::fs::read_to_string(dir.path().join("p.csv")).expect("read");
    let ecef: String = p
        .lines()
        .enumerate()
        .map(|(i, l)| if i == 0 { l.to_string() } else { l.replacen(",0,", ",4510000,", 1) })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(dir.path().join("p.csv"), ecef).expect("write");
    let e = Manifest::parse(&latlon, &path).and_then(|m| import_drive(&m)).map(|_| ()).expect_err("ecef").to_string();
    assert!(e.contains("pose.position.lat") && e.contains("4510000") && e.contains("outside ±90"), "{e}");
}

/// The synthetic drive's manifest after `edit`; the error text.
fn synthetic_error(edit: impl Fn(String) -> String) -> String {
    let duration = 40.0;
    let tr = Truth::new(duration);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = write_synthetic(dir.path(), &tr, duration);
    let text = edit(std::fs::read_to_string(&path).expect("read"));
    let m = Manifest::parse(&text, &path).expect("manifest");
    import_drive(&m).map(|_| ()).expect_err("an error").to_string()
}

#[test]
fn flipped_wheel_sign_and_heading_unit_and_convention_are_named() {
    let e = synthetic_error(|t| t.replace("{ column = \"right\", sign = -1 }", "{ column = \"right\" }"));
    assert!(e.contains("wheels.rear_right.sign") && e.contains("backwards"), "{e}");
    let e = synthetic_error(|t| t.replace("unit = \"deg\"", "unit = \"rad\""));
    assert!(e.contains("pose.heading.unit") && e.contains("degrees"), "{e}");
    let e = synthetic_error(|t| t.replace("convention = \"ned\"", "convention = \"enu\""));
    assert!(e.contains("pose.heading.convention"), "{e}");
}

#[test]
fn a_counter_narrower_than_declared_is_detected() {
    // The van's raw counters are 32-bit.
    let path = data("psu-mapping-van");
    let text = std::fs::read_to_string(&path)
        .expect("read")
        .replace("signal = \"ticks_cumulative\"", "signal = \"ticks_raw\"\ncounter_bits = 8")
        .replace("{ column = \"left_ticks_cum\" }", "{ column = \"c1_raw\", sign = -1 }")
        .replace("{ column = \"right_ticks_cum\" }", "{ column = \"c2_raw\" }");
    let e = import_drive(&Manifest::parse(&text, &path).expect("m")).map(|_| ()).expect_err("8 bits").to_string();
    assert!(e.contains("wheels.counter_bits") && e.contains("8-bit"), "{e}");
    assert!(!e.contains("NaN"), "{e}");
}

#[test]
fn long_fields_are_echoed_truncated() {
    let (e, _) = small_case_error(|t| t, |w| w.replacen("\n0.01,5,5", &format!("\n0.01,{},5", "x".repeat(10_000)), 1));
    assert!(e.contains("is not a number") && e.contains("(10000 bytes)") && e.len() < 300, "{e}");
}

#[test]
fn a_corrupt_wheel_row_is_dropped_not_turned_into_a_speed_spike() {
    // A cumulative count read as 0 for one row (as on the 2024-08-05 test track).
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text = std::fs::read_to_string(&path)
        .expect("read")
        .replace("signal = \"rev_per_s\"", "signal = \"ticks_cumulative\"\nticks_per_rev = 1000");
    std::fs::write(&path, text).expect("write");
    let mut w = String::from("t,left,right\n");
    for i in 0..400 {
        let c = if i == 200 { 0 } else { 5000 + 50 * i };
        writeln!(w, "{},{c},{c}", i as f64 / 100.0).expect("write");
    }
    std::fs::write(dir.path().join("w.csv"), w).expect("write");
    let (d, r) = load_drive(&path).expect("import");
    let r = r.expect("report");
    assert_eq!(r.streams.iter().map(|s| s.corrupt_rows_dropped).sum::<usize>(), 1, "{r}");
    assert!(r.warnings.iter().any(|w| w.contains("line 202")), "{r}");
    let worst = d.n_rl().iter().chain(d.n_rr()).map(|n| (n - 5.0).abs()).fold(0.0, f64::max);
    assert!(worst < 1e-9, "wheel speeds stay 5 rev/s: worst deviation {worst}");
}

// ---- Robust clock offset. ----

fn corr(offset_s: f64, peak: f64, second: Option<(f64, f64)>) -> signal::Correlation {
    signal::Correlation { offset_s, peak, pairs: 1000, curvature: 1.0, second }
}

#[test]
fn clock_estimate_is_doubted_when_not_clearly_better() {
    let h = 0.025;
    assert!(clock::doubt(Some(corr(0.1, 0.99, Some((1.0, 0.5)))), None, h).is_none());
    let d = clock::doubt(Some(corr(-1.09, 0.004, None)), None, h).expect("low correlation");
    assert!(d.contains("0.004 is below 0.9"), "{d}");
    let d = clock::doubt(Some(corr(0.1, 0.95, Some((0.9, 0.94)))), None, h).expect("ambiguous");
    assert!(d.contains("second correlation peak at +0.900 s"), "{d}");
    // A confident yaw-rate cross-check more than a sample away doubts it; a
    // weak one does not.
    assert!(clock::doubt(Some(corr(0.1, 0.99, None)), Some(corr(0.2, 0.9, None)), h).is_some());
    assert!(clock::doubt(Some(corr(0.1, 0.99, None)), Some(corr(0.2, 0.5, None)), h).is_none());
    assert!(clock::doubt(Some(corr(0.1, 0.99, None)), Some(corr(0.11, 0.9, None)), h).is_none());
    assert!(clock::doubt(None, None, h).is_some());
}

#[test]
fn auto_offset_keeps_the_manifest_offset_and_warns_when_in_doubt() {
    // Constant wheel speeds: nothing to correlate.
    let dir = tempfile::tempdir().expect("tempdir");
    let path = small_case(dir.path());
    let text = std::fs::read_to_string(&path).expect("read").replace("clock_offset = 0.0", "clock_offset = \"auto\"");
    let r = import_drive(&Manifest::parse(&text, &path).expect("m")).expect("import").report;
    assert!(r.clock_offset.applied_s.abs() < 1e-15, "{r}");
    assert!(r.clock_offset.doubt.is_some(), "{r}");
    assert!(r.warnings.iter().any(|w| w.contains("kept the streams' time_offset_s")), "{r}");
}

#[test]
fn a_known_offset_is_applied_with_its_confidence() {
    let duration = 70.0;
    let tr = Truth::new(duration);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = write_synthetic(dir.path(), &tr, duration);
    let c = import_drive(&Manifest::from_path(&path).expect("m")).expect("import").report.clock_offset;
    assert!(c.doubt.is_none(), "{c:?}");
    assert!((c.applied_s - TRUE_CLOCK_OFFSET_S).abs() < 0.025, "{c:?}");
    let k = c.peak_curvature_per_s2.expect("curvature");
    let u = c.uncertainty_s.expect("uncertainty");
    eprintln!(
        "simulated offset {TRUE_CLOCK_OFFSET_S}: estimated {:.4} s, curvature {k:.3} /s², ± {u:.4} s",
        c.applied_s
    );
    assert!(k > 0.0 && u < 0.1, "{c:?}");
}

// ---- Road bank: the lateral specific force from two antennas' roll. ----

/// The small case plus two antenna streams 1.5 m apart across the vehicle
/// (driving east along y = 0), rolled by `roll(i)` rad (positive: left
/// lower), the left one mounted `left_higher` m above the right one, RTK
/// flag 6 except where `bad` says; the manifest asks for the bank with
/// `bank_extra` appended to its table.
fn bank_case(
    dir: &Path,
    roll: impl Fn(usize) -> f64,
    left_higher: f64,
    bad: impl Fn(usize) -> bool,
    bank_extra: &str,
) -> PathBuf {
    let path = small_case(dir);
    let (lat0, lon0, re) = (40.86_f64, -77.83_f64, 6_378_137.0_f64);
    for (name, side, mount) in [("l.csv", 1.0, left_higher), ("r.csv", -1.0, 0.0)] {
        let mut s = String::from("t,lat,lon,alt,fix\n");
        for i in 0..40 {
            let (sn, cs) = roll(i).sin_cos();
            let (east, north) = (i as f64, side * 0.75 * cs);
            let lat = lat0 + (north / re).to_degrees();
            let lon = lon0 + (east / (re * lat0.to_radians().cos())).to_degrees();
            let alt = 300.0 - side * 0.75 * sn + mount;
            writeln!(s, "{},{lat:.10},{lon:.10},{alt:.6},{}", i as f64 / 10.0, if bad(i) { 2 } else { 6 })
                .expect("write");
        }
        std::fs::write(dir.join(name), s).expect("write");
    }
    let mut text = std::fs::read_to_string(&path).expect("read");
    text.push_str(&format!(
        r#"
[streams.gl]
file = "l.csv"
time_column = "t"

[streams.gr]
file = "r.csv"
time_column = "t"

[lateral_acceleration]
source = "from_wheels"

[lateral_acceleration.bank]
left = "gl"
right = "gr"
lat = "lat"
lon = "lon"
alt = "alt"
quality = {{ column = "fix", accept = [6] }}
baseline_m = 1.5
{bank_extra}
"#
    ));
    std::fs::write(&path, text).expect("write");
    path
}

#[test]
fn the_bank_turns_the_kinematic_a_y_into_the_lateral_specific_force() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Straight (kinematic a_y = 0) on a road 0.1 m lower on the left over 1.5 m.
    let phi = (0.1_f64 / 1.5).asin();
    let (d, r) = load_drive(bank_case(dir.path(), |_| phi, 0.0, |_| false, "")).expect("import");
    let want = -crate::io::import::bank::G_M_PER_S2 * 0.1 / 1.5;
    assert!(d.a_y().iter().all(|a| (a - want).abs() < 1e-4), "{:?} vs {want}", &d.a_y()[..3]);
    let r = r.expect("report");
    assert!(r.lateral_acceleration.contains("roll φ from the antennas 'gl' (left) and 'gr' (right)"), "{r}");
    assert!(r.lateral_acceleration.contains("mean φ +66.7 mrad"), "{}", r.lateral_acceleration);
    // Level, the left antenna mounted 0.1 m higher: a roll unless the offset is given.
    let (d, _) = load_drive(bank_case(dir.path(), |_| 0.0, 0.1, |_| false, "")).expect("mounted");
    assert!(d.a_y().iter().all(|a| (a + want).abs() < 1e-4), "{:?}", &d.a_y()[..3]);
    let (d, _) = load_drive(bank_case(dir.path(), |_| 0.0, 0.1, |_| false, "height_offset_m = 0.1")).expect("offset");
    assert!(d.a_y().iter().all(|a| a.abs() < 1e-4), "{:?}", &d.a_y()[..3]);
    // Without the bank table: the kinematic a_y, 0.
    let path = bank_case(dir.path(), |_| phi, 0.0, |_| false, "");
    let text = std::fs::read_to_string(&path).expect("read");
    let cut = text.find("[lateral_acceleration.bank]").expect("table");
    std::fs::write(&path, &text[..cut]).expect("write");
    let (d, r) = load_drive(&path).expect("no bank");
    assert!(d.a_y().iter().all(|a| a.abs() < 1e-9));
    assert!(!r.expect("report").lateral_acceleration.contains("bank"));
}

#[test]
fn roll_samples_without_both_antennas_accepted_split_the_drive_and_glitches_are_dropped() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Samples 15..=22 not RTK fixed: a 0.9 s hole in the roll splits the drive.
    let path = bank_case(dir.path(), |_| 0.0, 0.0, |i| (15..=22).contains(&i), "");
    let (d, r) = load_drive(&path).expect("import");
    let r = r.expect("report");
    assert_eq!(d.parts().len(), 2, "{r}");
    assert!(r.gaps.iter().any(|g| g.reasons.iter().any(|x| x.contains("roll (both antennas accepted)"))), "{r}");
    // One altitude glitch (46° of roll) among 40 pairs: dropped with a warning.
    let path = bank_case(dir.path(), |i| if i == 10 { 0.8 } else { 0.0 }, 0.0, |_| false, "");
    let (d, r) = load_drive(&path).expect("a glitch is dropped");
    let r = r.expect("report");
    assert!(r.warnings.iter().any(|w| w.contains("1 of 40 antenna pairs give a roll beyond")), "{r}");
    assert!(d.a_y().iter().all(|a| a.abs() < 1e-9), "{:?}", d.a_y());
}

#[test]
fn bank_errors_name_the_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let err = |phi: f64, extra: &str| -> String {
        let path = bank_case(d, |_| phi, 0.0, |_| false, extra);
        Manifest::from_path(&path).and_then(|m| import_drive(&m)).map(|_| ()).expect_err("an error").to_string()
    };
    let edit = |from: &str, to: &str| -> String {
        let path = bank_case(d, |_| 0.0, 0.0, |_| false, "");
        let text = std::fs::read_to_string(&path).expect("read").replace(from, to);
        std::fs::write(&path, text).expect("write");
        Manifest::from_path(&path).and_then(|m| import_drive(&m)).map(|_| ()).expect_err("an error").to_string()
    };
    let e = edit("baseline_m = 1.5", "baseline_m = 0.0");
    assert!(e.contains("lateral_acceleration.bank.baseline_m: must be a positive number, found 0"), "{e}");
    let e = edit("baseline_m = 1.5", "baseline_m = -1.5");
    assert!(e.contains("lateral_acceleration.bank.baseline_m: must be a positive number"), "{e}");
    // The antennas are 1.5 m apart, not 3.
    let e = edit("baseline_m = 1.5", "baseline_m = 3.0");
    let want = "lateral_acceleration.bank.baseline_m: the antennas of streams 'gl' and 'gr' are a median 1.";
    assert!(e.contains(want) && e.contains("not baseline_m = 3 "), "{e}");
    let e = edit("baseline_m = 1.5", "baseline_m = 1e300");
    assert!(e.contains("lateral_acceleration.bank.baseline_m: 1e300 is above the limit of 20"), "{e}");
    let e = err(0.0, "height_offset_m = 2.0");
    assert!(e.contains("lateral_acceleration.bank.height_offset_m: must be a finite number"), "{e}");
    let e = err(0.0, "max_roll_deg = 90");
    assert!(e.contains("lateral_acceleration.bank.max_roll_deg: must be in (0, 45]"), "{e}");
    let e = err(0.0, "smoothing_s = -1");
    assert!(e.contains("lateral_acceleration.bank.smoothing_s: must be >= 0"), "{e}");
    // Every pair rolled by 42°: an error, not glitches.
    let e = err(0.73, "");
    assert!(e.contains("lateral_acceleration.bank.max_roll_deg") && e.contains("40 of 40 antenna pairs"), "{e}");
    let e = edit("right = \"gr\"", "right = \"gl\"");
    assert!(e.contains("lateral_acceleration.bank.right: the right antenna's stream is the left one's"), "{e}");
    let e = edit("right = \"gr\"", "right = \"gx\"");
    assert!(e.contains("lateral_acceleration.bank.right: no stream named 'gx'"), "{e}");
    let e = edit("alt = \"alt\"", "alt = \"height\"");
    assert!(e.contains("height") && e.contains("lateral_acceleration.bank.alt"), "{e}");
    let e = edit("baseline_m = 1.5", "baseline_m = 1.5\nbaseline = 2");
    assert!(
        e.contains("lateral_acceleration") && e.contains("unknown field `baseline`, expected one of `left`"),
        "{e}"
    );
    // No common accepted sample.
    let path = bank_case(d, |_| 0.0, 0.0, |_| true, "");
    let e = load_drive(&path).map(|_| ()).expect_err("none accepted").to_string();
    assert!(e.contains("lateral_acceleration.bank.quality") && e.contains("no sample of accepted quality"), "{e}");
    // A kinematic-only option: an IMU already measures the specific force.
    let e = edit("source = \"from_wheels\"", "source = \"imu\"\nstream = \"gl\"\ncolumn = \"alt\"");
    assert!(e.contains("lateral_acceleration") && e.contains("bank"), "{e}");
    // Latitude in metres.
    let path = bank_case(d, |_| 0.0, 0.0, |_| false, "");
    let l = std::fs::read_to_string(d.join("l.csv")).expect("read");
    std::fs::write(d.join("l.csv"), l.replacen(",40.86", ",4086000.0", 1)).expect("write");
    let e = load_drive(&path).map(|_| ()).expect_err("metres").to_string();
    assert!(e.contains("l.csv") && e.contains("lateral_acceleration.bank.lat (left antenna)"), "{e}");
}
