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

    python3 perf/journal/scripts/tube_opening.py SUITE/cylinder RUN [RUN ...]

`--lid MASKS` (the training views' glass masks, `mitsuba_scenes.py
--train-masks`) prints instead what those masks say against the lid: for
rings of points just under the open top, how many of the training views
see them outside their glass mask, exactly and with the masks grown by one
pixel (a mask pixel is glass only where all of it is, so a point on the
glass near an outline can fall just outside it). The hull carves a point
that at least a tenth of the views seeing it leave out
(`reflection.seed_agree` 0.9); the wall's rings are printed beside the
lid's for comparison (they ignore occlusion by Stage I's surface, which
the hull's test leaves out).

    python3 perf/journal/scripts/tube_opening.py SUITE/cylinder --lid MASKS/cylinder

Needs numpy and Pillow.
"""
import argparse
import json
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "suite"))
from noise_floor import grown  # noqa: E402

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


def lid_report(dataset, masks):
    """`--lid`: per ring of points, the training views that see it and how
    many of them leave it outside their glass mask (exact; grown by one pixel)."""
    meta = json.load(open(os.path.join(dataset, "transforms_train.json")))
    views = []
    for f in meta["frames"]:
        name = os.path.basename(f["file_path"])
        m = np.array(Image.open(os.path.join(masks, f"{name}.png")).convert("L")) > 127
        views.append((np.array(f["transform_matrix"], float), m, grown(m)))
    h, w = views[0][1].shape
    fx = 0.5 * w / np.tan(0.5 * meta["camera_angle_x"])

    def outside(points):
        seen, out, out_grown = (np.zeros(len(points)) for _ in range(3))
        for c2w, m, g in views:
            p = (points - c2w[:3, 3]) @ c2w[:3, :3]
            z = -p[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                u, v = p[:, 0] / z * fx + w / 2, -p[:, 1] / z * fx + h / 2
            ok = (z > 0) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
            ui, vi = np.clip(np.nan_to_num(u), 0, w - 1).astype(int), np.clip(np.nan_to_num(v), 0, h - 1).astype(int)
            seen += ok
            out += ok & ~m[vi, ui]
            out_grown += ok & ~g[vi, ui]
        return seen, out, out_grown

    th = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    print("| ring | views seeing it | outside the mask (mean, max) | grown by 1 px (mean, max) | carved at agreement 0.9, exact / grown |")
    print("|---|---|---|---|---|")
    rings = [(f"lid r = {r:.1f}", r, Z1 - 0.02) for r in np.arange(0.0, 0.85, 0.1)] + [(f"wall z = {z:.2f}", R, z) for z in (0.2, 0.6, 1.0, 1.25)]
    for label, r, z in rings:
        pts = np.stack([r * np.cos(th), r * np.sin(th), np.full_like(th, z)], 1)
        s, o, g = outside(pts)
        print(f"| {label} | {s.mean():.0f} | {o.mean():.1f}, {o.max():.0f} | {g.mean():.1f}, {g.max():.0f} | {(o > 0.1 * s).mean():.2f} / {(g > 0.1 * s).mean():.2f} |")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("runs", nargs="*")
    ap.add_argument("--lid", metavar="MASKS", help="the training views' glass masks (VIEW.png): what they say against the lid")
    a = ap.parse_args()
    if a.lid:
        return lid_report(a.dataset, a.lid)
    if not a.runs:
        raise SystemExit("give at least one RUN (or --lid MASKS)")
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
