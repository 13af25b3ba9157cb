//! The importer's numbers on the real-drive slices are pinned bit for bit:
//! a change to the importer's structure must not change a single output
//! value. The expected hashes are the importer's output as released.

use odocal::{import, Manifest};

fn manifest(name: &str) -> Manifest {
    let p = format!("{}/tests/data/{name}/manifest.toml", env!("CARGO_MANIFEST_DIR"));
    Manifest::from_path(std::path::Path::new(&p)).expect("manifest")
}

/// FNV-1a over the IEEE bits of the values.
fn fnv(values: impl IntoIterator<Item = f64>) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for v in values {
        for b in v.to_bits().to_le_bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// `(column, hash)` of every numeric column, the parts and the length.
fn fingerprint(name: &str) -> Vec<(String, u64)> {
    let d = import(&manifest(name)).expect("import").0;
    let mut out: Vec<(String, u64)> =
        d.measured().columns().iter().map(|(c, v)| (c.to_string(), fnv(v.iter().copied()))).collect();
    out.push(("t".into(), fnv(d.t().iter().copied())));
    out.push(("parts".into(), fnv(d.parts().iter().flat_map(|r| [r.start as f64, r.end as f64]))));
    out.push(("len".into(), d.len() as u64));
    out
}

fn check(name: &str, expected: &[(&str, u64)]) {
    let got = fingerprint(name);
    let want: Vec<(String, u64)> = expected.iter().map(|(c, h)| (c.to_string(), *h)).collect();
    assert_eq!(got, want, "{name}: imported drive changed; got {got:#x?}");
}

#[test]
fn van_slice_import_is_bit_identical_to_before_the_split() {
    check(
        "psu-mapping-van",
        &[
            ("px", 0x2053f7135b88171a),
            ("py", 0x49b5895c9dd536ab),
            ("psi", 0x19493886e527ac80),
            ("n_rl", 0x7d5551a9769ec965),
            ("n_rr", 0xc9817f4032eccf0e),
            ("beta", 0x14a43d8edafb4685),
            ("a_y", 0x4b277460f5f137d4),
            ("t", 0x92b839857ce8d0c6),
            ("parts", 0x66172623ee82c08b),
            ("len", 0x000000000000136f),
        ],
    );
}

#[test]
fn rav4_slice_import_is_bit_identical_to_before_the_split() {
    check(
        "comma2k19-rav4",
        &[
            ("px", 0x90ac5a94dd5b9e87),
            ("py", 0x3bcb32a43de634e5),
            ("psi", 0xcad89c03a4419fba),
            ("n_rl", 0x61d1c06d41bca7c9),
            ("n_rr", 0x993ff0f6b2ca4042),
            ("beta", 0xed3d89f92ebb4b45),
            ("a_y", 0xd74d8a1a1dcb14f9),
            ("t", 0xf30f6b10d2fd8693),
            ("parts", 0xae8f17bc4c46daf5),
            ("len", 0x000000000000031d),
        ],
    );
}
