#!/usr/bin/env bash
# The feed-forward measurements that need the lent GPU machine (16 cores, one
# H200), in one call, from what tools/device/pack.sh put in .devdata/:
#  1. scaling of `mpirun -n N nst3d train` on its CPU, N = 1..16 ranks of one
#     thread, global batch 16 (the batch spread over the ranks), 64³ patches;
#     one process of 16 threads beside it; 128³ on 16 ranks. Seconds a step
#     from the times rank 0's step lines arrive (step 1 to the last), so
#     start-up is left out. The weights are tools/device/vgg_tv.py's (timing
#     only). FF_ARMS=0 stops after this part.
#  2. the independent PyTorch reference (tools/ff_ref/ff_reference.py) of the
#     paper's training on the GPU for MINUTES, several arms side by side, all
#     on the example models' training frames; the state dicts come back for
#     the held-out judge (tools/ff_heldout.sh after tools/ff_ref/to_nst3d.py).
# Writes $OUT/summary.txt and $OUT/results.tar.gz.
#
#   bash tools/device/ff_device.sh [MINUTES]
set -uo pipefail
cd "$(dirname "$0")/../.."
D=$PWD/.devdata
MIN=${1:-4.5}
GPU=${FF_DEVICE:-cuda} SP=${FF_SCALE_PATCH:-64} BP=${FF_BIG_PATCH:-128}  # smaller to try the script on a CPU
OUT=${OUT:-/tmp/ff_device}
W=/tmp/ffw
mkdir -p "$OUT" "$W"
T0=$(date +%s)
say() { echo "== $(( $(date +%s) - T0 ))s $*" | tee -a "$OUT/summary.txt"; }
say "machine"
{ lscpu | grep -E "^Model name|^CPU\(s\)|^Thread|^Core|^Socket"
  lscpu | grep -o -E "amx_bf16|avx512_bf16|avx512f " | sort -u | tr '\n' ' '; echo
  nvidia-smi -L; python3 -c "import torch; print('torch', torch.__version__)"; } 2>&1 | tee -a "$OUT/summary.txt"

# ---- 1. MPI scaling (CPU) -------------------------------------------------
python3 tools/device/vgg_tv.py "$D/vgg_cut.pth" "$W/vgg_tv.pth"
mpi() (
  B=$D/ompi
  export OPAL_PREFIX=$B/usr PMIX_INSTALL_PREFIX=$B/usr PATH=$B/usr/bin:$PATH \
    LD_LIBRARY_PATH=$B/lib:$B/usr/lib/x86_64-linux-gnu:$B/usr/lib/x86_64-linux-gnu/openmpi/lib \
    OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_btl=self,vader,tcp OMPI_MCA_pml=ob1
  "$@"
)
train() { # TAG RANKS THREADS PATCH STEPS: the run's log, each line with the time it arrived
  local bind=core; [ "$3" -gt 1 ] || [ "$2" -gt "$(nproc)" ] && bind=none
  timeout 150 bash -c "$(declare -f mpi); D=$D; mpi mpirun -n $2 --oversubscribe --bind-to $bind \
    $D/nst3d-mpi --threads $3 train --input '$D/plume48/fluid_data_####.vdb' --frames 20-40 \
    --style $D/styles/starry_night.jpg --mode density --patch $4 --batch 16 --steps $5 --seed 0 \
    --weights $W/vgg_tv.pth --out $W/$1_s$5.safetensors" 2>&1 |
    while IFS= read -r line; do echo "$(date +%s.%N) $line"; done > "$W/$1_s$5.log"
}
row() { # TAG RANKS THREADS PATCH STEPS: seconds a step from step 1's line to the last's
  [ $(( $(date +%s) - T0 )) -lt 300 ] || { say "skipped $1 (time)"; return; }
  train "$1" "$2" "$3" "$4" "$5"
  awk -v tag="$1" -v n="$2" -v th="$3" -v p="$4" -v steps="$5" '
    / step [0-9]+\/[0-9]+ loss/ { split($4, k, "/"); t[k[1] + 0] = $1 }
    END { if (!(1 in t) || !(steps in t)) { printf "scale %-10s FAILED\n", tag; exit }
      st = (t[steps] - t[1]) / (steps - 1)
      printf "scale %-10s ranks %2d threads %2d patch %3d  steps 1-%d  %.3f s/step  %.2f patches/s\n",
        tag, n, th, p, steps, st, 16 / st }' "$W/$1_s$5.log" | tee -a "$OUT/summary.txt"
}
say "MPI scaling, global batch 16"
mpi mpirun --version | head -1 | tee -a "$OUT/summary.txt"
train warm 2 1 $SP 1  # the binary, frames and weights into the page cache
row r1 1 1 $SP 6
row r2 2 1 $SP 6
row r4 4 1 $SP 8
row r8 8 1 $SP 10
row r16 16 1 $SP 12
row t16 1 16 $SP 6
row r16p$BP 16 1 $BP 5
for m in r2_s6 t16_s6; do
  [ -f "$W/$m.safetensors" ] && [ -f "$W/r1_s6.safetensors" ] && echo "same model bytes r1 vs $m (6 steps):" \
    "$(cmp -s "$W/r1_s6.safetensors" "$W/$m.safetensors" && echo yes || echo no)" | tee -a "$OUT/summary.txt"
done
[ "${FF_ARMS:-1}" = 1 ] || { tar -czf "$OUT/results.tar.gz" -C "$W" $(cd "$W" && ls *.log); exit 0; }

# ---- 2. the PyTorch reference on the GPU ----------------------------------
say "reference arms, $MIN minutes each, side by side"
export NST3D_VGG19=$D/vgg_cut.pth PYTHONUNBUFFERED=1
first=$D/frames/plume48_0030.npz
rest=$(ls "$D"/frames/*.npz | grep -v plume48_0030)
arm() { # NAME PAINTING PATCH GAMMA [extra]
  local name=$1 style=$2 patch=$3 gamma=$4; shift 4
  timeout $(awk -v m="$MIN" 'BEGIN{print int(m * 60 + 90)}') python3 tools/ff_ref/ff_reference.py "$first" \
    "$D/styles/$style.jpg" "$W/$name" --arm net --device $GPU --patch "$patch" --gamma "$gamma" \
    --minutes "$MIN" --save-every 30 --train-frames $rest "$@" > "$W/$name.out" 2>&1
}
arm starry_p${BP}_frame starry_night $BP frame --conserve &
arm starry_p${BP}_patch starry_night $BP patch --conserve &
arm starry_p${BP}_paper starry_night $BP frame &
arm shipwreck_p${BP}_frame shipwreck $BP frame --conserve &
arm woman_p${BP}_frame woman_with_hat $BP frame --conserve &
arm starry_p${SP}_frame starry_night $SP frame --conserve &
sleep 60; nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv | tee -a "$OUT/summary.txt"
wait
for f in "$W"/*.out; do
  n=$(basename "$f" .out)
  echo "arm $n: $(grep -m1 'ms a step' "$f") | last: $(tail -1 "$W/$n.log.csv" 2>/dev/null) | $(grep -c . "$W/$n.log.csv" 2>/dev/null) steps logged | $(grep -i -m1 error "$f")" |
    tee -a "$OUT/summary.txt"
done
say "done"
tar -czf "$OUT/results.tar.gz" -C "$W" $(cd "$W" && ls *.pt *.log.csv *.out *.log 2>/dev/null)
ls -la "$OUT"
