"""Several drives in calibrate / validate_on, and a manifest's [noise] and [reference] settings."""

import json
import pickle
import subprocess
import warnings

import numpy as np
import pytest

import odocal


def without_timing(d):
    d = dict(d)
    d.pop("timing_s")
    return d


def cli_json(odocal_bin, *args):
    out = subprocess.run([str(odocal_bin), *map(str, args), "--json", "-", "--quiet"], capture_output=True, text=True)
    assert out.returncode in (0, 3), out.stderr
    return json.loads(out.stdout)


@pytest.fixture(scope="module")
def csvs(tmp_path_factory):
    """Three short simulated drives as CSV files (without sidecars, as real drives)."""
    d = tmp_path_factory.mktemp("drives")
    paths = []
    for seed in (5, 6, 7):
        p = d / f"drive{seed}.csv"
        odocal.simulate(seed=seed, length_km=2.0).to_csv(p)
        p.with_suffix(".json").unlink()
        paths.append(p)
    return paths


def test_several_drives_are_fitted_jointly_as_the_cli_does(odocal_bin, csvs):
    a, b, c = csvs
    cli = cli_json(odocal_bin, "calibrate", a, b, "--method", "batch-gn", "--validate-on", c)
    drives = [odocal.Drive.from_csv(p) for p in (a, b)]
    r = odocal.calibrate(drives, "batch-gn", validate_on=odocal.Drive.from_csv(c)).to_dict()
    # The per-drive table names the drives: paths on the command line, indices here.
    assert [d["name"] for d in r["validate_on"]["drives"]] == ["validate_on[0]"]
    for x in (r, cli):
        for d in x["validate_on"]["drives"]:
            d.pop("name")
    assert without_timing(r) == without_timing(cli)
    assert r.get("truth") is None


def test_validate_on_several_drives(csvs):
    a, b, c = (odocal.Drive.from_csv(p) for p in csvs)
    r = odocal.calibrate(a, "batch-gn", validate_on=[b, c])
    v = r.to_dict()["validate_on"]
    assert len(v["drives"]) == 2
    per = [d["mean_position_error_m"] for d in v["drives"]]
    assert v["mean_over_drives_m"] == pytest.approx(np.mean(per), rel=1e-12)
    assert per[0] == pytest.approx(odocal.validate(b, r)["mean_position_error_m"], rel=1e-12)
    assert r.validation["held_out"]


def rows_of(drive, rows, step=1, t0=0.0):
    """A drive of `drive`'s samples `rows` (a slice), sampled `step` times as far apart, time from `t0`."""
    cols = [drive.column(n)[rows] for n in ("px", "py", "psi", "n_rl", "n_rr", "a_y")]
    t = t0 + np.arange(len(cols[0])) * drive.sample_time_s * step
    return odocal.Drive.from_arrays(t, *cols)


def test_a_part_or_a_thinned_copy_is_refused_and_validate_on_shares_the_rate(csvs):
    a, b = odocal.Drive.from_csv(csvs[0]), odocal.Drive.from_csv(csvs[1])
    part, thinned = rows_of(a, slice(0, 4000), t0=1000.0), rows_of(a, slice(1, None, 2), step=2)
    for copy in (part, thinned):
        with pytest.raises(odocal.OdocalError, match=r"^validate_on shares 100 % of its samples with drive \("):
            odocal.calibrate(a, "batch-gn", validate_on=copy)
        with pytest.raises(odocal.OdocalError, match=r"^drive\[1\] shares 100 % of its samples with drive\[0\]"):
            odocal.calibrate([a, copy], "batch-gn")
    # Another drive at 20 Hz: its validation segments would span twice the time.
    with pytest.raises(odocal.OdocalError, match=r"validation drive validate_on\[0\]: its sample time is 0\.050000 s"):
        odocal.calibrate(a, "batch-gn", validate_on=[rows_of(b, slice(0, None, 2), step=2)])


def test_several_drives_bad_input_raises(csvs):
    a = odocal.Drive.from_csv(csvs[0])
    with pytest.raises(odocal.OdocalError, match="no drives given"):
        odocal.calibrate([], "batch-gn")
    with pytest.raises(TypeError, match="give an odocal.Drive or a list of them"):
        odocal.calibrate([a, "drive.csv"], "batch-gn")
    with pytest.raises(TypeError, match="give an odocal.Drive or a list of them"):
        odocal.calibrate("drive.csv", "batch-gn")
    with pytest.raises(TypeError, match="validate_on: give an odocal.Drive or a list of them"):
        odocal.calibrate(a, "batch-gn", validate_on=[a, 3])
    t = np.arange(2000) * 0.05  # 20 Hz: another sample time
    other = odocal.Drive.from_arrays(t, t, 0 * t, 0 * t, 5 + 0 * t, 5 + 0 * t, 0 * t)
    with pytest.raises(odocal.OdocalError, match="joining drives"):
        odocal.calibrate([a, other], "batch-gn")
    with pytest.raises(odocal.OdocalError, match="lever_arm"):
        odocal.calibrate(a, "batch-gn", lever_arm=[1.0])
    with pytest.raises(odocal.OdocalError, match="θ is estimated by default"):
        odocal.calibrate(a, "batch-gn", estimate="t_r")


MANIFEST = """
[output]
clock_offset = 0.0
min_part_s = 1.0

[streams.d]
file = "{csv}"
time_column = "t"

[wheels]
stream = "d"
signal = "rev_per_s"
rear_left = {{ column = "n_rl" }}
rear_right = {{ column = "n_rr" }}

[pose]
stream = "d"
position = {{ kind = "local", x = "px", y = "py" }}
heading = {{ column = "psi", convention = "enu" }}

[lateral_acceleration]
source = "imu"
stream = "d"
column = "a_y"

[noise]
wheel_white_rel_sigma = 0.011

[reference]
heading_offset = 0.001
estimate = ["heading-offset"]
"""


def outcomes(report):
    return {u["key"]: u["outcome"] for u in report.to_dict()["manifest_settings"]}


def test_manifest_settings_apply_unless_a_keyword_is_given(odocal_bin, csvs, tmp_path):
    manifest = tmp_path / "m.toml"
    manifest.write_text(MANIFEST.format(csv=csvs[0].as_posix()))
    drive = odocal.Drive.from_manifest(manifest)
    assert drive.import_report["noise"]["wheel_white_rel_sigma"] == 0.011
    assert drive.import_report["reference"] == {"heading_offset": 0.001, "estimate": ["heading-offset"]}

    r = odocal.calibrate(drive, "batch-gn")
    assert outcomes(r) == {"noise": "ignored", "reference.heading_offset": "used", "reference.estimate": "used"}
    d = r.to_dict()
    assert d["extrinsics"]["free"] == ["heading_offset"] and d["extrinsics"]["initial"]["heading_offset"] == 0.001
    assert without_timing(d) == without_timing(cli_json(odocal_bin, "calibrate", manifest, "--method", "batch-gn"))

    # Keywords win, as the CLI's flags do.
    r = odocal.calibrate(drive, "batch-gn", estimate="lever-arm", heading_offset=0.0)
    assert outcomes(r)["reference.estimate"] == "overridden"
    assert r.to_dict()["extrinsics"]["free"] == ["lever_x", "lever_y"]
    r = odocal.calibrate(drive, "batch-gn", fix="heading_offset")
    assert "extrinsics" not in r.to_dict() or r.to_dict()["extrinsics"]["free"] == []

    # The settings travel with a pickled drive.
    again = pickle.loads(pickle.dumps(drive))
    assert outcomes(odocal.calibrate(again, "batch-gn")) == outcomes(odocal.calibrate(drive, "batch-gn"))


def test_manifest_noise_is_the_eiv_start(csvs, tmp_path):
    manifest = tmp_path / "m.toml"
    manifest.write_text(MANIFEST.format(csv=csvs[0].as_posix()).split("[reference]")[0])
    drive = odocal.Drive.from_manifest(manifest)
    opts = {"fix_noise": True, "fallback": False, "eiv_window": 1500}
    d = odocal.calibrate(drive, "eiv", **opts).to_dict()
    assert d["noise_start"]["wheel_white_rel_sigma"] == 0.011
    assert d["noise_model_origin"].startswith("[noise] of ")
    noise = tmp_path / "noise.toml"
    noise.write_text("wheel_white_rel_sigma = 0.009\n")
    d = odocal.calibrate(drive, "eiv", noise_model=str(noise), **opts).to_dict()
    assert d["noise_start"]["wheel_white_rel_sigma"] == 0.009
    assert d["noise_model_origin"] == f"--noise-model {noise}"
    assert {u["key"]: u["outcome"] for u in d["manifest_settings"]} == {"noise": "overridden"}


def oval(sign=1.0):
    """A noise-free oval (300 m straights, 40 m radius half circles) at 10 m/s, 1.3 laps at 40 Hz,
    driven counter-clockwise (sign +1): every turning segment turns one way."""
    t_s, v, r, straight, c_e, t_r = 0.025, 10.0, 40.0, 300.0, 2.0, 1.6
    lap = 2 * straight + 2 * np.pi * r
    n = int(1.3 * lap / v / t_s)
    along = (np.arange(n) * v * t_s) % lap
    omega = np.where(along % (lap / 2) < straight, 0.0, sign * v / r)
    psi = np.concatenate([[0.0], np.cumsum(omega[:-1] * t_s)])
    mid = psi + omega * t_s / 2
    px = np.concatenate([[0.0], np.cumsum(v * t_s * np.cos(mid[:-1]))])
    py = np.concatenate([[0.0], np.cumsum(v * t_s * np.sin(mid[:-1]))])
    n_rl = (v - omega * t_r / 2) / c_e
    n_rr = (v + omega * t_r / 2) / c_e
    return odocal.Drive.from_arrays(np.arange(n) * t_s, px, py, psi, n_rl, n_rr, v * omega)


def one_way_warnings(report):
    return [w for w in report.to_dict()["warnings"] if w["kind"] == "one_way_turns"]


def test_keep_one_way_keyword_and_manifest_setting(odocal_bin, tmp_path):
    drive = oval()
    assert len(one_way_warnings(odocal.calibrate(drive, "batch-gn"))) == 1
    r = odocal.calibrate(drive, "batch-gn", keep_one_way=True)
    assert one_way_warnings(r) == [] and r.to_dict()["options"]["keep_one_way_selection"] is True
    with pytest.raises(odocal.OdocalError, match="keep_one_way"):
        odocal.calibrate(drive, "eiv", keep_one_way=True)

    # The manifest's [calibration] keep_one_way, as the CLI reads it; the keyword wins.
    csv = tmp_path / "oval.csv"
    drive.to_csv(csv)
    manifest = tmp_path / "m.toml"
    text = MANIFEST.format(csv=csv.as_posix()).split("[noise]")[0]
    manifest.write_text(text + "[calibration]\nkeep_one_way = true\n")
    m = odocal.Drive.from_manifest(manifest)
    assert m.import_report["calibration"] == {"keep_one_way": True}
    r = odocal.calibrate(m, "batch-gn")
    assert one_way_warnings(r) == [] and outcomes(r) == {"calibration.keep_one_way": "used"}
    assert without_timing(r.to_dict()) == without_timing(cli_json(odocal_bin, "calibrate", manifest, "--method", "batch-gn"))
    manifest.write_text(text + "[calibration]\nkeep_one_way = false\n")
    m = odocal.Drive.from_manifest(manifest)
    assert len(one_way_warnings(odocal.calibrate(m, "batch-gn"))) == 1
    r = odocal.calibrate(m, "batch-gn", keep_one_way=True)
    assert one_way_warnings(r) == [] and outcomes(r) == {"calibration.keep_one_way": "overridden"}


def test_manifest_calibration_table_takes_any_setting(odocal_bin, csvs, tmp_path):
    """The manifest's method is used unless one is given, and a key of another method is ignored,
    saying so; the CLI reads the manifest the same way."""
    manifest = tmp_path / "m.toml"
    text = MANIFEST.format(csv=csvs[0].as_posix()).split("[noise]")[0]
    manifest.write_text(text + '[calibration]\nmethod = "batch-gn"\nmin_yaw_rate = 0.2\nbatches = 6\npicks = 3\n')
    m = odocal.Drive.from_manifest(manifest)
    r = odocal.calibrate(m)
    assert r.method == "batch-gn" and r.to_dict()["options"]["segments"]["min_peak_yaw_rate_rad_per_s"] == 0.2
    assert outcomes(r) == {
        "calibration.method": "used",
        "calibration.min_yaw_rate": "used",
        "calibration.batches": "ignored",
        "calibration.picks": "ignored",
    }
    assert without_timing(r.to_dict()) == without_timing(cli_json(odocal_bin, "calibrate", manifest))
    r = odocal.calibrate(m, "three-step", seed=2)
    assert r.method == "three-step" and r.to_dict()["options"]["method"]["initial_batches"] == 6
    assert outcomes(r)["calibration.method"] == "overridden" and outcomes(r)["calibration.batches"] == "used"


def test_validate_on_applies_the_drives_own_reference(odocal_bin, csvs, tmp_path):
    manifest = tmp_path / "v.toml"
    text = MANIFEST.format(csv=csvs[1].as_posix()).split("[noise]")[0]
    manifest.write_text(text + "[reference]\nlever_arm = [-0.9, 0.3]\nheading_offset = -0.01\n")
    fit = odocal.Drive.from_csv(csvs[0])
    r = odocal.calibrate(fit, "batch-gn", validate_on=odocal.Drive.from_manifest(manifest)).to_dict()
    x = r["validate_on"]["drives"][0]["extrinsics"]
    assert x["value"] == {"lever_x": -0.9, "lever_y": 0.3, "heading_offset": -0.01}
    assert x["source"] == {"lever_x": "drive", "lever_y": "drive", "heading_offset": "drive"}
    cli = cli_json(odocal_bin, "calibrate", csvs[0], "--method", "batch-gn", "--validate-on", manifest)
    for d in (r, cli):
        for row in d["validate_on"]["drives"]:
            row.pop("name")
    assert without_timing(r) == without_timing(cli)
    # validate() applies the drive's [reference] too, as `odocal validate` does
    # (its heading offset held as batch G-N held it; θ as numbers re-estimates it).
    v = odocal.validate(odocal.Drive.from_manifest(manifest), r["theta"], carry_heading_offset=True)
    assert v["extrinsics"] == {"lever_x": -0.9, "lever_y": 0.3, "heading_offset": -0.01}
    assert v["mean_position_error_m"] == pytest.approx(r["validate_on"]["drives"][0]["mean_position_error_m"], rel=1e-9)
    refit = odocal.validate(odocal.Drive.from_manifest(manifest), r["theta"])
    assert refit["heading_offset_fit"]["calibration"] == -0.01
    assert refit["extrinsics"]["lever_x"] == -0.9 and refit["extrinsics"]["heading_offset"] != -0.01
    # A keyword's heading offset wins for every drive: a conflict, reported.
    r = odocal.calibrate(fit, "batch-gn", heading_offset=0.0, validate_on=odocal.Drive.from_manifest(manifest))
    x = r.to_dict()["validate_on"]["drives"][0]["extrinsics"]
    assert x["source"]["heading_offset"] == "given"
    assert [c["param"] for c in x["conflicts"]] == ["heading_offset"]


def test_validate_on_re_estimates_each_drive_s_heading_offset_unless_carried(odocal_bin, csvs):
    a, b, _ = csvs
    da, db = odocal.Drive.from_csv(a), odocal.Drive.from_csv(b)
    keys = dict(estimate="heading-offset")
    r = odocal.calibrate(da, "batch-gn", validate_on=[db], **keys).to_dict()
    x = r["validate_on"]["drives"][0]["extrinsics"]
    assert x["source"]["heading_offset"] == "reestimated"
    assert x["heading_offset_fit"]["calibration"] == r["extrinsics"]["value"]["heading_offset"]
    assert x["value"]["heading_offset"] == x["heading_offset_fit"]["value"]
    cli = cli_json(odocal_bin, "calibrate", a, "--method", "batch-gn", "--estimate", "heading-offset", "--validate-on", b)
    assert cli["validate_on"]["drives"][0]["extrinsics"] == x
    carried = odocal.calibrate(da, "batch-gn", validate_on=[db], carry_heading_offset=True, **keys).to_dict()
    y = carried["validate_on"]["drives"][0]["extrinsics"]
    assert y["source"]["heading_offset"] == "estimated" and "heading_offset_fit" not in y
    assert y["value"]["heading_offset"] == r["extrinsics"]["value"]["heading_offset"]


def test_a_joint_calibration_reports_each_drive_s_heading_offset(odocal_bin, csvs):
    """The default method estimates the heading offset: one per drive, as the CLI's."""
    a, b, _ = csvs
    cli = cli_json(odocal_bin, "calibrate", a, b)
    r = odocal.calibrate([odocal.Drive.from_csv(p) for p in (a, b)]).to_dict()
    per = r["heading_offset_per_drive"]
    assert len(per) == 2
    assert [(p["value"], p["sigma"], p["fingerprint"]) for p in per] == [
        (p["value"], p["sigma"], p["fingerprint"]) for p in cli["heading_offset_per_drive"]
    ]
    assert [p["value"] for p in per] == [p["value"] for p in r["extrinsics"]["per_drive"]]
    assert r["extrinsics"]["value"]["heading_offset"] == pytest.approx(np.mean([p["value"] for p in per]), abs=1e-15)


def test_validate_on_a_calibration_drive_holds_its_own_heading_offset(tmp_path, csvs):
    """On a drive the calibration ran on (the same drive fingerprint), validate holds the
    calibration's own heading offset for it, so Ē_p is the calibration's own: with the
    report and with its parameter file; each drive of a joint calibration its own."""
    da, db = (odocal.Drive.from_csv(p) for p in csvs[:2])
    r = odocal.calibrate(da)
    own = r.to_dict()
    r.write_params(tmp_path / "p.yaml")
    for theta in (r, tmp_path / "p.yaml"):
        v = odocal.validate(da, theta)
        assert v["calibration_drive"] is True and "heading_offset_fit" not in v, v
        assert v["extrinsics"]["heading_offset"] == own["extrinsics"]["value"]["heading_offset"]
        assert v["mean_position_error_m"] == own["validation"]["mean_position_error_m"]
    other = odocal.validate(db, r)
    assert "calibration_drive" not in other and "heading_offset_fit" in other
    joint = odocal.calibrate([da, db])
    for drive, row in zip((da, db), joint.to_dict()["heading_offset_per_drive"]):
        v = odocal.validate(drive, joint)
        assert v["calibration_drive"] is True and v["extrinsics"]["heading_offset"] == row["value"]


def test_drives_that_count_wheel_revolutions_otherwise_are_not_mixed(tmp_path):
    """c_e is per model revolution, which the manifest defines: drives that
    count revolutions otherwise are not calibrated or validated together, the
    parameter file records the scale, and validate warns across scales."""
    from conftest import REPO

    runs = REPO / "examples" / "psu-mapping-van-testtrack"
    text = (runs / "run-15-28-33.toml").read_text()
    assert "ticks_per_rev = 40460.0" in text
    other = tmp_path / "other.toml"
    other.write_text(
        text.replace('"../../data', f'"{REPO}/data').replace("ticks_per_rev = 40460.0", "ticks_per_rev = 40360.0")
    )
    with pytest.warns(UserWarning):
        own = odocal.Drive.from_manifest(runs / "run-14-45-26.toml")
    same = odocal.Drive.from_manifest(runs / "run-15-28-33.toml")
    otherwise = odocal.Drive.from_manifest(other)
    with pytest.raises(odocal.OdocalError, match="count wheel revolutions differently"):
        odocal.calibrate([own, otherwise], "batch-gn")
    with pytest.raises(odocal.OdocalError, match="judged in another unit"):
        odocal.calibrate(own, "batch-gn", validate_on=otherwise)
    report = odocal.calibrate(own, "batch-gn")
    params = tmp_path / "p.yaml"
    report.write_params(params)
    assert 'wheel_scale: "ticks, one model revolution = ticks_per_rev = 40460 ticks' in params.read_text()
    with pytest.warns(UserWarning, match="counts wheel revolutions as"):
        odocal.validate(otherwise, str(params))
    with pytest.warns(UserWarning, match="counts wheel revolutions as"):
        odocal.validate(otherwise, report)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        odocal.validate(same, str(params))
