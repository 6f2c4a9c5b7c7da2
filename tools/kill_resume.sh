#!/usr/bin/env bash
# Kills an `nst3d volume --frames` run twice with SIGKILL and restarts it with
# the same command, then checks the result against an uninterrupted run
# (docs/guide/farm.md):
#
#   NST3D=target/release/nst3d bash tools/kill_resume.sh OUTDIR REFDIR -- <nst3d volume flags without --out>
#
# 1. kill -9 as soon as the progress lines reach sweep 3 (sweeps 1-2 checkpointed;
#    so the flags need --iters 3 or more);
# 2. restart; kill -9 again once KEEP (default 10) output frames have been written;
# 3. restart; it must keep those frames (same bytes, same modification time) and
#    write the rest;
# 4. restart once more: "nothing to do".
# Every output OUTDIR/s_####.vdb must equal REFDIR/s_####.vdb byte for byte.
set -euo pipefail
out=$1 ref=$2
shift 2
[ "$1" = "--" ] && shift
here="$(cd "$(dirname "$0")/.." && pwd)"
nst3d=${NST3D:-$here/target/release/nst3d}
keep=${KEEP:-10}
mkdir -p "$out"
cmd=("$nst3d" --threads 2 volume "$@" --out "$out/s_####.vdb")
count() { find "$out" -maxdepth 1 -name 's_*.vdb' | wc -l; }

echo "== run 1: kill -9 when sweep 3 starts"
"${cmd[@]}" >"$out/run1.out" 2>"$out/run1.err" &
pid=$!
until grep -q "sweep 3/" "$out/run1.err" 2>/dev/null; do
  kill -0 "$pid" 2>/dev/null || { echo "run 1 ended before sweep 3" >&2; exit 1; }
  sleep 0.1
done
kill -9 "$pid"
wait "$pid" 2>/dev/null || true
echo "killed during: $(grep 'sweep' "$out/run1.err" | tail -1)"
echo "outputs after the kill: $(count); work folder: $(cat "$out"/.nst3d-work/*/checkpoint)"

echo "== run 2: restart, kill -9 after $keep frames are written"
"${cmd[@]}" >"$out/run2.out" 2>"$out/run2.err" &
pid=$!
until [ "$(count)" -ge "$keep" ]; do
  kill -0 "$pid" 2>/dev/null || { echo "run 2 ended before $keep frames were written" >&2; exit 1; }
  sleep 0.05
done
kill -9 "$pid"
wait "$pid" 2>/dev/null || true
grep -m1 "resuming" "$out/run2.err"
echo "first progress line of run 2: $(grep -m1 '^\[' "$out/run2.err")"
echo "outputs after the kill: $(count)"
# Identity of the frames already written: content hash and modification time.
(cd "$out" && for f in s_*.vdb; do echo "$f $(sha256sum <"$f" | cut -c1-16) $(stat -c %Y.%y "$f")"; done) >"$out/kept.txt"

echo "== run 3: restart"
"${cmd[@]}" >"$out/run3.out" 2>"$out/run3.err"
grep -v '^\[' "$out/run3.err" || true
cat "$out/run3.out"
(cd "$out" && while read -r f _; do echo "$f $(sha256sum <"$f" | cut -c1-16) $(stat -c %Y.%y "$f")"; done <kept.txt) \
  | diff "$out/kept.txt" - && echo "the $(wc -l <"$out/kept.txt") frames written before the kill are untouched (hash and mtime)"

echo "== run 4: restart again"
"${cmd[@]}"

echo "== against the uninterrupted run"
n=0
for f in "$out"/s_*.vdb; do
  cmp "$f" "$ref/$(basename "$f")"
  n=$((n + 1))
done
echo "$n frames identical byte for byte to $ref"
