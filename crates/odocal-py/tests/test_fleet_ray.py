"""examples/fleet_ray.py on a local Ray of 2 CPUs: the same θ as serial calls."""

import csv
import importlib.util
import os

import pytest

import odocal
from conftest import REPO

os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
# On a busy 2-core machine the local raylet can take more than Ray's default
# wait to register (seen: "The current node timed out during startup").
os.environ.setdefault("RAY_raylet_start_wait_time_s", "300")
try:
    import ray  # noqa: F401
except ImportError as e:  # pragma: no cover - depends on the environment
    pytest.skip(f"ray is not installed ({e}); pip install ray to run the fleet example test", allow_module_level=True)

# Batch G-N (`--method`): the test checks the distribution of the
# calibrations (the same θ, σ and rows as serial calls), which does not
# depend on the method, and the fastest method keeps the Ray test short.
METHOD = "batch-gn"
OPTIONS = {"min_yaw_rate": 0.12}  # -o passes options through (one batch G-N uses)


def load_example():
    spec = importlib.util.spec_from_file_location("fleet_ray", REPO / "examples" / "fleet_ray.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def fleet_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fleet")
    for seed in range(1, 5):
        odocal.simulate(seed=seed, length_km=2.0).to_csv(d / f"car{seed}.csv")
    (d / "notes.txt").write_text("not a drive\n")
    return d


@pytest.fixture(scope="module")
def local_ray():
    fleet = load_example()
    fleet.init_ray(num_cpus=2, object_store_memory=100 * 1024 * 1024)
    yield fleet
    ray.shutdown()


def test_find_drives(fleet_dir):
    fleet = load_example()
    paths = fleet.find_drives([fleet_dir])
    assert [p.name for p in paths] == ["car1.csv", "car2.csv", "car3.csv", "car4.csv"]
    with pytest.raises(FileNotFoundError):
        fleet.find_drives([fleet_dir / "missing"])


def test_command_line_mistakes_end_with_a_message_and_keep_the_inputs(fleet_dir, tmp_path, capsys):
    fleet = load_example()
    with pytest.raises(SystemExit) as e:  # a usage error (argparse: exit 2), not a traceback
        fleet.main([str(fleet_dir / "missing.csv"), "--out", str(tmp_path / "t.csv"), "--serial"])
    assert e.value.code == 2
    assert "missing.csv: no such drive or directory" in capsys.readouterr().err
    drive = fleet_dir / "car1.csv"
    before = drive.read_bytes()
    with pytest.raises(SystemExit) as e:  # the table written over an input drive
        fleet.main([str(drive), "--out", str(drive), "--serial"])
    assert e.value.code == 2
    assert "would destroy it" in capsys.readouterr().err
    assert drive.read_bytes() == before
    # An option odocal.calibrate does not take, or one with a flag of its own: a usage error before any
    # drive is calibrated, and no table.
    out = tmp_path / "t.csv"
    for option, message in [("badopt=1", "-o badopt: not an option of odocal.calibrate; options: method, theta0"),
                            ("method=eiv", "-o method: give it as --method"),
                            ("threads=2", "-o threads: give it as --cpus-per-task")]:
        with pytest.raises(SystemExit) as e:
            fleet.main([str(drive), "--out", str(out), "--serial", "-o", option])
        assert e.value.code == 2
        assert message in capsys.readouterr().err
        assert not out.exists()
    # A bad value of a known option: an error row, the run goes on.
    assert fleet.main([str(drive), "--out", str(out), "--serial", "--method", "batch-gn", "-o", "fix=t_x"]) == 2
    assert "error" in out.read_text() and "t_x" in out.read_text()


def test_ray_equals_serial(local_ray, fleet_dir, tmp_path):
    fleet = local_ray
    paths = fleet.find_drives([fleet_dir])
    serial = [odocal.calibrate(odocal.Drive.from_csv(p), METHOD, **OPTIONS) for p in paths]

    # The example's command line, unchanged, on the running local Ray.
    out = tmp_path / "fleet.csv"
    opts = ["--method", METHOD, *(f"-o{k}={v}" for k, v in OPTIONS.items())]
    assert fleet.main([str(fleet_dir), "--out", str(out), *opts]) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    assert [r["drive"] for r in rows] == [str(p) for p in paths]
    for row, rep in zip(rows, serial):
        assert row["status"] == "ok", row["error"]
        assert {k: float(row[k]) for k in odocal.THETA_NAMES} == rep.theta
        for k in odocal.THETA_NAMES:  # empty for a parameter the 2 km drive could not determine
            s = rep.result_sigma[k]
            assert (row[f"sigma_{k}"] == "") if s is None else (float(row[f"sigma_{k}"]) == s), (k, row, s)
        assert row["sigma_source"] == rep.result_sigma["source"]
        assert float(row["mean_position_error_m"]) == rep.mean_position_error_m


def test_params_dir_holds_each_drives_parameter_file(local_ray, fleet_dir, tmp_path):
    fleet = local_ray
    paths = fleet.find_drives([fleet_dir])[:2]
    pdir = tmp_path / "params"
    out = tmp_path / "fleet.csv"
    opts = ["--method", METHOD, *(f"-o{k}={v}" for k, v in OPTIONS.items())]
    assert fleet.main([*map(str, paths), "--out", str(out), "--params-dir", str(pdir), *opts]) == 0
    with out.open() as f:
        rows = list(csv.DictReader(f))
    for row, p in zip(rows, paths):
        assert row["params_file"] == str(pdir / (p.stem + ".yaml"))
        back = odocal.read_params(row["params_file"])
        assert {k: back["parameters"][k] for k in odocal.THETA_NAMES} == {k: float(row[k]) for k in odocal.THETA_NAMES}
        assert back["verdict"] == row["verdict"]
        assert back["provenance"]["input"] == str(p)
    # Two drives of one name would overwrite each other's file: refused.
    other = tmp_path / "elsewhere"
    other.mkdir()
    (other / paths[0].name).write_bytes(paths[0].read_bytes())
    assert fleet.main([str(paths[0]), str(other / paths[0].name), "--out", str(out), "--params-dir", str(pdir)]) == 1


def test_bad_drive_gives_error_row(local_ray, fleet_dir, tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,px\n0,0\n")
    rows = local_ray.calibrate_fleet([bad, fleet_dir / "car1.csv"], method="batch-gn")
    assert rows[0]["status"] == "error" and "missing column" in rows[0]["error"]
    assert rows[1]["status"] == "ok"
