#!/usr/bin/env bash
# The Blender add-on's tests in Debian's Blender (3.4), after
# tools/test_python.sh has installed the nst3d package into .venv-py:
# headless, bakes a small smoke, runs "Stylize smoke", renders before | after
# into out/blender/blender_smoke_before_after.png (docs/img has the committed
# copy) and stylizes particle hair; then with a window under Xvfb, the
# operator's interactive path (a thread, progress in the panel).
#
#   bash tools/test_python.sh && bash tools/test_blender.sh
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v blender >/dev/null || ! command -v xvfb-run >/dev/null; then
  echo "== installing Debian's blender and xvfb"
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq blender xvfb >/dev/null
fi
SITE=$(.venv-py/bin/python -c "import nst3d, os; print(os.path.dirname(os.path.dirname(nst3d.__file__)))")
OUT=${1:-out/blender}
rm -rf "$OUT"
echo "== Blender add-on test ($(blender --version 2>/dev/null | head -1))"
LOG="$OUT.log"
mkdir -p "$(dirname "$LOG")"
PYTHONPATH="$SITE:$PWD/python/blender" blender -b --factory-startup --python-use-system-env \
  --python-exit-code 1 -P python/blender/test_addon.py -- "$OUT" > "$LOG" 2>&1 || true
grep -E "^(ok|FAILED|ALL OK|Error|Traceback|  File)" "$LOG" || true
# Blender can crash without a Python exit code: only the test's last line counts.
grep -q "^ALL OK" "$LOG" || { echo "Blender add-on test FAILED (log: $LOG)"; tail -20 "$LOG"; exit 1; }

echo "== Blender add-on, interactive path (window under Xvfb)"
UI="$OUT/ui"
blender -b --factory-startup -P python/blender/test_addon_ui.py -- "$UI" > "$OUT.ui-bake.log" 2>&1 || true
grep -q "saved the baked scene" "$OUT.ui-bake.log" || { echo "Blender UI test: bake FAILED"; tail -20 "$OUT.ui-bake.log"; exit 1; }
PYTHONPATH="$SITE:$PWD/python/blender" timeout 300 xvfb-run -a blender "$UI/scene.blend" --python-use-system-env \
  --python-exit-code 1 -P python/blender/test_addon_ui.py -- "$UI" > "$OUT.ui.log" 2>&1 || true
grep -E "^(ALL OK|FAILED)" "$OUT.ui.log" || true
grep -q "^ALL OK" "$OUT.ui.log" || { echo "Blender UI test FAILED (log: $OUT.ui.log)"; tail -20 "$OUT.ui.log"; exit 1; }
