#!/usr/bin/env python3
"""Normal maps of runs side by side with the ground truth of one test view.

The glass normal MAE alone can look good when the reflection set is one
sheet over the whole image at the glass's orientation (perf/RESULTS.md,
forty-second entry); a look at the normal maps tells a surface from a
sheet. For one test view of a dataset with normals (`mitsuba_scenes.py`
writes `test/NAME_normal.npy` and `test/NAME_mask.png`) this writes one
PNG, one row per scene given, each row:

    ground-truth image | ground-truth normal | glass mask | RUN_1 normal | RUN_2 normal | ...

(normals as RGB = n * 0.5 + 0.5, world space, as `tgs` writes
`renders/test/NAME_normal.png`), scaled up by --scale with nearest
neighbours. Rows of different sizes are padded with black.

    python3 perf/journal/scripts/normal_panels.py --out panels.png --view r_0 \\
        --row /tmp/suite/globe RUNS/globe/s0/I RUNS/globe/s0/default \\
        --row /tmp/suite/pane RUNS/pane/s0/I RUNS/pane/s0/default

Needs numpy and Pillow.
"""
import argparse
import os

import numpy as np
from PIL import Image


def rgb(path):
    if not os.path.exists(path):
        raise SystemExit(f"missing {path}")
    return np.asarray(Image.open(path).convert("RGB"))


def row(dataset, runs, view):
    test = os.path.join(dataset, "test")
    npy = os.path.join(test, f"{view}_normal.npy")
    if not os.path.exists(npy):
        raise SystemExit(f"missing {npy}: the dataset has no ground-truth normals for view {view}")
    n = np.load(npy).astype(np.float64)
    tiles = [
        rgb(os.path.join(test, f"{view}.png")),
        (np.clip(n * 0.5 + 0.5, 0.0, 1.0) * 255).astype(np.uint8),
        rgb(os.path.join(test, f"{view}_mask.png")),
    ]
    for r in runs:
        tiles.append(rgb(os.path.join(r, "renders", "test", f"{view}_normal.png")))
    h = max(t.shape[0] for t in tiles)
    tiles = [np.pad(t, ((0, h - t.shape[0]), (0, 0), (0, 0))) for t in tiles]
    return np.concatenate(tiles, 1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--view", default="r_0")
    ap.add_argument("--scale", type=int, default=4)
    ap.add_argument("--row", nargs="+", action="append", required=True, metavar="DATASET RUN", help="a dataset, then the runs to show (repeatable)")
    a = ap.parse_args()
    if os.path.exists(a.out):
        raise SystemExit(f"{a.out} exists: not writing over it")
    rows = [row(r[0], r[1:], a.view) for r in a.row]
    w = max(r.shape[1] for r in rows)
    img = np.concatenate([np.pad(r, ((0, 0), (0, w - r.shape[1]), (0, 0))) for r in rows], 0)
    Image.fromarray(img).resize((img.shape[1] * a.scale, img.shape[0] * a.scale), Image.NEAREST).save(a.out)
    print(f"wrote {a.out} ({len(rows)} rows)")


if __name__ == "__main__":
    main()
