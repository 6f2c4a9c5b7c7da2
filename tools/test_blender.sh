#!/usr/bin/env bash
# The Blender add-on's tests, after tools/test_python.sh has built the nst3d
# wheel and installed it into .venv-py:
#  1. Debian's Blender (3.4), the legacy add-on, headless: bakes a small
#     smoke (saved as OUT/baked.blend), Stylize smoke for the scene camera
#     with colour, rendered before | after into
#     OUT/blender_smoke_before_after.png, a feed-forward model, Esc during a
#     run, particle hair, hair Curves with colour
#     (OUT/blender_hair_before_after.png);
#  2. the same Blender with a window under Xvfb: a real Esc to the modal
#     operator, then the interactive path to its end (a thread, progress in
#     the panel);
#  3. Blender 4.2 as a Python module (PyPI's bpy, in .venv-bpy, installed
#     once): the extension zip built from the same wheel
#     (tools/build_blender_extension.sh), installed and enabled as Blender
#     installs it, the same tests as 1 on the scene 1 baked (the bpy module
#     cannot bake).
# docs/img has the committed copies of the pictures (rendered with
# --pictures: larger, more samples and iterations).
#
#   bash tools/test_python.sh && bash tools/test_blender.sh [OUT]
set -euo pipefail
cd "$(dirname "$0")/.."
stamp() { echo "== [${SECONDS}s] $*"; }
BPY_VERSION=4.2.23
if ! command -v blender >/dev/null || ! command -v xvfb-run >/dev/null; then
  stamp "installing Debian's blender and xvfb"
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq blender xvfb >/dev/null
fi
SITE=$(.venv-py/bin/python -c "import nst3d, os; print(os.path.dirname(os.path.dirname(nst3d.__file__)))")
OUT=$(realpath -m "${1:-out/blender}")
rm -rf "$OUT" "$OUT".*log
mkdir -p "$OUT"

# Only the test's last line counts: Blender can crash without an exit code.
verdict() {
  grep -E "^(ok|FAILED|ALL OK|Error|Traceback|  File)" "$2" || true
  grep -q "^ALL OK" "$2" || { echo "$1 FAILED (log: $2)"; tail -20 "$2"; exit 1; }
}

stamp "Blender add-on, headless ($(blender --version 2>/dev/null | head -1))"
PYTHONPATH="$SITE:$PWD/python/blender" blender -b --factory-startup --python-use-system-env \
  --python-exit-code 1 -P python/blender/test_addon.py -- "$OUT" > "$OUT.log" 2>&1 || true
verdict "Blender add-on test" "$OUT.log"

stamp "Blender add-on, a window under Xvfb: Esc, then the interactive path"
PYTHONPATH="$SITE:$PWD/python/blender" timeout 300 xvfb-run -a blender "$OUT/baked.blend" \
  --enable-event-simulate --python-use-system-env --python-exit-code 1 \
  -P python/blender/test_addon_ui.py -- "$OUT/ui" > "$OUT.ui.log" 2>&1 || true
verdict "Blender UI test" "$OUT.ui.log"

stamp "Blender $BPY_VERSION (bpy module): the extension"
# A CPython 3.11 for the bpy wheels; the venv is kept, so a second run
# installs nothing.
if ! .venv-bpy/bin/python -c "import importlib.metadata as m, sys; sys.exit(m.version('bpy') != '$BPY_VERSION')" 2>/dev/null; then
  py=$(for p in python3.11 python3 /usr/bin/python3; do
         if "$p" -c "import sys, venv; sys.exit(sys.version_info[:2] != (3, 11))" 2>/dev/null; then echo "$p"; break; fi
       done)
  [ -n "$py" ] || { echo "the bpy module needs CPython 3.11 with venv"; exit 1; }
  rm -rf .venv-bpy
  "$py" -m venv .venv-bpy
  .venv-bpy/bin/pip install -q --disable-pip-version-check "bpy==$BPY_VERSION"
fi
wheel=$(ls "${CARGO_TARGET_DIR:-$PWD/target}"/python-wheel/nst3d-*.whl 2>/dev/null | head -1 || true)
zip=$(bash tools/build_blender_extension.sh "$OUT/extension" $wheel | tail -1)
BLENDER_USER_RESOURCES="$OUT/bpy/user" .venv-bpy/bin/python python/blender/test_addon.py -- "$OUT/bpy" \
  --extension "$zip" --baked "$OUT/baked.blend" > "$OUT.bpy.log" 2>&1 || true
verdict "Blender $BPY_VERSION extension test" "$OUT.bpy.log"
stamp "Blender tests done"
