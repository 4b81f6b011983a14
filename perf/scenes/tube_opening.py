#!/usr/bin/env python3
"""The open tube's glass normal error, split where the view looks in
through its opening and where it sees the wall from outside.

The masks' hull of an open tube (`mitsuba_scenes.py` scene `cylinder`:
radius 0.85 about the z axis, z in [0.005, 1.305], no lid) is a solid
cylinder: every view sees the opening inside the glass's outline, so
silhouettes close the top with a lid that is not there. Seeds on it face
up, while through the opening the first glass is the far wall, seen from
inside. This prints, per run, the mean angular error of the rendered
normal (`renders/test/NAME_normal.png`) against the ground truth on the
test views' glass masks, for the pixels whose ray enters through the
opening and for the rest.

    python3 perf/scenes/tube_opening.py SUITE/cylinder RUN [RUN ...]

Needs numpy and Pillow.
"""
import argparse
import json
import os

import numpy as np
from PIL import Image

R, Z0, Z1 = 0.85, 0.005, 1.305


def through_opening(o, d):
    """Rays (unit d) whose first meeting with the tube is its open top."""
    a = d[..., 0] ** 2 + d[..., 1] ** 2
    b = 2 * (o[0] * d[..., 0] + o[1] * d[..., 1])
    c = o[0] ** 2 + o[1] ** 2 - R * R
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        t_wall = np.where(disc > 0, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
        z_wall = o[2] + t_wall * d[..., 2]
        t_top = (Z1 - o[2]) / d[..., 2]
    wall = (disc > 0) & (t_wall > 0) & (z_wall >= Z0) & (z_wall <= Z1)
    p = o + t_top[..., None] * d
    top = (t_top > 0) & (p[..., 0] ** 2 + p[..., 1] ** 2 < R * R)
    return top & ~(wall & (t_wall < t_top))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("runs", nargs="+")
    a = ap.parse_args()
    meta = json.load(open(os.path.join(a.dataset, "transforms_test.json")))
    errs = {r: ([], []) for r in a.runs}
    for f in meta["frames"]:
        name = os.path.basename(f["file_path"])
        mask = np.array(Image.open(os.path.join(a.dataset, "test", f"{name}_mask.png")).convert("L")) > 127
        gt = np.load(os.path.join(a.dataset, "test", f"{name}_normal.npy"))
        h, w = mask.shape
        fx = 0.5 * w / np.tan(0.5 * meta["camera_angle_x"])
        c2w = np.array(f["transform_matrix"], float)
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        d = np.stack([(u - w / 2) / fx, -(v - h / 2) / fx, -np.ones_like(u)], -1) @ c2w[:3, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        top = through_opening(c2w[:3, 3], d)
        g = gt / np.maximum(np.linalg.norm(gt, axis=-1, keepdims=True), 1e-9)
        keep = mask & (np.linalg.norm(gt, axis=-1) > 1e-6)
        for r in a.runs:
            n = np.array(Image.open(os.path.join(r, "renders", "test", f"{name}_normal.png")).convert("RGB"), float) / 255 * 2 - 1
            n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)
            ang = np.degrees(np.arccos(np.clip((n * g).sum(-1), -1, 1)))
            errs[r][0].extend(ang[keep & top])
            errs[r][1].extend(ang[keep & ~top])
    for r in a.runs:
        top, wall = (np.array(e) for e in errs[r])
        both = np.concatenate([top, wall])
        print(f"{r}: through the opening {len(top)} px {top.mean():.1f} deg; the wall from outside {len(wall)} px {wall.mean():.1f} deg; all {both.mean():.1f} deg")


if __name__ == "__main__":
    main()
