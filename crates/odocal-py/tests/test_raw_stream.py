"""odocal.online.RawStream: a shipped manifest's messages pushed one by one,
as a live system would, against the whole import of the same manifest."""

import csv
import heapq
import re

import numpy as np
import pytest

import odocal
import odocal.online
from conftest import REPO

# A test-track run with the road bank of two GNSS antennas; shorter than the
# warm-up, so the streamed samples are the whole import's bit for bit.
RUN = REPO / "examples" / "psu-mapping-van-testtrack" / "run-16-06-28.toml"


def rows(name, spec):
    """The rows of one stream's CSV file as (t, name, values), in file order."""
    with open(spec["file"], newline="") as f:
        for r in csv.DictReader(f):
            yield float(r[spec["time_column"]]), name, [float(r[c]) for c in spec["columns"]]


def push_all(raw):
    """Pushes every stream's rows in time order across the streams, taking
    the ready chunks as it goes; the chunks."""
    streams = raw.streams
    chunks = []
    for t, name, values in heapq.merge(*(rows(n, s) for n, s in streams.items()), key=lambda m: m[0]):
        raw.push_message(name, t, values)
        while (c := raw.take_chunk(400)) is not None:
            chunks.append(c)
    raw.finish()
    while (c := raw.take_chunk(400)) is not None:
        chunks.append(c)
    return chunks


@pytest.fixture(scope="module")
def pushed():
    raw = odocal.online.RawStream(RUN)
    return raw, push_all(raw)


def test_pushed_messages_give_the_whole_imports_samples(pushed):
    raw, chunks = pushed
    assert {"encoders", "pose", "gnss_left", "gnss_right"} <= set(raw.streams)
    whole = odocal.Drive.from_manifest(RUN)
    a = whole.to_numpy()
    assert sum(len(c["samples"]["t"]) for c in chunks) == len(whole)
    assert [c["start"] for c in chunks] == list(np.cumsum([0] + [len(c["samples"]["t"]) for c in chunks[:-1]]))
    # The samples are held until every stream has passed them: chunks come
    # out while the messages are pushed, not only at the end.
    assert len(chunks) > 2
    for j, name in enumerate(whole.columns):
        got = np.concatenate([c["samples"][name] for c in chunks])
        assert np.array_equal(got, a[:, j]), name
    parts = sum(c["starts_part"] for c in chunks)
    assert parts == len({c["part"] for c in chunks}) >= 1
    report = raw.report
    assert report["samples"] == len(whole)
    assert "bank" in report["lateral_acceleration"]
    assert raw.clock_offset["applied_s"] == report["clock_offset"]["applied_s"]


def test_chunks_feed_the_online_calibrator_as_the_whole_drive_does(pushed):
    _, chunks = pushed
    whole = odocal.Drive.from_manifest(RUN)
    a = odocal.online.Calibrator(sample_time_s=whole.sample_time_s)
    for c in chunks:
        a.push(**c["samples"])
    b = odocal.online.Calibrator(sample_time_s=whole.sample_time_s)
    b.push_drive(whole, chunk=400)
    assert a.theta == b.theta
    assert a.summary["samples"] == b.summary["samples"] == len(whole)


def test_errors_name_the_stream_and_its_columns():
    raw = odocal.online.RawStream(RUN, warm_up_s=60.0)
    with pytest.raises(odocal.OdocalError, match="no stream 'imu'"):
        raw.push_message("imu", 0.0, [1.0])
    cols = raw.streams["gnss_left"]["columns"]
    with pytest.raises(odocal.OdocalError, match="streams.gnss_left.*" + ", ".join(cols)):
        raw.push_message("gnss_left", 0.0, [1.0])
    raw.push_message("encoders", 10.0, [0.0, 0.0])
    with pytest.raises(odocal.OdocalError, match="time goes backwards"):
        raw.push_message("encoders", 9.0, [0.0, 0.0])
    with pytest.raises(odocal.OdocalError, match="warm_up_s"):
        odocal.online.RawStream(RUN, warm_up_s=0.0)
    with pytest.raises(odocal.OdocalError, match=re.escape(
            "values: got a ndarray of shape (1, 2), where a 1-D sequence of the stream's column values")):
        raw.push_message("encoders", 10.5, np.zeros((1, 2)))
    raw.push_message("encoders", 10.5, np.zeros(2))
    # push_messages: t 1-D and values 2-D (lists and ints converted), else the argument named with its shape.
    raw.push_messages("encoders", [11.0, 12.0], [[0, 0], [0, 0]])
    with pytest.raises(odocal.OdocalError, match=re.escape(
            "values: got a ndarray of shape (4,), where a 2-D array of 2 rows (one per time in t)")):
        raw.push_messages("encoders", np.array([13.0, 14.0]), np.zeros(4))
    with pytest.raises(odocal.OdocalError, match=re.escape("t: got a ndarray of shape (2, 1), where a 1-D array")):
        raw.push_messages("encoders", np.array([[13.0], [14.0]]), np.zeros((2, 2)))
    with pytest.raises(odocal.OdocalError, match="3 rows of values for 2 times"):
        raw.push_messages("encoders", [13.0, 14.0], np.zeros((3, 2)))
