#!/usr/bin/env bash
# Builds the Python package (maturin, dev profile) into a virtualenv it creates
# and runs its pytest suite, including the Ray fleet example on a local Ray.
# Run from anywhere: crates/odocal-py/test.sh   (extra arguments go to pytest)
#
#   ODOCAL_VENV  the virtualenv (default target/venv-py, created when missing)
#   PYTHON       the interpreter that creates it (default python3)
set -euo pipefail
cd "$(dirname "$0")/../.."

venv=${ODOCAL_VENV:-target/venv-py}
crates/odocal-py/env.sh
pip=("$venv/bin/python" -m pip install --quiet --disable-pip-version-check)

# pytest compares the package's reports with the CLI's JSON, from the binary
# the test build builds (test profile, opt-level 2): after the Rust half of
# README's test command this is a no-op, where a release build of the CLI
# would take 3 min of CI. Floating point is the same at every opt-level (no fast-math).
cargo test --workspace --no-run --quiet
# The wheel under test is built with the dev profile, whose settings the
# test profile shares (root Cargo.toml): it reuses the test build's
# artifacts and compiles only pyo3, numpy and the bindings (~1 min), where a
# release build would compile the whole dependency tree again (4 min on the
# 2-core machine). The workspace's debug assertions and overflow checks
# stay on, as in `cargo test`. A wheel to install for use:
# `pip install crates/odocal-py` (release).
rm -f target/wheels/odocal-*.whl
"$venv/bin/maturin" build --profile dev --quiet -m crates/odocal-py/Cargo.toml -o target/wheels
"${pip[@]}" --force-reinstall --no-deps target/wheels/odocal-*.whl

status=0
ODOCAL_BIN=${ODOCAL_BIN:-target/debug/odocal} RAY_USAGE_STATS_ENABLED=0 \
  "$venv/bin/python" -m pytest crates/odocal-py/tests -q -rs "$@" || status=$?
if [ "$status" -eq 5 ]; then
  # pytest's "no tests collected": the suite is missing or was filtered away.
  echo "error: pytest collected no tests in crates/odocal-py/tests" >&2
  exit 1
fi
exit "$status"
