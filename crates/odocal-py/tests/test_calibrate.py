"""calibrate / validate: the CLI's JSON, options, threads, progress and the GIL."""

import json
import re
import subprocess
import sys
import threading

import numpy as np
import pytest

import odocal
from conftest import REPO

# A quick 3-step calibration (the defaults run 50 batches).
QUICK = {"batches": 6, "picks": 3, "seed": 2}  # three-step options


def without_timing(d):
    d = dict(d)
    d.pop("timing_s")
    return d


def cli_json(odocal_bin, *args):
    out = subprocess.run([str(odocal_bin), *map(str, args), "--json", "-"], capture_output=True, text=True)
    # 3: a rejected calibration, or a θ that does not fit the drive validated on; the JSON is written either way.
    assert out.returncode in (0, 3), out.stderr
    return json.loads(out.stdout)


@pytest.mark.parametrize(
    "method, flags, kwargs",
    [
        ("batch-gn", [], {}),
        ("three-step", ["--batches", "6", "--picks", "3", "--seed", "2"], QUICK),
        (
            "batch-gn",
            ["--fix", "d", "--min-yaw-rate", "0.1", "--theta0", "1.9,0,1.5,0", "--max-iterations", "8",
             "--holdout", "first-half"],
            {"fix": ["d"], "min_yaw_rate": 0.1, "theta0": [1.9, 0, 1.5, 0], "max_iterations": 8,
             "holdout": "first-half"},
        ),
    ],
)
def test_equals_cli_json(odocal_bin, drive_csv, method, flags, kwargs):
    cli = cli_json(odocal_bin, "calibrate", drive_csv, "--method", method, *flags)
    report = odocal.calibrate(odocal.Drive.from_csv(drive_csv), method, **kwargs)
    assert "truth" in cli  # the sidecar is read on both sides
    assert without_timing(report.to_dict()) == without_timing(cli)
    assert without_timing(json.loads(report.to_json())) == without_timing(cli)


def test_manifest_equals_cli_json(odocal_bin):
    manifest = REPO / "examples" / "psu-mapping-van" / "manifest.toml"
    cli = cli_json(odocal_bin, "calibrate", manifest, "--method", "batch-gn", "--holdout", "second-half")
    report = odocal.calibrate(odocal.Drive.from_manifest(manifest), "batch-gn", holdout="second-half")
    assert "wheel_scale" in cli and report.validation["held_out"]
    assert without_timing(report.to_dict()) == without_timing(cli)


def test_manifest_import_warnings_as_the_cli(odocal_bin, tmp_path):
    # A test-track run whose encoder log has a corrupt row: the importer's warning is
    # a Python warning on loading, and the report's `import_warnings` as in the CLI's JSON.
    run = REPO / "examples" / "psu-mapping-van-testtrack" / "run-14-45-26.toml"
    with pytest.warns(UserWarning, match=r"run-14-45-26.toml: streams.encoders: 1 corrupt wheel row"):
        drive = odocal.Drive.from_manifest(run)
    cli = cli_json(odocal_bin, "calibrate", run, "--method", "batch-gn")
    assert cli["import_warnings"] == [f"{run}: {w}" for w in drive.import_report["warnings"]]
    report = odocal.calibrate(drive, "batch-gn")
    assert without_timing(report.to_dict()) == without_timing(cli)
    report.to_html(tmp_path / "r.html")  # the HTML report lists them too, as the CLI's
    warnings = (tmp_path / "r.html").read_text().split('id="warnings"')[1]
    assert "run-14-45-26.toml: streams.encoders: 1 corrupt wheel row" in warnings
    cli = cli_json(odocal_bin, "validate", run, "--theta", "2,0,1.6,0")
    assert odocal.validate(drive, [2, 0, 1.6, 0]) == cli


def test_validate_equals_cli_json(odocal_bin, drive_csv):
    cli = cli_json(odocal_bin, "validate", drive_csv, "--theta", "1.95,-0.002,1.53,0.0008")
    py = odocal.validate(odocal.Drive.from_csv(drive_csv), "1.95,-0.002,1.53,0.0008")
    assert py == cli
    assert odocal.validate(odocal.Drive.from_csv(drive_csv), [1.95, -0.002, 1.53, 0.0008]) == cli


def test_validate_judges_theta_against_the_drive_s_own_fit(small_drive):
    """drive_fit: the drive's own θ fits it, c_d 3 mm off does not; fit_drive=False leaves it out."""
    r = odocal.calibrate(small_drive, "batch-gn")
    fit = odocal.validate(small_drive, r)["drive_fit"]
    assert fit["fits"] and fit["ratio"] <= 1.6 and fit["method"] == "batch-gn", fit
    t = r.theta
    wide = odocal.validate(small_drive, [t["c_e"], t["c_d"] + 0.003, t["t_r"], t["d"]])
    assert not wide["drive_fit"]["fits"] and wide["drive_fit"]["ratio"] > 1.6, wide["drive_fit"]
    assert wide["mean_position_error_m"] == pytest.approx(wide["drive_fit"]["ratio"] * wide["drive_fit"]["mean_position_error_m"])
    assert "drive_fit" not in odocal.validate(small_drive, r, fit_drive=False)


def test_report_shortcuts(small_drive):
    r = odocal.calibrate(small_drive, "batch-gn")
    d = r.to_dict()
    assert r.method == "batch-gn"
    assert r.theta == d["theta"]
    np.testing.assert_array_equal(r.theta_array, [d["theta"][k] for k in odocal.THETA_NAMES])
    c = r.covariance
    assert c.shape == (4, 4)
    np.testing.assert_allclose(c, c.T, rtol=1e-12, atol=0)
    assert all(
        r.model_sigma[k] == pytest.approx(np.sqrt(c[i, i])) and r.model_sigma[k] > 0
        for i, k in enumerate(odocal.THETA_NAMES)
    )
    # The σ that stands for the result is the JSON's.
    assert r.sigma == {k: d["sigma"][k] for k in odocal.THETA_NAMES}
    assert r.result_sigma["source"] == d["sigma"]["source"]
    assert r.validation == d["validation"] and r.mean_position_error_m == d["validation"]["mean_position_error_m"]
    assert r.mean_position_error_m < r.initial["mean_position_error_m"]
    assert r.truth["theta"] == small_drive.theta_true
    assert r.verdict == d.get("verdict")
    assert r.warnings == d["warnings"]
    assert "batch-gn" in repr(r)
    # validate takes a report's θ and agrees with the report's Ē_p
    assert odocal.validate(small_drive, r)["mean_position_error_m"] == r.mean_position_error_m


def test_model_sigma_of_a_held_parameter_is_none_as_in_the_text(small_drive):
    # A held parameter has no model σ: the text prints "held", `sigma` None, never a σ of 0.
    r = odocal.calibrate(small_drive, "batch-gn", fix=["d"])
    assert r.covariance[3, 3] == 0.0
    assert r.model_sigma["d"] is None and r.sigma["d"] is None
    assert all(r.model_sigma[k] > 0 for k in ("c_e", "c_d", "t_r"))


def test_segment_options_too_small_name_the_keyword(small_drive):
    for key, value in [("segment_length", 1), ("segment_stride", 0), ("validation_length", 1)]:
        with pytest.raises(odocal.OdocalError, match=f"^invalid option `{key}`: = {value}: must be at least"):
            odocal.calibrate(small_drive, "batch-gn", **{key: value})
    with pytest.raises(odocal.OdocalError, match="^invalid option `validation_length`: must be at least"):
        odocal.validate(small_drive, [1.95, 0, 1.5, 0], validation_length=1)


def test_option_errors(small_drive):
    with pytest.raises(TypeError, match="unknown option 'batchez'; options: method, theta0, .*, holdout, validate_on, carry_heading_offset$"):
        odocal.calibrate(small_drive, batchez=3)
    with pytest.raises(odocal.OdocalError, match="^invalid option `segment_length`: invalid type: string"):
        odocal.calibrate(small_drive, "batch-gn", segment_length="long")
    with pytest.raises(odocal.OdocalError, match="^invalid option `noise_model`: unknown field.s. wheel_whte"):
        odocal.calibrate(small_drive, noise_model={"wheel_whte_rel_sigma": 0.01})
    with pytest.raises(odocal.OdocalError, match=r"^invalid option `batches`: = 0: must be at least 1$"):
        odocal.calibrate(small_drive, "three-step", batches=0)
    with pytest.raises(odocal.OdocalError, match=r"'newton': use three-step, batch-gn or eiv"):
        odocal.calibrate(small_drive, "newton")
    with pytest.raises(odocal.OdocalError, match="batches, picks apply to method three-step only, not to batch-gn"):
        odocal.calibrate(small_drive, "batch-gn", batches=3, picks=2)
    with pytest.raises(odocal.OdocalError, match="invalid parameter 'c_x': use c_e, c_d, t_r or d"):
        odocal.calibrate(small_drive, fix="c_x")
    with pytest.raises(odocal.OdocalError, match="t_r = -1 m must be positive"):
        odocal.calibrate(small_drive, theta0={"c_e": 2.0, "c_d": 0.0, "t_r": -1.0, "d": 0.0})
    with pytest.raises(odocal.OdocalError, match="invalid QP solver .osqp.: use structured or clarabel"):
        odocal.calibrate(small_drive, "three-step", qp_solver="osqp")
    with pytest.raises(odocal.OdocalError, match="threads"):
        odocal.calibrate(small_drive, "batch-gn", threads=0)
    with pytest.raises(odocal.OdocalError, match=r"`fix`: holds every parameter of θ: .*odocal.validate"):
        odocal.calibrate(small_drive, "batch-gn", fix="c_e,c_d,t_r,d")
    # A negative seed or count: an OdocalError saying so, not OverflowError's "can't convert negative int".
    with pytest.raises(odocal.OdocalError, match="seed = -1 is not a seed, an integer 0 … 2"):
        odocal.simulate(seed=-1, length_km=1.0)
    with pytest.raises(odocal.OdocalError, match="threads is a number of worker threads, 1 … 1024, got -2"):
        odocal.calibrate(small_drive, "batch-gn", threads=-2)
    with pytest.raises(odocal.OdocalError, match="a count is an integer 0 … 2\\^64 − 1, got -3"):
        odocal.simulate(length_km=1.0, substeps=-3)


def test_an_option_of_another_method_is_named_as_the_option(small_drive):
    """The option at fault is the one named in the prefix, not the method the caller chose."""
    with pytest.raises(odocal.OdocalError,
                       match="^invalid option `batches`: batches applies to method three-step only, not to eiv$"):
        odocal.calibrate(small_drive, batches=5)
    with pytest.raises(odocal.OdocalError, match="^invalid option `min_yaw_rate`: min_yaw_rate applies to the "
                                                 "segment-selecting methods"):
        odocal.calibrate(small_drive, min_yaw_rate=0.1)
    with pytest.raises(odocal.OdocalError, match="^invalid option `fix_noise`: fix_noise, fallback apply to method "
                                                 "eiv only, not to batch-gn$"):
        odocal.calibrate(small_drive, "batch-gn", fix_noise=True, fallback=False)


def test_errors_of_values_are_odocal_errors(small_drive):
    """Every bad value raises OdocalError (a ValueError), as the docs say."""
    nan = float("nan")
    cases = [
        lambda: odocal.calibrate(small_drive, "batch-gn", threads=0),
        lambda: odocal.calibrate(small_drive, "batch-gn", threads=-1),
        lambda: odocal.calibrate(small_drive, "batch-gn", threads=1025),
        lambda: odocal.validate(small_drive, "2,0,1.6,0", threads=1025),
        lambda: odocal.calibrate(small_drive, "batch-gn", theta0=[nan, 0.0, 1.6, 0.0]),
        lambda: odocal.validate(small_drive, [nan, 0.0, 1.6, 0.0]),
        lambda: odocal.simulate(seed=-1, length_km=0.5),
        lambda: odocal.validate(small_drive, [2.0, 0.0, 1.6, 0.0], validation_length=-1),
        lambda: odocal.validate(small_drive, [2.0, 0.0, 1.6, 0.0], params_node="odocal"),
        lambda: odocal.online.Calibrator().decide(),
        lambda: odocal.online.Calibrator(sample_time_s=0.01).push_drive(small_drive),
    ]
    for case in cases:
        with pytest.raises(odocal.OdocalError):
            case()
    with pytest.raises(odocal.OdocalError, match="^threads is a number of worker threads, 1 … 1024, got 1025"):
        odocal.calibrate(small_drive, "batch-gn", threads=1025)
    with pytest.raises(odocal.OdocalError, match="^θ: NaN is not a finite number$"):
        odocal.validate(small_drive, [nan, 0.0, 1.6, 0.0])


def test_a_seed_is_an_integer_of_64_bits(small_drive):
    """A seed beyond 64 bits, negative or a fraction is refused naming the range, as simulate's seed is."""
    three_step = {k: v for k, v in QUICK.items() if k != "seed"}
    for bad in (2**64, -1, 1.5, 2**70):
        message = "^" + re.escape(f"seed = {bad} is not a seed, an integer 0 … 2^64 − 1 (18446744073709551615)")
        with pytest.raises(odocal.OdocalError, match=message):
            odocal.calibrate(small_drive, "three-step", seed=bad, **three_step)
        with pytest.raises(odocal.OdocalError, match=message):
            odocal.simulate(seed=bad, length_km=0.5)
    with pytest.raises(odocal.OdocalError, match=re.escape("bootstrap_seed = -1 is not a seed")):
        odocal.calibrate(small_drive, bootstrap=2, bootstrap_seed=-1)
    assert len(odocal.simulate(seed=2**64 - 1, length_km=0.5)) > 0
    # Beyond 64 bits elsewhere: refused as such, not turned into a float.
    with pytest.raises(odocal.OdocalError, match="max_iterations: 18446744073709551616 is beyond the integers"):
        odocal.calibrate(small_drive, "batch-gn", max_iterations=2**64)


def test_theta0_takes_a_report_and_is_checked_as_every_theta(small_drive):
    """theta0 takes a CalibrationReport (its θ), as validate does; a dict is checked as the other forms of θ:
    a key other than the four and a value beyond the physical limits are refused."""
    first = odocal.calibrate(small_drive, "batch-gn")
    again = odocal.calibrate(small_drive, "batch-gn", theta0=first)
    assert again.initial["theta"] == first.theta
    assert again.theta == odocal.calibrate(small_drive, "batch-gn", theta0=first.theta).theta
    with pytest.raises(odocal.OdocalError, match="^invalid option `theta0`: .*unknown key 'x': θ has c_e, c_d, t_r and d"):
        odocal.calibrate(small_drive, "batch-gn", theta0={**first.theta, "x": 1.0})
    huge = {"c_e": 2000.0, "c_d": 0.0, "t_r": 1.6, "d": 0.0}
    with pytest.raises(odocal.OdocalError, match="c_e = 2000 m is outside 0.05 … 20 m"):
        odocal.calibrate(small_drive, "batch-gn", theta0=huge)
    with pytest.raises(odocal.OdocalError, match="c_e = 2000 m is outside 0.05 … 20 m"):
        odocal.validate(small_drive, huge)


def test_default_method_is_eiv(small_drive):
    r = odocal.calibrate(small_drive)
    d = r.to_dict()
    assert r.method == "eiv" and d["options"]["method"]["name"] == "eiv"
    assert d["eiv_result"] in ("eiv", "batch-gn-fallback")
    with pytest.raises(odocal.OdocalError, match="batches applies to method three-step only, not to eiv"):
        odocal.calibrate(small_drive, batches=3)


def test_not_observable_is_library_error():
    straight = odocal.simulate(seed=1, length_km=1.0)
    with pytest.raises(odocal.OdocalError, match="not observable"):
        odocal.calibrate(straight, "batch-gn", min_yaw_rate=5.0)
    r = odocal.calibrate(straight, "batch-gn", min_yaw_rate=5.0, auto_fix=True)
    assert r.to_dict()["auto_fixed"] == ["c_d", "t_r", "d"]


def test_thread_count_independent(small_drive):
    one = odocal.calibrate(small_drive, "three-step", threads=1, **QUICK).to_dict()
    two = odocal.calibrate(small_drive, "three-step", threads=2, **QUICK).to_dict()
    assert without_timing(one) == without_timing(two)


def test_progress_on_calling_thread(small_drive):
    calls = []
    me = threading.get_ident()

    def progress(stage, done, total):
        calls.append((threading.get_ident(), stage, done, total))

    r = odocal.calibrate(small_drive, "three-step", progress=progress, **QUICK)
    assert calls, "the progress callback was never called"
    assert {c[0] for c in calls} == {me}
    stages = [c[1] for c in calls]
    assert "compensation" in stages
    for _, stage, done, total in calls:
        assert 0 <= done <= total
    last_comp = [c for c in calls if c[1] == "compensation"][-1]
    assert last_comp[2] == last_comp[3] == r.to_dict()["compensation"]["jobs"]


def test_progress_exception_is_raised(small_drive):
    class Stop(Exception):
        pass

    def progress(stage, done, total):
        raise Stop(stage)

    with pytest.raises(Stop):
        odocal.calibrate(small_drive, "batch-gn", progress=progress)


def test_gil_released_during_calibration(small_drive):
    """Another Python thread keeps running while a calibration runs.

    The switch interval is raised so that the calling thread never hands the
    GIL over on its own: the counter can then only advance during the call
    if the binding released the GIL. The counting thread gives the GIL back
    at every step (sleep(0)), so the calling thread gets it back at once.
    """
    counter = [0]
    started = threading.Event()
    stop = threading.Event()

    def count():
        import time

        while not stop.is_set():
            counter[0] += 1
            started.set()
            time.sleep(0)

    old = sys.getswitchinterval()
    th = threading.Thread(target=count, daemon=True)
    th.start()
    try:
        assert started.wait(10)
        sys.setswitchinterval(100.0)
        before = counter[0]
        odocal.calibrate(small_drive, "three-step", **QUICK)
        after = counter[0]
    finally:
        sys.setswitchinterval(old)
        stop.set()
        th.join()
    assert after > before, "no other Python thread ran during the calibration: the GIL was held"


def test_to_html(small_drive, tmp_path):
    r = odocal.calibrate(small_drive, "three-step", **QUICK)
    out = tmp_path / "report.html"
    r.to_html(out, title="car 3")
    html = out.read_text()
    assert html.startswith("<!DOCTYPE html>")
    assert "car 3" in html and "<svg" in html and 'id="map"' in html
    held = odocal.calibrate(small_drive, "batch-gn", holdout="second-half")
    held.to_html(tmp_path / "held.html")
    assert (tmp_path / "held.html").stat().st_size > 1000
    with pytest.raises(ValueError, match="no drive"):
        odocal.CalibrationReport(r.to_dict(), r.to_json()).to_html(tmp_path / "x.html")


def _without_eiv_timing(d):
    d = without_timing(d)
    d["eiv"] = dict(d["eiv"])
    d["eiv"].pop("timing_s")
    return d


def test_eiv_equals_cli_json(odocal_bin, drive_csv):
    shape = ["--quantisation", "counting", "--heading-noise", "separate", "--quantisation-level", "from-readings"]
    cli = cli_json(odocal_bin, "calibrate", drive_csv, "--method", "eiv", "--fix-noise", "--eiv-window", "1500", *shape)
    report = odocal.calibrate(
        odocal.Drive.from_csv(drive_csv),
        method="eiv",
        fix_noise=True,
        eiv_window=1500,
        quantisation="counting",
        heading_noise="separate",
        quantisation_level="from-readings",
    )
    d = report.to_dict()
    assert report.method == "eiv" and d["eiv_result"] in ("eiv", "batch-gn-fallback")
    filt = d["options"]["method"]["filter"]
    assert (filt["quantisation"], filt["heading_scale"], filt["quantisation_level"]) == ("counting", "separate", "from_readings")
    assert d["eiv"]["noise"]["wheel_white_rel_sigma"] == d["noise_start"]["wheel_white_rel_sigma"]  # fixed
    assert "reason" in d["eiv"]["termination"]
    assert _without_eiv_timing(d) == _without_eiv_timing(cli)
    with pytest.raises(odocal.OdocalError, match="fix_noise applies to method eiv only, not to batch-gn"):
        odocal.calibrate(odocal.Drive.from_csv(drive_csv), "batch-gn", fix_noise=True)
    with pytest.raises(odocal.OdocalError, match="invalid quantisation model 'ticks': use process, measurement or counting"):
        odocal.calibrate(odocal.Drive.from_csv(drive_csv), "eiv", quantisation="ticks")
    with pytest.raises(odocal.OdocalError, match="invalid quantisation level 'auto': use scaled, given or from-readings"):
        odocal.calibrate(odocal.Drive.from_csv(drive_csv), "eiv", quantisation_level="auto")
    stated = odocal.calibrate(odocal.Drive.from_csv(drive_csv), eiv_window=1500, lateral_noise="stated").to_dict()
    assert stated["options"]["method"]["filter"]["lateral_noise"] == "stated"
    assert stated["eiv"]["noise"]["sideslip_sigma_rad"] == stated["noise_start"]["sideslip_sigma_rad"]
    with pytest.raises(odocal.OdocalError, match="invalid lateral noise 'free': use tied or stated"):
        odocal.calibrate(odocal.Drive.from_csv(drive_csv), lateral_noise="free")
    with pytest.raises(odocal.OdocalError, match="heading_noise applies to method eiv only"):
        odocal.calibrate(odocal.Drive.from_csv(drive_csv), "batch-gn", heading_noise="tied")


def test_known_noise_equals_cli_json(odocal_bin, drive_csv):
    cli = cli_json(odocal_bin, "calibrate", drive_csv, "--eiv-window", "1500", "--known-noise", "pose-white")
    report = odocal.calibrate(odocal.Drive.from_csv(drive_csv), eiv_window=1500, known_noise=["pose_white"])
    d = report.to_dict()
    assert d["options"]["method"]["filter"]["eta_held"] == [False] * 3 + [True] + [False] * 2
    assert _without_eiv_timing(d) == _without_eiv_timing(cli)
    # The EIV account: the same lines as the CLI's terminal output, and in the HTML report.
    details = report.method_details
    assert details.startswith("EIV: ") and "  known (held at the start): pose_white\n" in details, details
    text = subprocess.run(
        [str(odocal_bin), "calibrate", str(drive_csv), "--eiv-window", "1500", "--known-noise", "pose-white"],
        capture_output=True,
        text=True,
    )
    assert text.returncode in (0, 3), text.stderr
    assert details in text.stdout, (details, text.stdout)
    report.to_html(drive_csv.parent / "eiv.html")
    html = (drive_csv.parent / "eiv.html").read_text()
    assert "<h2>Method details</h2>" in html and "known (held at the start): pose_white" in html
    gn = odocal.calibrate(odocal.Drive.from_csv(drive_csv), "batch-gn").method_details
    assert gn.startswith("batch G-N: ") and " it, " in gn, gn
    same = odocal.calibrate(odocal.Drive.from_csv(drive_csv), eiv_window=1500, known_noise="pose-white")
    assert _without_eiv_timing(same.to_dict()) == _without_eiv_timing(d)
    with pytest.raises(odocal.OdocalError, match="invalid noise source 'heading'"):
        odocal.calibrate(odocal.Drive.from_csv(drive_csv), known_noise=["heading"])
    with pytest.raises(odocal.OdocalError, match="known_noise applies to method eiv only"):
        odocal.calibrate(odocal.Drive.from_csv(drive_csv), "batch-gn", known_noise="heading_white")


def test_correct_bias_equals_cli_json(odocal_bin, drive_csv):
    """correct_bias=B is --correct-bias B, correct_bias_of= --correct-bias-of, correct_bias=0
    --no-bias-correction, and the default (B = 4, c_e and c_d) the CLI's: the named parameters corrected, their σ with
    the correction's Monte Carlo error."""
    args = ("calibrate", drive_csv, "--eiv-window", "1500", "--no-fallback")
    drive = odocal.Drive.from_csv(drive_csv)
    cli = cli_json(odocal_bin, *args, "--correct-bias", "2", "--bootstrap-seed", "5", "--correct-bias-of", "c_e,c_d,t_r,d")
    d = odocal.calibrate(
        drive, eiv_window=1500, fallback=False, correct_bias=2, bootstrap_seed=5, correct_bias_of=["c_e", "c_d", "t_r", "d"]
    ).to_dict()
    assert _without_eiv_timing(d) == _without_eiv_timing(cli)
    assert d["options"]["method"]["correct_bias"] == {"replicates": 2, "seed": 5, "parameters": ["c_e", "c_d", "t_r", "d"]}
    cli_plain = cli_json(odocal_bin, *args, "--no-bias-correction")
    plain = odocal.calibrate(drive, eiv_window=1500, fallback=False, correct_bias=0).to_dict()
    assert _without_eiv_timing(plain) == _without_eiv_timing(cli_plain)
    assert plain["options"]["method"]["correct_bias"] is None
    default = odocal.calibrate(drive, eiv_window=1500, fallback=False, bootstrap_seed=3).to_dict()
    assert _without_eiv_timing(default) == _without_eiv_timing(cli_json(odocal_bin, *args, "--bootstrap-seed", "3"))
    assert default["options"]["method"]["correct_bias"] == {"replicates": 4, "seed": 3, "parameters": ["c_e", "c_d"]}
    for c, corrected in ((d, [True] * 4), (default, [True, True, False, False])):
        e, p = c["eiv"], plain["eiv"]
        assert e["theta_uncorrected"] == p["theta"]
        for i, free in enumerate(e["free"]):
            on = free and corrected[i]
            assert (e["sigma_bias_correction"][i] > 0) == on
            if on:
                assert e["sigma"][i] ** 2 == pytest.approx(p["sigma"][i] ** 2 + e["sigma_bias_correction"][i] ** 2)
            else:
                name = ("c_e", "c_d", "t_r", "d")[i]
                assert (e["theta"][name], e["sigma"][i]) == (p["theta"][name], p["sigma"][i])
    with pytest.raises(odocal.OdocalError, match="bootstrap_seed`: is the seed of the bias correction"):
        odocal.calibrate(drive, eiv_window=1500, correct_bias=0, bootstrap_seed=5)
    with pytest.raises(odocal.OdocalError, match="correct_bias`: = 3: must be 0 .no correction. or an even number"):
        odocal.calibrate(drive, eiv_window=1500, correct_bias=3)
    with pytest.raises(odocal.OdocalError, match="correct_bias applies to method eiv only"):
        odocal.calibrate(drive, "batch-gn", correct_bias=2)


def test_params_files_round_trip_and_equal_the_cli(odocal_bin, drive_csv, tmp_path):
    """write_params writes what `--params-out` writes; read_params and every θ argument read it back."""
    drive = odocal.Drive.from_csv(drive_csv)
    report = odocal.calibrate(drive, eiv_window=1500)
    for name in ("p.yaml", "p.json"):
        ours, theirs = tmp_path / ("py-" + name), tmp_path / ("cli-" + name)
        report.write_params(ours)  # provenance.input: the drive's file, as the CLI's
        out = subprocess.run(
            [str(odocal_bin), "calibrate", str(drive_csv), "--eiv-window", "1500", "--params-out", str(theirs)],
            capture_output=True,
            text=True,
        )
        assert out.returncode in (0, 3), out.stderr
        # The same file but for the date line (a run across midnight UTC).
        undated = lambda p: [l for l in p.read_text().splitlines() if '"date"' not in l and "date:" not in l]
        assert undated(ours) == undated(theirs)
        back = odocal.read_params(ours)
        params = back["parameters"]
        assert [params[k] for k in odocal.THETA_NAMES] == [report.theta[k] for k in odocal.THETA_NAMES]
        rs = report.result_sigma
        assert rs["covers"] == "next-drive"
        within = report.within_drive_sigma
        assert within["covers"] == "within-drive"
        for k in odocal.THETA_NAMES:
            assert params.get(k + "_sigma") == rs[k], (k, params, rs)
            if rs[k] is not None and within[k] is not None:
                assert rs[k] >= within[k], (k, rs, within)
        assert back["provenance"]["sigma_covers"] == "σ for the next drive: within-drive ⊕ between-drive"
        assert back["verdict"] == report.verdict["level"]
        # A file is a θ: validate takes its θ and the heading offset its calibration estimated;
        # carried, it gives the calibration's own Ē_p to the bit; the bare θ (no offset) does not.
        v = odocal.validate(drive, ours, carry_heading_offset=True)
        assert v["mean_position_error_m"] == report.mean_position_error_m
        assert v["extrinsics"]["heading_offset"] == params["heading_offset"] != 0.0
        assert "heading_offset_fit" not in v
        bare = ",".join(repr(report.theta[k]) for k in odocal.THETA_NAMES)
        assert odocal.validate(drive, bare)["mean_position_error_m"] != report.mean_position_error_m
        carried = odocal.validate(drive, str(ours), carry_heading_offset=True)
        assert carried["mean_position_error_m"] == report.mean_position_error_m
        # The report itself as θ carries the same extrinsics.
        carried = odocal.validate(drive, report, carry_heading_offset=True)
        assert carried["mean_position_error_m"] == report.mean_position_error_m
        # On the calibration's own drive the default holds its heading offset for that drive too.
        own = odocal.validate(drive, ours)
        assert own["calibration_drive"] is True and "heading_offset_fit" not in own
        assert own["mean_position_error_m"] == report.mean_position_error_m
    bad = tmp_path / "bad.yaml"
    bad.write_text("odocal:\n  ros__parameters:\n    c_e: 1.95\n")
    with pytest.raises(odocal.OdocalError, match="bad.yaml: node `odocal`: no `c_d`"):
        odocal.validate(drive, bad)
    with pytest.raises(odocal.OdocalError, match="no `c_d`"):
        odocal.read_params(bad)


def test_params_files_are_checked_and_several_nodes_need_params_node(drive_csv, tmp_path):
    """A parameter file's extrinsics get the plausibility checks; a file with two nodes needs params_node."""
    drive = odocal.Drive.from_csv(drive_csv)
    node = "{n}:\n  ros__parameters:\n    c_e: 2.0\n    c_d: 0.0\n    t_r: 1.6\n    d: 0.0\n{extra}"
    lever = tmp_path / "lever.yaml"
    lever.write_text(node.format(n="odocal", extra="    lever_x: 1.0e300\n"))
    with pytest.raises(odocal.OdocalError, match="key `lever_x`: .* not within ±20 m"):
        odocal.validate(drive, lever)
    two = tmp_path / "two.yaml"
    two.write_text(node.format(n="a", extra="") + node.format(n="b", extra="    lever_x: 0.5\n"))
    with pytest.raises(odocal.OdocalError, match="several nodes hold odocal's parameters .*params_node="):
        odocal.read_params(two)
    with pytest.raises(odocal.OdocalError, match="several nodes"):
        odocal.validate(drive, two)
    assert odocal.read_params(two, params_node="b")["parameters"]["lever_x"] == 0.5
    assert odocal.validate(drive, two, params_node="b")["extrinsics"]["lever_x"] == 0.5
