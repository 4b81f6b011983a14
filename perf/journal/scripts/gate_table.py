#!/usr/bin/env python3
"""The fifty-seventh entry's gate table: per scene, the glass / beside-the-glass normal MAE of
Stage I and of Stage II at each `reflection.residual_normal_min_r`, from `suite.py --variant default
--eval-variant r0@default:... r03 r05 r10` runs (RUNS/SCENE/s0/{I,default,rNN.eval.json}).

    python3 perf/journal/scripts/gate_table.py RUNS cabinet,cylinder,...
"""
import json
import os
import sys

runs = sys.argv[1]
scenes = sys.argv[2].split(",")
th = [("r0", "0"), ("r03", "0.03"), ("r05", "0.05"), ("default", "0.07 (default)"), ("r10", "0.1")]
def rec(scene, name):
    b = os.path.join(runs, scene, "s0")
    if name == "I":
        m = json.load(open(os.path.join(b, "I", "metrics.json")))
        return [s for s in m["stages"] if s["stage"] == "I"][0]["test"]
    if name == "default":
        m = json.load(open(os.path.join(b, "default", "metrics.json")))
        ii = [s for s in m["stages"] if s["stage"] == "II"]
        return ii[0]["test"] if ii else m["test"]
    return json.load(open(os.path.join(b, name + ".eval.json")))
print("| scene | Stage I | " + " | ".join(t for _, t in th) + " |")
print("|---|---|" + "---|" * len(th))
sums = [[0, 0] for _ in range(len(th) + 1)]
worst = [0] * (len(th) + 1)
for s in scenes:
    cells = []
    one = rec(s, "I")
    for k, (n, _) in enumerate([("I", "")] + th):
        r = rec(s, n)
        g, o = r["normal_mae_deg"], r["normal_mae_outside_deg"]
        sums[k][0] += g; sums[k][1] += o
        worst[k] = max(worst[k], o - one["normal_mae_outside_deg"])
        cells.append(f"{g:.1f}° / {o:.1f}°")
    print(f"| {s} | " + " | ".join(cells) + " |")
n = len(scenes)
print("| **mean** | " + " | ".join(f"{a/n:.1f}° / {b/n:.1f}°" for a, b in sums) + " |")
print("| **most harm beside the glass** | – | " + " | ".join(f"{w:+.1f}°" for w in worst[1:]) + " |")
