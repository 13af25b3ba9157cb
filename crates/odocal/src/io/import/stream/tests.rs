//! The streamed import against the whole import on the shipped manifests.

use std::path::Path;

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
        mask.extend(&c.reference_measured);
        for k in 0..c.t.len() {
            let g = &c.signals;
            sig.push([g.px[k], g.py[k], g.psi[k], g.n_rl[k], g.n_rr[k], g.beta[k], g.a_y[k]]);
        }
        if let Some(p) = parts.last_mut() {
            p.end = t.len();
        }
    }
    let report = s.report().expect("report").clone();
    let d = Drive::builder(t, sig)
        .parts(parts)
        .reference_measured(mask)
        .sample_time_s(1.0 / m.output.rate_hz)
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
    ] {
        let m = manifest(rel);
        let whole = crate::io::import::import(&m).expect("import");
        let (d, r) = streamed(&m, StreamOptions::default(), chunk);
        assert_eq!(d.fingerprint(), whole.drive.fingerprint(), "{rel}, chunk {chunk}");
        assert_eq!(d.reference_measured(), whole.drive.reference_measured());
        assert_eq!(r.clock_offset.applied_s.to_bits(), whole.report.clock_offset.applied_s.to_bits());
        assert_eq!(r.samples, whole.report.samples);
        assert_eq!(r.parts.len(), whole.report.parts.len());
        assert_eq!(r.gaps.len(), whole.report.gaps.len());
        assert_eq!(r.distance_m.to_bits(), whole.drive.distance_m().to_bits());
    }
}

#[test]
fn unsupported_manifests_are_refused_with_the_reason() {
    let m = manifest("../../examples/psu-mapping-van/manifest.toml");
    let e = RawStream::new(&m, StreamOptions::default()).expect_err("bank").to_string();
    assert!(e.contains("cannot be imported as a stream") && e.contains("bank"), "{e}");
}
