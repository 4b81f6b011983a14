#!/usr/bin/env python3
"""Where a run's reflection set lies against the known glass of a shipped scene.

Issue 11's question is whether Stage II puts its Gaussians on the glass. The
datasets carry no depth, so this reads the glass from the scene generators:
the built-in `glass` scene (harness/dataset/src/scene/trace.rs: sphere at
(0, 0, 0.8), radius 0.75) and every glass of `perf/suite/mitsuba_scenes.py`
(`globe` and `globe_far`: sphere at (0, 0, 0.95), radius 0.95; `pane`: the
plane x = 0, |y| <= 1.2, 0 <= z <= 1.4; `dome`: sphere at the origin,
radius 1.1; `cabinet`: a 1.4 x 1.4 x 1.2 box turned 25 degrees about z;
`cylinder`: the open tube of radius 0.85 about the z axis; `facade`: the
plane x = 0.4; `windshield`: the arc of radius 2 about x = -1.6).
`lantern` (../shared/data) has no generator here.

    python3 perf/journal/scripts/glass_placement.py RUN/reflection.ply --scene globe

Prints the share of splats within a tenth of the glass's size (its radius,
or 0.1 for the flat ones) of the glass, the signed distance percentiles
(positive outside or on the cameras' side), and the median and mean angle
between the splats' normals and the glass normal at their nearest glass
point, over all splats and those near the glass. Needs numpy only.
"""
import argparse

import numpy as np

SCENES = ["glass", "globe", "globe_far", "pane", "dome", "cabinet", "cylinder", "facade", "windshield"]


def glass(scene, p):
    """Signed distance to the scene's glass, the glass normal at the nearest
    glass point, and the distance that counts as near."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    if scene in ("glass", "globe", "globe_far", "dome"):
        c, r = {"glass": ([0, 0, 0.8], 0.75), "globe": ([0, 0, 0.95], 0.95), "globe_far": ([0, 0, 0.95], 0.95), "dome": ([0, 0, 0], 1.1)}[scene]
        rel = p - np.array(c, float)
        rad = np.maximum(np.linalg.norm(rel, axis=1), 1e-12)
        return rad - r, rel / rad[:, None], 0.1 * r
    if scene in ("pane", "facade"):
        # A rectangle with normal +x: the pane at x = 0 (|y| <= 1.2, z in
        # [0, 1.4]), the facade at x = 0.4 (|y| <= 1.4, z in [0, 1.5]).
        x0, hy, h = (0.0, 1.2, 1.4) if scene == "pane" else (0.4, 1.4, 1.5)
        dy = np.maximum(np.abs(y) - hy, 0)
        dz = np.maximum(np.abs(z - h / 2) - h / 2, 0)
        return np.sqrt((x - x0) ** 2 + dy ** 2 + dz ** 2) * np.sign(x - x0), np.tile([1.0, 0.0, 0.0], (len(p), 1)), 0.1
    if scene == "cabinet":
        # Box centre (0, 0, 0.61), half sizes (0.7, 0.7, 0.6), turned 25 degrees about z.
        a = np.radians(25.0)
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        q = (p - [0, 0, 0.61]) @ rot
        half = np.array([0.7, 0.7, 0.6])
        out = np.abs(q) - half
        k = np.argmax(out, 1)
        idx = np.arange(len(p))
        nl = np.zeros_like(q)
        nl[idx, k] = np.sign(q[idx, k])
        dist = np.where(out.max(1) > 0, np.linalg.norm(np.maximum(out, 0), axis=1), out.max(1))
        return dist, nl @ rot.T, 0.1
    # Vertical cylinders: the tube (radius 0.85 about the z axis, z in
    # [0.005, 1.305]) and the windshield (radius 2 about x = -1.6, |y| <= 1.4, z in [0, 1.5]).
    cx, r, z0, z1 = (0.0, 0.85, 0.005, 1.305) if scene == "cylinder" else (-1.6, 2.0, 0.0, 1.5)
    rel = np.stack([x - cx, y, 0 * z], 1)
    rad = np.maximum(np.linalg.norm(rel, axis=1), 1e-12)
    dz = np.maximum(np.maximum(z0 - z, z - z1), 0)
    side = np.sign(rad - r)
    return np.sqrt((rad - r) ** 2 + dz ** 2) * side, rel / rad[:, None], 0.1


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
    ap.add_argument("--scene", required=True, choices=SCENES)
    a = ap.parse_args()
    d = read_ply(a.ply)
    p = np.stack([d["x"], d["y"], d["z"]], 1)
    n = normals(d)
    dist, g, tol = glass(a.scene, p)
    near = np.abs(dist) < tol
    ang = np.degrees(np.arccos(np.clip(np.abs((n * g).sum(1)), 0, 1)))
    pc = np.percentile(dist, [5, 25, 50, 75, 95])
    near_ang = f"{np.median(ang[near]):.1f} / {ang[near].mean():.1f}" if near.any() else "none"
    print(f"{a.ply}: {len(p)} splats; within {tol:.3g} of the glass: {near.mean() * 100:.1f}%; "
          f"signed distance 5/25/50/75/95%: {' '.join(f'{v:.2f}' for v in pc)}; "
          f"normal error median / mean {np.median(ang):.1f} / {ang.mean():.1f} deg (near the glass: {near_ang})")


if __name__ == "__main__":
    main()
