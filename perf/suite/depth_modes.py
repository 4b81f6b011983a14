#!/usr/bin/env python3
"""Does Stage I leave a faint layer at the glass? (issue 77's TSPE-GS lead)

TSPE-GS finds semi-transparent surfaces as a weak near mode in a pixel's
blend weights: a little opacity in front of the main surface. This casts
every test pixel's ray through a Stage I run's surfels on the CPU (the
2DGS ray-splat intersection, alpha = min(0.99, opacity G), front to back,
no screen-space filter; its median depth is within ~0.1 of `tgs render`'s
depth map), and takes per pixel

  front 0.8  the blend weight in front of 0.8 x the median depth (the
             depth where the transmittance falls to 0.5)
  front 0.9  the same in front of 0.9 x the median depth
  total      the ray's total weight (1 - final transmittance)

and prints each cue's mean on and off the glass and its AUC as a detector
of the test glass masks (0.5: chance; the same AUC as glass_evidence.py).

    python3 perf/suite/depth_modes.py DATA RUNS SCENE[,SCENE...] [SEED] [--views N]

DATA/SCENE: a dataset with test masks (`mitsuba_scenes.py`); RUNS: a
`suite.py` run tree (RUNS/SCENE/sSEED/I/point_cloud.ply). About a minute a
scene at 50² with 12 test views. Needs numpy and Pillow.
"""
import argparse
import json
import math
import os

import numpy as np
from PIL import Image


def read_ply(path):
    """The float properties of a binary PLY's vertices, by name."""
    with open(path, "rb") as f:
        names, n = [], 0
        while True:
            line = f.readline().decode().strip()
            if line.startswith("element vertex"):
                n = int(line.split()[-1])
            if line.startswith("property float"):
                names.append(line.split()[-1])
            if line == "end_header":
                break
        data = np.frombuffer(f.read(n * 4 * len(names)), dtype="<f4").reshape(n, len(names))
    return {k: data[:, i].astype(float) for i, k in enumerate(names)}


def surfels(d):
    """Centres, tangent axes scaled by 1 / scale, normals and opacities (tgs's PLY: log scales, raw opacity, w x y z)."""
    q = np.stack([d[f"rot_{i}"] for i in range(4)], 1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    tu = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], 1)
    tv = np.stack([2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)], 1)
    nn = np.cross(tu, tv)
    c = np.stack([d["x"], d["y"], d["z"]], 1)
    return c, tu / np.exp(d["scale_0"])[:, None], tv / np.exp(d["scale_1"])[:, None], nn, 1 / (1 + np.exp(-d["opacity"]))


def cues(s, origin, dirs, chunk=64):
    """Per ray: weight in front of 0.8 and 0.9 x the median depth, total weight."""
    c, tu, tv, nn, op = s
    co_n = ((c - origin) * nn).sum(1)
    out = []
    for k in range(0, len(dirs), chunk):
        dd = dirs[k:k + chunk]
        dn = dd @ nn.T
        t = co_n[None] / np.where(np.abs(dn) < 1e-9, 1e-9, dn)
        rel = origin[None, None] + t[..., None] * dd[:, None] - c[None]
        u, v = (rel * tu[None]).sum(-1), (rel * tv[None]).sum(-1)
        a = np.minimum(0.99, op[None] * np.exp(-0.5 * (u * u + v * v)))
        a[(t < 0.2) | (a < 1 / 255)] = 0
        for i in range(len(dd)):
            hit = np.nonzero(a[i])[0]
            hit = hit[np.argsort(t[i, hit], kind="stable")]
            al, tt = a[i, hit], t[i, hit]
            w = al * np.concatenate([[1.0], np.cumprod(1 - al)[:-1]])
            cw = np.cumsum(w)
            if len(w) == 0 or cw[-1] < 0.5:
                out.append((0.0, 0.0, cw[-1] if len(w) else 0.0))
                continue
            med = tt[np.searchsorted(cw, 0.5)]
            out.append((w[tt < 0.8 * med].sum(), w[tt < 0.9 * med].sum(), cw[-1]))
    return np.array(out)


def auc(pos, neg, cap=4000):
    """P(a glass pixel's value > an off-glass pixel's), ties counted half."""
    rng = np.random.default_rng(0)
    pos = pos if len(pos) <= cap else rng.choice(pos, cap, replace=False)
    neg = neg if len(neg) <= cap else rng.choice(neg, cap, replace=False)
    return float((pos[:, None] > neg[None, :]).mean() + 0.5 * (pos[:, None] == neg[None, :]).mean())


def scene_cues(data, run, views):
    """Each test pixel's cues and whether it is glass, over the first `views` test views."""
    meta = json.load(open(os.path.join(data, "transforms_test.json")))
    s = surfels(read_ply(os.path.join(run, "point_cloud.ply")))
    rows, glass = [], []
    for fr in meta["frames"][:views]:
        name = os.path.basename(fr["file_path"])
        mask = np.asarray(Image.open(os.path.join(data, "test", name + "_mask.png")).convert("L")) > 127
        h, w = mask.shape
        f = 0.5 * w / math.tan(0.5 * meta["camera_angle_x"])
        m = np.array(fr["transform_matrix"])
        jj, ii = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
        dc = np.stack([(ii + 0.5 - w / 2) / f, -(jj + 0.5 - h / 2) / f, -np.ones((h, w))], -1).reshape(-1, 3)
        dw = dc @ m[:3, :3].T
        rows.append(cues(s, m[:3, 3], dw / np.linalg.norm(dw, axis=1, keepdims=True)))
        glass.append(mask.reshape(-1))
    return np.concatenate(rows), np.concatenate(glass)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("runs")
    ap.add_argument("scenes")
    ap.add_argument("seed", nargs="?", type=int, default=0)
    ap.add_argument("--views", type=int, default=12, help="test views to cast (default 12)")
    a = ap.parse_args()
    print("| scene | front 0.8: glass / off, AUC | front 0.9: glass / off, AUC | total: glass / off, AUC |")
    print("|---|---|---|---|")
    for scene in a.scenes.split(","):
        run = os.path.join(a.runs, scene, f"s{a.seed}", "I")
        if not os.path.exists(os.path.join(run, "point_cloud.ply")):
            raise SystemExit(f"{run}/point_cloud.ply: missing (a suite.py Stage I run)")
        c, g = scene_cues(os.path.join(a.data, scene), run, a.views)
        if not g.any() or g.all():
            raise SystemExit(f"{scene}: no test view shows both glass and something else")
        cells = [f"{c[g, k].mean():.3f} / {c[~g, k].mean():.3f}, {auc(c[g, k], c[~g, k]):.2f}" for k in range(3)]
        print(f"| {scene} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
