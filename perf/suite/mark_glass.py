#!/usr/bin/env python3
"""Mark the glass of suite scenes in `tgs view` as a user would, scripted.

For each scene: the clicks a user makes around the glass (the exact mask's
outermost pixel towards each of 8 directions: the glass's outline, which
the user sees in the photo) in VIEWS training views where its outline
is clear (the mask whole, not cut by an occluder or the border: a user
marks the views that show the glass plainly; the view with the most glass,
then each next the one farthest in angle from those chosen),
replayed in `tgs view RUN --train-cameras` under xvfb-run (key G, `click`
lines, `marks DIR`). The masks land in OUT/SCENE, ready for
`suite.py --seed-masks OUT`; the script prints each scene's clicks and
the marked masks' IoU and recall against the exact ones.

    python3 perf/suite/mark_glass.py --scenes /tmp/suite --runs /tmp/suite-runs \\
        --exact /tmp/exact-masks --out /tmp/marked [--views 2] [--clicks 8] [--tgs target/release/tgs]

RUNS/SCENE/s0/I is the Stage I run `suite.py` trains (any run of the
scene will do: only its dataset and cameras are used); EXACT/SCENE holds
the exact training masks (`mitsuba_scenes.py --train-masks`). With
`--pieces ROOT`, a scene with ROOT/SCENE/K (the masks of its K-th piece of
glass alone, `mitsuba_scenes.py --train-masks --piece K`) is marked piece
by piece, as a user marks a vehicle's windows: each piece outlined in its
own views, key B between them. Needs numpy and Pillow (or imageio) to
read the masks.
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
from PIL import Image


def frames(scene_dir):
    t = json.load(open(os.path.join(scene_dir, "transforms_train.json")))
    return t["frames"]


def stem(path):
    b = os.path.basename(path)
    return os.path.splitext(b)[0] if b.endswith((".png", ".jpg", ".jpeg", ".exr")) else b


def clicks(mask, n, offset=0.0):
    """N clicks around the glass: its outermost pixel towards each of N directions from OFFSET radians (window coordinates of pixel centres)."""
    ys, xs = np.nonzero(mask)
    out = []
    for k in range(n):
        a = offset + k * 2 * math.pi / n
        i = int(np.argmax(math.cos(a) * xs + math.sin(a) * ys))
        p = (xs[i] + 0.5, ys[i] + 0.5)
        if p not in out:
            out.append(p)
    return out


def quad_corners(mask):
    """A pane's four corners as a user clicks them: the two mask pixels farthest apart, and on each side of the line
    through them the pixel farthest from it (the largest quadrilateral, near enough), clockwise on the screen from
    the one nearest its top left (window coordinates: each the outer corner of its pixel)."""
    ys, xs = np.nonzero(mask)
    p = np.stack([xs + 0.5, ys + 0.5], 1)
    if len(p) < 4:
        return [tuple(q) for q in p]
    d2 = ((p[:, None] - p[None]) ** 2).sum(-1)
    i, j = np.unravel_index(int(np.argmax(d2)), d2.shape)
    a, b = p[i], p[j]
    side = (b[0] - a[0]) * (p[:, 1] - a[1]) - (b[1] - a[1]) * (p[:, 0] - a[0])
    quad = [a, p[int(np.argmax(side))], b, p[int(np.argmin(side))]]
    c = np.mean(quad, 0)
    quad.sort(key=lambda q: math.atan2(q[1] - c[1], q[0] - c[0]))
    k = min(range(4), key=lambda t: quad[t][0] + quad[t][1])
    # The corner pixel's outer corner, where the pane's corner lies within it.
    return [tuple(float(v + 0.5 * np.sign(v - cv)) for v, cv in zip(quad[(k + t) % 4], c)) for t in range(4)]


def corner_clicks(corners, frame, fov, size):
    """A rectangle's world corners as a user clicks them in a view: each at the centre of the pixel it falls in."""
    c2w = np.array(frame["transform_matrix"], float)
    w, h = size
    f = 0.5 * w / math.tan(0.5 * fov)
    out = []
    for x in corners:
        p = c2w[:3, :3].T @ (np.array(x) - c2w[:3, 3])
        u, v = f * p[0] / -p[2] + 0.5 * w, -f * p[1] / -p[2] + 0.5 * h
        out.append((math.floor(u) + 0.5, math.floor(v) + 0.5))
    return out


def hull_area(mask):
    """Area of the convex hull of the mask's pixels (their corners), by the shoelace formula."""
    ys, xs = np.nonzero(mask)
    pts = sorted({(x + dx, y + dy) for x, y in zip(xs.tolist(), ys.tolist()) for dx in (0, 1) for dy in (0, 1)})
    if len(pts) < 3:
        return 0.0

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    hull = []
    for seq in (pts, pts[::-1]):
        start = len(hull)
        for p in seq:
            while len(hull) >= start + 2 and cross(hull[-2], hull[-1], p) <= 0:
                hull.pop()
            hull.append(p)
        hull.pop()
    return 0.5 * abs(sum(hull[i][0] * hull[(i + 1) % len(hull)][1] - hull[(i + 1) % len(hull)][0] * hull[i][1] for i in range(len(hull))))


def choose(masks, dirs, n, solidity, same_side=False):
    """Views where the glass's outline is clear (its mask fills at least SOLIDITY of its convex hull: not cut by
    an occluder or the image border), the one with the most glass first, then each next the one whose camera
    direction is farthest from those chosen; with SAME_SIDE only views looking the first one's way (within 70
    degrees: a pane's corners clicked from its back come in the mirrored order, which no user clicks) that show at
    least half as much of it (a user clicks corners where the pane faces the camera, not edge on)."""
    area = [m.sum() for m in masks]
    clear = [i for i in range(len(masks)) if area[i] >= 9 and not (masks[i][0].any() or masks[i][-1].any() or masks[i][:, 0].any() or masks[i][:, -1].any())]
    clear = [i for i in clear if area[i] >= solidity * hull_area(masks[i])]
    have = clear or [i for i in range(len(masks)) if area[i] >= 9]
    if not have:
        return []
    chosen = [max(have, key=lambda i: area[i])]
    if same_side:
        have = [i for i in have if float(np.dot(dirs[i], dirs[chosen[0]])) > math.cos(math.radians(70)) and area[i] >= 0.5 * area[chosen[0]]]
    while len(chosen) < n and len(chosen) < len(have):
        def gap(i):
            return min(math.acos(max(-1.0, min(1.0, float(np.dot(dirs[i], dirs[j]))))) for j in chosen)
        chosen.append(max((i for i in have if i not in chosen), key=gap))
    return chosen


def mark(a, scene, run, pieces, chosen, out, size, corners):
    """Replay the clicks of CHOSEN (views per piece) in `tgs view`, the masks into OUT; the clicks and the masks.
    A flat piece with CORNERS (its world corners, `mitsuba_scenes.py --piece`'s corners.json) is clicked at them."""
    t = json.load(open(os.path.join(a.scenes, scene, "transforms_train.json")))
    fr, fov = t["frames"], t["camera_angle_x"]
    if os.path.exists(out):
        raise SystemExit(f"{out} exists: choose another --out (nothing is written over)")
    lines = ["key t", "key g"]
    at, n_clicks = 0, 0
    for k, (piece, views) in enumerate(zip(pieces, chosen)):
        if k > 0:
            lines.append("key b")
        if a.flat:
            lines.append("key f")
        for i in views:
            lines += ["key n"] * (i - at) if i >= at else ["key p"] * (at - i)
            at = i
            if a.flat and corners[k] is not None:
                pts = corner_clicks(corners[k], fr[i], fov, size)
            else:
                pts = quad_corners(piece[i]) if a.flat else clicks(piece[i], a.clicks)
            for x, y in pts:
                lines.append(f"click {x} {y}")
                n_clicks += 1
    lines.append(f"marks {out}")
    os.makedirs(a.out, exist_ok=True)
    script = out + ".view.txt"
    open(script, "w").write("\n".join(lines) + "\n")
    w, h = size
    p = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1024x768x24", a.tgs, "view", run, "--size", f"{w}x{h}", "--mark-tolerance", str(a.tolerance), "--script", script], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{scene}: tgs view failed:\n{p.stdout}{p.stderr}")
    names = [stem(f["file_path"]) for f in fr]
    return n_clicks, [np.array(Image.open(os.path.join(out, n + ".png")).convert("L")) > 127 for n in names]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", required=True)
    ap.add_argument("--runs", required=True)
    ap.add_argument("--exact", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--clicks", type=int, default=8, help="directions clicked around the glass in each view")
    ap.add_argument("--solidity", type=float, default=0.9, help="a view is marked only where the glass's mask fills this share of its convex hull (its outline clear)")
    ap.add_argument("--only", action="append")
    ap.add_argument("--tolerance", type=int, default=0, help="tgs view --mark-tolerance: outlined views that may leave a point out")
    ap.add_argument("--pieces", metavar="ROOT", help="mark the glass of ROOT/SCENE/K piece by piece (one region each)")
    ap.add_argument("--flat", action="store_true", help="with --pieces: each piece a flat pane (key F), clicked at its four corners: where its corners.json (mitsuba_scenes.py --piece) puts them, each at the centre of the pixel it falls in, else the largest quadrilateral in its mask, clockwise from the top left")
    ap.add_argument("--greedy", action="store_true", help="the first two views by angle, each next the one whose marked mask is furthest off the glass (as a user sees the tinted region)")
    ap.add_argument("--tgs", default="target/release/tgs")
    a = ap.parse_args()
    if a.greedy and a.pieces:
        raise SystemExit("--greedy marks one region: not with --pieces")
    scenes = a.only or sorted(d for d in os.listdir(a.exact) if os.path.isdir(os.path.join(a.exact, d)))
    print("| scene | views marked | clicks | IoU against exact masks | recall | marked share of the image |")
    print("|---|---|---|---|---|---|")
    for scene in scenes:
        fr = frames(os.path.join(a.scenes, scene))
        names = [stem(f["file_path"]) for f in fr]
        masks = [np.array(Image.open(os.path.join(a.exact, scene, n + ".png")).convert("L")) > 127 for n in names]
        # Camera viewing directions (NeRF c2w: the camera looks down -z).
        dirs = [-np.array(f["transform_matrix"])[:3, 2] for f in fr]
        dirs = [d / np.linalg.norm(d) for d in dirs]
        pdir = os.path.join(a.pieces, scene) if a.pieces else None
        if pdir and os.path.isdir(pdir):
            keys = sorted(os.listdir(pdir), key=lambda k: int(k) if k.isdigit() else k)
            pieces = [[np.array(Image.open(os.path.join(pdir, k, n + ".png")).convert("L")) > 127 for n in names] for k in keys]
            found = [os.path.join(pdir, k, "corners.json") for k in keys]
            corners = [json.load(open(c))["corners"] if os.path.exists(c) else None for c in found]
        else:
            pieces, corners = [masks], [None]
        out = os.path.abspath(os.path.join(a.out, scene))
        if os.path.exists(out):
            raise SystemExit(f"{out} exists: choose another --out (nothing is written over)")
        h, w = masks[0].shape
        run = os.path.join(a.runs, scene, "s0", "I")
        chosen = [choose(piece, dirs, min(a.views, 2) if a.greedy else a.views, a.solidity, a.flat) for piece in pieces]
        if a.greedy:
            # A user sees the marked region tinted on the photo of the view
            # at hand, and outlines next the view where it is furthest off.
            while len(chosen[0]) < a.views:
                probe = os.path.abspath(os.path.join(a.out, f".{scene}-probe-{len(chosen[0])}"))
                n_clicks, k_masks = mark(a, scene, run, pieces, chosen, probe, (w, h), corners)
                shutil.rmtree(probe)
                os.remove(probe + ".view.txt")
                pool = [i for i in choose(masks, dirs, len(masks), a.solidity) if i not in chosen[0]]
                if not pool:
                    break
                chosen[0].append(max(pool, key=lambda i: int((k_masks[i] != masks[i]).sum())))
        n_clicks, _ = mark(a, scene, run, pieces, chosen, out, (w, h), corners)
        both = either = truth = covered = marked = 0
        for n, m in zip(names, masks):
            k = np.array(Image.open(os.path.join(out, n + ".png")).convert("L")) > 127
            both += int((k & m).sum())
            either += int((k | m).sum())
            truth += int(m.sum())
            marked += int(k.sum())
        print(f"| {scene} | {' / '.join(', '.join(str(i) for i in c) for c in chosen)} | {n_clicks} | {both / max(either, 1):.3f} | {both / max(truth, 1):.3f} | {marked / (len(masks) * w * h):.3f} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
