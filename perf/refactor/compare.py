"""compare.py A B: are two output trees of same-outputs.sh the same?

Every file must be byte-identical, except: checkpoints may differ in their
header's run id and dataset path (their arrays must be identical), and JSON
and JSON-lines files may differ in wall times, run ids and dataset paths
(keys ending in _s or _ms, and the names in TIMEKEYS: times, ids, paths). Prints each file that
differs and "bad N"; exits 1 when N > 0.
"""
import sys, os, json, struct
a, b = sys.argv[1], sys.argv[2]
TIMEKEYS = {"wall_s","seconds","train_s","time_s","elapsed_s","s","ms","timings","time","started","finished","run_id","id","checksum","created","date","dataset","from","eval_s","total_s","stage_s","stages_s","per_iteration_ms"}
def strip(o):
    if isinstance(o, dict):
        return {k: strip(v) for k, v in o.items() if k not in TIMEKEYS and not k.endswith("_s") and not k.endswith("_ms")}
    if isinstance(o, list):
        return [strip(v) for v in o]
    return o
def files(d):
    out = {}
    for r, _, fs in os.walk(d):
        for f in fs:
            p = os.path.join(r, f); out[os.path.relpath(p, d)] = p
    return out
fa, fb = files(a), files(b)
bad = 0
for k in sorted(set(fa) | set(fb)):
    if k not in fa or k not in fb:
        print("MISSING", k); bad += 1; continue
    x, y = open(fa[k], 'rb').read(), open(fb[k], 'rb').read()
    if x == y: continue
    if k.endswith('.bin'):

        def split(z):
            n = struct.unpack('<I', z[8:12])[0]
            h = json.loads(z[12:12+n]); h.pop('run_id', None); h.pop('dataset', None); h.get('identity', {}).pop('run_id', None); h.get('identity', {}).pop('dataset', None)
            for key in list(h):
                if 'run' in key or 'dataset' in key: h.pop(key)
            return h, z[12+n+4:]
        hx, bx = split(x); hy, by = split(y)
        if hx == hy and bx == by:
            print("same-but-id", k); continue
        print("header same" if hx == hy else "header differs", "arrays same" if bx == by else "arrays differ")
    if k.endswith('.json') or k.endswith('.jsonl'):
        try:
            if k.endswith('.jsonl'):
                X = [strip(json.loads(l)) for l in x.splitlines()]; Y = [strip(json.loads(l)) for l in y.splitlines()]
            else:
                X, Y = strip(json.loads(x)), strip(json.loads(y))
            if X == Y:
                print("same-but-times", k); continue
        except Exception as e:
            pass
    print("DIFF", k, len(x), len(y)); bad += 1
print("bad", bad)
sys.exit(1 if bad else 0)
