#!/usr/bin/env python3
"""A look sheet of one groom stylized toward several styles, drawn by
`nst3d preview` (the pictures an artist sees): a front row and a side row,
input | each style's result, and a row of the styles under their results.

    python3 tools/groom_look_sheet.py OUT.png GROOM [--mesh MESH] [--up y|z] [--height 512] \
        [--preset NAME] NAME=RESULT.ply=STYLE.png [NAME=RESULT.ply=STYLE.png ...]

Every picture is `--height` pixels tall (512 by default); front is the
preview's first turntable azimuth, side the second (90 degrees round the
up axis); `--preset` draws with that preset's look and culling (grass on
its ground needs `--preset grass`). Needs the release binary (target/release/nst3d) and Pillow.
"""
import argparse
import os
import subprocess
import sys
import tempfile

from PIL import Image, ImageDraw

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def previews(groom, mesh, up, height, workdir, tag, preset=None):
    """Front and side pictures of `groom`."""
    out = os.path.join(workdir, tag + '_####.png')
    cmd = [os.path.join(ROOT, 'target/release/nst3d'), 'preview', '--input', groom, '--turntable', '4',
           '--height', str(height), '--out', out]
    if mesh:
        cmd += ['--mesh', mesh]
    if up:
        cmd += ['--up', up]
    if preset:
        cmd += ['--preset', preset]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f'groom_look_sheet: nst3d preview failed on {groom}: {r.stderr.strip().splitlines()[-1:]}')
    return [Image.open(out.replace('####', f'{i:04d}')).convert('RGB') for i in (1, 2)]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('out')
    ap.add_argument('groom')
    ap.add_argument('items', nargs='+', help='NAME=RESULT=STYLE')
    ap.add_argument('--mesh')
    ap.add_argument('--up')
    ap.add_argument('--height', type=int, default=512)
    ap.add_argument('--preset')
    a = ap.parse_args()
    items = []
    for it in a.items:
        parts = it.split('=')
        if len(parts) != 3:
            sys.exit(f'groom_look_sheet: {it!r} is not NAME=RESULT=STYLE')
        items.append(parts)
    h = a.height
    with tempfile.TemporaryDirectory() as tmp:
        cols = [('input', previews(a.groom, a.mesh, a.up, h, tmp, 'input', a.preset), None)]
        for name, result, style in items:
            cols.append((name, previews(result, a.mesh, a.up, h, tmp, name, a.preset), style))
    w = cols[0][1][0].width
    sheet = Image.new('RGB', (w * len(cols), 3 * h), 'black')
    draw = ImageDraw.Draw(sheet)
    for i, (name, (front, side), style) in enumerate(cols):
        sheet.paste(front, (i * w, 0))
        sheet.paste(side, (i * w, h))
        if style:
            s = Image.open(style).convert('RGB')
            s = s.resize((max(1, round(s.width * h / s.height)), h))
            left = (s.width - w) // 2
            s = s.crop((left, 0, left + w, h)) if s.width > w else s
            sheet.paste(s, (i * w + (w - s.width) // 2, 2 * h))
        draw.text((i * w + 8, 8), name, fill='white')
    tmp_out = a.out + '.tmp.png'
    sheet.save(tmp_out)
    os.replace(tmp_out, a.out)


if __name__ == '__main__':
    main()
