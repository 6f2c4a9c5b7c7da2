#!/usr/bin/env bash
# Shows that the working tree's nst3d writes byte-identical outputs, reports
# and notes to those of an earlier revision on the shared examples:
#
#   bash tools/compare_builds.sh REV        # e.g. a tag or a commit before a refactor
#
# REV is built in a temporary git worktree (its own target folder, so the
# first run takes a full release build), both binaries run
# tools/same_outputs.sh, and the hash lists are diffed. Exit status 0 and
# "IDENTICAL" when every file matches.
set -euo pipefail
cd "$(dirname "$0")/.."
REV=${1:?usage: compare_builds.sh REV}
WORK=${TMPDIR:-/tmp}/nst3d-compare
mkdir -p "$WORK"
if [ ! -d "$WORK/tree" ]; then
  git worktree add -q --detach "$WORK/tree" "$REV"
else
  git -C "$WORK/tree" checkout -q --detach "$REV"
fi
(cd "$WORK/tree" && cargo build --release -q -p nst3d-cli)
cargo build --release -q -p nst3d-cli
# The script of this tree runs both, so both run the same examples.
bash tools/same_outputs.sh "$WORK/tree/target/release/nst3d" "$WORK/before" > "$WORK/before.txt"
bash tools/same_outputs.sh target/release/nst3d "$WORK/after" > "$WORK/after.txt"
if diff "$WORK/before.txt" "$WORK/after.txt"; then
  echo "IDENTICAL: $(wc -l < "$WORK/after.txt") files from $REV and the working tree"
else
  echo "outputs differ (see the diff above; files under $WORK/before and $WORK/after)" >&2
  exit 1
fi
