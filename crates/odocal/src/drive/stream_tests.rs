//! The streamed drive against the drive read whole: the same samples,
//! sample time, parts, fingerprint, warnings and errors.

use super::*;
use crate::drive::ExtraColumn;
use crate::sim::{simulate, SimOptions};

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// A simulated drive (with truth columns) cut in two parts by a gap of
/// 5 s, with a text column.
fn drive_with_parts() -> Drive {
    let d = simulate(&SimOptions { length_km: 1.5, ..SimOptions::paper(7) }).expect("sim").drive;
    let k = d.len() / 3;
    let t: Vec<f64> = d.t().iter().enumerate().map(|(i, &t)| if i < k { t } else { t + 5.0 }).collect();
    let truth = d.truth().expect("truth").clone();
    let note = ExtraColumn {
        name: "note".into(),
        values: crate::drive::ExtraValues::Text((0..d.len()).map(|i| format!("n{i}")).collect()),
    };
    crate::drive::DriveBuilder {
        t,
        measured: d.measured().clone(),
        truth: Some(truth),
        parts: Some(vec![0..k, k..d.len()]),
        extra: vec![note],
        ..Default::default()
    }
    .build()
    .expect("d")
}

fn write(dir: &tempfile::TempDir, name: &str, text: &[u8]) -> PathBuf {
    let p = dir.path().join(name);
    std::fs::write(&p, text).expect("write");
    p
}

/// Every chunk equals the whole drive's samples, bit for bit.
fn assert_same(stream: &DriveStream, whole: &Drive, size: usize) {
    assert_eq!(stream.len(), whole.len());
    assert_eq!(stream.parts, whole.parts());
    assert_eq!(stream.sample_time_s.to_bits(), whole.sample_time_s.to_bits());
    let t = whole.t();
    assert_eq!(bits(&[stream.time_span_s.0, stream.time_span_s.1]), bits(&[t[0], t[t.len() - 1]]));
    assert_eq!(stream.fingerprint().expect("fingerprint"), whole.fingerprint());
    let mut next = 0;
    let mut chunks = 0;
    for c in stream.chunks(size) {
        let c = c.expect("chunk");
        let r = c.start..c.start + c.t.len();
        assert_eq!(r.start, next);
        let part = &whole.parts()[c.part];
        assert!(part.start <= r.start && r.end <= part.end && !r.is_empty(), "{r:?} in {part:?}");
        assert_eq!(c.starts_part, r.start == part.start);
        assert!(r.end == part.end || r.len() == size, "{r:?}");
        assert_eq!(bits(&c.t), bits(&t[r.clone()]));
        for ((name, a), (_, b)) in c.signals.columns().iter().zip(whole.measured().columns()) {
            assert_eq!(bits(a), bits(&b[r.clone()]), "column {name} at {r:?}");
        }
        next = r.end;
        chunks += 1;
    }
    assert_eq!(next, whole.len());
    let expected: usize = whole.parts().iter().map(|p| p.len().div_ceil(size)).sum();
    assert_eq!(chunks, expected);
}

#[test]
fn chunks_equal_the_drive_read_whole() {
    let dir = tempfile::tempdir().expect("tmp");
    let d = drive_with_parts();
    let p = dir.path().join("parts.csv");
    d.write_csv(&p).expect("write");
    let (whole, warnings) = Drive::read_csv(&p).expect("whole");
    assert_eq!(whole.parts().len(), 2);
    let stream = DriveStream::open(&p).expect("stream");
    assert_eq!(stream.warnings, warnings.as_slice());
    for size in [400, 333, 1, 100_000] {
        assert_same(&stream, &whole, size);
    }
    // One part, no truth, no newline at the end, a BOM and CRLF.
    let one = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(8) }).expect("sim").drive;
    let one =
        crate::drive::DriveBuilder { t: one.t().to_vec(), measured: one.measured().clone(), ..Default::default() }
            .build()
            .expect("one");
    let mut text = b"\xEF\xBB\xBF".to_vec();
    one.write_csv_to(&mut text).expect("csv");
    let text = String::from_utf8(text).expect("utf8").trim_end().replace('\n', "\r\n");
    let p = write(&dir, "one.csv", text.as_bytes());
    let (whole, warnings) = Drive::read_csv(&p).expect("whole");
    let stream = DriveStream::open(&p).expect("stream");
    assert_eq!(warnings.len(), 1);
    assert_eq!(stream.warnings, warnings.as_slice());
    assert_same(&stream, &whole, 400);
}

#[test]
fn a_wrapped_heading_is_unwrapped_as_whole() {
    let dir = tempfile::tempdir().expect("tmp");
    let mut s = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
    let mut psi = -0.0f64;
    for k in 0..400 {
        let wrapped = (psi + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI) - std::f64::consts::PI;
        s.push_str(&format!("{},{},0,{},5,5,0,0\n", k as f64 * 0.1, k as f64, if k == 0 { psi } else { wrapped }));
        psi += 0.3 * if k < 200 { 1.0 } else { -1.0 };
    }
    let p = write(&dir, "wrap.csv", s.as_bytes());
    let whole = Drive::read_csv(&p).expect("whole").0;
    assert!(whole.psi().iter().any(|v| v.abs() > 10.0), "the heading winds up");
    assert_same(&DriveStream::open(&p).expect("stream"), &whole, 64);
}

/// Files the whole reader refuses: the stream refuses them with the same words.
#[test]
fn errors_are_the_whole_readers() {
    let good = |rows: usize, ts: f64| {
        let mut s = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
        for i in 0..rows {
            s.push_str(&format!("{},{},0,0,5,5,0,0\n", i as f64 * ts, i as f64 * 0.25));
        }
        s
    };
    let g = good(6, 0.025);
    let parts = "t,px,py,psi,n_rl,n_rr,beta,a_y,part\n";
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("empty", b"  \n".to_vec()),
        ("header only", b"t,px,py,psi,n_rl,n_rr,beta,a_y\n".to_vec()),
        ("missing", b"t,px,py\n0,0,0\n".to_vec()),
        ("semicolons", b"t;px;py;psi;n_rl;n_rr;beta;a_y\n0;0;0;0;0;0;0;0\n".to_vec()),
        ("duplicate", b"t,px,py,psi,n_rl,n_rr,beta,a_y,t\n0,0,0,0,0,0,0,0,1\n".to_vec()),
        ("nul header", b"t,px,py,psi,n_rl,n_rr,beta,a_y,x\0\n0,0,0,0,0,0,0,0,1\n".to_vec()),
        ("nan", g.replacen("0.05,0.5", "0.05,NaN", 1).into_bytes()),
        ("text", g.replacen("0.05,0.5", "0.05,abc", 1).into_bytes()),
        ("nan and later text", g.replacen("0.05,0.5", "0.05,inf", 1).replacen("0.1,1", "0.1,x", 1).into_bytes()),
        ("not increasing", g.replacen("0.05,", "0.01,", 1).into_bytes()),
        ("not uniform", g.replacen("0.1,", "0.11,", 1).into_bytes()),
        ("short last row", g.as_bytes()[..g.len() - 6].to_vec()),
        ("short row", g.replacen("0.05,0.5,0,0,5,5,0,0\n", "0.05,0.5,0\n", 1).into_bytes()),
        ("one row", good(1, 0.025).into_bytes()),
        ("milliseconds", good(6, 25.0).into_bytes()),
        ("wheel", g.replacen("0.05,0.5,0,0,5,5", "0.05,0.5,0,0,5,1e300", 1).into_bytes()),
        ("a_y", g.replacen("0.05,0.5,0,0,5,5,0,0", "0.05,0.5,0,0,5,5,0,100", 1).into_bytes()),
        ("beta", g.replacen("0.05,0.5,0,0,5,5,0,0", "0.05,0.5,0,0,5,5,2,0", 1).into_bytes()),
        ("speed", g.replacen("0.05,0.5", "0.05,1e9", 1).into_bytes()),
        ("yaw", g.replacen("0.05,0.5,0,0", "0.05,0.5,0,3", 1).into_bytes()),
        (
            "wheel after a time error",
            g.replacen("0.05,", "0.01,", 1).replacen("0.1,1,0,0,5,5", "0.1,1,0,0,5,1e300", 1).into_bytes(),
        ),
        ("float part id", format!("{parts}0,0,0,0,1,1,0,0,0\n0.1,0,0,0,1,1,0,0,0.5\n").into_bytes()),
        ("negative part id", format!("{parts}0,0,0,0,1,1,0,0,-1\n0.1,0,0,0,1,1,0,0,-1\n").into_bytes()),
        (
            "alternating parts",
            format!("{parts}0,0,0,0,1,1,0,0,0\n0.1,0,0,0,1,1,0,0,1\n0.2,0,0,0,1,1,0,0,0\n").into_bytes(),
        ),
        ("mask", b"t,px,py,psi,n_rl,n_rr,beta,a_y,ref_measured\n0,0,0,0,1,1,0,0,1\n0.1,0,0,0,1,1,0,0,2\n".to_vec()),
        ("truth nan", b"t,px,py,psi,n_rl,n_rr,beta,a_y,px_true\n0,0,0,0,1,1,0,0,1\n0.1,0,0,0,1,1,0,0,nan\n".to_vec()),
        ("gzip", b"\x1f\x8b\x08\x00rest".to_vec()),
        // Extra columns whose names no drive takes: empty (a header ending
        // in a comma), with a tab.
        ("empty extra name", g.replacen("a_y\n", "a_y,\n", 1).replace("0,0\n", "0,0,5\n").into_bytes()),
        ("tab in an extra name", g.replacen("a_y\n", "a_y,a\tb\n", 1).replace("0,0\n", "0,0,5\n").into_bytes()),
        ("utf8", b"t,px,py,psi,n_rl,n_rr,beta,a_y,x\n0,0,0,0,1,1,0,0,\xff\n0.1,0,0,0,1,1,0,0,1\n".to_vec()),
    ];
    let dir = tempfile::tempdir().expect("tmp");
    for (name, text) in cases {
        let p = write(&dir, "bad.csv", &text);
        let whole = Drive::read_csv(&p).expect_err(name).to_string();
        let stream = DriveStream::open(&p).expect_err(name).to_string();
        assert_eq!(stream, whole, "{name}");
    }
    let whole = Drive::read_csv(dir.path()).expect_err("dir").to_string();
    assert_eq!(DriveStream::open(dir.path()).expect_err("dir").to_string(), whole);
    let missing = dir.path().join("missing.csv");
    assert_eq!(
        DriveStream::open(&missing).expect_err("missing").to_string(),
        Drive::read_csv(&missing).expect_err("missing").to_string()
    );
}

/// Files the whole reader accepts at the edge of its checks: the stream too.
#[test]
fn edge_cases_are_accepted_as_whole() {
    let dir = tempfile::tempdir().expect("tmp");
    let cases = [
        // Steps within 1 % of the mean; extra columns with text, infinity and NaN.
        "t,px,py,psi,n_rl,n_rr,beta,a_y,e\n0,0,0,0,5,5,0,0,inf\n0.1,1,0,0,5,5,0,0,x\n0.2004,2,0,0,5,5,0,0,NaN\n0.3,3,0,0,5,5,0,0,1\n",
        // Parts with a gap; a one-sample part; a mask; negative zeros.
        "t,px,py,psi,n_rl,n_rr,beta,a_y,part,ref_measured\n0,-0,0,-0,5,5,0,0,3,1\n0.1,1,0,0,5,5,0,0,3,-0\n9,1,0,0,5,5,0,0,1,1\n20,1,0,0,5,5,0,0,4,1\n20.1,2,0,0,5,5,0,0,4,0\n",
        // Blank lines and spaces around fields.
        "t, px ,py,psi,n_rl,n_rr,beta,a_y\n\n0 ,0,0,0,5,5,0,0\n\n0.1,1,0,0,5,5,0,0\n\n",
    ];
    for (i, text) in cases.iter().enumerate() {
        let p = write(&dir, &format!("edge{i}.csv"), text.as_bytes());
        let (whole, warnings) = Drive::read_csv(&p).expect("whole");
        let stream = DriveStream::open(&p).expect("stream");
        assert_eq!(stream.warnings, warnings.as_slice(), "case {i}");
        assert_same(&stream, &whole, 2);
    }
}

#[test]
fn unwrap_matches_the_whole_column() {
    let raw: Vec<f64> =
        (0..200).map(|k| ((k * k) as f64 * 0.37).sin() * 3.1 + if k % 7 == 0 { -0.0 } else { 0.0 }).collect();
    let mut whole = raw.clone();
    crate::drive::unwrap_in_place(&mut whole);
    let mut u = Unwrap::default();
    let streamed: Vec<f64> = raw.iter().map(|&v| u.next(v)).collect();
    assert_eq!(bits(&streamed), bits(&whole));
}

/// A good drive followed by one line longer than the CSV line limit, or by
/// NUL bytes, is refused by the stream and by the whole reader with the
/// line named, before the reader's record buffer grows with the line.
#[test]
fn a_line_too_long_or_a_nul_byte_is_refused_with_its_line() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = simulate(&SimOptions { length_km: 0.3, ..SimOptions::noise_free(3) }).expect("sim").drive;
    let mut good = Vec::new();
    d.write_csv_to(&mut good).expect("csv");
    let lines = good.iter().filter(|&&b| b == b'\n').count() as u64;
    let long_line = [good.as_slice(), &vec![b'7'; 3 << 20], b"\n"].concat();
    let nul = [good.as_slice(), &vec![0u8; 3 << 20]].concat();
    let only_nul = vec![0u8; 3 << 20];
    for (name, bytes, line, what) in [
        ("long.csv", long_line, lines + 1, "longer than 1 MiB"),
        ("nul.csv", nul, lines + 1, "a NUL byte"),
        ("only_nul.csv", only_nul, 1, "longer than 1 MiB"),
    ] {
        let p = write(&dir, name, &bytes);
        let whole = Drive::read_csv(&p).map(|_| ()).expect_err("whole").to_string();
        let streamed = DriveStream::open(&p).map(|_| ()).expect_err("stream").to_string();
        let want = format!("{}: line {line}: ", p.display());
        for e in [&whole, &streamed] {
            assert!(e.starts_with(&want) && e.contains(what) && e.contains("is this a CSV file?"), "{e}");
        }
    }
}
