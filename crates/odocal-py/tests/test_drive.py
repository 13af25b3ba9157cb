"""Drive: arrays <-> Drive round trips and the library's checks on bad arrays."""

import pickle
import re
import tracemalloc

import numpy as np
import pytest

import odocal


def columns(drive):
    a = drive.to_numpy()
    return {name: a[:, i].copy() for i, name in enumerate(drive.columns)}


def from_columns(c, **kw):
    return odocal.Drive.from_arrays(
        c["t"], c["px"], c["py"], c["psi"], c["n_rl"], c["n_rr"], c["a_y"], beta=c["beta"], **kw
    )


def test_columns_and_shape(small_drive):
    a = small_drive.to_numpy()
    assert small_drive.columns == ["t", "px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"] == odocal.COLUMNS
    assert a.shape == (len(small_drive), 8)
    assert a.dtype == np.float64
    np.testing.assert_array_equal(a[:, 4], small_drive.column("n_rl"))
    assert small_drive.column("n_rl_true").shape == (len(small_drive),)
    with pytest.raises(KeyError, match="no numeric column 'nope'"):
        small_drive.column("nope")


def test_round_trip_arrays(small_drive):
    c = columns(small_drive)
    back = from_columns(c)
    np.testing.assert_array_equal(back.to_numpy(), small_drive.to_numpy())
    assert back.sample_time_s == pytest.approx(small_drive.sample_time_s, rel=1e-12)
    assert back.parts == [(0, len(small_drive))]
    assert back.theta_true is None  # arrays carry no truth
    # With the nominal sample time the drive is the same to the bit, so it calibrates the same.
    exact = from_columns(c, sample_time_s=small_drive.sample_time_s)
    assert exact.sample_time_s == small_drive.sample_time_s
    a = odocal.calibrate(exact, method="batch-gn").theta
    b = odocal.calibrate(small_drive, method="batch-gn").theta
    assert a == b


def test_lists_ints_default_beta_and_parts():
    n = 200
    t = [k * 0.025 for k in range(n)]
    x = np.arange(n) * 0.25  # 10 m/s
    ones = [1] * n  # integers are converted to float64
    part = [7] * 120 + [9] * 80
    d = odocal.Drive.from_arrays(t, x, np.zeros(n), np.zeros(n), [5] * n, [5] * n, np.zeros(n), part=part)
    assert len(d) == n
    np.testing.assert_array_equal(d.column("beta"), np.zeros(n))
    np.testing.assert_array_equal(d.column("n_rl"), np.asarray(ones) * 5.0)
    assert d.parts == [(0, 120), (120, 200)]
    np.testing.assert_array_equal(d.part_ids(), [0] * 120 + [1] * 80)
    back = from_columns(columns(d), part=d.part_ids())
    assert back.parts == d.parts


def test_heading_is_unwrapped(small_drive):
    c = columns(small_drive)
    wrapped = np.angle(np.exp(1j * c["psi"]))
    assert np.abs(wrapped - c["psi"]).max() > 1.0  # the route turns more than π
    back = from_columns({**c, "psi": wrapped})
    np.testing.assert_allclose(back.column("psi"), c["psi"], rtol=0, atol=1e-9)


def _bad(c, **changes):
    return from_columns({**c, **changes})


def test_nan_names_column_and_sample(small_drive):
    c = columns(small_drive)
    n_rl = c["n_rl"].copy()
    n_rl[7] = np.nan
    with pytest.raises(odocal.OdocalError) as e:
        _bad(c, n_rl=n_rl)
    assert str(e.value) == "numpy arrays: column 'n_rl', sample 7: value NaN is not finite"
    assert isinstance(e.value, ValueError)


def test_length_mismatch(small_drive):
    c = columns(small_drive)
    with pytest.raises(odocal.OdocalError, match=r"^numpy arrays: column n_rr has \d+ samples, t has \d+$"):
        _bad(c, n_rr=c["n_rr"][:-1])


def test_time_not_increasing(small_drive):
    c = columns(small_drive)
    t = c["t"].copy()
    t[5] = t[4]
    with pytest.raises(odocal.OdocalError, match=r"^numpy arrays: column 't', sample 5: time is not strictly increasing"):
        _bad(c, t=t)


def test_non_uniform_time(small_drive):
    c = columns(small_drive)
    t = c["t"].copy()
    t[100:] += 0.01
    with pytest.raises(odocal.OdocalError, match=re.escape("numpy arrays: column 't', sample 100: sample step")):
        _bad(c, t=t)


def test_not_one_dimensional(small_drive):
    """A column that is not 1-D raises OdocalError naming the argument, its shape and the
    1-D array of N samples expected (numpy's bare "dimensionality mismatch" named none)."""
    c = columns(small_drive)
    n = len(small_drive)
    two = np.stack([c["px"], c["px"]])
    with pytest.raises(odocal.OdocalError, match=re.escape(
            f"px: got a ndarray of shape (2, {n}), where a 1-D array of {n} samples (one value per sample, "
            "as t) is expected")):
        _bad(c, px=two)
    with pytest.raises(odocal.OdocalError, match=re.escape(f"t: got a ndarray of shape ({n}, 1), where a 1-D array")):
        _bad(c, t=c["t"][:, None])
    with pytest.raises(odocal.OdocalError, match=re.escape("a_y: got a float of shape (), where a 1-D array")):
        _bad(c, a_y=3.0)
    with pytest.raises(odocal.OdocalError, match=re.escape(f"beta: got a list of shape ({n}, 2)")):
        _bad(c, beta=[[0.0, 0.0]] * n)
    with pytest.raises(odocal.OdocalError, match=re.escape(f"part: got a ndarray of shape ({n}, 1)")):
        from_columns(c, part=np.zeros((n, 1), dtype=np.int64))
    with pytest.raises(odocal.OdocalError, match="^n_rr: could not convert string to float: 'x'; a 1-D array"):
        _bad(c, n_rr=["x"] * n)
    # Lengths that differ and values that are not finite: the library's errors, naming the column.
    with pytest.raises(odocal.OdocalError, match=f"column py has {n - 1} samples, t has {n}"):
        _bad(c, py=c["py"][:-1])
    inf = c["psi"].copy()
    inf[3] = np.inf
    with pytest.raises(odocal.OdocalError, match="column 'psi', sample 3: value inf is not finite"):
        _bad(c, psi=inf)


def test_csv_round_trip(small_drive, drive_csv):
    back = odocal.Drive.from_csv(drive_csv)
    np.testing.assert_array_equal(back.to_numpy(), small_drive.to_numpy())
    assert back.theta_true == small_drive.theta_true == {"c_e": 1.95, "c_d": -0.002, "t_r": 1.53, "d": 0.0008}
    assert odocal.Drive.load(drive_csv).parts == back.parts


def test_csv_errors_are_library_errors(tmp_path):
    with pytest.raises(odocal.OdocalError, match="nope.csv"):
        odocal.Drive.from_csv(tmp_path / "nope.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("t,px,py,psi,n_rl,n_rr,beta,a_y\n0,0,0,0,5,5,0,0\n0.025,0.25,0,0,x,5,0,0\n")
    with pytest.raises(odocal.OdocalError, match=r"bad.csv: line 3, column 'n_rl'"):
        odocal.Drive.from_csv(bad)


def test_pickle_is_exact(small_drive):
    back = pickle.loads(pickle.dumps(small_drive))
    np.testing.assert_array_equal(back.to_numpy(), small_drive.to_numpy())
    np.testing.assert_array_equal(back.column("px_true"), small_drive.column("px_true"))
    assert back.sample_time_s == small_drive.sample_time_s
    assert back.theta_true == small_drive.theta_true
    assert back.simulation == small_drive.simulation
    a = odocal.calibrate(back, method="batch-gn").to_dict()
    b = odocal.calibrate(small_drive, method="batch-gn").to_dict()
    a.pop("timing_s"), b.pop("timing_s")
    assert a == b


def test_manifest():
    from conftest import REPO

    manifest = REPO / "examples" / "psu-mapping-van" / "manifest.toml"
    d = odocal.Drive.from_manifest(manifest)
    assert len(d) > 1000 and len(d.parts) >= 1
    assert d.import_report["samples"] == len(d)
    assert d.theta_true is None


def test_from_arrays_refuses_a_huge_size_before_copying():
    """A huge column raises OdocalError before anything is copied (a zero-stride view costs no memory)."""
    big = np.broadcast_to(0.0, (60_000_000,))
    with pytest.raises(odocal.OdocalError, match="^t has 60000000 samples, more than the 50000000 a drive from"):
        odocal.Drive.from_arrays(big, big, big, big, big, big, big)


def test_from_arrays_checks_the_size_before_numpy_converts():
    """An int32 column numpy would first convert to float64 (400 MB for 50,000,001 samples) is measured
    before the conversion: refused with no copy made (numpy reports its buffers to tracemalloc)."""
    big = np.broadcast_to(np.int32(0), (50_000_001,))  # a zero-stride view: no memory of its own
    view = np.broadcast_to(0.0, (50_000_001,))  # float64: numpy would not copy it
    small = np.zeros(10)
    tracemalloc.start()
    try:
        with pytest.raises(odocal.OdocalError, match="^t has 50000001 samples, more than the 50000000"):
            odocal.Drive.from_arrays(big, view, view, view, view, view, view)
        # Any argument (part too), before any is converted.
        with pytest.raises(odocal.OdocalError, match="^part has 50000001 samples"):
            odocal.Drive.from_arrays(small, small, small, small, small, small, small, part=big)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, f"{peak / 1e6:.0f} MB allocated before refusing"


def test_tracemalloc_sees_numpy_conversions():
    """The check above can fail: a conversion of an int32 array to float64 shows in tracemalloc's peak."""
    a = np.zeros(2_000_000, dtype=np.int32)
    tracemalloc.start()
    try:
        np.asarray(a, dtype=np.float64)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak >= 16e6


def test_part_ids_are_whole_non_negative_numbers():
    """Part ids are read as the CSV's `part` column: whole numbers 0, 1, 2, … (floats only when whole);
    a fraction, a negative id or a bool is refused naming the sample, not truncated or taken."""
    n = 200
    t = np.arange(n) * 0.025
    x = np.arange(n) * 0.25
    z = np.zeros(n)

    def make(part):
        return odocal.Drive.from_arrays(t, x, z, z, [5.0] * n, [5.0] * n, z, part=part)

    assert make([0.0] * 120 + [1.0] * 80).parts == [(0, 120), (120, 200)]
    assert make(np.array([3] * 120 + [2] * 80, dtype=np.uint8)).parts == [(0, 120), (120, 200)]
    for part, shown in [([0.5] * n, "0.5"), ([0] * 120 + [1.5] * 80, "1.5"), ([0] * 120 + [-1] * 80, "-1"),
                        ([0.0] * 120 + [-1.0] * 80, "-1"), ([0.0] * 120 + [np.nan] * 80, "NaN")]:
        sample = 0 if shown == "0.5" else 120
        with pytest.raises(odocal.OdocalError, match=re.escape(
                f"numpy arrays: column 'part', sample {sample}: part id {shown} is not a non-negative integer "
                "(parts are numbered 0, 1, 2, …)")):
            make(part)
    with pytest.raises(odocal.OdocalError, match="part: got an array of numpy dtype bool, where integer part ids"):
        make([True] * 120 + [False] * 80)


def test_complex_numbers_and_extra_theta_keys_are_refused(small_drive):
    with pytest.raises(TypeError, match="a complex number is not a real number"):
        odocal.validate(small_drive, [2 + 0j, 0.0, 1.6, 0.0])
    with pytest.raises(odocal.OdocalError, match="unknown key 'lever'"):
        odocal.validate(small_drive, {"c_e": 2.0, "c_d": 0.0, "t_r": 1.6, "d": 0.0, "lever": 1.0})
    with pytest.raises(odocal.OdocalError, match="threads is a number of worker threads, 1 … 1024, got 100000"):
        odocal.validate(small_drive, "2,0,1.6,0", threads=100000)


def test_bools_where_numbers_are_expected_are_type_errors(small_drive):
    """True and False are ints to Python: as θ values or numeric options they raise TypeError naming the key."""
    with pytest.raises(TypeError, match=r"θ: c_d = True \(item 1\) is a bool, not a number"):
        odocal.validate(small_drive, [2.0, True, 1.6, 0.0])
    with pytest.raises(TypeError, match=r"θ: d = False is a bool, not a number"):
        odocal.validate(small_drive, {"c_e": 2.0, "c_d": 0.0, "t_r": 1.6, "d": False})
    with pytest.raises(TypeError, match=r"theta0: \[2.0,0.0,true,0.0\] holds a bool where a number is expected"):
        odocal.calibrate(small_drive, theta0=[2.0, 0.0, True, 0.0])
    with pytest.raises(TypeError, match=r"bootstrap: true holds a bool where a number is expected"):
        odocal.calibrate(small_drive, bootstrap=True)


def test_bools_for_counts_and_reals_are_type_errors(small_drive):
    """Keyword arguments typed as counts or reals refuse True/False, naming the argument."""
    cases = [
        lambda: odocal.calibrate(small_drive, method="batch-gn", threads=True),
        lambda: odocal.validate(small_drive, "2,0,1.6,0", threads=False),
        lambda: odocal.validate(small_drive, "2,0,1.6,0", validation_length=True),
        lambda: odocal.simulate(seed=True, length_km=0.5),
        lambda: odocal.simulate(length_km=True),
        lambda: odocal.simulate(length_km=0.5, substeps=True),
        lambda: from_columns(columns(small_drive), sample_time_s=True),
        lambda: odocal.online.Calibrator(sample_time_s=True),
        lambda: odocal.online.Calibrator().push_drive(small_drive, chunk=True),
    ]
    for case in cases:
        with pytest.raises(TypeError, match="not the bool"):
            case()
    # Ints stay numbers where reals are asked for.
    assert odocal.simulate(seed=1, length_km=1).sample_time_s > 0
