#!/usr/bin/env bash
# Builds the Blender extension (Blender 4.2 and later): a zip of the add-on
# package python/blender/nst3d_blender with the nst3d wheel for this
# machine in wheels/, its manifest's version, platforms and wheels set from
# that wheel. Blender installs the wheel with the extension, so users need
# nothing else (Edit > Preferences > Get Extensions > Install from Disk, or
# `blender --command extension install-file -r user_default -e ZIP`).
#
#   bash tools/build_blender_extension.sh [OUT_DIR] [WHEEL]
#
# OUT_DIR defaults to out/blender-extension. WHEEL is an nst3d wheel already
# built (tools/test_python.sh leaves one in $CARGO_TARGET_DIR/python-wheel);
# without it the wheel is built here with maturin (release). The wheel is
# abi3 (CPython 3.9 and later): one wheel serves every Blender from 4.2 on.
# Prints the zip's path last.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/blender-extension}
wheel=${2:-}
if [ -z "$wheel" ]; then
  [ -x .venv-py/bin/python ] || /usr/bin/python3 -m venv --system-site-packages .venv-py
  .venv-py/bin/pip install -q --disable-pip-version-check "maturin>=1.5,<2"
  wheels="${CARGO_TARGET_DIR:-$PWD/target}/python-wheel"
  rm -rf "$wheels"
  (cd python && ../.venv-py/bin/maturin build --release --quiet -i ../.venv-py/bin/python -o "$wheels")
  wheel=$(ls "$wheels"/nst3d-*.whl)
fi
mkdir -p "$out"
python3 - "$wheel" "$out" python/blender/nst3d_blender <<'PY'
import os, re, sys, zipfile

wheel, out, src = sys.argv[1:]
name = os.path.basename(wheel)
version, plat = name.split("-")[1], name[:-4].split("-")[-1]
# The wheel's platform tag as Blender names platforms.
arch = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}
system = "linux" if "linux" in plat else "macos" if plat.startswith("macosx") else "windows"
machine = next((v for k, v in arch.items() if plat.endswith(k)), None)
if machine is None or plat.endswith("universal2"):
    sys.exit(f"build_blender_extension: no Blender platform for the wheel {name}")
platform = f"{system}-{machine}"
manifest = open(os.path.join(src, "blender_manifest.toml")).read()
for key, value in (("version", f'"{version}"'), ("platforms", f'["{platform}"]'),
                   ("wheels", f'["./wheels/{name}"]')):
    manifest, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", manifest)
    if n != 1:
        sys.exit(f"build_blender_extension: the manifest has no single '{key} =' line")
zip_path = os.path.join(out, f"nst3d-{version}-{platform.replace('-', '_')}.zip")
tmp = zip_path + ".tmp"
with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
    z.writestr("blender_manifest.toml", manifest)
    for f in sorted(os.listdir(src)):
        if f.endswith(".py"):
            z.write(os.path.join(src, f), f)
    z.write(wheel, f"wheels/{name}")
os.replace(tmp, zip_path)
print(zip_path)
PY
