"""Shared fixtures of the odocal Python tests."""

import os
import shutil
from pathlib import Path

import pytest

import odocal

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="session")
def small_drive() -> "odocal.Drive":
    """A 3 km simulated drive with paper-like noise (seed 3)."""
    return odocal.simulate(seed=3, length_km=3.0)


@pytest.fixture(scope="session")
def drive_csv(tmp_path_factory, small_drive) -> Path:
    """`small_drive` as a canonical CSV with its simulator sidecar beside it."""
    path = tmp_path_factory.mktemp("drive") / "drive.csv"
    small_drive.to_csv(path)
    assert path.with_suffix(".json").exists()
    return path


@pytest.fixture(scope="session")
def odocal_bin() -> Path:
    """The `odocal` CLI binary: $ODOCAL_BIN, else target/release or target/debug of the repository."""
    env = os.environ.get("ODOCAL_BIN")
    candidates = [Path(env)] if env else [REPO / "target" / "release" / "odocal", REPO / "target" / "debug" / "odocal"]
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return c
    found = shutil.which("odocal")
    if found and not env:
        return Path(found)
    pytest.fail(
        f"the odocal CLI binary was not found ({', '.join(map(str, candidates))}); "
        "build it with `cargo build --release -p odocal-cli` or set ODOCAL_BIN"
    )
