#!/usr/bin/env python3
"""How much of the glass's reflection a Stage I run leaves for Stage II to find.

Stage II seeds the reflection set where the Stage I residual |I_gt - I_scat|
is (stages/reflection/seed/). That only finds the glass if the residual is
larger on the glass than elsewhere. This measures it on a run's test views
(whose masks mark the glass) against a render of the same views with the
glass's reflection switched off (`mitsuba_scenes.py --no-reflection`), so
that the reflection itself is known:

- reflection: mean |I_gt - I_norefl| on the glass, the light the glass
  reflects (the same difference off the glass is the path tracer's noise
  between two renders);
- Stage I residual on the glass and off it, their ratio per view averaged
  over the views (the contrast, as `metrics.json`'s `residual_contrast`
  measures it on the float renders), and the AUC of
  the residual as a glass detector (the chance that a glass pixel's
  residual exceeds an off-glass pixel's; 0.5: no better than a coin);
- absorbed: 1 - (residual on the glass) / (reflection on the glass), the
  share of the reflection Stage I reproduced with its scattering set.

    /tmp/mv/bin/python perf/suite/glass_evidence.py --suite /work/suite \
        --norefl /tmp/norefl --runs /work/runs-sh3 [--seed 0] globe dome pane

Without --norefl (real data, or no such render) only the residual's
columns are filled. RUNS/SCENE/sSEED/I (or RUNS itself with {scene} and {seed} filled in, when
it names them) must hold a Stage I run with test renders
(renders/test/NAME.png, as `tgs train` writes); NOREFL/SCENE_norefl the
scene rendered without reflection. Reads only; needs numpy and Pillow.
"""
import argparse
import json
import os
import sys

import numpy as np
from PIL import Image


def rgb(path):
    if not os.path.exists(path):
        raise SystemExit(f"{path}: missing")
    return np.asarray(Image.open(path).convert("RGB"), float) / 255.0


def glass_mask(suite, scene, name):
    """The test view's glass mask (True on the glass)."""
    return np.asarray(Image.open(os.path.join(suite, scene, "test", name + "_mask.png")).convert("L")) > 127


def stage1_run(runs, scene, seed):
    """RUNS/SCENE/sSEED/I, or RUNS with {scene} and {seed} filled in when it names them."""
    return runs.format(scene=scene, seed=seed) if "{scene}" in runs else os.path.join(runs, scene, f"s{seed}", "I")


def auc(pos, neg, cap=4000):
    """P(a glass pixel's value > an off-glass pixel's), ties counted half."""
    rng = np.random.default_rng(0)
    pos = pos if len(pos) <= cap else rng.choice(pos, cap, replace=False)
    neg = neg if len(neg) <= cap else rng.choice(neg, cap, replace=False)
    return float((pos[:, None] > neg[None, :]).mean() + 0.5 * (pos[:, None] == neg[None, :]).mean())


def panel(suite, norefl, run, scene, name, scale=8.0):
    """One row: the image, without the reflection, the reflection x scale,
    Stage I, its residual x scale, the glass mask (each 3 x the pixels)."""
    gt = rgb(os.path.join(suite, scene, "test", name + ".png"))
    nr = rgb(os.path.join(norefl, scene + "_norefl", "test", name + ".png"))
    st1 = rgb(os.path.join(run, "renders", "test", name + ".png"))
    mask = glass_mask(suite, scene, name)[..., None].repeat(3, -1).astype(float)
    tiles = [gt, nr, np.clip(np.abs(gt - nr) * scale, 0, 1), st1, np.clip(np.abs(gt - st1) * scale, 0, 1), mask]
    row = np.concatenate([np.pad(t, ((1, 1), (1, 1), (0, 0)), constant_values=1.0) for t in tiles], 1)
    return np.kron(row, np.ones((3, 3, 1)))


def scene_row(suite, norefl, runs, scene, seed):
    meta = os.path.join(suite, scene, "transforms_test.json")
    if not os.path.exists(meta):
        raise SystemExit(f"{meta}: missing")
    frames = json.load(open(meta))["frames"]
    renders = os.path.join(stage1_run(runs, scene, seed), "renders", "test")
    acc = {k: [] for k in ("refl", "noise", "res_on", "res_off", "contrast", "auc")}
    for f in frames:
        name = os.path.basename(f["file_path"])
        gt = rgb(os.path.join(suite, scene, "test", name + ".png"))
        nr = rgb(os.path.join(norefl, scene + "_norefl", "test", name + ".png")) if norefl else None
        st1 = rgb(os.path.join(renders, name + ".png"))
        mask = glass_mask(suite, scene, name)
        if not mask.any() or mask.all():
            continue
        res = np.abs(gt - st1).mean(-1)
        if nr is not None:
            refl = np.abs(gt - nr).mean(-1)
            acc["refl"].append(refl[mask].mean())
            acc["noise"].append(refl[~mask].mean())
        acc["res_on"].append(res[mask].mean())
        acc["res_off"].append(res[~mask].mean())
        acc["contrast"].append(res[mask].mean() / max(res[~mask].mean(), 1e-12))
        acc["auc"].append(auc(res[mask], res[~mask]))
    if not acc["res_on"]:
        raise SystemExit(f"{scene}: no test view shows both glass and something else")
    m = {k: float(np.mean(v)) if v else None for k, v in acc.items()}
    m["absorbed"] = 1.0 - m["res_on"] / max(m["refl"], 1e-12) if norefl else None
    return m


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--suite", required=True)
    ap.add_argument("--norefl", help="renders without the reflection (mitsuba_scenes.py --no-reflection); without it only the residual's columns")
    ap.add_argument("--runs", required=True)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--figure", help="also draw, for each scene's first test view: the image, without the reflection, |difference| x 8, Stage I, its residual x 8, the glass mask (needs --norefl)")
    ap.add_argument("scenes", nargs="+")
    a = ap.parse_args()
    if a.figure and not a.norefl:
        raise SystemExit("--figure needs --norefl")
    print("| scene | reflection on the glass (×1e3) | noise (×1e3) | Stage I residual on / off the glass (×1e3) | contrast | AUC | absorbed |")
    print("|---|---|---|---|---|---|---|")
    k3 = lambda v: "–" if v is None else f"{1e3 * v:.1f}"
    for s in a.scenes:
        m = scene_row(a.suite, a.norefl, a.runs, s, a.seed)
        absorbed = "–" if m["absorbed"] is None else f"{m['absorbed']:.2f}"
        print(f"| {s} | {k3(m['refl'])} | {k3(m['noise'])} | {1e3 * m['res_on']:.1f} / {1e3 * m['res_off']:.1f} | {m['contrast']:.2f} | {m['auc']:.2f} | {absorbed} |")
        sys.stdout.flush()
    if a.figure:
        rows = []
        for s in a.scenes:
            name = os.path.basename(json.load(open(os.path.join(a.suite, s, "transforms_test.json")))["frames"][0]["file_path"])
            rows.append(panel(a.suite, a.norefl, stage1_run(a.runs, s, a.seed), s, name))
        w = max(r.shape[1] for r in rows)
        img = np.concatenate([np.pad(r, ((0, 0), (0, w - r.shape[1]), (0, 0)), constant_values=1.0) for r in rows], 0)
        Image.fromarray((img * 255).round().astype(np.uint8)).save(a.figure)
        print(f"wrote {a.figure}")


if __name__ == "__main__":
    main()
