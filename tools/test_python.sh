#!/usr/bin/env bash
# The Python package's tests: builds the release binary (the tests compare
# the package with it byte for byte) and the nst3d wheel (`maturin build`),
# installs that wheel file into .venv-py (a venv over Debian's python3, so
# OpenVDB's own binding pyopenvdb is importable beside it), type-checks the
# package and a user's calls with mypy --strict (python/tests/typecheck_usage.py:
# right calls pass, wrong ones are flagged) and runs pytest.
#
#   bash tools/test_python.sh
set -euo pipefail
cd "$(dirname "$0")/.."

if ! /usr/bin/python3 -c "import venv, ensurepip" >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-venv >/dev/null
fi
[ -x .venv-py/bin/python ] || /usr/bin/python3 -m venv --system-site-packages .venv-py
.venv-py/bin/pip install -q --disable-pip-version-check pytest "maturin>=1.5,<2" "mypy>=1.8"

echo "== building the release binary and the nst3d wheel"
cargo build --release -q -p nst3d-cli
wheels="${CARGO_TARGET_DIR:-$PWD/target}/python-wheel"
rm -rf "$wheels"
(cd python && ../.venv-py/bin/maturin build --release --quiet -i ../.venv-py/bin/python -o "$wheels")
wheel=$(ls "$wheels"/nst3d-*.whl)
.venv-py/bin/pip install -q --disable-pip-version-check --force-reinstall --no-deps "$wheel"
.venv-py/bin/pip install -q --disable-pip-version-check "$wheel"  # its dependencies, where missing

echo "== type check (mypy --strict): the package and a user's calls"
(cd python && ../.venv-py/bin/mypy --strict --cache-dir=/dev/null nst3d tests/typecheck_usage.py)

echo "== Python package tests"
cd python && ../.venv-py/bin/pytest -q tests
