#!/usr/bin/env python3
"""Would per-pixel photometric evidence keep Stage II's normals on the glass
and off the spill? (fifty-sixth entry)

For a Stage II run's test renders (RUN/renders/test: the composite NAME.png,
the scattering layer NAME_scat.png, the output and both layers' normals)
and the dataset's test views (ground-truth image, normals, glass mask),
per pixel where the reflection set decides the normal: the gain
g = |gt - I_scat| - |gt - I| (channel mean, 8-bit renders) and its AUC as
a glass detector; then the normal MAE on and off the glass of three
rules: Stage I's normals, the output's, and the output's only where
g > TAU (Stage I's elsewhere). The test views stand for held-out views
that would give such evidence per pixel: an upper bound of what a
per-surfel verdict from a validation slice could do.

    python3 perf/journal/scripts/gain_gate.py DATA RUNS SCENE[,SCENE...] [VARIANT [SEED [TAU]]]

Needs numpy and mitsuba (image reading).
"""
import json
import os
import sys

import numpy as np
import mitsuba as mi

mi.set_variant("scalar_rgb")
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "suite"))
from view_inconsistency import auc  # noqa: E402


def image(path, linear=False):
    b = mi.Bitmap(path)
    a = np.array(b.convert(component_format=mi.Struct.Type.Float32, srgb_gamma=False if linear else b.srgb_gamma()), dtype=np.float64)
    return a


def normals(path):
    """World normals from a tgs normal PNG (n * 0.5 + 0.5)."""
    a = np.array(mi.Bitmap(path).convert(component_format=mi.Struct.Type.Float32, srgb_gamma=False), dtype=np.float64)[..., :3]
    return a * 2 - 1


def angle(a, b):
    na = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-9)
    nb = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-9)
    return np.degrees(np.arccos(np.clip((na * nb).sum(-1), -1, 1)))


def scene(data, run, tau):
    t = json.load(open(os.path.join(data, "transforms_test.json")))
    gains, labels, err = [], [], {"Stage I": ([], []), "output": ([], []), f"gated (g > {tau:g})": ([], [])}
    for fr in t["frames"]:
        name = os.path.basename(fr["file_path"])
        r = os.path.join(run, "renders", "test", name)
        gt = image(os.path.join(data, fr["file_path"] + ".png"))[..., :3]
        comp, scat = image(r + ".png")[..., :3], image(r + "_scat.png")[..., :3]
        n_out, n_scat, n_refl = normals(r + "_normal.png"), normals(r + "_normal_scat.png"), normals(r + "_normal_refl.png")
        n_gt = np.load(os.path.join(data, fr["normal_path"]))
        mask = image(os.path.join(data, fr["mask_path"]), linear=True)
        mask = (mask[..., 0] if mask.ndim == 3 else mask) > 0.5
        valid = np.linalg.norm(n_gt, axis=-1) > 0.5
        decides = valid & (angle(n_out, n_refl) < 1.0) & (angle(n_out, n_scat) > 1.0)
        g = np.abs(gt - scat).mean(-1) - np.abs(gt - comp).mean(-1)
        gains.append(g[decides])
        labels.append(mask[decides])
        gated = np.where((decides & (g > tau))[..., None], n_out, n_scat)
        for k, n in zip(err, (n_scat, n_out, gated)):
            e = angle(n, n_gt)
            err[k][0].append(e[valid & mask])
            err[k][1].append(e[valid & ~mask])
    g, lab = np.concatenate(gains), np.concatenate(labels)
    mae = {k: (np.concatenate(a).mean(), np.concatenate(b).mean()) for k, (a, b) in err.items()}
    return auc(g, lab), lab.mean() if len(lab) else float("nan"), mae


def main():
    if len(sys.argv) < 4:
        sys.exit(__doc__)
    data, runs, names = sys.argv[1], sys.argv[2], sys.argv[3].split(",")
    variant = sys.argv[4] if len(sys.argv) > 4 else "default"
    seed = sys.argv[5] if len(sys.argv) > 5 else "0"
    tau = float(sys.argv[6]) if len(sys.argv) > 6 else 0.0
    print(f"| scene | AUC of the gain where the set decides | share of those pixels on the glass | glass / beside MAE: Stage I | output | gated (g > {tau:g}) |")
    print("|---|---|---|---|---|---|")
    for s in names:
        a, share, mae = scene(os.path.join(data, s), os.path.join(runs, s, f"s{seed}", variant), tau)
        cells = " | ".join(f"{v[0]:.1f}° / {v[1]:.1f}°" for v in mae.values())
        print(f"| {s} | {a:.3f} | {share:.2f} | {cells} |")


if __name__ == "__main__":
    main()
