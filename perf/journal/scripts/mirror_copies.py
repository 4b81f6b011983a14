#!/usr/bin/env python3
"""Does Stage I hold a mirrored copy of real geometry behind a pane? (issue 77's last lead)

A pane's reflection shows the objects in front of it as a virtual image
behind it, at their positions mirrored across the pane. If Stage I fitted
that image with surfels, free space behind the pane (no real surface
within 0.08) would hold surfels near the mirrored objects' surfaces,
more than near a control copy (the same objects mirrored across y = 0
instead, which no reflection shows). The `pane` scene is the best case: a
single 2.4 x 1.4 pane at x = 0 between a sphere (x = 0.25) and a box
(x = -0.3) with free space behind it on both sides; the geometry below is
perf/suite/mitsuba_scenes.py's.

    python3 perf/journal/scripts/mirror_copies.py RUNS/pane/s0/I/point_cloud.ply [...]
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "suite"))
from depth_modes import read_ply  # noqa: E402

SPHERE = (np.array([0.25, -0.15, 0.35]), 0.35)
BOX = (np.array([-0.3, 0.3, 0.4]), np.array([0.15, 0.15, 0.4]), 20.0)


def box_distance(p, c, h, deg):
    a = np.radians(deg)
    r = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    q = np.abs((p - c) @ r) - h
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(1), 0)


def surface_distance(p, flip):
    """Unsigned distance to the sphere's and the box's surfaces mirrored by `flip` (a per-axis sign)."""
    (sc, sr), (bc, bh, deg) = SPHERE, BOX
    turn = deg * flip[0] * flip[1]
    return np.minimum(np.abs(np.linalg.norm(p - sc * flip, axis=1) - sr), np.abs(box_distance(p, bc * flip, bh, turn)))


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        d = read_ply(path)
        p = np.stack([d["x"], d["y"], d["z"]], 1)
        real = np.minimum(surface_distance(p, np.array([1, 1, 1])), p[:, 2])
        free = (real > 0.08) & (np.abs(p[:, 0]) > 0.08) & (np.abs(p).max(1) < 1.5)
        virtual = surface_distance(p, np.array([-1, 1, 1]))
        control = surface_distance(p, np.array([1, -1, 1]))
        print(f"{path}: {free.sum()} surfels in free space of {len(p)}")
        for t in (0.05, 0.1, 0.2):
            print(f"  within {t} of the mirrored objects: {(free & (virtual < t)).sum()}, of the control copy: {(free & (control < t)).sum()}")


if __name__ == "__main__":
    main()
