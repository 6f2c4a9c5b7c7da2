#!/usr/bin/env python3
"""How much colour a groom can carry before its grey look gets worse
(the grey half of the colour stage against white hair).

    python tools/color_toward_white.py OUTDIR T SHEET.png [SHEET.png ...]

Each SHEET is a `grey | colour` pair as `nst3d preview --input GREY
--compare COLOUR --color --turntable 8 ...` writes it: the same strands
drawn in white and in their stylized colours. The splat renderer is linear
in the strands' colours (the splats' opacities do not depend on them), so
the picture of colours blended towards white, `(1 − T) c + T · white`, is
the same blend of the two pictures; this writes it without rendering
again, as two sheets per input, `grey | blend`:

- `OUTDIR/c_NAME`: in colour, for the colour judge
  (`judge_sanity PAINTING OUTDIR/c_NAME --color`);
- `OUTDIR/g_NAME`: the luminance of both halves (the judge's weights), for
  the grey judge (`judge_sanity PAINTING OUTDIR/g_NAME`).

T = 0 is the stylized colour, T = 1 the grey result. (Up to the PNGs'
8-bit steps: the grey judge of the written `T = 0` sheets is 1.063 where
`nst3d preview` scores the renders themselves 1.078.)
"""
import os
import sys

import numpy as np
from PIL import Image

# The judge's luminance weights (crates/core/src/image.rs, `LUMA`).
LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


def save(path, img):
    # Written under a temporary name and renamed: a stopped run leaves no half picture.
    tmp = path + ".tmp.png"
    Image.fromarray((np.clip(img, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)).save(tmp)
    os.replace(tmp, path)


def main(argv):
    if len(argv) < 3:
        sys.exit("usage: color_toward_white.py OUTDIR T SHEET.png [SHEET.png ...]")
    out, sheets = argv[0], argv[2:]
    try:
        t = float(argv[1])
    except ValueError:
        sys.exit(f"T = {argv[1]!r} is not a number")
    if not 0.0 <= t <= 1.0:
        sys.exit(f"T = {t} is not in [0, 1]")
    os.makedirs(out, exist_ok=True)
    for path in sheets:
        try:
            img = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
        except OSError as e:
            sys.exit(f"{path}: cannot read the sheet ({e})")
        w = img.shape[1] // 2
        grey, colour = img[:, :w], img[:, img.shape[1] - w :]
        sheet = np.concatenate([grey, (1.0 - t) * colour + t * grey], axis=1)
        name = os.path.basename(path)
        save(os.path.join(out, "c_" + name), sheet)
        save(os.path.join(out, "g_" + name), sheet @ LUMA)


if __name__ == "__main__":
    main(sys.argv[1:])
