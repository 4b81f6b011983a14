#!/usr/bin/env python3
"""Test PSNR of a run's renders, split into the glass mask and the rest.

Issue 12 asks what the reflection term gains; this says where. For each test
view of a Blender-format dataset with `test/NAME_mask.png`, it compares the
render `RENDERS/NAME.png` (a run's `renders/stage1`, `renders/stage2` or
`renders/test`) with the ground truth, both at the run's resolution:

    python3 perf/suite/psnr_split.py DATASET --downscale 4 RUN/renders/stage1 RUN/renders/test

With `--train-masks DIR` it compares the training views instead, each with
the glass mask `DIR/NAME.png` (what `mitsuba_scenes.py --train-masks`
writes) and the render `RENDERS/NAME.png` (`tgs render RUN --cameras train
--out RENDERS`): set beside the test split, how much of a stage's gain on
the glass is fit to the views it trained on and how much carries to new ones.

The ground truth is box-downscaled by `--downscale` (RGBA over a white
background, as `tgs train`'s default), the mask likewise, a pixel counting as
glass when all its sub-pixels are. Errors are pooled over the views, so the
"all" figure is not metrics.json's mean of per-view PSNRs; the renders are
8-bit PNGs. Needs numpy and Pillow.
"""
import argparse
import glob
import json
import os
import sys

import numpy as np
from PIL import Image


def load_rgb(path):
    try:
        im = np.asarray(Image.open(path)).astype(np.float64) / 255
    except OSError as e:
        sys.exit(f"{path}: cannot read the image ({e})")
    if im.ndim == 2:
        im = np.repeat(im[..., None], 3, axis=-1)
    if im.shape[-1] == 4:
        im = im[..., :3] * im[..., 3:] + (1 - im[..., 3:])
    return im[..., :3]


def box_down(a, f):
    h, w = a.shape[0] // f, a.shape[1] // f
    return a[: h * f, : w * f].reshape(h, f, w, f, *a.shape[2:]).mean(axis=(1, 3))


def test_masks(dataset):
    """(view name, mask path) of every test view of `dataset` that has
    test/NAME_mask.png, by path; exits when none has."""
    masks = sorted(glob.glob(os.path.join(dataset, "test", "*_mask.png")))
    if not masks:
        sys.exit(f"{dataset}/test: no NAME_mask.png")
    return [(os.path.basename(p)[: -len("_mask.png")], p) for p in masks]


def train_masks(dataset, masks):
    """(view name, ground truth path, mask path) of every training frame of
    `dataset` (transforms_train.json) with MASKS/NAME.png; exits when none has."""
    tf = os.path.join(dataset, "transforms_train.json")
    try:
        with open(tf) as f:
            frames = json.load(f)["frames"]
    except (OSError, ValueError, KeyError) as e:
        sys.exit(f"{tf}: cannot read its frames ({e})")
    views = []
    for fr in frames:
        rel = fr["file_path"] if fr["file_path"].endswith(".png") else fr["file_path"] + ".png"
        n = os.path.basename(rel)[: -len(".png")]
        m = os.path.join(masks, n + ".png")
        if os.path.exists(m):
            views.append((n, os.path.join(dataset, rel), m))
    if not views:
        sys.exit(f"{masks}: no NAME.png for any training frame of {dataset}")
    return views


def psnr(errors):
    return -10 * np.log10(np.concatenate(errors).mean())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", help="Blender-format dataset with test/NAME_mask.png")
    ap.add_argument("renders", nargs="+", help="folders holding NAME.png per test view")
    ap.add_argument("--downscale", type=int, default=1, help="the run's --downscale")
    ap.add_argument("--train-masks", metavar="DIR", help="compare the training views, with the glass masks DIR/NAME.png")
    a = ap.parse_args()
    if a.downscale < 1:
        sys.exit(f"--downscale must be at least 1, not {a.downscale}")
    if a.train_masks:
        paths = train_masks(a.dataset, a.train_masks)
    else:
        paths = [(n, os.path.join(a.dataset, "test", n + ".png"), p) for n, p in test_masks(a.dataset)]
    # The truth and the masks, read and downscaled once for every render folder.
    views = []
    for n, g, p in paths:
        gt = box_down(load_rgb(g), a.downscale)
        m = box_down((np.asarray(Image.open(p).convert("L")) > 127).astype(np.float64), a.downscale) > 0.999
        views.append((n, gt, m))
    for run in a.renders:
        glass, rest = [], []
        for n, gt, m in views:
            r = load_rgb(os.path.join(run, n + ".png"))
            if r.shape != gt.shape:
                sys.exit(f"{run}/{n}.png is {r.shape[1]}x{r.shape[0]}, the downscaled truth {gt.shape[1]}x{gt.shape[0]}: check --downscale")
            e = ((r - gt) ** 2).mean(axis=-1)
            glass.append(e[m])
            rest.append(e[~m])
        print(f"{run}: glass {psnr(glass):.3f} dB ({sum(map(len, glass))} px), rest {psnr(rest):.3f} dB, all {psnr(glass + rest):.3f}")


if __name__ == "__main__":
    main()
