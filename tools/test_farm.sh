#!/usr/bin/env bash
# The farm-engine tests (farm/tests): builds the MPI-enabled binary beside
# the release one (tools/build_mpi.sh, which installs Open MPI and its PMIx;
# tools/test_python.sh built the release binary), then starts the
# single-node Slurm cluster (tools/slurm_up.sh), installs openjd-cli into
# .venv-py (made by tools/test_python.sh), and runs pytest. MPI comes
# first: slurmd loads its PMIx plugin when it starts, and one started
# before the PMIx library was installed fails every `srun --mpi=pmix`
# step ("can not load PMIx library" in its log).
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$(date +%s)
bash tools/build_mpi.sh
echo "== the MPI build took $(( $(date +%s) - t0 )) s"
t0=$(date +%s)
bash tools/slurm_up.sh
echo "== Slurm set-up took $(( $(date +%s) - t0 )) s"
.venv-py/bin/pip install -q --disable-pip-version-check openjd-cli
echo "== farm tests (OpenJD, Slurm)"
cd farm && ../.venv-py/bin/pytest -q -s tests
