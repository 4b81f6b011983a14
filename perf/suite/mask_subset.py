#!/usr/bin/env python3
"""Glass masks for some of the training views: copies the masks of every
K-th view (`r_N.png` with N a multiple of K, as `mitsuba_scenes.py
--train-masks` names them) from MASKS into a new directory OUT, for
`reflection.seed_masks` (a view without a mask takes no part in the
seeding). It refuses an OUT that exists, so no masks are overwritten.

    python3 perf/suite/mask_subset.py MASKS K OUT
    tgs train --from STAGE1_RUN --out RUN --stages II \\
        --set reflection.iterations=1000 --set reflection.seed_masks=OUT

The forty-sixth entry of perf/RESULTS.md ran it with K = 4 and 12 on the
suite's exact masks (60 training views: 15 and 5 masked views), with
`--set reflection.seed_normal=plane` for Stage I runs made before `auto`.
Needs only the standard library.
"""
import argparse
import os
import re
import shutil


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("masks", help="directory of the training views' masks, r_N.png")
    ap.add_argument("k", type=int, help="keep the masks of views N with N %% K == 0")
    ap.add_argument("out", help="new directory for the kept masks")
    a = ap.parse_args()
    if a.k < 1:
        raise SystemExit(f"K must be at least 1, not {a.k}")
    if not os.path.isdir(a.masks):
        raise SystemExit(f"{a.masks}: not a directory")
    if os.path.exists(a.out):
        raise SystemExit(f"{a.out} exists: give a new directory (nothing is overwritten)")
    names = sorted((int(m.group(1)), f) for f in os.listdir(a.masks) if (m := re.fullmatch(r"r_(\d+)\.png", f)))
    if not names:
        raise SystemExit(f"{a.masks}: no r_N.png masks")
    kept = [f for n, f in names if n % a.k == 0]
    os.makedirs(a.out)
    for f in kept:
        shutil.copy2(os.path.join(a.masks, f), os.path.join(a.out, f))
    print(f"{len(kept)} of {len(names)} views' masks in {a.out}")


if __name__ == "__main__":
    main()
