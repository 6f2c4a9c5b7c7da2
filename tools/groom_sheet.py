#!/usr/bin/env python3
"""Lays groom preview pictures out as the strand paper shows its results
(docs/guide/strands.md): one row per view, input | result |
painting, and measures how much of each picture the hair covers.

    python tools/groom_sheet.py OUT.png --style PAINTING.jpg \
        SHEET.png=LABEL [SHEET.png=LABEL ...]

Each SHEET is an input | result pair as `nst3d preview --input GROOM
--compare RESULT --turntable 4 ...` writes it (two equal pictures side by
side); each becomes a row, labelled LABEL, with the painting scaled to the
row's height on the right, written with 256 colours (small enough for
docs).

    python tools/groom_sheet.py --measure SHEET.png [SHEET.png ...]

prints, per sheet, the fraction of the picture the hair covers (a pixel off
the black background by more than 0.02 in any channel, as the judge's
hair-only loss counts it) in the input and the result, and their ratio: the
silhouette kept (1) or pulled in (below 1); the same for pixels brighter
than 0.25 (the body of the hair, without its faint translucent tips).
"""
import sys

import numpy as np
from PIL import Image, ImageDraw


def halves(path):
    img = np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0
    w = img.shape[1] // 2
    return img[:, :w], img[:, img.shape[1] - w:]


def coverage(pic, level=0.02):
    return float((pic.max(axis=2) > level).mean())


def measure(paths):
    for p in paths:
        a, b = halves(p)
        ca, cb = coverage(a), coverage(b)
        da, db = coverage(a, 0.25), coverage(b, 0.25)
        print(f"{p}: hair covers {ca:.4f} of the input picture, {cb:.4f} of the result's: ratio {cb / ca:.3f}; "
              f"brighter than 0.25: {da:.4f}, {db:.4f}: ratio {db / da:.3f}")


def sheet(out, style, pairs):
    rows = []
    painting = Image.open(style).convert("RGB")
    for spec in pairs:
        path, _, label = spec.partition("=")
        pic = Image.open(path).convert("RGB")
        h = pic.size[1]
        paint = painting.resize((round(painting.size[0] * h / painting.size[1]), h), Image.LANCZOS)
        row = Image.new("RGB", (pic.size[0] + 4 + paint.size[0], h), (90, 90, 90))
        row.paste(pic, (0, 0))
        row.paste(paint, (pic.size[0] + 4, 0))
        if label:
            d = ImageDraw.Draw(row)
            d.rectangle([0, 0, 8 + 7 * len(label), 18], fill=(0, 0, 0))
            d.text((4, 3), label, fill=(255, 255, 255))
        rows.append(row)
    width = max(r.size[0] for r in rows)
    total = sum(r.size[1] for r in rows) + 4 * (len(rows) - 1)
    canvas = Image.new("RGB", (width, total), (90, 90, 90))
    y = 0
    for r in rows:
        canvas.paste(r, (0, y))
        y += r.size[1] + 4
    # 256 colours: a third of the size of full RGB, small enough for docs.
    canvas.quantize(256, method=Image.Quantize.MEDIANCUT).save(out, optimize=True)


def main(argv):
    if len(argv) >= 2 and argv[0] == "--measure":
        measure(argv[1:])
        return 0
    if len(argv) < 4 or argv[1] != "--style":
        print(__doc__, file=sys.stderr)
        return 2
    sheet(argv[0], argv[2], argv[3:])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
