"""Careless input: what a hurried user passes is refused with an error that
names the argument and says what it takes, and a drive's files stay safe
wherever the process moves to."""

import hashlib
import inspect
import pickle
import threading
import tracemalloc

import numpy as np
import pytest

import odocal
import odocal.online
from conftest import REPO

RUN = REPO / "examples" / "psu-mapping-van-testtrack" / "run-16-06-28.toml"


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_drive_read_by_a_relative_path_keeps_its_files_safe_after_chdir(tmp_path, small_drive, monkeypatch):
    folder = tmp_path / "drives"
    folder.mkdir()
    small_drive.to_csv(folder / "drive.csv")
    before = digest(folder / "drive.csv")
    monkeypatch.chdir(folder)
    drive = odocal.Drive.from_csv("drive.csv")
    assert drive.source == "drive.csv"  # as given, as the CLI's JSON names it
    moved = pickle.loads(pickle.dumps(drive))
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    report = odocal.calibrate(drive, "batch-gn")
    for write in (
        lambda: drive.to_csv(folder / "drive.csv"),
        lambda: moved.to_csv(folder / "drive.csv"),
        lambda: report.to_html(folder / "drive.csv"),
        lambda: report.write_params(folder / "drive.json"),  # the sidecar
    ):
        with pytest.raises(odocal.OdocalError, match="would destroy that file"):
            write()
    assert digest(folder / "drive.csv") == before
    # The same name in the new working directory is another file.
    drive.to_csv("drive.csv")
    assert (elsewhere / "drive.csv").exists()


def test_to_csv_leaves_a_json_beside_path_that_is_no_sidecar(tmp_path):
    """A simulated drive's sidecar goes beside the CSV under its name with .json: a file there
    that is not a simulator sidecar is left alone; an older sidecar is replaced."""
    drive = odocal.simulate(seed=1, length_km=1.0)
    side = tmp_path / "run.json"
    side.write_text('{"validation": {"mean_position_error_m": 1.0}}\n')
    with pytest.raises(odocal.OdocalError, match="is not a simulator sidecar"):
        drive.to_csv(tmp_path / "run.csv")
    assert side.read_text() == '{"validation": {"mean_position_error_m": 1.0}}\n'
    assert not (tmp_path / "run.csv").exists()
    side.unlink()
    drive.to_csv(tmp_path / "run.csv")
    odocal.simulate(seed=2, length_km=1.0).to_csv(tmp_path / "run.csv")
    assert '"seed": 2' in side.read_text()


def test_masked_arrays_with_masked_values_are_refused(small_drive):
    t, px, py, psi, n_rl, n_rr, beta, a_y = small_drive.to_numpy().T
    holes = np.ma.masked_where((t > 5) & (t < 6), px)
    with pytest.raises(odocal.OdocalError, match=r"px: a masked array with \d+ masked value\(s\), the first at sample 201"):
        odocal.Drive.from_arrays(t, holes, py, psi, n_rl, n_rr, a_y)
    part = np.ma.masked_where(t > 5, np.zeros(len(t), dtype=int))
    with pytest.raises(odocal.OdocalError, match="part: a masked array"):
        odocal.Drive.from_arrays(t, px, py, psi, n_rl, n_rr, a_y, part=part)
    cal = odocal.online.Calibrator(sample_time_s=small_drive.sample_time_s)
    with pytest.raises(odocal.OdocalError, match="px: a masked array"):
        cal.push(t, holes, py, psi, n_rl, n_rr, a_y)
    assert cal.summary["samples"] == 0
    # A masked array without a masked value is its data.
    plain = odocal.Drive.from_arrays(t, np.ma.masked_array(px), py, psi, n_rl, n_rr, a_y, beta=beta)
    assert plain.fingerprint == small_drive.fingerprint


def test_unsigned_part_ids_beyond_int64_are_named_as_they_are(small_drive):
    t, px, py, psi, n_rl, n_rr, beta, a_y = small_drive.to_numpy().T
    part = np.full(len(t), 2**63 + 5, dtype=np.uint64)
    with pytest.raises(odocal.OdocalError, match="sample 0: part id 9223372036854775813 is not"):
        odocal.Drive.from_arrays(t, px, py, psi, n_rl, n_rr, a_y, part=part)
    small = (t > 100).astype(np.uint8)
    assert len(odocal.Drive.from_arrays(t, px, py, psi, n_rl, n_rr, a_y, part=small).parts) == 2


def test_theta_that_is_no_parameter_file_or_not_four_numbers_says_what_theta_takes(small_drive, tmp_path):
    with pytest.raises(odocal.OdocalError, match=r"is not a parameter file: give the \.yaml, \.yml or \.json file"):
        odocal.validate(small_drive, tmp_path)
    with pytest.raises(odocal.OdocalError, match=r"shape \(1, 4\), where four numbers c_e, c_d, t_r, d"):
        odocal.validate(small_drive, np.array([[2.0, 0.0, 1.6, 0.0]]))
    with pytest.raises(odocal.OdocalError, match=r"shape \(1, 4\)"):
        odocal.calibrate(small_drive, "batch-gn", theta0=np.array([[2.0, 0.0, 1.6, 0.0]]))
    with pytest.raises(TypeError, match="complex"):
        odocal.validate(small_drive, np.array([2.0, 0.0, 1.6, 0.0], dtype=complex))
    as_list = odocal.validate(small_drive, [2.0, 0.0, 1.6, 0.0], fit_drive=False)
    as_array = odocal.validate(small_drive, np.array([2.0, 0.0, 1.6, 0.0]), fit_drive=False)
    assert as_array["mean_position_error_m"] == as_list["mean_position_error_m"]


def test_a_progress_that_cannot_be_called_is_refused_before_the_calibration(small_drive):
    with pytest.raises(TypeError, match=r"progress: give a function progress\(stage, done, total\) \(got str\)"):
        odocal.calibrate(small_drive, progress="yes")


def test_run_keywords_of_another_type_are_named(small_drive):
    with pytest.raises(TypeError, match=r"carry_heading_offset: give True or False \(got str\)"):
        odocal.calibrate(small_drive, "batch-gn", carry_heading_offset="yes")
    with pytest.raises(TypeError, match=r"holdout: give \"first-half\" or \"second-half\" \(got int\)"):
        odocal.calibrate(small_drive, "batch-gn", holdout=2)


def test_take_chunk_takes_a_count_of_at_least_one():
    raw = odocal.online.RawStream(RUN)
    with pytest.raises(odocal.OdocalError, match="at least 1 sample, got 0"):
        raw.take_chunk(0)
    with pytest.raises(odocal.OdocalError, match="got -1"):
        raw.take_chunk(-1)
    with pytest.raises(TypeError, match="bool"):
        raw.take_chunk(True)
    assert raw.take_chunk(1) is None  # nothing pushed yet


def test_help_shows_no_rust_doc_links():
    objects = [odocal.Drive, odocal.online.Calibrator, odocal.online.RawStream, odocal._odocal.History]
    for cls in objects:
        for name, member in inspect.getmembers(cls):
            doc = getattr(member, "__doc__", None) or ""
            assert "[`" not in doc, f"{cls.__name__}.{name}: {doc}"
    for f in (odocal._odocal.calibrate, odocal._odocal.validate, odocal.simulate, odocal.read_params):
        assert "[`" not in (f.__doc__ or ""), f.__name__


def test_a_push_of_a_huge_size_is_refused_before_anything_is_copied():
    """A zero-stride view costs no memory until it is copied: Calibrator.push and
    RawStream.push_messages measure it first, as Drive.from_arrays does."""
    big = np.broadcast_to(np.int32(0), (50_000_001,))
    small = np.zeros(10)
    cal = odocal.online.Calibrator(sample_time_s=0.025)
    raw = odocal.online.RawStream(RUN)
    tracemalloc.start()
    try:
        with pytest.raises(odocal.OdocalError, match="^px has 50000001 samples, more than the 50000000 one push"):
            cal.push(None, big, big, big, big, big, big)
        with pytest.raises(odocal.OdocalError, match="^beta has 50000001 samples.*push the samples in chunks"):
            cal.push(None, small, small, small, small, small, small, beta=big)
        with pytest.raises(odocal.OdocalError, match="^t has 50000001 samples, more than the 50000000 one call"):
            raw.push_messages("encoders", big, np.broadcast_to(np.int32(0), (50_000_001, 2)))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, f"{peak / 1e6:.0f} MB allocated before refusing"
    assert cal.summary["samples"] == 0


def test_a_calibrator_used_from_several_threads_waits_for_a_running_push():
    """A push runs without the GIL; a reader on another thread (a monitor, a
    ROS callback) or a second pusher waits for it, never a borrow error."""
    drive = odocal.simulate(seed=2, length_km=3.0, noise="off")
    a = drive.to_numpy()
    cal = odocal.online.Calibrator(sample_time_s=drive.sample_time_s)
    alone = odocal.online.Calibrator(sample_time_s=drive.sample_time_s)
    alone.push_drive(drive, chunk=20)
    other = odocal.online.Calibrator(sample_time_s=drive.sample_time_s)
    done, errors, reads = threading.Event(), [], []

    def reader():
        while not done.is_set():
            try:
                reads.append(cal.summary["samples"])
                cal.theta, cal.heading_offset, cal.buffered_samples
            except Exception as e:  # any error is the failure
                errors.append(repr(e))
                return

    def pusher(start):
        try:
            for i in range(start, len(drive), 800):
                c = a[i : i + 400]
                other.push(None, c[:, 1], c[:, 2], c[:, 3], c[:, 4], c[:, 5], c[:, 7])
        except Exception as e:
            errors.append(repr(e))

    threads = [threading.Thread(target=reader)] + [threading.Thread(target=pusher, args=(k,)) for k in (0, 400)]
    for t in threads:
        t.start()
    cal.push_drive(drive, chunk=20)
    done.set()
    for t in threads:
        t.join()
    assert errors == []
    assert reads and reads == sorted(reads)
    assert cal.theta == alone.theta  # the reads change nothing
    assert other.summary["samples"] == len(drive)


def test_a_raw_stream_read_from_another_thread_waits_for_a_running_push():
    raw = odocal.online.RawStream(RUN)
    spec = raw.streams["encoders"]
    data = np.genfromtxt(spec["file"], delimiter=",", names=True)
    t = data[spec["time_column"]]
    values = np.column_stack([data[c] for c in spec["columns"]])
    done, errors = threading.Event(), []

    def reader():
        while not done.is_set():
            try:
                raw.held, raw.clock_offset, raw.report
            except Exception as e:  # any error is the failure
                errors.append(repr(e))
                return

    th = threading.Thread(target=reader)
    th.start()
    raw.push_messages("encoders", t, values)
    done.set()
    th.join()
    assert errors == []
    assert raw.held > 0
