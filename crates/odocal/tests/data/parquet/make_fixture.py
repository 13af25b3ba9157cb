#!/usr/bin/env python3
"""Writes the Parquet fixtures of tests/import_parquet.rs with pyarrow, an
independent writer (not the Rust `parquet` crate odocal reads with).

Run once; the outputs are committed:

    python3 -m venv /tmp/pa && /tmp/pa/bin/pip install pyarrow
    /tmp/pa/bin/python crates/odocal/tests/data/parquet/make_fixture.py

From the van slice's CSV streams (../psu-mapping-van/) it writes

* encoders.parquet: the columns the van manifest reads, as double (time,
  byte-stream-split) and int64 / int32 (the cumulative ticks, delta-packed),
  zstd, two row groups;
* pose.parquet: double columns (byte-stream-split) and the RTK flag as a
  dictionary-encoded uint8, snappy (pyarrow's default codec), three row
  groups;

each number parsed from the CSV text with Python's float()/int() (correctly
rounded, as Rust's parser), so the Parquet drive must equal the CSV drive bit
for bit. And small files for the error tests:

* bad.parquet: 4 rows with a double time, a string column, a column with a
  null, a list column, a decimal column, and the time again as timestamp[ns].
"""

import csv
import decimal
import pathlib

import pyarrow as pa
import pyarrow.parquet as pq

HERE = pathlib.Path(__file__).resolve().parent
VAN = HERE.parent / "psu-mapping-van"


def read_csv(path, columns):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    return {c: [r[c] for r in rows] for c in columns}


def main():
    enc = read_csv(VAN / "encoders.csv", ["ros_time_s", "left_ticks_cum", "right_ticks_cum"])
    encoders = pa.table(
        {
            "ros_time_s": pa.array([float(v) for v in enc["ros_time_s"]], pa.float64()),
            "left_ticks_cum": pa.array([int(v) for v in enc["left_ticks_cum"]], pa.int64()),
            "right_ticks_cum": pa.array([int(v) for v in enc["right_ticks_cum"]], pa.int32()),
        }
    )
    pq.write_table(
        encoders,
        HERE / "encoders.parquet",
        compression="zstd",
        row_group_size=(encoders.num_rows + 1) // 2,
        use_dictionary=False,
        column_encoding={
            "ros_time_s": "BYTE_STREAM_SPLIT",
            "left_ticks_cum": "DELTA_BINARY_PACKED",
            "right_ticks_cum": "DELTA_BINARY_PACKED",
        },
    )

    cols = ["gps_time_s", "x_east_m", "y_north_m", "yaw_enu_rad", "both_fix6"]
    pose = read_csv(VAN / "pose_rear_antenna_mid.csv", cols)
    table = pa.table(
        {c: pa.array([float(v) for v in pose[c]], pa.float64()) for c in cols[:-1]}
        | {"both_fix6": pa.array([int(v) for v in pose["both_fix6"]], pa.uint8())}
    )
    pq.write_table(
        table,
        HERE / "pose.parquet",
        row_group_size=(table.num_rows + 2) // 3,
        use_dictionary=["both_fix6"],
        column_encoding={c: "BYTE_STREAM_SPLIT" for c in cols[:-1]},
    )

    bad = pa.table(
        {
            "t_s": pa.array([0.0, 0.1, 0.2, 0.3], pa.float64()),
            "t_ns": pa.array([0, 100_000_000, 200_000_000, 300_000_000], pa.timestamp("ns")),
            "label": pa.array(["a", "b", "c", "d"], pa.string()),
            "with_null": pa.array([1.0, 2.0, None, 4.0], pa.float64()),
            "speeds": pa.array([[1.0], [2.0], [3.0], [4.0]], pa.list_(pa.float64())),
            "price": pa.array([decimal.Decimal(f"{i}.5") for i in range(4)], pa.decimal128(5, 2)),
            "speed": pa.array([1.0, 2.0, 3.0, 4.0], pa.float32()),
        }
    )
    pq.write_table(bad, HERE / "bad.parquet")


if __name__ == "__main__":
    main()
