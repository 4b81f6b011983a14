#!/usr/bin/env python3
"""The Monte Carlo noise of a path-traced dataset's test views, and renders judged against it.

A path-traced image is a noisy estimate of the scene's light. No model can
fit that noise, so it bounds every test PSNR; and through glass in sunlight
the path tracer also leaves fireflies (single saturated pixels from rare
caustic paths), each worth more to a 50-pixel image's PSNR than the glass's
whole reflection. Both are measured against a second rendering of the same
test views with other sampler seeds:

    /tmp/mv/bin/python perf/suite/mitsuba_scenes.py --scene dome --res 50 --split test --sampler-seed 1 --out AGAIN
    /tmp/mv/bin/python perf/suite/noise_floor.py DATASET AGAIN/dome [RENDERS ...]

(the same --res and --spp as DATASET). For the test views it prints the
fireflies per view (a pixel whose smallest channel exceeds 0.9 and whose
brightness exceeds the median of its eight neighbours by 0.3, found in
either rendering; with its neighbours, which the film's filter lights too);
the noise variance without them (half the mean squared difference of the
two renderings, the mean over RGB), on the glass mask and off it; and the
PSNR an exact model would reach against DATASET's images there. For each
RENDERS folder (a run's `renders/test`): its PSNR over every pixel and over
the pixels without fireflies, and its error beyond the noise on the glass
and off it (its mean squared error minus the noise variance there: what a
better model could still remove). Errors are pooled over the views; the
images are 8-bit PNGs. Needs numpy and Pillow.
"""
import argparse
import os
import sys

import numpy as np
from PIL import Image

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from psnr_split import load_rgb, test_masks  # noqa: E402


def neighbours(a):
    """The eight neighbours of every pixel of a 2-D array (edges repeated), stacked."""
    h, w = a.shape
    p = np.pad(a, 1, mode="edge")
    return np.stack([p[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)])


def fireflies(img):
    """Isolated saturated pixels (see the module's doc)."""
    lum = img.mean(axis=-1)
    return (img.min(axis=-1) > 0.9) & (lum > np.median(neighbours(lum), axis=0) + 0.3)


def grown(core):
    """A mask and its pixels' eight neighbours."""
    return core | neighbours(core.astype(np.uint8)).any(axis=0)


def psnr(mse):
    return -10 * np.log10(mse) if mse > 0 else float("inf")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", help="Blender-format dataset with test/NAME.png and test/NAME_mask.png")
    ap.add_argument("again", help="the same test views rendered with other sampler seeds (mitsuba_scenes.py --sampler-seed)")
    ap.add_argument("renders", nargs="*", help="folders holding NAME.png per test view")
    a = ap.parse_args()
    names, truth, on, off, kept, noise, cores, share = [], [], [], [], [], [], 0, []
    for n, p in test_masks(a.dataset):
        gt = load_rgb(os.path.join(a.dataset, "test", n + ".png"))
        other = os.path.join(a.again, "test", n + ".png")
        if not os.path.isfile(other):
            sys.exit(f"{other}: missing (render {a.again} with mitsuba_scenes.py --split test --sampler-seed N)")
        b = load_rgb(other)
        if b.shape != gt.shape:
            sys.exit(f"{other} is {b.shape[1]}x{b.shape[0]}, {a.dataset}'s test views {gt.shape[1]}x{gt.shape[0]}")
        glass = np.asarray(Image.open(p).convert("L")) > 127
        core = fireflies(gt)
        ff = grown(core | fireflies(b))
        names.append(n)
        truth.append(gt)
        on.append(glass & ~ff)
        off.append(~glass & ~ff)
        kept.append(~ff)
        noise.append(((gt - b) ** 2).mean(axis=-1) / 2)
        cores += int(core.sum())
        share.append(ff.mean())

    def pooled(errs, sel):
        return np.concatenate([e[s] for e, s in zip(errs, sel)]).mean()

    print(f"{a.dataset}: {len(names)} test views, {cores / len(names):.1f} fireflies per view "
          f"(with the other rendering's and their neighbours {np.mean(share) * 100:.1f}% of the pixels, left out below)")
    print(f"  noise variance without them (x1e3): glass {pooled(noise, on) * 1e3:.3f}, off the glass {pooled(noise, off) * 1e3:.3f}, "
          f"all {pooled(noise, kept) * 1e3:.3f}: an exact model's PSNR {psnr(pooled(noise, kept)):.2f} dB")
    for r in a.renders:
        errs = []
        for n, gt in zip(names, truth):
            img = load_rgb(os.path.join(r, n + ".png"))
            if img.shape != gt.shape:
                sys.exit(f"{r}/{n}.png is {img.shape[1]}x{img.shape[0]}, the test views {gt.shape[1]}x{gt.shape[0]}")
            errs.append(((img - gt) ** 2).mean(axis=-1))
        every = np.concatenate([e.ravel() for e in errs]).mean()
        print(f"  {r}: PSNR {psnr(every):.3f} dB, without fireflies {psnr(pooled(errs, kept)):.3f} dB; "
              f"error beyond the noise (x1e3) glass {(pooled(errs, on) - pooled(noise, on)) * 1e3:.3f}, off {(pooled(errs, off) - pooled(noise, off)) * 1e3:.3f}")


if __name__ == "__main__":
    main()
