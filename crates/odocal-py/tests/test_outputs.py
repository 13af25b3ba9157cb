"""Data safety in Python: outputs never overwrite a drive's files, the same
drive is not calibrated twice, fingerprints, and a sidecar is the truth of
its own drive only."""

import hashlib
import shutil
import subprocess
import warnings

import numpy as np
import pytest

import odocal
from conftest import REPO

VAN = REPO / "crates" / "odocal" / "tests" / "data" / "psu-mapping-van"


def documented_fingerprint(d: odocal.Drive) -> str:
    """The fingerprint as `Drive::fingerprint` documents it, computed here from the drive's arrays."""
    h = hashlib.sha256(b"odocal drive fingerprint v1\0")
    parts = d.parts
    h.update(np.array([len(d), len(parts)], dtype="<u8").tobytes())
    h.update(np.array([x for p in parts for x in p], dtype="<u8").tobytes())
    h.update(np.array([round(d.sample_time_s * 1e9)], dtype="<i8").tobytes())
    cols = d.to_numpy() + 0.0  # a negative zero as zero
    for j in range(cols.shape[1]):
        h.update(np.ascontiguousarray(cols[:, j]).astype("<f8").tobytes())
    return h.hexdigest()


def test_fingerprint_is_the_documented_hash(small_drive):
    assert small_drive.fingerprint == documented_fingerprint(small_drive)
    van = odocal.Drive.from_manifest(VAN / "manifest.toml")
    assert len(van.parts) > 1
    assert van.fingerprint == documented_fingerprint(van)


def test_a_manifest_and_its_csv_have_one_fingerprint(tmp_path):
    van = odocal.Drive.from_manifest(VAN / "manifest.toml")
    van.to_csv(tmp_path / "van.csv")
    back = odocal.Drive.from_csv(tmp_path / "van.csv")
    assert back.fingerprint == van.fingerprint
    assert back.source == str(tmp_path / "van.csv")


def test_the_same_drive_twice_is_refused(tmp_path, small_drive, drive_csv):
    copy = tmp_path / "copy.csv"
    shutil.copy(drive_csv, copy)
    a, b = odocal.Drive.from_csv(drive_csv), odocal.Drive.from_csv(copy)
    with pytest.raises(odocal.OdocalError, match=r"drive\[1\] \(.*copy.csv\) is the same drive as drive\[0\]"):
        odocal.calibrate([a, b], "batch-gn")
    with pytest.raises(odocal.OdocalError, match=r"validate_on \(.*copy.csv\) is the same drive as drive"):
        odocal.calibrate(a, "batch-gn", validate_on=b)
    with pytest.raises(ValueError, match="same drive"):
        odocal.calibrate(small_drive, "batch-gn", validate_on=[a])


def test_report_names_the_drives_and_params_carry_the_fingerprint(tmp_path, drive_csv):
    d = odocal.Drive.from_csv(drive_csv)
    r = odocal.calibrate(d, "batch-gn")
    assert r.to_dict()["drives"] == [{"role": "calibration", "path": str(drive_csv), "fingerprint": d.fingerprint}]
    r.write_params(tmp_path / "p.yaml")
    assert odocal.read_params(tmp_path / "p.yaml")["provenance"]["fingerprint"] == d.fingerprint
    v = odocal.validate(d, r)
    assert v["drives"][0]["fingerprint"] == d.fingerprint


def test_params_name_the_drives_they_come_from(tmp_path, small_drive, drive_csv):
    """provenance.input names the calibration drives as the CLI's --params-out does: a drive read from a file by
    its path (a joint fit: each, comma separated), a simulated one as such, "python" only for arrays."""

    def input_of(report, **kw):
        report.write_params(tmp_path / "p.yaml", **kw)
        return odocal.read_params(tmp_path / "p.yaml")["provenance"]["input"]

    d = odocal.Drive.from_csv(drive_csv)
    assert input_of(odocal.calibrate(d, "batch-gn")) == str(drive_csv)
    assert input_of(odocal.calibrate(small_drive, "batch-gn")) == "simulated drive"
    a = small_drive.to_numpy()
    arrays = odocal.Drive.from_arrays(a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5], a[:, 7], beta=a[:, 6])
    assert input_of(odocal.calibrate(arrays, "batch-gn")) == "python"
    other = tmp_path / "other.csv"
    odocal.simulate(seed=4, length_km=3.0).to_csv(other)
    joint = odocal.calibrate([d, odocal.Drive.from_csv(other)], "batch-gn")
    assert input_of(joint) == f"{drive_csv}, {other}"
    assert input_of(joint, input="fleet run 7") == "fleet run 7"


def test_write_params_refuses_a_node_ros_2_cannot_load(tmp_path, drive_csv, odocal_bin):
    """The node is checked as the CLI's --params-out node (the library's check): nothing is written."""
    r = odocal.calibrate(odocal.Drive.from_csv(drive_csv), "batch-gn")
    for bad in ["bad node!", "", "a:b", "x\ny", "my-node"]:
        for name in ["bn.yaml", "bn.json"]:
            with pytest.raises(odocal.OdocalError, match="^invalid option `node`: .* is not a ROS 2 node name: give"):
                r.write_params(tmp_path / name, node=bad)
            assert not (tmp_path / name).exists(), (bad, name)
    r.write_params(tmp_path / "ok.yaml", node="/vehicle/odometry")
    assert odocal.read_params(tmp_path / "ok.yaml")["node"] == "/vehicle/odometry"
    with pytest.raises(odocal.OdocalError) as e:
        r.write_params(tmp_path / "bn.yaml", node="bad node!")
    out = subprocess.run([str(odocal_bin), "calibrate", str(drive_csv), "--method", "batch-gn", "--params-out",
                          str(tmp_path / "cli.yaml"), "--params-node", "bad node!"], capture_output=True, text=True)
    assert out.returncode == 2 and not (tmp_path / "cli.yaml").exists()
    reason = str(e.value).split(": ", 1)[1]
    assert reason in out.stderr, (reason, out.stderr)


def test_outputs_onto_the_drives_files_are_refused(tmp_path, drive_csv):
    work = tmp_path / "w"
    work.mkdir()
    csv = work / "d.csv"
    shutil.copy(drive_csv, csv)
    shutil.copy(drive_csv.with_suffix(".json"), work / "d.json")
    before = csv.read_bytes(), (work / "d.json").read_bytes()
    d = odocal.Drive.from_csv(csv)
    assert d.theta_true is not None
    with pytest.raises(odocal.OdocalError, match=r"to_csv\(path\) .*d.csv is also the CSV"):
        d.to_csv(work / "." / "d.csv")
    with pytest.raises(ValueError, match="name ending in .csv"):
        d.to_csv(work / "x.json")
    r = odocal.calibrate(d, "batch-gn")
    with pytest.raises(odocal.OdocalError, match=r"write_params\(path\) .*is also the simulator sidecar"):
        r.write_params(work / "d.json")
    with pytest.raises(odocal.OdocalError, match=r"to_html\(path\) .*is also the CSV"):
        r.to_html(csv)
    assert (csv.read_bytes(), (work / "d.json").read_bytes()) == before
    # A manifest's stream file.
    van_dir = tmp_path / "van"
    shutil.copytree(VAN, van_dir)
    van = odocal.Drive.from_manifest(van_dir / "manifest.toml")
    with pytest.raises(odocal.OdocalError, match="is also stream 'encoders' of the manifest"):
        van.to_csv(van_dir / "encoders.csv")


def test_a_sidecar_of_another_drive_is_not_the_truth(tmp_path, small_drive):
    small_drive.to_csv(tmp_path / "d.csv")
    assert odocal.Drive.from_csv(tmp_path / "d.csv").theta_true is not None
    other = odocal.simulate(seed=9, length_km=3.0)
    shutil.copy(tmp_path / "d.json", tmp_path / "keep.json")
    other.to_csv(tmp_path / "d.csv")
    shutil.copy(tmp_path / "keep.json", tmp_path / "d.json")
    with pytest.warns(UserWarning, match="d.json is not the truth of this drive"):
        d = odocal.Drive.from_csv(tmp_path / "d.csv")
    assert d.theta_true is None
    assert "truth" not in odocal.calibrate(d, "batch-gn").to_dict()


def test_a_last_line_without_newline_warns(tmp_path, drive_csv):
    text = drive_csv.read_text()
    (tmp_path / "open.csv").write_text(text.rstrip("\n"))
    with pytest.warns(UserWarning, match="no newline at its end"):
        odocal.Drive.from_csv(tmp_path / "open.csv")
    (tmp_path / "cut.csv").write_text(text[: len(text) - 30])
    with pytest.raises(odocal.OdocalError, match="the last row is short"):
        odocal.Drive.from_csv(tmp_path / "cut.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        odocal.Drive.from_csv(drive_csv)


def test_pickled_drive_keeps_its_source(drive_csv):
    import pickle

    d = odocal.Drive.from_csv(drive_csv)
    back = pickle.loads(pickle.dumps(d))
    assert back.source == d.source and back.fingerprint == d.fingerprint
