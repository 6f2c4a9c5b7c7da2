#!/usr/bin/env bash
# Binary USD against the reference implementation, PyPI's usd-core
# (installed into .venv-usd, pinned):
#  1. usd-core writes the reference grooms (crate file, package, a stage
#     that sublayers one, one that references it) and says what it reads in
#     them; crates/io/tests/groom_usd.rs reads the same with nst3d's reader
#     (the committed copies of these files are what it reads without
#     Python);
#  2. usd-core writes the 100-strand groom as .usdc and .usdz, the release
#     `nst3d strands` stylizes each, and usd-core must find in every output
#     the input's topology, upAxis, metersPerUnit and every primvar, and no
#     fault its validators know (tools/usd_groom.py round-trip).
#
#   bash tools/test_usd.sh
set -euo pipefail
cd "$(dirname "$0")/.."

USD_CORE="usd-core==26.11"
python=/usr/bin/python3
[ -x "$python" ] || python=$(command -v python3)
if ! "$python" -c "import venv, ensurepip" >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-venv >/dev/null
fi
[ -x .venv-usd/bin/python ] || "$python" -m venv .venv-usd
.venv-usd/bin/pip install -q --disable-pip-version-check "$USD_CORE"

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

echo "== usd-core's grooms read by nst3d as usd-core reads them"
# usd-core says on stderr when a time code makes it write crate version 0.9.0.
quiet() { grep -v "^Warning: in RequestWriteVersionUpgrade" >&2 || true; }
.venv-usd/bin/python tools/usd_groom.py fixtures "$work/reference" 2> >(quiet)
if cargo nextest --version >/dev/null 2>&1; then
  # The workspace build of tools/test.sh (its profile), filtered: no second build.
  NST3D_USD_REFERENCE="$work/reference" cargo nextest run --cargo-profile "${NST3D_TEST_PROFILE:-test}" \
    --workspace --exclude nst3d-python --no-fail-fast -E 'binary(groom_usd)'
else
  NST3D_USD_REFERENCE="$work/reference" cargo test -p nst3d-io --test groom_usd
fi

echo "== nst3d's stylized .usdc and .usdz read by usd-core"
cargo build --release -q -p nst3d-cli
.venv-usd/bin/python tools/usd_groom.py round-trip "${CARGO_TARGET_DIR:-$PWD/target}/release/nst3d" "$work/round-trip" \
  2> >(quiet)
