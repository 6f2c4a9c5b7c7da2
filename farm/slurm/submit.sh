#!/usr/bin/env bash
# Submits farm/slurm/nst3d-volume.sbatch as an array of ceil((LAST-FIRST+1)/CHUNK)
# chunks; extra arguments go to sbatch (e.g. --wait, --partition, -o LOG).
# The settings come from the environment (INPUT, OUTPUT, STYLE, FIRST, LAST,
# CHUNK, WARMUP, NST3D, SETTINGS; see the sbatch script).
set -euo pipefail
FIRST=${FIRST:-1}
: "${LAST:?set LAST, the last frame}"
CHUNK=${CHUNK:-10}
tasks=$(( (LAST - FIRST + CHUNK) / CHUNK ))
export FIRST LAST CHUNK
exec sbatch --parsable --array=0-$(( tasks - 1 )) "$@" "$(dirname "$0")/nst3d-volume.sbatch"
