#!/usr/bin/env bash
# The Python package's tests: builds the release binary (the tests compare
# the package with it byte for byte), installs the package with pip from
# this checkout into .venv-py (a venv over Debian's python3, so OpenVDB's
# own binding pyopenvdb is importable beside it) and runs pytest.
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
.venv-py/bin/pip install -q --disable-pip-version-check pytest

echo "== building the release binary and the nst3d wheel"
cargo build --release -q -p nst3d-cli
.venv-py/bin/pip install -q --disable-pip-version-check ./python

echo "== Python package tests"
cd python && ../.venv-py/bin/pytest -q tests
