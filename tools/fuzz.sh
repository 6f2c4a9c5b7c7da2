#!/usr/bin/env bash
# Coverage-guided fuzzing of every nst3d reader with libFuzzer, on the stable
# toolchain: the coverage instrumentation is rustc's own sancov pass, enabled
# by the flags below (what cargo-fuzz passes, minus the nightly-only
# sanitizers), and libFuzzer itself comes from the libfuzzer-sys crate.
#
#   tools/fuzz.sh                         every reader for 8 s (the CI run, ~2 min)
#   tools/fuzz.sh --seconds 600 vdb usda  those readers for 10 minutes each
#   tools/fuzz.sh --runs 1000000          every reader for a million inputs
#   tools/fuzz.sh --jobs 2 ...            two readers at a time
#   tools/fuzz.sh --fork 8 --seconds 420 vdb   one reader on 8 cores (libFuzzer -fork)
#   tools/fuzz.sh --build-only            just build target/fuzz/.../readers
#   NST3D_FUZZ_BIN=path tools/fuzz.sh --no-seed ...   a binary built elsewhere, on
#                                         corpora carried along (no ../shared there)
#
# Corpora grow in fuzz/corpus/<reader> (not committed; rebuilt from the seeds
# each time if missing): the seeds are the real files of ../shared/data, the
# test fixtures, fuzz/seeds/ and small synthetic files (tools/fuzz_seeds.py).
# An input that panics, overflows, runs over 1 s or allocates over 2 GB is
# saved to fuzz/artifacts/<reader>/ and the script fails; such a file becomes
# a regression test beside the reader. Per-reader figures go to
# fuzz/artifacts/summary.tsv (docs/design/performance.md quotes them).
set -euo pipefail
cd "$(dirname "$0")/.."

seconds=8
runs=""
jobs=1
fork=""
seed=true
build_only=false
readers=()
while [[ $# -gt 0 ]]; do
  case "$1" in
    --seconds) seconds="$2"; shift 2 ;;
    --runs) runs="$2"; shift 2 ;;
    --jobs) jobs="$2"; shift 2 ;;
    --fork) fork="$2"; shift 2 ;;
    --no-seed) seed=false; shift ;;
    --build-only) build_only=true; shift ;;
    -h|--help) sed -n '2,22p' "$0"; exit 0 ;;
    -*) echo "fuzz.sh: unknown option $1" >&2; exit 2 ;;
    *) readers+=("$1"); shift ;;
  esac
done

if [[ -n "${NST3D_FUZZ_BIN:-}" ]]; then
  bin=$NST3D_FUZZ_BIN
else
  triple=$(rustc -vV | sed -n 's/^host: //p')
  # NST3D_FUZZ_EXTRA_RUSTFLAGS adds flags (e.g. a static build for another machine).
  export RUSTFLAGS="--cfg fuzzing -Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
  -Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
  -Cllvm-args=-sanitizer-coverage-trace-compares ${NST3D_FUZZ_EXTRA_RUSTFLAGS:-}"
  export CARGO_TARGET_DIR="$PWD/target/fuzz"
  # --target keeps the instrumentation off build scripts and proc macros.
  cargo build --release --manifest-path fuzz/Cargo.toml --target "$triple" --bin readers
  bin="$CARGO_TARGET_DIR/$triple/release/readers"
  $build_only && { echo "built $bin"; exit 0; }
fi

all=$(sed -n 's/^    ("\([a-z_]*\)", [a-z_]*),$/\1/p' fuzz/src/lib.rs)
[[ ${#readers[@]} -gt 0 ]] || read -r -a readers <<<"$(echo $all)"
for r in "${readers[@]}"; do
  grep -qx "$r" <<<"$all" || { echo "fuzz.sh: no reader '$r' (readers: $(echo $all))" >&2; exit 2; }
done

# Keep freed memory in the allocator: otherwise every large buffer a VDB
# input decodes is a fresh mmap whose page faults take a third of the time.
export GLIBC_TUNABLES="${GLIBC_TUNABLES:-glibc.malloc.mmap_threshold=67108864:glibc.malloc.trim_threshold=268435456:glibc.malloc.top_pad=67108864}"

$seed && python3 tools/fuzz_seeds.py fuzz/corpus "${readers[@]}"
mkdir -p fuzz/artifacts
summary=fuzz/artifacts/summary.tsv
[[ -f $summary ]] || printf 'reader\texecs\tseconds\texecs_per_s\tcorpus\tfindings\tdate\n' >"$summary"

fuzz_one() {
  local r=$1 log="fuzz/artifacts/$1.log"
  mkdir -p "fuzz/artifacts/$r"
  local budget=(-max_total_time="$seconds")
  [[ -n "$runs" ]] && budget=(-runs="$runs")
  [[ -n "$fork" ]] && budget+=(-fork="$fork")
  local start=$SECONDS status=0
  # max_len: the real seeds are up to ~60 KB; larger inputs only slow the search.
  NST3D_FUZZ_TARGET=$r "$bin" "fuzz/corpus/$r" "${budget[@]}" -timeout=1 -rss_limit_mb=2048 \
    -max_len=65536 -print_final_stats=1 -artifact_prefix="fuzz/artifacts/$r/" >"$log" 2>&1 || status=$?
  local execs
  # The last status line's count (also in -fork mode, which prints no final stats).
  execs=$(sed -n 's/^#\([0-9][0-9]*\).*/\1/p' "$log" | tail -1)
  local findings
  findings=$(find "fuzz/artifacts/$r" -type f | wc -l)
  local took=$((SECONDS - start))
  printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$r" "${execs:-?}" "$took" "$(( ${execs:-0} / (took > 0 ? took : 1) ))" \
    "$(ls "fuzz/corpus/$r" | wc -l)" "$findings" "$(date -u +%FT%TZ)" >>"$summary"
  if [[ $status -ne 0 || $findings -ne 0 ]]; then
    echo "FAIL $r (exit $status): $(grep -m1 -E 'panicked|ERROR|SUMMARY' "$log" || true); inputs in fuzz/artifacts/$r/" >&2
    return 1
  fi
  echo "ok   $r: ${execs:-?} inputs in ${took}s"
}
export -f fuzz_one
export bin seconds runs fork summary

failed=0
printf '%s\n' "${readers[@]}" | xargs -P "$jobs" -I{} bash -c 'fuzz_one {}' || failed=1
exit $failed
