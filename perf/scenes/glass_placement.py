#!/usr/bin/env python3
"""Where a run's reflection set lies against the known glass of a shipped scene.

Issue 11's question is whether Stage II puts its Gaussians on the glass. The
datasets carry no depth, so this reads the glass from the scene generators:
the built-in `glass` scene (harness/dataset/src/scene/trace.rs: sphere at
(0, 0, 0.8), radius 0.75) and `perf/scenes/mitsuba_scenes.py`'s `globe`
(sphere at (0, 0, 0.95), radius 0.95) and `pane` (the plane x = 0,
|y| <= 1.2, |z - 0.7| <= 0.7).

    python3 perf/scenes/glass_placement.py RUN/reflection.ply --scene globe

Prints the share of splats within a tenth of the sphere's radius (0.1 for
the pane) of the glass, the distance percentiles, and the median angle
between the splats' normals and the glass normal at their nearest glass
point. Needs numpy only.
"""
import argparse

import numpy as np

SCENES = {
    "glass": ("sphere", np.array([0.0, 0.0, 0.8]), 0.75),
    "globe": ("sphere", np.array([0.0, 0.0, 0.95]), 0.95),
    "pane": ("pane", None, None),
}


def read_ply(path):
    with open(path, "rb") as fh:
        data = fh.read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().split("\n")
    n = int(next(line for line in header if line.startswith("element vertex")).split()[-1])
    names = [line.split()[-1] for line in header if line.startswith("property")]
    if any(not line.startswith("property float ") for line in header if line.startswith("property")):
        raise SystemExit(f"{path}: expected float properties only")
    a = np.frombuffer(data[end:end + 4 * n * len(names)], dtype="<f4").reshape(n, len(names))
    return {k: a[:, i].astype(np.float64) for i, k in enumerate(names)}


def normals(d):
    """Third column of each splat's rotation (rot_0..3 = w, x, y, z)."""
    w, x, y, z = (d[f"rot_{i}"] for i in range(4))
    q = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / q, x / q, y / q, z / q
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], 1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("ply")
    ap.add_argument("--scene", required=True, choices=sorted(SCENES))
    a = ap.parse_args()
    d = read_ply(a.ply)
    p = np.stack([d["x"], d["y"], d["z"]], 1)
    n = normals(d)
    kind, c, r = SCENES[a.scene]
    if kind == "sphere":
        rel = p - c
        rad = np.maximum(np.linalg.norm(rel, axis=1), 1e-12)
        dist = rad - r
        g = rel / rad[:, None]
        near = np.abs(dist) < 0.1 * r
    else:
        # Distance to the pane's rectangle; its normal is +-x.
        dy = np.maximum(np.abs(p[:, 1]) - 1.2, 0)
        dz = np.maximum(np.abs(p[:, 2] - 0.7) - 0.7, 0)
        dist = np.sqrt(p[:, 0] ** 2 + dy ** 2 + dz ** 2) * np.sign(p[:, 0])
        g = np.tile([1.0, 0.0, 0.0], (len(p), 1))
        near = np.abs(dist) < 0.1
    ang = np.degrees(np.arccos(np.clip(np.abs((n * g).sum(1)), 0, 1)))
    pc = np.percentile(dist, [5, 25, 50, 75, 95])
    print(f"{a.ply}: {len(p)} splats; within {'a tenth of the radius' if kind == 'sphere' else '0.1'} of the glass: "
          f"{near.mean() * 100:.1f}%; signed distance 5/25/50/75/95%: {' '.join(f'{v:.2f}' for v in pc)}; "
          f"normal error median {np.median(ang):.1f} deg (near the glass: {np.median(ang[near]) if near.any() else float('nan'):.1f})")


if __name__ == "__main__":
    main()
