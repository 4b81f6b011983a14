#!/usr/bin/env python3
"""Put a Stage II run's reflection set on the known glass: an oracle start.

Issue 42 asks why Stage II's normals miss the glass. This separates where
the seeds start from what training does with them: it copies a run whose
checkpoint is inside Stage II (e.g. `tgs train --from STAGE1 --stages II
--set reflection.iterations=1`) to a new directory and edits the copy's
checkpoint so that the reflection set lies on the scene's glass (each
Gaussian moved along the glass normal onto it), has the glass's normals,
or both. Continue it with `tgs train --resume --out NEW --set
reflection.iterations=N` and evaluate; the untouched copy resumed the same
way is the control (perf/RESULTS.md, forty-second entry).

    python3 perf/journal/scripts/oracle_seeds.py RUN NEW --scene globe --what both

The glass comes from `glass_placement.py` (the generators' geometry):
spheres (`glass`, `globe`, `globe_far`, `dome`) and vertical cylinders
(`cylinder`, `windshield`) move radially, the flat `pane` and `facade`
along x; `cabinet` is not supported. A Gaussian past a flat glass's edge
is moved onto the glass's plane, not onto its rectangle. NEW must not
exist; RUN is only read. Needs numpy.
"""
import argparse
import json
import os
import shutil
import struct
import zlib

import numpy as np

from glass_placement import glass

MAGIC = b"TGSCKPT2"
SPHERES = {"glass": ([0, 0, 0.8], 0.75), "globe": ([0, 0, 0.95], 0.95), "globe_far": ([0, 0, 0.95], 0.95), "dome": ([0, 0, 0], 1.1)}
PLANES = {"pane": 0.0, "facade": 0.4}
CYLINDERS = {"cylinder": (0.0, 0.85), "windshield": (-1.6, 2.0)}


def read(path):
    b = open(path, "rb").read()
    if b[:8] != MAGIC:
        raise SystemExit(f"{path}: not a version-2 tgs checkpoint")
    hlen = struct.unpack("<I", b[8:12])[0]
    hb = b[12:12 + hlen]
    header = json.loads(hb)
    if "reflection" not in header:
        raise SystemExit(f"{path}: holds no reflection set (a checkpoint inside Stage II is needed)")
    at = 12 + hlen + 4
    names = [tuple(a) for a in header["arrays"]] + [tuple(a) for a in header["reflection"]["arrays"]]
    arrays = []
    for name, n in names:
        raw = b[at:at + 4 * n]
        if len(raw) != 4 * n or struct.unpack("<I", b[at + 4 * n:at + 4 * n + 4])[0] != zlib.crc32(raw):
            raise SystemExit(f"{path}: array {name} is truncated or damaged")
        arrays.append(np.frombuffer(raw, dtype="<f4").copy())
        at += 4 * n + 4
    if at != len(b):
        raise SystemExit(f"{path}: trailing bytes")
    return hb, names, arrays


def write(path, hb, arrays):
    out = bytearray(MAGIC + struct.pack("<I", len(hb)) + hb + struct.pack("<I", zlib.crc32(hb)))
    for a in arrays:
        raw = a.astype("<f4").tobytes()
        out += raw + struct.pack("<I", zlib.crc32(raw))
    with open(path, "wb") as fh:
        fh.write(bytes(out))


def onto_glass(scene, p):
    if scene in SPHERES:
        c, r = SPHERES[scene]
        rel = p - np.array(c, float)
        return np.array(c, float) + rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-12) * r
    if scene in PLANES:
        q = p.copy()
        q[:, 0] = PLANES[scene]
        return q
    if scene in CYLINDERS:
        cx, r = CYLINDERS[scene]
        rel = p[:, :2] - [cx, 0.0]
        q = p.copy()
        q[:, :2] = [cx, 0.0] + rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-12) * r
        return q
    raise SystemExit(f"--scene {scene}: no projection onto its glass here")


def quats_facing(n):
    """Quaternions (w, x, y, z) whose rotation takes +z to the unit normals n."""
    q = np.stack([1 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], 1)
    q[q[:, 0] < 1e-6] = [0.0, 1.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run")
    ap.add_argument("new")
    ap.add_argument("--scene", required=True, choices=sorted(list(SPHERES) + list(PLANES) + list(CYLINDERS)))
    ap.add_argument("--what", choices=["positions", "normals", "both"], default="both")
    a = ap.parse_args()
    src = os.path.join(a.run, "checkpoint.bin")
    if os.path.exists(a.new):
        raise SystemExit(f"{a.new} exists: not writing over it")
    hb, names, arrays = read(src)
    idx = {name: i for i, (name, _) in enumerate(names)}
    means = arrays[idx["refl.param.means"]].reshape(-1, 3).astype(np.float64)
    quats = arrays[idx["refl.param.quats"]].reshape(-1, 4)
    dist, _, _ = glass(a.scene, means)
    moved = onto_glass(a.scene, means) if a.what in ("positions", "both") else means
    if a.what in ("normals", "both"):
        _, n, _ = glass(a.scene, moved)
        quats[:] = quats_facing(n)
    arrays[idx["refl.param.means"]] = moved.astype(np.float32).reshape(-1)
    shutil.copytree(a.run, a.new)
    write(os.path.join(a.new, "checkpoint.bin"), hb, arrays)
    print(f"{a.new}: {len(means)} reflection Gaussians, {a.what} set from the {a.scene} glass "
          f"(they lay a median {np.median(np.abs(dist)):.3f} from it); continue with "
          f"`tgs train --resume --out {a.new} --set reflection.iterations=N`")


if __name__ == "__main__":
    main()
