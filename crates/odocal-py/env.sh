#!/usr/bin/env bash
# Creates the Python test environment of crates/odocal-py/test.sh when
# missing and installs what the suite needs into it: maturin, pytest,
# numpy, and Ray (large and optional: without it the fleet test is skipped,
# saying why). Run from anywhere; test.sh runs it first, and .ci/run runs it
# in the background while the Rust checks compile.
#
#   ODOCAL_VENV  the virtualenv (default target/venv-py, created when missing)
#   PYTHON       the interpreter that creates it (default python3)
set -euo pipefail
cd "$(dirname "$0")/../.."

venv=${ODOCAL_VENV:-target/venv-py}
if [ ! -x "$venv/bin/python" ]; then
  "${PYTHON:-python3}" -m venv "$venv"
fi
pip=("$venv/bin/python" -m pip install --quiet --disable-pip-version-check)
"${pip[@]}" maturin pytest numpy
"${pip[@]}" ray || echo "warning: could not install ray; the Ray fleet test will be skipped" >&2
