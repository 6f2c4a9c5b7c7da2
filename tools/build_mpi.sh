#!/usr/bin/env bash
# Builds the MPI-enabled nst3d (`mpirun -n N nst3d train`, docs/guide/farm.md)
# as target/release/nst3d-mpi, beside the default target/release/nst3d, which
# it leaves as the default build (no MPI). Installs what the build and the
# runs need first, if missing: Debian's Open MPI (libopenmpi-dev, openmpi-bin)
# and libclang-dev (the `mpi` crate generates its bindings from mpi.h with
# bindgen). Idempotent; the second build only relinks.
#
#   bash tools/build_mpi.sh
#   mpirun -n 2 target/release/nst3d-mpi train --batch 2 ...
set -euo pipefail
cd "$(dirname "$0")/.."
have_all() {
  command -v mpirun >/dev/null && command -v mpicc >/dev/null &&
    compgen -G "/usr/lib/llvm-*/lib/libclang.so" >/dev/null
}
if ! have_all; then
  echo "== installing Open MPI and libclang"
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
    libopenmpi-dev openmpi-bin libclang-dev >/dev/null
fi
target="${CARGO_TARGET_DIR:-$PWD/target}"
echo "== building nst3d with MPI ($(mpirun --version | head -1))"
cargo build --release -q -p nst3d-cli --features mpi
cp "$target/release/nst3d" "$target/release/nst3d-mpi"
# The default binary back in its place (cargo keeps both builds: no compiling).
cargo build --release -q -p nst3d-cli
echo "== $target/release/nst3d-mpi"
