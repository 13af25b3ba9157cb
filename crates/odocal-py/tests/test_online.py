"""odocal.online.Calibrator and odocal.History against the library and the CLI."""

import json
import re
import sqlite3
import subprocess

import numpy as np
import pytest

import odocal
import odocal.online


@pytest.fixture(scope="module")
def clean_drive() -> "odocal.Drive":
    """A 4 km noise-free simulated drive (seed 2)."""
    return odocal.simulate(seed=2, length_km=4.0, noise="off")


def push_in_chunks(cal, drive, chunk=400, with_t=True):
    a = drive.to_numpy()
    for i in range(0, len(drive), chunk):
        c = a[i:i + chunk]
        cal.push(c[:, 0] if with_t else None, c[:, 1], c[:, 2], c[:, 3], c[:, 4], c[:, 5], c[:, 7], beta=c[:, 6])


def test_calibrator_converges_on_a_noise_free_drive(clean_drive):
    cal = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    push_in_chunks(cal, clean_drive)
    truth = clean_drive.theta_true
    assert abs(cal.theta["c_e"] / truth["c_e"] - 1) < 1e-4
    assert abs(cal.theta["c_d"] - truth["c_d"]) < 1e-4
    assert set(cal.sigma) == {"c_e", "c_d", "t_r", "d"}
    assert cal.sigma["c_e"] < 1e-3 * truth["c_e"]
    s = cal.summary
    assert s["samples"] == len(clean_drive)
    assert s["folded_segments"] > 10 and s["validation_segments"] > 3
    assert cal.covariance.shape == (5, 5)
    value, sd = cal.heading_offset
    assert abs(value) < 1e-3 and sd > 0
    # Memory is bounded: at most two validation segments and a chunk.
    assert cal.buffered_samples <= 2 * 1300 + 400


def test_chunks_of_arrays_equal_the_library_replay_of_the_drive(clean_drive):
    a = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    push_in_chunks(a, clean_drive, chunk=123)
    b = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    b.push_drive(clean_drive, chunk=400)
    assert a.theta == b.theta
    assert a.summary == b.summary
    # Without t the samples follow on: the same again.
    c = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    push_in_chunks(c, clean_drive, chunk=500, with_t=False)
    assert c.theta == b.theta


def test_a_wrapped_heading_is_unwrapped_across_chunks(clean_drive):
    a = clean_drive.to_numpy()
    wrapped = np.angle(np.exp(1j * a[:, 3]))
    assert np.max(np.abs(np.diff(wrapped))) > 3.0, "the drive should turn through ±π"
    cal = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    for i in range(0, len(a), 300):
        c = a[i:i + 300]
        cal.push(c[:, 0], c[:, 1], c[:, 2], wrapped[i:i + 300], c[:, 4], c[:, 5], c[:, 7], beta=c[:, 6])
    ref = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    ref.push_drive(clean_drive)
    for k in ("c_e", "c_d", "t_r", "d"):
        assert cal.theta[k] == pytest.approx(ref.theta[k], rel=1e-9, abs=1e-12)


def test_a_gap_in_time_starts_a_new_part(clean_drive):
    a = clean_drive.to_numpy()[:3000].copy()
    a[1500:, 0] += 60.0
    cal = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    cal.push(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 7])
    assert cal.summary["samples"] == 3000


def test_bad_input_raises_odocal_error(clean_drive):
    a = clean_drive.to_numpy()[:500]
    cal = odocal.online.Calibrator(sample_time_s=clean_drive.sample_time_s)
    with pytest.raises(odocal.OdocalError, match="^the pushed samples: column py has 499 samples, px has 500$"):
        cal.push(a[:, 0], a[:, 1], a[:-1, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 7])
    bad = a[:, 4].copy()
    bad[7] = np.nan
    # The column and the sample at fault, as Drive.from_arrays names them.
    with pytest.raises(odocal.OdocalError, match=r"^the pushed samples: column 'n_rl', sample 7: value NaN is not finite$"):
        cal.push(None, a[:, 1], a[:, 2], a[:, 3], bad, a[:, 5], a[:, 7])
    t = a[:, 0].copy()
    t[10:] += 0.3 * clean_drive.sample_time_s
    with pytest.raises(odocal.OdocalError, match=r"sample 10: step"):
        cal.push(t, a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 7])
    # A value that is not finite after a gap in t: nothing of the push is taken.
    gap = a[:, 0].copy()
    gap[300:] += 10.0
    late = a[:, 1].copy()
    late[450] = np.inf
    with pytest.raises(odocal.OdocalError, match=r"column 'px', sample 450: value inf is not finite"):
        cal.push(gap, late, a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 7])
    assert cal.summary["samples"] == 0
    # An argument that is not 1-D: named, with its shape and the length expected (px's).
    with pytest.raises(odocal.OdocalError, match=re.escape(
            "py: got a ndarray of shape (500, 2), where a 1-D array of 500 samples (one value per sample, as px)")):
        cal.push(None, a[:, 1], a[:, 1:3], a[:, 3], a[:, 4], a[:, 5], a[:, 7])
    with pytest.raises(odocal.OdocalError, match=re.escape("t: got a ndarray of shape (500, 1)")):
        cal.push(a[:, :1], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 7])
    with pytest.raises(TypeError, match="information_scal"):
        odocal.online.Calibrator(information_scal=0.01)
    with pytest.raises(odocal.OdocalError, match="information_scale"):
        odocal.online.Calibrator(information_scale=-1.0)
    with pytest.raises(odocal.OdocalError, match="sample_time_s"):
        odocal.online.Calibrator(sample_time_s=0.0)
    with pytest.raises(odocal.OdocalError, match="no stored θ"):
        cal.decide()


def test_sigma0_is_a_sigma_not_a_theta(clean_drive):
    """sigma0 takes a history row's σ (small, no physical limits of θ) as a dict or four numbers."""
    small = {"c_e": 8e-4, "c_d": 1.5e-4, "t_r": 8e-3, "d": 1e-4}
    by_dict = odocal.online.Calibrator(sigma0=small, sample_time_s=clean_drive.sample_time_s)
    by_list = odocal.online.Calibrator(sigma0=list(small.values()), sample_time_s=clean_drive.sample_time_s)
    assert by_dict.sigma == by_list.sigma
    assert by_dict.sigma["c_e"] < odocal.online.Calibrator().sigma["c_e"]
    with pytest.raises(odocal.OdocalError, match="sigma0: unknown key 'ce'"):
        odocal.online.Calibrator(sigma0={**small, "ce": 1e-3})
    with pytest.raises(odocal.OdocalError, match="sigma0: missing d"):
        odocal.online.Calibrator(sigma0={k: v for k, v in small.items() if k != "d"})
    with pytest.raises(odocal.OdocalError, match="sigma0: t_r = -0.008: a standard deviation is a finite number"):
        odocal.online.Calibrator(sigma0={**small, "t_r": -8e-3})


def test_options_and_gates_reach_the_library(clean_drive):
    cal = odocal.online.Calibrator(
        [0.97, 0.0, 1.5, 0.0],
        sample_time_s=clean_drive.sample_time_s,
        random_walk={"c_e_relative": 0.0},
        gates={"steady_s": 0.0, "max_change_c_e_relative": 1e-6},
    )
    assert cal.gates["steady_s"] == 0.0
    cal.stored = [0.97, 0.0, 1.5, 0.0]
    assert cal.stored == {"c_e": 0.97, "c_d": 0.0, "t_r": 1.5, "d": 0.0}
    cal.push_drive(clean_drive)
    d = cal.decide()
    assert d["action"] in ("write", "hold", "flag")
    assert d["theta"] == cal.theta
    # θ moved far from the stored guess: a recorded calibration bounds the change.
    assert d["action"] in ("flag", "hold")
    assert any("c_e changes" in r for r in d["reasons"])
    assert cal.decide(calibrated=False)["action"] in ("write", "hold")


def test_drive_estimate_is_the_drives_own_the_gates_compare_with(clean_drive):
    """After a step in c_e the recursion lags; the drive's own estimate is at the truth,
    the value the gates' reason names, and None before and after the drive."""
    truth = clean_drive.theta_true
    stored = {**truth, "c_e": truth["c_e"] / 1.025}
    small = {"c_e": 7.4e-4, "c_d": 1.7e-4, "t_r": 6e-3, "d": 6e-5}
    cal = odocal.online.Calibrator(stored, small, sample_time_s=clean_drive.sample_time_s)
    assert cal.drive_estimate is None
    cal.stored = stored
    cal.push_drive(clean_drive)
    own = cal.drive_estimate
    assert set(own) == {"theta", "sigma"}
    assert set(own["theta"]) == set(own["sigma"]) == {"c_e", "c_d", "t_r", "d"}
    assert abs(own["theta"]["c_e"] / truth["c_e"] - 1) < 1e-4
    assert 0 < own["sigma"]["c_e"] < 1e-3 * truth["c_e"]
    # The recursion is short of it: its prior holds it near the stored value.
    assert truth["c_e"] - cal.theta["c_e"] > 3 * cal.sigma["c_e"]
    reasons = cal.decide()["reasons"]
    alone = [r for r in reasons if r.startswith("this drive alone puts c_e at")]
    assert len(alone) == 1, reasons
    named = float(alone[0].split(" at ")[1].split(" ")[0])
    assert named == pytest.approx(own["theta"]["c_e"], rel=1e-6)
    cal.new_drive()
    assert cal.drive_estimate is None


def test_history_records_rows_flags_drift_and_pools(tmp_path, small_drive):
    db = odocal.History(tmp_path / "van.sqlite")
    assert db.schema_version >= 1
    base = {"vehicle": "van", "method": "eiv", "theta": {"c_e": 0.97, "c_d": 1e-4, "t_r": 1.5, "d": 0.0},
            "sigma": {"c_e": 1e-4, "c_d": 1e-5, "t_r": 1e-3, "d": 1e-5}}
    first = db.record({**base, "fingerprint": "a"})
    assert first["new"] is True
    assert db.record({**base, "fingerprint": "a"}) == {"id": first["id"], "new": False}
    moved = {**base["theta"], "c_d": 1e-3}
    db.record({**base, "fingerprint": "b", "theta": moved, "sources": ["b.csv"]})
    rows = db.rows("van")
    assert [r["fingerprint"] for r in rows] == ["a", "b"]
    assert rows[1]["sources"] == ["b.csv"] and rows[1]["theta"]["c_d"] == 1e-3
    flags = db.drift("van")
    assert [f["parameter"] for f in flags] == ["c_d"]
    assert flags[0]["from_id"] == rows[0]["id"] and flags[0]["to_id"] == rows[1]["id"]
    assert rows[0]["sigma_model_only"] is None and flags[0]["model_sigma_only"] is False
    p = db.pooled("van")
    assert p["rows"] == 2 and p["between_drive_sd"]["c_d"] > 0
    assert db.pooled("van", ids=[rows[0]["id"]])["rows"] == 1
    assert db.pooled("nobody") is None and db.rows("nobody") == []
    report = odocal.calibrate(small_drive, method="batch-gn")
    r = db.record(report, vehicle="van")
    assert r["new"] is True
    assert db.record(report, vehicle="van")["new"] is False
    row = db.latest("van", usable_only=False)
    assert row["fingerprint"] == small_drive.fingerprint and row["method"] == "batch-gn"
    assert row["theta"] == report.theta and row["verdict"] is not None
    # Whether the σ is the model's alone is recorded from the verdict.
    assert row["sigma_model_only"] == ("model_sigma_only" in json.dumps(report.verdict))
    # The verdict's reason kinds are recorded with the row; rows given as dicts without them: not known.
    assert row["reasons"] == [x["kind"] for x in report.verdict["reasons"]]
    assert rows[0]["reasons"] is None
    # A row naming a bias beyond its σ is not pooled, and `pooled` names it.
    bias = [k for k in ("input_noise_bias", "heading_offset_held") if k in row["reasons"]]
    assert db.pooled("van")["biased"] == ([{"id": row["id"], "reasons": bias}] if bias else [])
    # A σ of the model alone: a flag it takes part in says so.
    other = odocal.History(tmp_path / "other.sqlite")
    other.record({**base, "fingerprint": "a"})
    other.record({**base, "fingerprint": "b", "theta": moved, "sigma_model_only": True})
    assert [f["model_sigma_only"] for f in other.drift("van")] == [True]
    with pytest.raises(odocal.OdocalError):
        db.record({"vehicle": "van", "fingerprint": "c"})


def test_history_records_the_source_digest_of_a_drive_read_from_a_file(tmp_path, small_drive, drive_csv):
    """A drive read from a file records its files' source digest (the CLI's
    `calibrate --db` records the same); a drive made in memory has none."""
    db = odocal.History(tmp_path / "h.sqlite")
    db.record(odocal.calibrate(odocal.Drive.from_csv(drive_csv), method="batch-gn"), vehicle="van")
    db.record(odocal.calibrate(small_drive, method="batch-gn", fix=["d"]), vehicle="mem")
    digest = db.rows("van")[-1]["source_digest"]
    assert isinstance(digest, str) and len(digest) == 64, digest
    assert db.rows("mem")[-1]["source_digest"] is None


def test_latest_is_the_row_follow_starts_from(tmp_path, drive_csv, odocal_bin):
    """`latest` passes over rejected rows and those whose verdict names a bias beyond its σ, as `odocal
    follow` does when it picks its start; `usable_only=False` gives the most recent row whatever its verdict."""
    path = tmp_path / "van.sqlite"
    db = odocal.History(path)
    assert db.latest("van") is None and db.latest("van", usable_only=False) is None
    base = {"vehicle": "van", "method": "eiv", "theta": {"c_e": 1.95, "c_d": -2e-3, "t_r": 1.53, "d": 8e-4},
            "sigma": {"c_e": 1e-4, "c_d": 1e-5, "t_r": 1e-3, "d": 1e-5}}
    usable = db.record({**base, "fingerprint": "a", "verdict": "accepted", "reasons": []})["id"]
    db.record({**base, "fingerprint": "b", "verdict": "rejected", "reasons": []})
    db.record({**base, "fingerprint": "c", "method": "batch-gn", "verdict": "doubtful",
               "reasons": ["model_sigma_only", "input_noise_bias"]})
    last = db.record({**base, "fingerprint": "d", "verdict": "accepted", "reasons": ["heading_offset_held"]})["id"]
    assert db.latest("van")["id"] == usable
    assert db.latest("van", usable_only=False)["id"] == last
    with pytest.raises(TypeError):
        db.latest("van", False)  # a keyword, not a position
    # The CLI's follow starts from the same row.
    out = subprocess.run([str(odocal_bin), "follow", str(drive_csv), "--vehicle", "van", "--db", str(path)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert f"(history row {usable};" in out.stdout, out.stdout
    # Rejected or biased only: no row to start from, as follow's θ_0.
    only = odocal.History(tmp_path / "only.sqlite")
    only.record({**base, "fingerprint": "b", "verdict": "rejected"})
    only.record({**base, "fingerprint": "c", "reasons": ["input_noise_bias"]})
    assert only.latest("van") is None and only.latest("van", usable_only=False)["fingerprint"] == "c"


def test_history_checks_a_record_as_the_cli_does(tmp_path, small_drive, odocal_bin):
    """The library's checks of every record (the vehicle as `--vehicle` takes it, the method, θ within the
    physical limits, σ) and, for a dict, its keys: nothing is written for a record refused."""
    db = odocal.History(tmp_path / "van.sqlite")
    base = {"vehicle": "van", "fingerprint": "a", "method": "eiv",
            "theta": {"c_e": 1.95, "c_d": 0.0, "t_r": 1.5, "d": 0.0}}
    cases = [
        ({**base, "vehicle": " "}, r"^invalid option `vehicle`: the vehicle's identifier is empty"),
        ({**base, "vehicle": "van "}, "has a space at an end"),
        ({**base, "method": "foo"}, r"'foo' is not a method of odocal's: eiv, three-step, batch-gn, online$"),
        ({**base, "theta": {**base["theta"], "c_e": 2000.0}}, "c_e = 2000 m is outside 0.05 … 20 m"),
        ({**base, "theta": {**base["theta"], "x": 1.0}}, "unknown key 'x'"),
        ({**base, "sigmaa": {"c_e": 1e-3, "c_d": 1e-4, "t_r": 1e-3, "d": 1e-4}},
         r"^invalid option `record`: unknown key 'sigmaa'; a record has .*sigma,"),
        ({**base, "sigma": {"c_e": 1e-3, "c_d": 1e-4, "t_r": float("nan"), "d": 1e-4}}, "not a finite number"),
        ({**base, "sigma": {"c_e": 1e-3, "c_d": -1e-4, "t_r": 1e-3, "d": 1e-4}},
         "c_d = -0.0001: a standard deviation is a finite number, not negative"),
        ({**base, "sigma": {"c_e": 1e-3, "c_d": 1e-4, "t_r": 1e-3, "dd": 1e-4}}, "sigma: unknown key 'dd'"),
        ({**base, "held": ["x"]}, r"^invalid option `held`: 'x' is not a parameter of θ"),
    ]
    for record, message in cases:
        with pytest.raises(odocal.OdocalError, match=message):
            db.record(record)
    report = odocal.calibrate(small_drive, method="batch-gn")
    with pytest.raises(odocal.OdocalError, match="the vehicle's identifier is empty"):
        db.record(report, vehicle="")
    assert db.rows("van") == [] and db.rows(" ") == [] and db.rows("") == []
    assert db.record(base)["new"] is True
    assert db.record(report, vehicle="van")["new"] is True
    held_d = {**base, "fingerprint": "b", "held": ["d"], "sigma": {"c_e": 1e-3, "c_d": 1e-4, "t_r": 1e-3, "d": None}}
    assert db.record(held_d)["new"] is True
    assert db.rows("van")[-1]["sigma"]["d"] is None and db.rows("van")[-1]["held"] == ["d"]
    # The CLI refuses the same vehicle with the same words.
    csv = tmp_path / "d.csv"
    small_drive.to_csv(csv)
    out = subprocess.run([str(odocal_bin), "calibrate", str(csv), "--method", "batch-gn", "--vehicle", " ", "--db",
                          str(tmp_path / "cli.sqlite")], capture_output=True, text=True)
    assert out.returncode == 2 and "the vehicle's identifier is empty" in out.stderr, out.stderr


def test_history_refuses_a_file_that_is_not_one(tmp_path):
    p = tmp_path / "not.sqlite"
    p.write_text("this is not a database\n" * 100)
    with pytest.raises(odocal.OdocalError, match="not.sqlite"):
        odocal.History(p)


def test_a_database_written_by_follow_opens_with_sqlite3(tmp_path, odocal_bin):
    paths = []
    for seed in (4, 5):
        d = odocal.simulate(seed=seed, length_km=3.0)
        paths.append(tmp_path / f"run{seed}.csv")
        d.to_csv(paths[-1])
    db = tmp_path / "van.sqlite"
    out = tmp_path / "follow.json"
    cmd = [str(odocal_bin), "follow", *map(str, paths), "--vehicle", "van-1", "--db", str(db), "--json", str(out),
           "--steady-s", "0"]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    report = json.loads(out.read_text())
    assert [d["source"] for d in report["drives"]] == [str(p) for p in paths]
    for d in report["drives"]:
        assert set(d) >= {"source", "fingerprint", "prequential_mean_position_error_m", "updates"}
        assert d["updates"][0]["decision"] in ("written", "held", "flagged")
    con = sqlite3.connect(db)
    decisions = con.execute("SELECT vehicle, fingerprint, decision, c_e FROM decisions ORDER BY id").fetchall()
    assert [r[1] for r in decisions] == [d["fingerprint"] for d in report["drives"]]
    assert all(r[0] == "van-1" and r[3] > 0 for r in decisions)
    written = con.execute("SELECT fingerprint, method, c_e, sigma_c_e FROM calibrations WHERE vehicle = 'van-1'").fetchall()
    assert len(written) == sum(d["updates"][0]["decision"] == "written" for d in report["drives"])
    assert all(m == "online" and s > 0 for _, m, _, s in written)
    con.close()
    h = odocal.History(db)
    assert [d["decision"] for d in h.decisions("van-1")] == [r[2] for r in decisions]
    assert len(h.rows("van-1")) == len(written)
    # The same drives again add nothing.
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    con = sqlite3.connect(db)
    assert con.execute("SELECT COUNT(*) FROM decisions").fetchone()[0] == len(decisions)
    con.close()
