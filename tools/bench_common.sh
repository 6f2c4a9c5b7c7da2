# Shared by the tools/bench_*vs_torch.sh pairing scripts (sourced, not run):
# finds a Python with torch and builds nst3d, then gives the helpers both
# scripts use to read their runs.
#
# $TORCH_PYTHON names the Python; otherwise ./.venv-torch is created with
# `pip install torch numpy` on first use.
PY=${TORCH_PYTHON:-}
if [ -z "$PY" ]; then
  if [ ! -x .venv-torch/bin/python ]; then
    python3 -m venv .venv-torch
    .venv-torch/bin/pip install -q torch numpy
  fi
  PY=.venv-torch/bin/python
fi
cargo build --release -q -p nst3d-cli

# Peak resident memory in MB from a `/usr/bin/time -v` report.
peak() { grep -E "Maximum resident" "$1" | awk '{printf "%.0f", $NF/1024}'; }
# Value of the last `NAME value` line of a file.
field() { grep -E "^$1 " "$2" | tail -1 | awk '{print $2}'; }
# Median of the arguments.
med() { printf '%s\n' "$@" | sort -n | awk '{a[NR]=$1} END{print (NR%2)?a[(NR+1)/2]:(a[NR/2]+a[NR/2+1])/2}'; }
