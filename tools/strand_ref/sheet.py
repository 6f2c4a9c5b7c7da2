"""sheet.py OUT.png SIZE REST NAME=FILE... : front renders (reference renderer) in a grid of 3 columns."""
import sys, os
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import *
from judge import load
out, size, rest = sys.argv[1], int(sys.argv[2]), sys.argv[3]
items = [('rest', rest)] + [a.split('=', 1) for a in sys.argv[4:]]
P0 = load(rest); flat = P0.reshape(-1, 3)
center = (flat.min(0).values + flat.max(0).values) / 2
R = (flat - center).norm(dim=1).max().item()
cam = Cam(center, R, 0, 0, size)
tiles = []
with torch.no_grad():
    for name, f in items:
        if f.endswith(('.png', '.jpg')):
            t = resize_grey(grey_of(Image.open(f)), size)[:, :size]
            t = torch.nn.functional.pad(t, (0, size - t.shape[1]))
        else:
            t = render(load(f), cam, sigma_px=0.7 * size / 256)
        tiles.append(t.clamp(0, 1))
cols = 3
while len(tiles) % cols: tiles.append(torch.zeros(size, size))
rows = [torch.cat(tiles[i:i + cols], 1) for i in range(0, len(tiles), cols)]
to_png(torch.cat(rows, 0), out)
