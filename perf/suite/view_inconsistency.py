#!/usr/bin/env python3
"""Does the residual's disagreement between views mark the glass?

Issue 77's first cue: reflections are multi-view inconsistent, Stage I's
underfit is not. For every test pixel of a scene this takes Stage I's
surface point there (the test render's depth), finds the training views
that see that point (projected, and in front of or at their own Stage I
depth within 5%), and reads the signed residual I_gt - I_scat each of them
measured there (the residual maps a Stage II run saves). Per pixel:

  magnitude    mean over the views of |r| (what the residual hull seeds
               from: the same in every view where Stage I underfits)
  spread       the standard deviation over the views of r (per channel,
               averaged): large where the views disagree
  ratio        spread / (magnitude + 0.01)
  image spread the standard deviation over the views of the training
               images themselves there (multi-view photo-consistency)
  Stage I colour spread  the same of Stage I's own renders of the views

and prints each cue's AUC as a detector of the test glass mask (0.5:
chance), over the pixels at least 4 views see, with how many there are.

    python3 perf/suite/view_inconsistency.py DATA RUNS SCENE[,SCENE...] [VARIANT [SEED]]

DATA/SCENE: a dataset with test masks (`mitsuba_scenes.py`); RUNS: a
`suite.py` run tree (RUNS/SCENE/sSEED/I and RUNS/SCENE/sSEED/VARIANT, whose
`residual/` this reads; VARIANT `default`, SEED 0); the training views'
Stage I depth comes from `tgs render RUNS/SCENE/sSEED/I --cameras train`
(RUNS/SCENE/sSEED/I/renders/train; run it first). Needs numpy and mitsuba
(EXR and PNG reading).
"""
import json
import math
import os
import sys

import numpy as np
import mitsuba as mi

mi.set_variant("scalar_rgb")


def image(path):
    a = np.array(mi.Bitmap(path).convert(component_format=mi.Struct.Type.Float32, srgb_gamma=False), dtype=np.float64)
    return a[..., 0] if a.ndim == 3 and a.shape[2] == 1 else a


def plane(path):
    """The first channel of an image (tgs writes depth EXRs as RGB)."""
    a = image(path)
    return a[..., 0] if a.ndim == 3 else a


def frames(data, split):
    t = json.load(open(os.path.join(data, f"transforms_{split}.json")))
    return t["camera_angle_x"], t["frames"]


def world_points(depth, c2w, fov):
    """World points of a z-depth map (OpenGL camera: x right, y up, -z forward)."""
    h, w = depth.shape
    f = 0.5 * w / math.tan(0.5 * fov)
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    # tgs's pixel centres are at integers with the principal point at (w - 1) / 2.
    d = np.stack([(u - (w - 1) / 2) / f, -(v - (h - 1) / 2) / f, -np.ones_like(u, float)], -1)
    return (d * depth[..., None]) @ c2w[:3, :3].T + c2w[:3, 3]


def project(x, c2w, fov, w, h):
    """Pixel (col, row) and z-depth of world points in a camera."""
    w2c = np.linalg.inv(c2w)
    p = x @ w2c[:3, :3].T + w2c[:3, 3]
    z = -p[..., 2]
    f = 0.5 * w / math.tan(0.5 * fov)
    with np.errstate(divide="ignore", invalid="ignore"):
        col = f * p[..., 0] / z + (w - 1) / 2
        row = -f * p[..., 1] / z + (h - 1) / 2
    return col, row, z


def auc(score, label):
    """Probability that a glass pixel scores above a non-glass one (ties half)."""
    pos, neg = score[label], score[~label]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    order = np.argsort(np.concatenate([pos, neg]), kind="mergesort")
    ranks = np.empty(len(order))
    ranks[order] = np.arange(1, len(order) + 1)
    allv = np.concatenate([pos, neg])
    # Average the ranks of ties.
    _, inv, counts = np.unique(allv, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, ranks)
    ranks = sums[inv] / counts[inv]
    return (ranks[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg))


def scene(data, run_i, run_ii):
    fov, train = frames(data, "train")
    _, test = frames(data, "test")
    views = []
    for fr in train:
        name = os.path.basename(fr["file_path"])
        r = image(os.path.join(run_ii, "residual", name + ".exr"))[..., :3]
        z = plane(os.path.join(run_i, "renders", "train", name + "_depth.exr"))
        gt = image(os.path.join(data, fr["file_path"] + ("" if fr["file_path"].endswith(".png") else ".png")))[..., :3]
        own = image(os.path.join(run_i, "renders", "train", name + ".png"))[..., :3]
        views.append((np.array(fr["transform_matrix"], float), np.concatenate([r, gt, own], -1), z))
    cues = {"magnitude": [], "spread": [], "ratio": [], "image spread": [], "Stage I colour spread": []}
    labels = []
    for fr in test:
        name = os.path.basename(fr["file_path"])
        z = plane(os.path.join(run_i, "renders", "test", name + "_depth.exr"))
        mask = plane(os.path.join(data, fr["mask_path"])) > 0.5
        x = world_points(z, np.array(fr["transform_matrix"], float), fov)
        seen = z > 0
        samples = []
        for c2w, r, zv in views:
            h, w = zv.shape
            col, row, zp = project(x, c2w, fov, w, h)
            ci, ri = np.rint(col).astype(int), np.rint(row).astype(int)
            ok = seen & (zp > 0) & (ci >= 0) & (ri >= 0) & (ci < w) & (ri < h)
            ci, ri = np.where(ok, ci, 0), np.where(ok, ri, 0)
            zs = zv[ri, ci]
            ok &= (zs > 0) & (zp <= zs * 1.05)
            samples.append(np.where(ok[..., None], r[ri, ci], np.nan))
        a = np.stack(samples)  # views x H x W x 9: residual, image, Stage I's colour
        s, gt, own = a[..., :3], a[..., 3:6], a[..., 6:]
        n = np.isfinite(s[..., 0]).sum(0)
        use = n >= 4
        mag = np.nanmean(np.abs(s).mean(-1), 0)
        spread = np.nanstd(s, 0).mean(-1)
        cues["magnitude"].append(mag[use])
        cues["spread"].append(spread[use])
        cues["ratio"].append((spread / (mag + 0.01))[use])
        cues["image spread"].append(np.nanstd(gt, 0).mean(-1)[use])
        cues["Stage I colour spread"].append(np.nanstd(own, 0).mean(-1)[use])
        labels.append(mask[use])
    label = np.concatenate(labels)
    return {k: auc(np.concatenate(v), label) for k, v in cues.items()}, int(label.sum()), len(label)


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    data, runs, names = sys.argv[1], sys.argv[2], sys.argv[3].split(",")
    variant = sys.argv[4] if len(sys.argv) > 4 else "default"
    seed = sys.argv[5] if len(sys.argv) > 5 else "0"
    print("| scene | residual magnitude (the hull's cue) | residual spread | spread / magnitude | image spread | Stage I colour spread | glass / all pixels seen by ≥ 4 views |")
    print("|---|---|---|---|---|---|---|")
    for s in names:
        base = os.path.join(runs, s, f"s{seed}")
        train_depth = os.path.join(base, "I", "renders", "train")
        if not os.path.isdir(train_depth):
            sys.exit(f"{train_depth}: missing; run `tgs render {os.path.join(base, 'I')} --cameras train` first")
        a, g, n = scene(os.path.join(data, s), os.path.join(base, "I"), os.path.join(base, variant))
        print(f"| {s} | {a['magnitude']:.3f} | {a['spread']:.3f} | {a['ratio']:.3f} | {a['image spread']:.3f} | {a['Stage I colour spread']:.3f} | {g} / {n} |")


if __name__ == "__main__":
    main()
