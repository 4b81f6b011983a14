#!/usr/bin/env python3
"""Run tgs on a suite of glass scenes and report every scene, the mean and the worst.

The suite is a directory of datasets (each with transforms_train.json), such
as `mitsuba_scenes.py --scene suite` writes. For every scene and seed this
trains Stage I once (`RUNS/SCENE/sSEED/I`, kept and reused on a rerun), then
every variant's Stage II from it with `--from` (`RUNS/SCENE/sSEED/VARIANT`,
also kept), and prints one Markdown table per variant:

    scene | Stage I MAE | ray-facing MAE | Stage II MAE | II / I | II / ray-facing | coverage | off mask | off-glass MAE I -> II | PSNR I -> II | gain | residual contrast | Stage II s

with the mean and the worst scene (the largest II / I) under it. "off
mask" is the share of the pixels the reflection set covers that lie off
the glass; "off-glass MAE" the normal error on the rest of the scene (when
the dataset's normals cover the whole image), where Stage II must not
make Stage I's normals worse; "gain" how much the reflection layer lowers
the held-out image error (mean |gt - I_scat| - |gt - I|, x 1e3) on the glass
and off it: the photometric evidence its normals have; "residual contrast"
Stage I's error on the glass over its error off it, how strongly the
residual that Stage II seeds from marks the glass (1: not at all). Over
several seeds a cell is the mean over seeds, with the spread (max - min) in
brackets. A variant is `NAME` (today's defaults) or `NAME:KEY=VALUE;KEY=VALUE`
(tgs `--set` pairs, e.g. `geom:reflection.lr_quats=1e-2;reflection.lr_scales=5e-3`).
Nothing is written over: run directories that hold a finished run are read,
not retrained; a half-written one (no metrics.json) is an error naming it.

    python3 perf/suite/suite.py --scenes /tmp/suite --runs /tmp/suite-runs \
        --variant default --variant 'geom:reflection.lr_quats=1e-2' [--seeds 0,1] [--tgs target/debug/tgs]

`--seed-masks ROOT` gives every Stage II the glass masks in ROOT/SCENE
(`reflection.seed_masks`; the forty-fourth entry of perf/RESULTS.md):

    python3 perf/suite/suite.py --scenes /tmp/suite --runs /tmp/suite-runs \
        --seed-masks /tmp/masks --variant masks --variant 'masks-halfway:reflection.seed_normal=halfway'

`--eval-variant NAME@BASE:KEY=VALUE;...` trains nothing: it evaluates variant
BASE's Stage II with `tgs eval --set` for settings that change only the
output (`reflection.normal_min_r`, `reflection.residual_normal_min_r`),
kept as `RUNS/SCENE/sSEED/NAME.eval.json`, and prints its table like a
variant's (Stage II s is BASE's):

    python3 perf/suite/suite.py --scenes /tmp/suite --runs /tmp/suite-runs --variant default \
        --eval-variant 'r05@default:reflection.residual_normal_min_r=0.05'

`--stage3` also trains Stage III from every variant's Stage II
(`RUNS/SCENE/sSEED/VARIANT-III`, with the variant's `light_field.` pairs)
and prints, per variant, the test PSNR
of all three stages and their wall times against issue 42's other aims
(Stage III at least Stage I + 0.3 dB; Stage II at most half of Stage I's
time; the seconds are timings only when nothing else ran beside them).

Only the Python standard library is needed.
"""
import argparse
import json
import os
import subprocess
import sys
import time


def run(cmd, log):
    t0 = time.time()
    with open(log, "w") as fh:
        p = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT)
    if p.returncode != 0:
        raise SystemExit(f"failed ({p.returncode}): {' '.join(cmd)}; see {log}")
    return time.time() - t0


def train(tgs, out, args, label):
    metrics = os.path.join(out, "metrics.json")
    if os.path.exists(metrics):
        return json.load(open(metrics))
    if os.path.exists(out):
        raise SystemExit(f"{out} exists without metrics.json (an unfinished run): resume it with `tgs train --resume --out {out}` or remove it")
    os.makedirs(os.path.dirname(out), exist_ok=True)
    log = out + ".log"
    print(f"{label} ...", end="", flush=True, file=sys.stderr)
    s = run([tgs, "train", "--quiet", "--out", out] + args, log)
    print(f" {s:.0f} s", file=sys.stderr, flush=True)
    return json.load(open(metrics))


def evaluate(tgs, base, out, kvs, label):
    """`tgs eval BASE --set ...` as a Stage II record, kept in OUT (read, not rerun, when there)."""
    if not os.path.exists(out):
        print(f"{label} ...", end="", flush=True, file=sys.stderr)
        tmp = out + ".part"
        s = run([tgs, "eval", base] + [x for kv in kvs for x in ("--set", kv)], tmp)
        os.replace(tmp, out)
        print(f" {s:.0f} s", file=sys.stderr, flush=True)
    return json.load(open(out))


def stage(m, name):
    for s in m.get("stages", []):
        if s.get("stage") == name:
            return s
    return None


def fmt(vals, digits=1):
    vals = [v for v in vals if v is not None]
    if not vals:
        return "–"
    mean = sum(vals) / len(vals)
    if len(vals) == 1:
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ({max(vals) - min(vals):.{digits}f})"


def test_value(row, st, key):
    """`key` of a (Stage I, Stage II, Stage III) record row's stage `st` on the test views."""
    return row[st].get("test", {}).get(key) if row[st] else None


def wall(row, st):
    """Wall seconds of a record row's stage `st`."""
    return row[st].get("wall_s") if row[st] else None


def cell(v, digits=1):
    """A mean-row cell: `v` to `digits` places, or – where nothing was measured."""
    return "–" if v is None else f"{v:.{digits}f}"


def mean(vals):
    vals = [v for v in vals if v is not None]
    return sum(vals) / len(vals) if vals else None


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", required=True, help="directory of datasets")
    ap.add_argument("--runs", required=True, help="directory for the runs (kept; reruns reuse them)")
    ap.add_argument("--variant", action="append", default=[], help="NAME or NAME:KEY=VALUE;KEY=VALUE (repeatable)")
    ap.add_argument("--eval-variant", action="append", default=[], help="NAME@BASE:KEY=VALUE;... output-only settings evaluated on variant BASE's Stage II (tgs eval --set; repeatable)")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--only", action="append", help="scene names to run, in this order (repeatable; default: all, by name)")
    ap.add_argument("--stage1", default="", help="KEY=VALUE;... for Stage I (part of its run directory's identity: use a new --runs when changing it)")
    ap.add_argument("--seed-masks", metavar="ROOT", help="every Stage II seeds from ROOT/SCENE's glass masks (reflection.seed_masks; `mitsuba_scenes.py --train-masks` writes them); use its own --runs names or variants")
    ap.add_argument("--stage3", action="store_true", help="also train Stage III from every variant's Stage II (`RUNS/SCENE/sSEED/VARIANT-III`) and print a table per variant against issue 42's PSNR and time aims")
    ap.add_argument("--tgs", default=os.path.join(os.path.dirname(__file__), "..", "..", "target", "debug", "tgs"))
    a = ap.parse_args()
    scenes = sorted(d for d in os.listdir(a.scenes) if os.path.exists(os.path.join(a.scenes, d, "transforms_train.json")))
    if a.only:
        missing = [s for s in a.only if s not in scenes]
        if missing:
            raise SystemExit(f"no dataset {missing} in {a.scenes} (it has {scenes})")
        scenes = list(dict.fromkeys(a.only))  # in the order given
    if not scenes:
        raise SystemExit(f"{a.scenes} holds no dataset (a directory with transforms_train.json)")
    seeds = [int(s) for s in a.seeds.split(",")]
    variants = []
    for v in a.variant or ["default"]:
        name, _, sets = v.partition(":")
        if not name or "/" in name or name == "I" or name.endswith("-III"):
            raise SystemExit(f"bad variant name '{name}' (a plain name other than I, not ending in -III)")
        variants.append((name, [kv for kv in sets.split(";") if kv]))
    stage1_sets = [kv for kv in a.stage1.split(";") if kv]
    evals = []
    for v in a.eval_variant:
        head, _, sets_ = v.partition(":")
        name, _, base = head.partition("@")
        if not name or "/" in name or name in ("I",) or name in [n for n, _ in variants] or base not in [n for n, _ in variants]:
            raise SystemExit(f"bad --eval-variant '{v}': NAME@BASE:KEY=VALUE;... with BASE one of the --variant names and NAME a new plain name")
        evals.append((name, base, [kv for kv in sets_.split(";") if kv]))

    def sets(kvs):
        return [x for kv in kvs for x in ("--set", kv)]

    res = {}  # (scene, seed, variant) -> (stage I record, stage II record)
    for scene in scenes:
        data = os.path.join(a.scenes, scene)
        for seed in seeds:
            base = os.path.join(a.runs, scene, f"s{seed}")
            one = os.path.join(base, "I")
            m1 = train(a.tgs, one, [data, "--stages", "I", "--set", f"seed={seed}"] + sets(stage1_sets), f"{scene} seed {seed} Stage I")
            masks = []
            if a.seed_masks:
                d = os.path.join(a.seed_masks, scene)
                if not os.path.isdir(d):
                    raise SystemExit(f"--seed-masks: {d} is not a directory (`mitsuba_scenes.py --train-masks {data} --scene {scene} --out {d}` writes it)")
                masks = [f"reflection.seed_masks={os.path.abspath(d)}"]
            for name, kvs in variants:
                m2 = train(a.tgs, os.path.join(base, name), [data, "--from", one, "--stages", "II"] + sets(masks + kvs), f"{scene} seed {seed} {name}")
                m3 = None
                if a.stage3:
                    # Stage III takes the variant's own Stage III settings (`--from` refuses the others).
                    lf = [kv for kv in kvs if kv.startswith("light_field.")]
                    m3 = train(a.tgs, os.path.join(base, name + "-III"), [data, "--from", os.path.join(base, name), "--stages", "III"] + sets(lf), f"{scene} seed {seed} {name} Stage III")
                res[(scene, seed, name)] = (stage(m1, "I"), stage(m2, "II"), stage(m3, "III") if m3 else None)
            for name, bname, kvs in evals:
                test = evaluate(a.tgs, os.path.join(base, bname), os.path.join(base, name + ".eval.json"), kvs, f"{scene} seed {seed} {name} (eval)")
                r1, r2, _ = res[(scene, seed, bname)]
                res[(scene, seed, name)] = (r1, {"stage": "II", "test": test, "wall_s": r2.get("wall_s") if r2 else None}, None)

    for name, kvs in variants + [(n, [f"eval of {b}"] + k) for n, b, k in evals]:
        print(f"\n### {name}" + (f": `{'; '.join(kvs)}`" if kvs else " (today's defaults)"))
        print(f"seeds {a.seeds}; cells are means over seeds, (spread) = max - min\n")
        print("| scene | Stage I MAE | ray-facing | Stage II MAE | II / I | II / ray-facing | coverage | off mask | off-glass MAE I → II | PSNR I → II | gain ×1e3 glass / off | residual contrast (I) | Stage II s |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        ratios = {}
        cols = {k: [] for k in ("i", "ray", "ii", "r1", "rr", "cov", "off", "o1", "o2", "p1", "p2", "g1", "g2", "rc", "s")}
        for scene in scenes:
            rows = [res[(scene, s, name)] for s in seeds]
            t = test_value
            i = [t(r, 0, "normal_mae_deg") for r in rows]
            ray = [t(r, 0, "normal_mae_ray_facing_deg") for r in rows]
            ii = [t(r, 1, "normal_mae_deg") for r in rows]
            r1 = [b / a_ if a_ and b is not None else None for a_, b in zip(i, ii)]
            rr = [b / a_ if a_ and b is not None else None for a_, b in zip(ray, ii)]
            cov = [t(r, 1, "reflection_coverage") for r in rows]
            off = [t(r, 1, "reflection_outside_mask") for r in rows]
            o1 = [t(r, 0, "normal_mae_outside_deg") for r in rows]
            o2 = [t(r, 1, "normal_mae_outside_deg") for r in rows]
            p1 = [t(r, 0, "psnr") for r in rows]
            p2 = [t(r, 1, "psnr") for r in rows]
            k3 = lambda v: None if v is None else 1e3 * v
            g1 = [k3(t(r, 1, "reflection_gain_mask")) for r in rows]
            g2 = [k3(t(r, 1, "reflection_gain_outside")) for r in rows]
            rc = [t(r, 0, "residual_contrast") for r in rows]
            sec = [wall(r, 1) for r in rows]
            ratios[scene] = mean(r1)
            for k, v in zip(cols, (i, ray, ii, r1, rr, cov, off, o1, o2, p1, p2, g1, g2, rc, sec)):
                cols[k].append(mean(v))
            print(f"| {scene} | {fmt(i)}° | {fmt(ray)}° | {fmt(ii)}° | {fmt(r1, 2)} | {fmt(rr, 2)} | {fmt(cov, 2)} | {fmt(off, 2)} | {fmt(o1)}° → {fmt(o2)}° | {fmt(p1, 2)} → {fmt(p2, 2)} | {fmt(g1, 2)} / {fmt(g2, 2)} | {fmt(rc, 2)} | {fmt(sec, 0)} |")
        m = {k: mean(v) for k, v in cols.items()}
        f = cell
        print(f"| **mean** | {f(m['i'])}° | {f(m['ray'])}° | {f(m['ii'])}° | {f(m['r1'], 2)} | {f(m['rr'], 2)} | {f(m['cov'], 2)} | {f(m['off'], 2)} | {f(m['o1'])}° → {f(m['o2'])}° | {f(m['p1'], 2)} → {f(m['p2'], 2)} | {f(m['g1'], 2)} / {f(m['g2'], 2)} | {f(m['rc'], 2)} | {f(m['s'], 0)} |")
        known = {k: v for k, v in ratios.items() if v is not None}
        if known:
            w = max(known, key=known.get)
            print(f"| **worst** ({w}) | | | | {known[w]:.2f} | | | | | | | | |")
        if a.stage3 and name in [n for n, _ in variants]:
            print_stage3(scenes, seeds, name, res)


def print_stage3(scenes, seeds, name, res):
    """Issue 42's other two aims per scene: test PSNR after Stage III at
    least Stage I's + 0.3 dB, and Stage II's wall time at most half of Stage
    I's (the seconds are timings only when nothing else ran beside them)."""
    print(f"\n{name}, all three stages: test PSNR and wall time (aims: III − I ≥ 0.3 dB; II / I time ≤ 0.5)\n")
    print("| scene | PSNR I | PSNR II | PSNR III | III − I dB | Stage I s | Stage II s | II / I time | Stage III s | III / II time |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    cols = {k: [] for k in ("p1", "p2", "p3", "d", "s1", "s2", "q", "s3", "q3")}
    for scene in scenes:
        rows = [res[(scene, s, name)] for s in seeds]
        ratio = lambda x, y: x / y if x is not None and y else None
        p1 = [test_value(r, 0, "psnr") for r in rows]
        p2 = [test_value(r, 1, "psnr") for r in rows]
        p3 = [test_value(r, 2, "psnr") for r in rows]
        d = [c - b if b is not None and c is not None else None for b, c in zip(p1, p3)]
        s1 = [wall(r, 0) for r in rows]
        s2 = [wall(r, 1) for r in rows]
        s3 = [wall(r, 2) for r in rows]
        q = [ratio(y, x) for x, y in zip(s1, s2)]
        q3 = [ratio(z, y) for y, z in zip(s2, s3)]
        for k, v in zip(cols, (p1, p2, p3, d, s1, s2, q, s3, q3)):
            cols[k].append(mean(v))
        print(f"| {scene} | {fmt(p1, 2)} | {fmt(p2, 2)} | {fmt(p3, 2)} | {fmt(d, 2)} | {fmt(s1, 0)} | {fmt(s2, 0)} | {fmt(q, 2)} | {fmt(s3, 0)} | {fmt(q3, 2)} |")
    m = {k: mean(v) for k, v in cols.items()}
    f = cell
    print(f"| **mean** | {f(m['p1'], 2)} | {f(m['p2'], 2)} | {f(m['p3'], 2)} | {f(m['d'], 2)} | {f(m['s1'], 0)} | {f(m['s2'], 0)} | {f(m['q'], 2)} | {f(m['s3'], 0)} | {f(m['q3'], 2)} |")
    known = [(v, s) for v, s in zip(cols["d"], scenes) if v is not None]
    if known:
        v, s = min(known)
        print(f"| **worst** ({s}) | | | | {v:.2f} | | | | | |")


if __name__ == "__main__":
    main()
