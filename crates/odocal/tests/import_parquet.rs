//! Parquet streams (`format = "parquet"`): the van slice written as Parquet by
//! pyarrow (tests/data/parquet/make_fixture.py, an independent writer) must
//! import to the same drive as its CSV manifest, bit for bit; missing
//! columns, wrong types and nulls are clear errors naming the file and the
//! column. The feature is off by default:
//!
//! ```sh
//! cargo test -p odocal --features parquet --test import_parquet
//! ```
//!
//! Without the feature only the test of the "build with --features parquet"
//! error runs.

use std::path::{Path, PathBuf};

use odocal::{import, Manifest};

fn data(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(rel)
}

fn manifest(rel: &str) -> Manifest {
    Manifest::from_path(data(rel)).expect("manifest")
}

#[cfg(feature = "parquet")]
mod with_feature {
    use super::*;

    /// A manifest in a temporary folder: the van manifest with its pose stream
    /// replaced by `pose` (a TOML table body) and the pose columns by `columns`.
    fn van_with_pose(pose: &str, columns: &str) -> (tempfile::TempDir, Manifest) {
        let dir = tempfile::tempdir().expect("tempdir");
        let enc = data("parquet/encoders.parquet");
        let text = format!(
            r#"[output]
    rate_hz = 40.0
    min_part_s = 10.0
    
    [streams.encoders]
    format = "parquet"
    file = "{}"
    time_column = "ros_time_s"
    
    [streams.pose]
    {pose}
    
    [wheels]
    stream = "encoders"
    signal = "ticks_cumulative"
    ticks_per_rev = 40360.0
    rear_left = {{ column = "left_ticks_cum" }}
    rear_right = {{ column = "right_ticks_cum" }}
    
    [pose]
    stream = "pose"
    
    {columns}
    "#,
            enc.display()
        );
        let path = dir.path().join("m.toml");
        std::fs::write(&path, text).expect("write manifest");
        let m = Manifest::from_path(&path).expect("manifest");
        (dir, m)
    }

    const VAN_POSE: &str = r#"[pose.position]
kind = "local"
x = "x_east_m"
y = "y_north_m"

[pose.heading]
column = "yaw_enu_rad"
convention = "enu"
"#;

    fn pose_stream(file: &Path, time: &str) -> String {
        format!("format = \"parquet\"\nfile = \"{}\"\ntime_column = \"{time}\"", file.display())
    }

    fn import_err(m: &Manifest) -> String {
        import(m).expect_err("the import must fail").to_string()
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn van_parquet_imports_to_the_csv_drive_bit_for_bit() {
        let csv = import(&manifest("psu-mapping-van/manifest.toml")).expect("csv import");
        let pq = import(&manifest("parquet/manifest.toml")).expect("parquet import");
        let (a, b) = (&csv.0, &pq.0);
        assert!(a.len() > 4000, "the slice is ~2 min at 40 Hz, got {}", a.len());
        assert_eq!(a.parts(), b.parts());
        assert_eq!(bits(a.t()), bits(b.t()), "t");
        for ((ca, va), (cb, vb)) in a.measured().columns().iter().zip(b.measured().columns().iter()) {
            assert_eq!(ca, cb);
            assert_eq!(bits(va), bits(vb), "column {ca}");
        }
        // The reports agree too, but for the file names and the wall time.
        let strip = |r: &odocal::ImportReport| {
            let mut v = serde_json::to_value(r).expect("report json");
            let o = v.as_object_mut().expect("object");
            o.remove("manifest");
            o.remove("elapsed_s");
            for s in o["streams"].as_array_mut().expect("streams") {
                s.as_object_mut().expect("stream").remove("file");
            }
            v
        };
        assert_eq!(strip(&csv.1), strip(&pq.1));
        assert_eq!(serde_json::to_value(&pq.1).expect("JSON")["streams"][0]["rows"], 13_000);
    }

    #[test]
    fn missing_column_names_the_key_file_and_the_columns_found() {
        let (_d, m) = van_with_pose(
            &pose_stream(&data("parquet/pose.parquet"), "gps_time_s"),
            &VAN_POSE.replace("x_east_m", "x_m"),
        );
        let e = import_err(&m);
        for want in [
            "pose.position.x",
            "column 'x_m' not found in",
            "pose.parquet",
            "columns found: gps_time_s (double), x_east_m (double), y_north_m (double), yaw_enu_rad (double), \
             both_fix6 (uint8)",
        ] {
            assert!(e.contains(want), "{want:?} not in: {e}");
        }
    }

    #[test]
    fn missing_time_column_names_time_column() {
        let (_d, m) = van_with_pose(&pose_stream(&data("parquet/pose.parquet"), "stamp"), VAN_POSE);
        let e = import_err(&m);
        assert!(e.contains("streams.pose.time_column: column 'stamp' not found"), "{e}");
    }

    /// Pose columns of `bad.parquet`: x from `x`, y from `t_s`.
    fn bad_pose(x: &str) -> String {
        format!("[pose.position]\nkind = \"local\"\nx = \"{x}\"\ny = \"t_s\"\n")
    }

    /// `bad.parquet` has a double time `t_s` and columns of every refused
    /// kind; the import of its `column` as the pose's x fails with this.
    fn bad_column(column: &str) -> String {
        let (_d, m) = van_with_pose(&pose_stream(&data("parquet/bad.parquet"), "t_s"), &bad_pose(column));
        import_err(&m)
    }

    #[test]
    fn wrong_types_are_named() {
        for (column, kind) in [
            ("label", "is string, not a number"),
            ("speeds", "is a list, not a number"),
            ("price", "is decimal(5, 2), not a number"),
        ] {
            let e = bad_column(column);
            for want in [
                "pose.position.x".to_string(),
                format!("column '{column}' of "),
                "bad.parquet".into(),
                kind.into(),
                "columns found: t_s (double), t_ns (timestamp[ns]), label (string), with_null (double)".into(),
            ] {
                assert!(e.contains(&want), "{column}: {want:?} not in: {e}");
            }
        }
    }

    #[test]
    fn a_null_is_named_with_its_row() {
        let e = bad_column("with_null");
        assert!(
            e.contains("pose.position.x: column 'with_null' of ")
                && e.contains("bad.parquet has a null in row 2 (counting from 0)"),
            "{e}"
        );
    }

    #[test]
    fn numbers_of_other_widths_are_read() {
        // float32 `speed` and the timestamp time pass the column checks and
        // fail later for what they hold (4 rows, 0.3 s), not for their type.
        let e = bad_column("speed");
        assert!(e.contains("do not overlap in time") && e.contains("streams.pose (pose) t = 0 … 0.3 s"), "{e}");
    }

    #[test]
    fn timestamp_time_column_needs_its_unit() {
        let file = data("parquet/bad.parquet");
        let (_d, m) = van_with_pose(&pose_stream(&file, "t_ns"), &bad_pose("t_s"));
        let e = import_err(&m);
        assert!(
            e.contains("streams.pose.time_column: column 't_ns' of ")
                && e.contains("is a timestamp in ns: set time_unit = \"ns\""),
            "{e}"
        );
        let (_d, m) = van_with_pose(&format!("{}\ntime_unit = \"ns\"", pose_stream(&file, "t_ns")), &bad_pose("t_s"));
        let e = import_err(&m);
        assert!(e.contains("do not overlap in time") && e.contains("streams.pose (pose) t = 0 … 0.3"), "{e}");
    }

    #[test]
    fn a_file_that_is_not_parquet_is_named() {
        let (_d, m) = van_with_pose(&pose_stream(&data("psu-mapping-van/pose_rear_antenna_mid.csv"), "t"), VAN_POSE);
        let e = import_err(&m);
        assert!(
            e.contains("streams.pose.file: ") && e.contains("pose_rear_antenna_mid.csv is not a readable Parquet file"),
            "{e}"
        );
    }
}

#[cfg(not(feature = "parquet"))]
#[test]
fn without_the_feature_parquet_asks_for_it() {
    let e = import(&manifest("parquet/manifest.toml")).expect_err("no parquet reader").to_string();
    assert!(
        e.contains("streams.encoders.format")
            && e.contains("cargo install --locked --path crates/odocal-cli --features parquet")
            && e.contains("export the table to CSV"),
        "{e}"
    );
    // The manifest parses all the same.
    let files = manifest("parquet/manifest.toml").stream_files();
    assert!(files.iter().any(|(name, f)| name == "pose" && f.ends_with("pose.parquet")), "{files:?}");
}
