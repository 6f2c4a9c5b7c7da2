#!/usr/bin/env python3
"""Crops the "after" panel out of nst3d preview sheets and lays them side by
side, labelled, in one small PNG (docs/design/volumes.md, "Art-directable
strength").

    python tools/strip.py OUT.png [--style STYLE.jpg] [--height 256] \
        [--row ROW_LABEL] SHEET.png=LABEL SHEET.png=LABEL ... \
        [--row ROW_LABEL] SHEET.png=LABEL ...

A preview sheet (`nst3d volume --preview`) is before | after | painting,
all PREVIEW_HEIGHT (384) rows tall; before and after are equally wide and
the painting keeps its aspect, so the after panel is found from the sheet's
width and the painting's aspect (--style, default Starry Night). Each
`--row` starts a new row of the strip; `--before` puts the first sheet's
"before" panel at the start of every row. Panels are scaled to --height
rows and the strip is written as a 8-bit grey PNG, small enough for docs.

    python tools/strip.py --sheet SHEET.png OUT.png

writes a whole preview sheet (before | after | painting) as a grey PNG,
the smoke at 128 greys and the painting at 32, about 150 KB
(docs/design/volumes.md).

    python tools/strip.py --measure SHEET.png ...

prints, for each sheet, numbers that go with the pictures: the silhouette
IoU of after against before (grey > 0.15), the mean grey inside the input's
smoke, the RMS of the laplacian of the row means (horizontal streaks) and
of the column means over lit rows/columns, and the largest laplacian of the
column means near the centre column in the top half (the vertical line of
docs/design/volumes.md) against that half's RMS. Panels are brought
back to 106 rows, about the optimiser's own render, first.

Needs Pillow and NumPy (e.g. a throwaway venv:
`python3 -m venv /tmp/pilvenv && /tmp/pilvenv/bin/pip install pillow numpy`).
"""
import sys

import numpy as np
from PIL import Image, ImageDraw, ImageFont

SHEET_HEIGHT = 384


def panels(sheet, style_aspect):
    """(before, after) of a preview sheet as PIL images."""
    w, h = sheet.size
    if h != SHEET_HEIGHT:
        sys.exit(f"strip: sheet is {h} rows tall, expected {SHEET_HEIGHT}")
    painting = round(style_aspect * h)
    for p in (painting, painting - 1, painting + 1):
        if (w - p) % 2 == 0 and w - p > 0:
            half = (w - p) // 2
            return sheet.crop((0, 0, half, h)), sheet.crop((half, 0, 2 * half, h))
    sys.exit(f"strip: cannot split a {w}-wide sheet with a {painting}-wide painting")


def measure(path, aspect):
    before, after = panels(Image.open(path).convert("L"), aspect)
    b = np.asarray(before, dtype=np.float64) / 255
    a = np.asarray(after, dtype=np.float64) / 255
    inside = b > 0.15
    iou = (inside & (a > 0.15)).sum() / (inside | (a > 0.15)).sum()

    def small(p):
        w = round(p.width * 106 / p.height)
        return np.asarray(p.resize((w, 106), Image.BOX), dtype=np.float64) / 255

    def lap_rms(m):
        lit = (m > 0.1 * m.max())[1:-1]
        lap = m[:-2] - 2 * m[1:-1] + m[2:]
        return np.sqrt((lap[lit] ** 2).mean()), lap

    sb, sa = small(before), small(after)
    rows, _ = lap_rms(sa.mean(axis=1))
    cols, _ = lap_rms(sa.mean(axis=0))
    rows_in, _ = lap_rms(sb.mean(axis=1))
    top, lap = lap_rms(sa[:53].mean(axis=0))
    c = sa.shape[1] // 2 - 1
    centre = np.abs(lap[c - 2:c + 2]).max()
    print(f"{path}: IoU {iou:.2f}  grey {a[inside].mean():.2f} (input {b[inside].mean():.2f})  "
          f"rows {rows:.3f} (input {rows_in:.3f})  cols {cols:.3f}  centre line {centre:.3f} vs {top:.3f}")


def sheet(path, out, aspect):
    """The whole sheet in grey: smoke panels at 128 levels, painting at 32."""
    im = Image.open(path).convert("L")
    before, _ = panels(im, aspect)
    a = np.asarray(im, dtype=np.float64)
    q = lambda x, n: np.round(x / 255 * (n - 1)) * (255 / (n - 1))
    half = 2 * before.width
    a[:, :half], a[:, half:] = q(a[:, :half], 128), q(a[:, half:], 32)
    Image.fromarray(a.astype(np.uint8), "L").save(out, optimize=True)


def font(size):
    for name in ("DejaVuSans.ttf", "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf"):
        try:
            return ImageFont.truetype(name, size)
        except OSError:
            pass
    return ImageFont.load_default()


def main():
    argv = sys.argv[1:]
    if not argv or argv[0] in ("-h", "--help"):
        sys.exit(__doc__)
    if argv[0] == "--sheet":
        sheet(argv[1], argv[2], 1024 / 640)
        return
    if argv[0] == "--measure":
        for path in argv[1:]:
            measure(path, 1024 / 640)
        return
    out, style, H, with_before, items = argv[0], None, 256, False, []
    i = 1
    while i < len(argv):
        a = argv[i]
        if a == "--style":
            style, i = argv[i + 1], i + 2
        elif a == "--height":
            H, i = int(argv[i + 1]), i + 2
        elif a == "--before":
            with_before, i = True, i + 1
        elif a == "--row":
            items.append(("row", argv[i + 1]))
            i += 2
        else:
            items.append(("sheet", a))
            i += 1

    aspect = 1024 / 640
    if style:
        with Image.open(style) as s:
            aspect = s.width / s.height

    # Rows of (label, image); "--row X" starts a row labelled X.
    rows, row_labels = [[]], [""]
    for kind, it in items:
        if kind == "row":
            if rows[-1]:
                rows.append([])
                row_labels.append("")
            row_labels[-1] = it
            continue
        path, _, label = it.partition("=")
        before, after = panels(Image.open(path).convert("L"), aspect)
        if with_before and not rows[-1]:
            rows[-1].append(("input", before))
        rows[-1].append((label or path, after))

    lab_h = max(14, H // 12)
    f = font(lab_h - 2)
    side = max((int(f.getlength(r)) + 8 if r else 0) for r in row_labels)
    pad = 4
    scaled = [[(l, im.resize((max(1, round(im.width * H / im.height)), H), Image.LANCZOS)) for l, im in r] for r in rows]
    # A panel's slot is as wide as its picture or its label, whichever is wider.
    slot = lambda l, im: max(im.width, int(f.getlength(l)) + 4)
    width = side + max(sum(slot(l, im) + pad for l, im in r) for r in scaled)
    height = len(scaled) * (H + lab_h + pad)
    canvas = Image.new("L", (width, height), 255)
    draw = ImageDraw.Draw(canvas)
    y = 0
    for label, r in zip(row_labels, scaled):
        if label:
            draw.text((4, y + lab_h + H // 2 - lab_h // 2), label, fill=0, font=f)
        x = side
        for l, im in r:
            draw.text((x + 2, y), l, fill=0, font=f)
            w = slot(l, im)
            canvas.paste(im, (x + (w - im.width) // 2, y + lab_h))
            x += w + pad
        y += H + lab_h + pad
    # Quantise to 64 greys: the smoke is smooth, this keeps the PNG small.
    a = np.asarray(canvas, dtype=np.float32)
    a = (np.round(a / 255 * 63) * (255 / 63)).astype(np.uint8)
    Image.fromarray(a, "L").save(out, optimize=True)


if __name__ == "__main__":
    main()
