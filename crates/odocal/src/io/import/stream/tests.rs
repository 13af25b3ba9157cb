//! The streamed import against the whole import on the shipped manifests.

use std::path::Path;

use super::reader::ManifestStream;
use super::*;
use crate::drive::Drive;

fn manifest(rel: &str) -> Manifest {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    Manifest::from_path(&p).expect("manifest")
}

/// The streamed drive, built as the whole import builds its drive.
fn streamed(m: &Manifest, opts: StreamOptions, chunk: usize) -> (Drive, ImportReport) {
    let mut s = ManifestStream::open(m, opts).expect("open");
    let mut sig = Signals::with_capacity(0);
    let (mut t, mut mask, mut parts) = (Vec::new(), Vec::new(), Vec::<std::ops::Range<usize>>::new());
    while let Some(c) = s.next_chunk(chunk).expect("chunk") {
        assert!(c.t.len() <= chunk);
        let s0 = t.len();
        assert_eq!(c.start, s0);
        if c.starts_part {
            parts.push(s0..s0);
        }
        t.extend(&c.t);
        mask.extend(c.reference_measured.expect("an import chunk carries the mask"));
        for k in 0..c.t.len() {
            let g = &c.signals;
            sig.push([g.px[k], g.py[k], g.psi[k], g.n_rl[k], g.n_rr[k], g.beta[k], g.a_y[k]]);
        }
        if let Some(p) = parts.last_mut() {
            p.end = t.len();
        }
    }
    let report = s.raw().report().expect("report").clone();
    let d = crate::drive::DriveBuilder {
        t,
        measured: sig,
        parts: Some(parts),
        reference_measured: Some(mask),
        sample_time_s: Some(1.0 / m.output.rate_hz),
        ..Default::default()
    }
    .build()
    .expect("drive");
    (d, report)
}

#[test]
fn a_drive_within_the_warm_up_is_the_whole_import_bit_for_bit() {
    for (rel, chunk) in [
        ("tests/data/comma2k19-rav4/manifest.toml", 1),
        ("tests/data/comma2k19-rav4/manifest.toml", 400),
        ("tests/data/psu-mapping-van/manifest.toml", 400),
        ("../../examples/psu-mapping-van-testtrack/run-16-47-33.toml", 400),
        ("../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", 400),
        ("../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", 1),
        ("../../examples/psu-mapping-van-testtrack/run-15-28-33.toml", 400),
        ("../../examples/psu-mapping-van-testtrack/run-16-06-28.toml", 400),
        ("../../examples/psu-mapping-van-testtrack/run-17-45-46.toml", 400),
        ("../../examples/psu-mapping-van-testtrack/run-18-01-26.toml", 400),
    ] {
        let m = manifest(rel);
        let whole = crate::io::import::import_drive(&m).expect("import");
        let (d, r) = streamed(&m, StreamOptions::default(), chunk);
        assert_eq!(d.fingerprint(), whole.drive.fingerprint(), "{rel}, chunk {chunk}");
        assert_eq!(d.reference_measured(), whole.drive.reference_measured());
        assert_eq!(r.clock_offset.applied_s.to_bits(), whole.report.clock_offset.applied_s.to_bits());
        assert_eq!(r.samples, whole.report.samples);
        assert_eq!(r.parts.len(), whole.report.parts.len());
        assert_eq!(r.gaps.len(), whole.report.gaps.len());
        let spans = |r: &ImportReport| -> Vec<(u64, u64, Option<String>)> {
            let parts = r.parts.iter().map(|p| (p.t_start_s, p.t_end_s, p.dropped_because.clone()));
            let gaps = r.gaps.iter().map(|g| (g.t_start_s, g.t_end_s, None));
            parts.chain(gaps).map(|(a, b, why)| (a.to_bits(), b.to_bits(), why)).collect()
        };
        assert_eq!(spans(&r), spans(&whole.report), "{rel}: the parts' and gaps' spans");
        assert_eq!(r.distance_m.to_bits(), whole.drive.distance_m().to_bits());
        assert_eq!(jitter_bits(&r), jitter_bits(&whole.report), "{rel}: the jitter report");
        // the road bank's roll: its pairs, glitches and statistics
        assert_eq!(r.lateral_acceleration, whole.report.lateral_acceleration, "{rel}");
        let glitches =
            |r: &ImportReport| r.warnings.iter().filter(|w| w.contains("glitches")).cloned().collect::<Vec<_>>();
        assert_eq!(glitches(&r), glitches(&whole.report), "{rel}");
        assert_eq!(
            r.gaps.iter().map(|g| &g.reasons).collect::<Vec<_>>(),
            whole.report.gaps.iter().map(|g| &g.reasons).collect::<Vec<_>>()
        );
    }
}

/// The jitter report's figures, bit for bit (`None` without a de-jittered
/// wheel stream).
fn jitter_bits(r: &ImportReport) -> Option<[u64; 2]> {
    r.jitter.as_ref().map(|j| [j.wheel_speed_noise_raw_pct.to_bits(), j.wheel_speed_noise_dejittered_pct.to_bits()])
}

#[test]
fn unsupported_manifests_are_refused_with_the_reason() {
    let m = manifest("../../examples/psu-mapping-van/manifest.toml");
    assert_eq!(not_streamable(&m), None, "a road bank is streamed");
    let m = manifest("../../examples/psu-mapping-van/manifest-mcap.toml");
    let e = RawStream::with_options(&m, StreamOptions::default()).expect_err("mcap").to_string();
    assert!(e.contains("cannot be imported as a stream") && e.contains("is an MCAP source, read whole"), "{e}");
    let m = manifest("tests/data/parquet/manifest.toml");
    let why = not_streamable(&m).expect("parquet is read whole");
    assert!(why.ends_with("is a Parquet source, read whole"), "{why}");
}

/// The heading derived from the track (no `[pose.heading]`; the samples at
/// the start wait until the vehicle moves): the whole import's bit for bit,
/// with the default chord, one shorter than the steps and a long one.
#[test]
fn a_heading_derived_from_the_track_is_streamed_bit_for_bit() {
    for (rel, baseline) in [
        ("../../examples/psu-mapping-van-testtrack/run-16-06-28.toml", None),
        ("../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", None),
        ("../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", Some(12.0)),
        ("tests/data/psu-mapping-van/manifest.toml", None),
        ("tests/data/psu-mapping-van/manifest.toml", Some(0.3)),
        ("tests/data/psu-mapping-van/manifest.toml", Some(25.0)),
        ("tests/data/comma2k19-rav4/manifest.toml", None),
        ("tests/data/comma2k19-rav4/manifest.toml", Some(8.0)),
    ] {
        let m = variant(rel, |t| {
            let t = without(t, "[pose.heading]");
            match baseline {
                Some(b) => t.replacen("[pose]\n", &format!("[pose]\nderive_heading_baseline_m = {b}\n"), 1),
                None => t,
            }
        });
        let m = match m {
            Ok(m) => m,
            Err(e) => panic!("{rel}: {e}"),
        };
        let want = baseline.unwrap_or(crate::io::import::manifest::DEFAULT_DERIVE_HEADING_BASELINE_M);
        assert_eq!(m.pose.derive_heading_baseline_m.to_bits(), want.to_bits(), "{rel}");
        assert!(m.pose.heading.is_none() && not_streamable(&m).is_none(), "{rel}");
        let whole = crate::io::import::import_drive(&m).expect("import");
        let (d, r) = streamed(&m, StreamOptions::default(), 400);
        assert_eq!(d.fingerprint(), whole.drive.fingerprint(), "{rel}");
        assert_eq!(d.reference_measured(), whole.drive.reference_measured(), "{rel}");
        assert_eq!(r.clock_offset.applied_s.to_bits(), whole.report.clock_offset.applied_s.to_bits(), "{rel}");
    }
}

/// Manifest text without its table `header` (its keys included).
fn without(text: &str, header: &str) -> String {
    let mut out = String::new();
    let mut skip = false;
    for line in text.lines() {
        if line.trim_start().starts_with('[') {
            skip = line.trim() == header;
        }
        if !skip {
            out.push_str(line);
            out.push('\n');
        }
    }
    out
}

/// A shipped manifest with its text edited by `edit`.
fn variant(rel: &str, edit: impl Fn(&str) -> String) -> crate::Result<Manifest> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    Manifest::parse(&edit(&std::fs::read_to_string(&p).expect("read")), &p)
}

/// a_y from the pose (speed × yaw rate of the reference, one sample of
/// look-ahead), with and without the road bank: the whole import's bit for bit.
#[test]
fn a_y_from_the_pose_is_streamed_bit_for_bit() {
    for (rel, bank) in [
        ("../../examples/psu-mapping-van-testtrack/run-16-06-28.toml", true),
        ("../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", false),
        ("tests/data/psu-mapping-van/manifest.toml", false),
    ] {
        let m = variant(rel, |t| {
            let t = t.replace("source = \"from_wheels\"", "source = \"from_pose\"");
            if bank {
                t
            } else {
                without(&t, "[lateral_acceleration.bank]")
            }
        });
        let m = match m {
            Ok(m) => m,
            Err(e) => panic!("{rel}: {e}"),
        };
        assert!(matches!(m.lateral_acceleration, LateralAccelerationSpec::FromPose { .. }), "{rel}");
        assert_eq!(m.lateral_acceleration.bank().is_some(), bank, "{rel}");
        let whole = crate::io::import::import_drive(&m).expect("import");
        let (d, r) = streamed(&m, StreamOptions::default(), 400);
        assert_eq!(d.fingerprint(), whole.drive.fingerprint(), "{rel}");
        assert_eq!(r.lateral_acceleration, whole.report.lateral_acceleration, "{rel}");
    }
}

/// The calibration of `d` by the default method without its bias
/// correction (the default options otherwise): θ and σ. The clock offset
/// moves the samples, not the estimator's bias; the correction's replicates
/// would double the cost of the test.
fn fit(d: &Drive) -> ([f64; 4], [f64; 4]) {
    let method = crate::Method::Eiv(crate::calibrate::EivMethodOptions { correct_bias: None, ..Default::default() });
    let opts = crate::CalibrationOptions { method, ..Default::default() };
    let r = crate::calibrate(d, &opts).expect("calibrate");
    (r.theta.to_array(), std::array::from_fn(|i| r.covariance[i][i].sqrt()))
}

/// A drive longer than the warm-up: the clock offset from the prefix, the
/// samples on the whole import's time base, and what the difference does to
/// the calibration.
#[test]
#[ignore = "slow tier, a tolerance claim on six real manifests (~12 s): cargo test --workspace -- --ignored"]
fn a_drive_longer_than_the_warm_up_stays_within_the_clock_estimates_tolerance() {
    let cases = [
        ("../../examples/psu-mapping-van/manifest.toml", 60.0),
        ("../../examples/psu-mapping-van/manifest.toml", 150.0),
        ("../../examples/psu-mapping-van/manifest.toml", 300.0),
        ("../../examples/psu-mapping-van-testtrack/run-14-45-26.toml", 60.0),
        ("../../examples/psu-mapping-van-testtrack/run-16-47-33.toml", 60.0),
        ("../../examples/comma2k19-rav4/manifest.toml", 20.0),
    ];
    let mut compared = 0;
    // The whole import and its fit, once per manifest; a streamed drive
    // equal to one fitted before (the same clock estimate from another
    // warm-up) is not fitted again.
    let mut whole_of = std::collections::HashMap::new();
    let mut fit_of = std::collections::HashMap::new();
    for (rel, warm_up_s) in cases {
        let (m, whole, (a, sa)) = &*whole_of.entry(rel).or_insert_with(|| {
            let m = manifest(rel);
            let whole = crate::io::import::import_drive(&m).expect("import");
            let fitted = fit(&whole.drive);
            (m, whole, fitted)
        });
        let (d, r) = streamed(m, StreamOptions { warm_up_s }, 400);
        let corrupt = |r: &ImportReport| r.streams.iter().map(|s| s.corrupt_rows_dropped).sum::<usize>();
        let dtau = r.clock_offset.applied_s - whole.report.clock_offset.applied_s;
        let dorigin = r.time_origin_s - whole.report.time_origin_s;
        let (b, _) = *fit_of.entry(d.fingerprint()).or_insert_with(|| fit(&d));
        let in_sigma: Vec<f64> = (0..4).map(|i| (b[i] - a[i]) / sa[i]).collect();
        eprintln!(
            "{rel} warm-up {warm_up_s} s ({} corrupt rows): τ whole {:+.5} s, streamed {:+.5} s (Δ {:+.2} ms, uncertainty {:.2} ms); \
             origin Δ {:+.4} s; samples {} vs {}; Δθ/σ = {:+.3?}",
            corrupt(&whole.report),
            whole.report.clock_offset.applied_s,
            r.clock_offset.applied_s,
            dtau * 1e3,
            whole.report.clock_offset.uncertainty_s.unwrap_or(f64::NAN) * 1e3,
            dorigin,
            d.len(),
            whole.drive.len(),
            in_sigma
        );
        assert_eq!(corrupt(&r), corrupt(&whole.report), "{rel}: corrupt wheel rows dropped");
        // The clock estimate of the prefix lies within the whole drive's
        // uncertainty of it; the calibration moves by less than 4 σ (batch
        // Gauss-Newton's σ, too small under input noise: a 4.5 ms change of
        // the offset moves t_r by 3.5 σ on a 170 s test-track run).
        let u = whole.report.clock_offset.uncertainty_s.unwrap_or(0.0);
        assert!(dtau.abs() <= u.max(1e-12) || dtau == 0.0, "{rel}: Δτ {dtau} s, uncertainty {u} s");
        // (A parameter the drive does not resolve has no σ: the calibration
        // reports it unobservable, as t_r and d of a test-track run with its
        // road bank, and it is not compared.)
        assert!(
            (0..4).all(|i| b[i].to_bits() == a[i].to_bits() || sa[i] == 0.0 || in_sigma[i].abs() < 4.0),
            "{rel}: Δθ/σ {in_sigma:?}"
        );
        compared += 1;
    }
    assert_eq!(compared, cases.len());
}

/// With the clock offset fixed (the whole import's estimate), a drive
/// longer than the warm-up comes out of the stream bit for bit, road bank
/// included: the streamed roll, its smoothing and the specific force are
/// the whole import's arithmetic.
#[test]
fn with_the_clock_offset_given_a_long_banked_drive_is_the_whole_import_bit_for_bit() {
    for rel in
        ["../../examples/psu-mapping-van/manifest.toml", "../../examples/psu-mapping-van-testtrack/run-16-06-28.toml"]
    {
        let auto = manifest(rel);
        let tau = crate::io::import::import_drive(&auto).expect("import").report.clock_offset.applied_s;
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
        let text = std::fs::read_to_string(&p).expect("read");
        assert!(text.contains("clock_offset = \"auto\""), "{rel}");
        let m = Manifest::parse(&text.replace("clock_offset = \"auto\"", &format!("clock_offset = {tau:?}")), &p)
            .expect("manifest");
        assert!(m.lateral_acceleration.bank().is_some());
        let whole = crate::io::import::import_drive(&m).expect("import");
        let (d, r) = streamed(&m, StreamOptions { warm_up_s: 30.0 }, 400);
        assert!(whole.drive.len() as f64 * 0.025 > 120.0, "{rel}: longer than the warm-up");
        assert_eq!(d.fingerprint(), whole.drive.fingerprint(), "{rel}");
        assert_eq!(r.lateral_acceleration, whole.report.lateral_acceleration, "{rel}");
        assert!(r.jitter.is_some(), "{rel}: the encoders are de-jittered");
        assert_eq!(jitter_bits(&r), jitter_bits(&whole.report), "{rel}: the jitter report");
    }
}

/// An output sample: time and signals.
type Sample = (f64, [f64; 7]);

/// A drive on two streams, wheels `w` at 50 Hz (rev/s) and a local pose
/// `p` at 10 Hz without a heading: standing still for `still_s`, then
/// driving `drive_s` along gentle curves (consistent with θ_0).
struct Synthetic {
    wheels: Vec<(f64, [f64; 2])>,
    pose: Vec<(f64, [f64; 2])>,
}

impl Synthetic {
    fn new(still_s: f64, drive_s: f64) -> Synthetic {
        let (c_e, t_r) = (2.0, 1.6);
        let end = still_s + drive_s;
        let motion = |t: f64| -> (f64, f64) {
            let u = t - still_s;
            if u <= 0.0 {
                (0.0, 0.0)
            } else {
                let v = 8.0 * (u / 5.0).min(1.0);
                (v, 0.15 * (u / 23.0).sin() * (v / 8.0))
            }
        };
        let wheels = (0..=(end * 50.0) as usize)
            .map(|k| {
                let t = k as f64 * 0.02;
                let (v, om) = motion(t);
                (t, [(v - 0.5 * om * t_r) / c_e, (v + 0.5 * om * t_r) / c_e])
            })
            .collect();
        let (mut x, mut y, mut psi) = (12.0f64, -3.0f64, 0.4f64);
        let mut pose = Vec::new();
        let dt = 0.001;
        for k in 0..=(end / dt) as usize {
            let t = k as f64 * dt;
            if k % 100 == 0 {
                pose.push((t, [x, y]));
            }
            let (v, om) = motion(t);
            x += v * psi.cos() * dt;
            y += v * psi.sin() * dt;
            psi += om * dt;
        }
        Synthetic { wheels, pose }
    }

    /// The manifest over the files in `dir` (written by [`Synthetic::write`]).
    fn manifest(dir: &Path) -> Manifest {
        let text = r#"[output]
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
rear_left = { column = "l" }
rear_right = { column = "r" }
[pose]
stream = "p"
[pose.position]
kind = "local"
x = "x"
y = "y"
"#;
        Manifest::parse(text, &dir.join("m.toml")).expect("manifest")
    }

    fn write(&self, dir: &Path) {
        for (name, head, rows) in [("w.csv", "t,l,r", &self.wheels), ("p.csv", "t,x,y", &self.pose)] {
            let mut s = format!("{head}\n");
            for (t, v) in rows.iter() {
                s.push_str(&format!("{t},{},{}\n", v[0], v[1]));
            }
            std::fs::write(dir.join(name), s).expect("write");
        }
    }

    /// Pushes the messages in time order (pose messages up to `pose_until`
    /// s only), taking the samples as they come; the most rows held at
    /// once, the first error, and the samples (time, signals).
    fn push(&self, s: &mut RawStream, pose_until: f64) -> (usize, crate::Result<()>, Vec<Sample>) {
        let (mut i, mut j, mut most) = (0, 0, 0);
        let mut taken = Vec::new();
        let mut take = |s: &mut RawStream| {
            while let Some(c) = s.take_chunk(400) {
                for k in 0..c.t.len() {
                    let g = &c.signals;
                    taken.push((c.t[k], [g.px[k], g.py[k], g.psi[k], g.n_rl[k], g.n_rr[k], g.beta[k], g.a_y[k]]));
                }
            }
        };
        while i < self.wheels.len() || j < self.pose.len() {
            let wheel_next = j >= self.pose.len() || (i < self.wheels.len() && self.wheels[i].0 <= self.pose[j].0);
            let r = if wheel_next {
                i += 1;
                s.push_message("w", self.wheels[i - 1].0, &self.wheels[i - 1].1)
            } else {
                j += 1;
                if self.pose[j - 1].0 > pose_until {
                    continue;
                }
                s.push_message("p", self.pose[j - 1].0, &self.pose[j - 1].1)
            };
            if r.is_err() {
                return (most, r, taken);
            }
            take(s);
            most = most.max(s.held());
        }
        let r = s.finish().map(|_| ());
        take(s);
        (most, r, taken)
    }
}

/// A heading derived from the track and a standstill at the start longer
/// than the hold (the warm-up): the rows held stay bounded whatever the
/// standstill's length; the standstill beyond the hold is a gap, and every
/// sample out of the stream is the whole import's, bit for bit.
#[test]
fn a_long_standstill_before_the_first_motion_is_held_for_at_most_the_warm_up() {
    let opts = StreamOptions { warm_up_s: 20.0 };
    let mut peaks = Vec::new();
    for still_s in [100.0, 1000.0] {
        let dir = tempfile::tempdir().expect("tmp");
        let syn = Synthetic::new(still_s, 120.0);
        syn.write(dir.path());
        let m = Synthetic::manifest(dir.path());
        let whole = crate::io::import::import_drive(&m).expect("import");
        let mut s = RawStream::with_options(&m, opts.clone()).expect("stream");
        let (most, r, taken) = syn.push(&mut s, f64::INFINITY);
        r.expect("streamed");
        peaks.push(most);
        let d = &whole.drive;
        let first = d.t().partition_point(|&t| t < taken[0].0);
        assert_eq!(d.len() - first, taken.len(), "standstill {still_s} s: the samples after the hold");
        // The hold before the first motion is decided: that is half the
        // derived heading's baseline (1 m) of travel in, 1.1 s.
        assert!(taken[0].0 > still_s - 20.0 && taken[0].0 < still_s - 20.0 + 2.0, "{}", taken[0].0);
        for (k, (t, sig)) in taken.iter().enumerate() {
            let w = d.measured();
            let want = [w.px[first + k], w.py[first + k], w.psi[first + k], w.n_rl[first + k], w.n_rr[first + k]];
            assert_eq!(t.to_bits(), d.t()[first + k].to_bits());
            for (a, b) in sig.iter().zip(want) {
                assert_eq!(a.to_bits(), b.to_bits(), "standstill {still_s} s, t = {t}");
            }
        }
        let report = s.report().expect("report");
        assert!(report.gaps.iter().any(|g| g.reasons.iter().any(|r| r.contains("pose heading unknown"))));
    }
    eprintln!("rows held at most: {peaks:?}");
    assert!((peaks[1] as f64) < 1.1 * peaks[0] as f64, "held {peaks:?}");
}

/// A stream that stops sending while the others go on: an error naming it
/// once the rows held span twice the warm-up, not before.
#[test]
fn a_stalled_stream_is_named_once_the_rows_held_reach_the_bound() {
    let syn = Synthetic::new(2.0, 200.0);
    let m = Synthetic::manifest(Path::new("/nonexistent"));
    let mut s = RawStream::with_options(&m, StreamOptions { warm_up_s: 20.0 }).expect("stream");
    let (most, r, _) = syn.push(&mut s, 100.0);
    let e = r.expect_err("stalled").to_string();
    assert!(e.contains("streams.p") && e.contains("stalled") && e.contains("100.000 s"), "{e}");
    assert!(most < 50 * 45, "held {most} rows");
    // The pose stopping 30 s before the wheels: within the bound.
    let syn = Synthetic::new(2.0, 60.0);
    let mut s = RawStream::with_options(&m, StreamOptions { warm_up_s: 20.0 }).expect("stream");
    let (_, r, _) = syn.push(&mut s, 32.0);
    assert!(r.as_ref().err().is_none_or(|e| !e.to_string().contains("stalled")), "{r:?}");
}

/// The streamed import's error, reading the whole manifest.
fn streamed_error(m: &Manifest, opts: StreamOptions) -> String {
    let mut s = ManifestStream::open(m, opts).expect("open");
    loop {
        match s.next_chunk(400) {
            Ok(Some(_)) => {}
            Ok(None) => panic!("{}: no error", m.path.display()),
            Err(e) => return e.to_string(),
        }
    }
}

/// The wheel and heading convention checks and the IMU's a_y check judge
/// the warm-up prefix: a drive within the warm-up is refused with the whole
/// import's message; a longer one names the same key (the figures are the
/// prefix's).
#[test]
fn a_stream_with_a_wrong_convention_is_refused_as_the_whole_import_refuses_it() {
    let rav4 = "tests/data/comma2k19-rav4/manifest.toml";
    let van = "tests/data/psu-mapping-van/manifest.toml";
    let track = "../../examples/psu-mapping-van-testtrack/run-14-45-26.toml";
    type Edit = fn(&str) -> String;
    let cases: [(&str, Edit, &str); 6] = [
        (rav4, |t| t.replace("{ column = \"rl_mps\" }", "{ column = \"rl_mps\", sign = -1 }"), "wheels.rear_left.sign"),
        (
            van,
            |t| t.replace("{ column = \"right_ticks_cum\" }", "{ column = \"right_ticks_cum\", sign = -1 }"),
            "wheels.rear_right.sign",
        ),
        (track, |t| t.replace("unit = \"rad\"", "unit = \"deg\""), "pose.heading.unit"),
        (track, |t| t.replace("convention = \"enu\"", "convention = \"ned\""), "pose.heading.convention"),
        (
            track,
            |t| {
                without(t, "[pose.heading]")
                    .replace("{ column = \"left_ticks_cum\" }", "{ column = \"RIGHT\" }")
                    .replace("{ column = \"right_ticks_cum\" }", "{ column = \"left_ticks_cum\" }")
                    .replace("{ column = \"RIGHT\" }", "{ column = \"right_ticks_cum\" }")
            },
            "wheels.rear_left.column",
        ),
        (rav4, |t| t.replace("sign = -1", "sign = 1"), "lateral_acceleration.sign"),
    ];
    for (rel, edit, key) in cases {
        let m = match variant(rel, edit) {
            Ok(m) => m,
            Err(e) => panic!("{rel}: {e}"),
        };
        let whole = match crate::io::import::import_drive(&m) {
            Ok(i) => panic!("{rel}, {key}: the whole import takes it: {:?}", i.report.warnings),
            Err(e) => e.to_string(),
        };
        assert!(whole.contains(key), "{rel}: {whole}");
        let within = streamed_error(&m, StreamOptions { warm_up_s: 1000.0 });
        assert_eq!(within, whole, "{rel}");
        let prefix = streamed_error(&m, StreamOptions { warm_up_s: 120.0 });
        assert!(prefix.contains(key), "{rel}, a 120 s warm-up: {prefix}");
    }
}

/// Repeated stamps are warned about as the whole import warns about them,
/// with the same text, once per stream: rows repeating a stamp with other
/// values, and more than a tenth of a stream's rows repeating a stamp.
#[test]
fn repeated_stamps_are_warned_about_as_the_whole_import_warns() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = crate::io::import::tests::small_case(dir.path());
    let w = dir.path().join("w.csv");
    let clean = std::fs::read_to_string(&w).expect("read");
    let doubled: String = clean
        .lines()
        .enumerate()
        .map(|(i, l)| if i % 2 == 1 { format!("{l}\n{l}\n") } else { format!("{l}\n") })
        .collect();
    let repeats =
        |r: &ImportReport| r.warnings.iter().filter(|w| w.contains("repeat the stamp")).cloned().collect::<Vec<_>>();
    for (text, count) in [(clean.replacen("\n2,5,5\n", "\n2,5,5\n2,15,15\n", 1), 1), (doubled, 1)] {
        std::fs::write(&w, text).expect("write");
        let m = Manifest::from_path(&path).expect("manifest");
        let whole = crate::io::import::import_drive(&m).expect("import");
        let (_, r) = streamed(&m, StreamOptions::default(), 64);
        let found = repeats(&r);
        assert_eq!(found.len(), count, "{found:?}");
        assert_eq!(found, repeats(&whole.report));
        assert!(found[0].starts_with("streams.wheels: "), "{found:?}");
    }
}
