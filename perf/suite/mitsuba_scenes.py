#!/usr/bin/env python3
"""Transmissive validation scenes rendered by an independent path tracer.

Writes datasets in the format of ../shared/docs/dataset-format.md (the
NeRF/Blender layout, test views with world-space normals of the first hit and
a mask of pixels whose first hit is glass everywhere inside the pixel), with
Mitsuba 3's path tracer and thin-dielectric glass, the way `lantern` was made.
They are for checking that a setting tuned on the built-in scene and `lantern`
carries over to other glass shapes; nothing in the tests depends on them.

    python3 -m venv /tmp/mv && /tmp/mv/bin/pip install mitsuba numpy
    /tmp/mv/bin/python perf/suite/mitsuba_scenes.py --out /tmp/scenes [--scene globe|suite] [--res 200] [--spp 128]

Scenes (every one: checkered floor, sun and sky; all but `globe_far` a ring
of checkered blocks outside the camera orbit for near-field reflections):
  globe      a thin glass sphere over a diffuse sphere and box (closed, curved)
  globe_far  the same with nothing around it: only the sky and the floor to
             reflect (distant light)
  pane       a vertical glass pane between the two objects (flat, open)
  dome       a glass hemisphere over the objects, four pillars around it
             inside the camera orbit (near-field structures)
  cabinet    a glass box standing on the floor with the objects inside
             (closed, flat faces, edges)
  cylinder   an open glass tube (no caps) around the objects (open, curved,
             seen from inside through its top)
  facade     a flat glass front of a lit room (walls, ceiling lamp, objects);
             cameras in front only
  windshield a curved glass front (a section of a vertical cylinder) of the
             same kind of room; cameras in front only
  diffuse    no glass at all (Stage II should skip it)
  bookshelf  two glass doors side by side in a wooden case's front frame (a
             lamp, books, a ball inside); cameras in front only
  house      a house with a window in each of two walls at a right angle (a
             lamp, a ball and a box inside)
  vehicle    planar windows around an opaque body (a cabin on four wheels)
  globe_near the globe among nearby pillars and boxes
  pyramid    a glass pyramid of four flat faces over the objects, pillars near
  garage     the vehicle inside an open-fronted garage: its windows mirror
             the near walls; cameras in front only
  display    a monitor's glass 0.03 in front of its lit screen, on a desk;
             cameras in front only
The suite the Stage II defaults are chosen on: every scene but `diffuse`
(`--scene suite`).

`--no-reflection` renders the same scenes (same cameras, same sampler seeds)
with the glass's reflection weighted by zero (thin-dielectric
`specular_reflectance` 0: the transmitted light is unchanged in
expectation) into `NAME_norefl`: the ground truth a perfect reflection
model would leave for the scattering set, for measuring what a reflection
model can gain at most. Mitsuba still picks the reflection lobe with
probability R at a glass hit and then returns nothing, so the glass carries
somewhat more Monte Carlo noise than in `NAME`.

`--sampler-seed N` (N >= 1) renders with other sampler seeds than the
default 0: the same images up to their Monte Carlo noise, for measuring
that noise (`noise_floor.py`); `--split test` renders the test views only.
Through glass in sunlight the path tracer leaves fireflies (rare caustic
paths of the sun; more samples find more of them: at 1024 samples the
dome has 13 per test view, at 128 three). `--median-of K` makes each
image the per-pixel median of K renderings of --spp samples each: no
fireflies and less noise, at the price of a bias (the sun's caustics
through the glass, light that is really there, are dropped).

Masks and normals are ray-cast here in numpy against the same primitives
(16 stratified rays per pixel for the mask, the pixel centre for the normal),
so they do not depend on the renderer's sampling.

`--train-masks DATASET --scene NAME --out DIR` renders nothing: it writes
the glass mask of every training view of DATASET (a dataset this script
made of scene NAME; its poses and image size are read from it) as
`DIR/VIEW.png`, the layout `tgs train --set reflection.seed_masks=DIR`
reads (Stage II's seeds from known glass masks instead of the residual;
issue 42's measure of what exact masks are worth). DATASET is only read;
DIR must not hold masks already. A pixel is glass where all of its 16 rays
hit glass; `--mask-share 0.5` makes it where half of them do (the outline
a segmentation model draws).
"""
import argparse
import json
import math
import os
import tempfile
import time

import numpy as np


def translate_scale(t, s, rot_z_deg=0.0):
    """4x4 to_world: scale, then rotate about z, then translate."""
    a = math.radians(rot_z_deg)
    r = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = r @ np.diag(np.broadcast_to(np.asarray(s, float), (3,)))
    m[:3, 3] = t
    return m


class Prim:
    """One shape: kind in sphere | cube | rectangle | cylinder (Mitsuba's unit
    shapes; the cylinder open, radius 1, z in [0, 1]) | arc (the part of that
    cylinder with |azimuth| <= `half_angle`, a triangle mesh for Mitsuba) |
    triangles (flat triangles, `tris` a T x 3 x 3 array in the shape's frame)."""

    def __init__(self, kind, to_world, bsdf, glass=False, emitter=None, half_angle=None, tris=None):
        self.kind, self.m, self.bsdf, self.glass = kind, to_world, bsdf, glass
        self.emitter, self.half_angle, self.tris = emitter, half_angle, tris
        self.inv = np.linalg.inv(to_world)

    def transformed(self, t):
        """The same shape moved by the 4x4 `t` (applied after its own to_world)."""
        return Prim(self.kind, t @ self.m, self.bsdf, self.glass, self.emitter, self.half_angle, self.tris)

    def mitsuba(self, mi, tmp):
        d = {"type": self.kind, "to_world": mi.ScalarTransform4f(self.m.tolist()), "bsdf": self.bsdf}
        if self.kind == "arc":
            d["type"], d["filename"], d["face_normals"] = "obj", arc_obj(tmp, self.half_angle), False
        if self.kind == "triangles":
            d["type"], d["filename"], d["face_normals"] = "obj", triangles_obj(tmp, self.tris), True
        if self.emitter is not None:
            d["emitter"] = self.emitter
        return d

    def intersect(self, o, d):
        """Nearest t > 1e-6 (inf when missed) and world normals, for rays o + t d (N x 3)."""
        lo = o @ self.inv[:3, :3].T + self.inv[:3, 3]
        ld = d @ self.inv[:3, :3].T
        n_local = np.zeros_like(lo)
        inf = np.full(len(o), np.inf)
        if self.kind == "sphere":
            a = (ld * ld).sum(1)
            b = 2 * (lo * ld).sum(1)
            c = (lo * lo).sum(1) - 1
            disc = b * b - 4 * a * c
            ok = disc >= 0
            sq = np.sqrt(np.where(ok, disc, 0))
            t0 = (-b - sq) / (2 * a)
            t1 = (-b + sq) / (2 * a)
            t = np.where(ok & (t0 > 1e-6), t0, np.where(ok & (t1 > 1e-6), t1, inf))
            n_local = lo + np.where(np.isfinite(t), t, 0)[:, None] * ld
        elif self.kind == "rectangle":
            with np.errstate(divide="ignore", invalid="ignore"):
                t = -lo[:, 2] / ld[:, 2]
            p = lo + np.where(np.isfinite(t), t, 0)[:, None] * ld
            ok = np.isfinite(t) & (t > 1e-6) & (np.abs(p[:, 0]) <= 1) & (np.abs(p[:, 1]) <= 1)
            t = np.where(ok, t, inf)
            n_local[:, 2] = 1
        elif self.kind == "cube":
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (-1 - lo) / ld
                t2 = (1 - lo) / ld
            tmin = np.nan_to_num(np.minimum(t1, t2), nan=-np.inf)
            tmax = np.nan_to_num(np.maximum(t1, t2), nan=np.inf)
            tn, tf = tmin.max(1), tmax.min(1)
            ok = (tn <= tf) & (tf > 1e-6)
            t = np.where(ok, np.where(tn > 1e-6, tn, tf), inf)
            p = lo + np.where(np.isfinite(t), t, 0)[:, None] * ld
            axis = np.abs(p).argmax(1)
            n_local[np.arange(len(o)), axis] = np.sign(p[np.arange(len(o)), axis])
        elif self.kind in ("cylinder", "arc"):
            a = ld[:, 0] ** 2 + ld[:, 1] ** 2
            b = 2 * (lo[:, 0] * ld[:, 0] + lo[:, 1] * ld[:, 1])
            c = lo[:, 0] ** 2 + lo[:, 1] ** 2 - 1
            with np.errstate(divide="ignore", invalid="ignore"):
                disc = b * b - 4 * a * c
                ok = (disc >= 0) & (a > 0)
                sq = np.sqrt(np.where(ok, disc, 0))
                roots = [(-b - sq) / (2 * a), (-b + sq) / (2 * a)]
            t = inf.copy()
            for r in reversed(roots):  # the nearer root wins when both are valid
                r = np.where(ok, r, np.inf)
                p = lo + np.where(np.isfinite(r), r, 0)[:, None] * ld
                good = np.isfinite(r) & (r > 1e-6) & (p[:, 2] >= 0) & (p[:, 2] <= 1)
                if self.kind == "arc":
                    good &= np.abs(np.arctan2(p[:, 1], p[:, 0])) <= self.half_angle
                t = np.where(good, r, t)
                n_local = np.where(good[:, None], p * np.array([1.0, 1.0, 0.0]), n_local)
        elif self.kind == "triangles":
            t = inf.copy()
            for a, b, c in self.tris:
                # Moller-Trumbore, both sides.
                e1, e2 = b - a, c - a
                pv = np.cross(ld, e2)
                det = pv @ e1
                with np.errstate(divide="ignore", invalid="ignore"):
                    inv = 1.0 / det
                    tv = lo - a
                    u = (tv * pv).sum(1) * inv
                    qv = np.cross(tv, e1)
                    v = (ld * qv).sum(1) * inv
                    r = (qv @ e2) * inv
                good = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (r > 1e-6) & (r < t)
                t = np.where(good, r, t)
                n_local = np.where(good[:, None], np.cross(e1, e2), n_local)
        else:
            raise ValueError(self.kind)
        n = n_local @ self.inv[:3, :3]  # inverse transpose
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        return t, n


def arc_obj(tmp, half_angle, segments=512):
    """An OBJ of the unit cylinder's part with |azimuth| <= half_angle, with
    vertex normals (smooth shading; the chord error at 512 segments is far
    below a pixel)."""
    path = os.path.join(tmp, f"arc_{half_angle:.6f}.obj")
    a = np.linspace(-half_angle, half_angle, segments + 1)
    lines = []
    for z in (0.0, 1.0):
        lines += [f"v {math.cos(t):.9f} {math.sin(t):.9f} {z}" for t in a]
    lines += [f"vn {math.cos(t):.9f} {math.sin(t):.9f} 0" for t in a] * 2
    m = segments + 1
    for i in range(segments):
        q = (i + 1, i + 2, m + i + 2, m + i + 1)
        lines.append("f " + " ".join(f"{v}//{v}" for v in q))
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return path


def triangles_obj(tmp, tris):
    """An OBJ of flat triangles (T x 3 x 3)."""
    path = os.path.join(tmp, f"tris_{len(tris)}_{abs(hash(tris.tobytes()))}.obj")
    lines = [f"v {x:.9f} {y:.9f} {z:.9f}" for tri in tris for x, y, z in tri]
    lines += [f"f {3 * k + 1} {3 * k + 2} {3 * k + 3}" for k in range(len(tris))]
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return path


def pyramid_faces(half, height):
    """The four sloping faces of a square pyramid standing on z = 0, base
    half-width `half`, apex `height` above the centre (no base)."""
    c = [np.array(p, float) for p in ((half, half, 0), (-half, half, 0), (-half, -half, 0), (half, -half, 0))]
    apex = np.array([0.0, 0.0, height])
    return np.array([[c[k], c[(k + 1) % 4], apex] for k in range(4)])


def twosided(bsdf):
    return {"type": "twosided", "bsdf": bsdf}


def checker(mi, c0, c1, scale):
    return {"type": "diffuse", "reflectance": {"type": "checkerboard", "color0": {"type": "rgb", "value": c0}, "color1": {"type": "rgb", "value": c1}, "to_uv": mi.ScalarTransform4f().scale([scale, scale, 1])}}


SCENES = ["globe", "globe_far", "pane", "dome", "cabinet", "cylinder", "facade", "windshield", "diffuse", "vehicle", "globe_near", "bookshelf", "house", "pyramid", "garage", "display"]
# The suite of issue 42; `vehicle` (planar windows around an opaque body),
# `globe_near` (a glass sphere among nearby objects), `bookshelf` (two
# glass doors in one frame, pieces of glass apart in one plane) and `house`
# (a window in each of two walls at a right angle) and `pyramid` (a glass
# pyramid over two objects among near pillars: closed glass of flat faces),
# `garage` (the vehicle inside an open-fronted garage: its windows reflect
# the near walls) and `display` (a monitor's glass over its screen, on a
# desk) are the paper's kinds added for issue 77: `--scene paper` makes them.
PAPER = ["vehicle", "globe_near", "bookshelf", "house", "pyramid", "garage", "display"]
SUITE = [n for n in SCENES if n != "diffuse" and n not in PAPER]
FRONT_ONLY = {"facade", "windshield", "bookshelf", "garage", "display"}


def upright(width, height, centre, normal_axis="x"):
    """A rectangle standing upright: `width` along world y (normal +x) or x
    (normal +y), `height` along z, centred at `centre`."""
    m = np.eye(4)
    if normal_axis == "x":
        m[:3, :3] = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]]) @ np.diag([width / 2, height / 2, 1.0])
    else:
        m[:3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, 1, 0]]) @ np.diag([width / 2, height / 2, 1.0])
    m[:3, 3] = centre
    return m


def lamp(centre, half, radiance):
    """A ceiling lamp: a rectangle of half-sizes `half` facing down (its
    normal flipped by a rotation about x) that emits `radiance`."""
    m = translate_scale(centre, [half[0], half[1], 1]) @ np.diag([1.0, -1.0, -1.0, 1.0])
    return Prim("rectangle", m, {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.9, 0.9, 0.9]}},
                emitter={"type": "area", "radiance": {"type": "rgb", "value": radiance}})


def room(mi, front_x):
    """A room behind a glass front at x = front_x: checkered back and side
    walls, a ceiling with a lamp under it, a sphere and a box inside."""
    wall = twosided(checker(mi, [0.85, 0.82, 0.7], [0.45, 0.3, 0.25], 6))
    side = twosided(checker(mi, [0.3, 0.45, 0.7], [0.85, 0.85, 0.8], 5))
    depth = front_x + 1.6
    prims = [Prim("rectangle", upright(2.8, 1.5, [-1.6, 0, 0.75]), wall),
             Prim("rectangle", upright(depth, 1.5, [front_x - depth / 2, -1.4, 0.75], "y"), side),
             Prim("rectangle", upright(depth, 1.5, [front_x - depth / 2, 1.4, 0.75], "y"), side),
             Prim("rectangle", translate_scale([-0.6, 0, 1.5], [1.0, 1.4, 1]), twosided({"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.8, 0.8, 0.8]}}))]
    prims.append(lamp([-0.6, 0, 1.49], [0.35, 0.25], [6.0, 5.6, 5.0]))
    prims.append(Prim("sphere", translate_scale([-0.5, -0.5, 0.35], 0.35), checker(mi, [0.9, 0.85, 0.2], [0.8, 0.2, 0.6], 4)))
    prims.append(Prim("cube", translate_scale([-0.9, 0.55, 0.4], [0.2, 0.2, 0.4], 20), {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.95, 0.55, 0.15]}}))
    return prims


def vehicle(mi, glass):
    """A vehicle-like object under the sky: an opaque body on four wheels,
    a cabin of four planar windows (front, back, sides) under an opaque
    roof, seats inside: planar glass around an object, whose masks' hull is
    a box with caps that are not glass."""
    paint = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.75, 0.12, 0.1]}}
    dark = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.06, 0.06, 0.07]}}
    prims = [Prim("cube", translate_scale([0, 0, 0.45], [0.95, 0.45, 0.2]), paint),
             Prim("rectangle", translate_scale([0, 0, 1.05], [0.52, 0.44, 1]), twosided(paint)),
             Prim("cube", translate_scale([0, 0, 0.75], [0.3, 0.32, 0.1]), checker(mi, [0.95, 0.85, 0.3], [0.2, 0.3, 0.8], 4))]
    for sx in (-0.6, 0.6):
        for sy in (-0.42, 0.42):
            prims.append(Prim("cube", translate_scale([sx, sy, 0.16], [0.16, 0.05, 0.16]), dark))
    # The windows: glass only, between the body's top (0.65) and the roof (1.05).
    prims.append(Prim("rectangle", upright(0.88, 0.4, [0.52, 0.0, 0.85]), glass, glass=True))
    prims.append(Prim("rectangle", upright(0.88, 0.4, [-0.52, 0.0, 0.85]), glass, glass=True))
    prims.append(Prim("rectangle", upright(1.04, 0.4, [0.0, 0.44, 0.85], "y"), glass, glass=True))
    prims.append(Prim("rectangle", upright(1.04, 0.4, [0.0, -0.44, 0.85], "y"), glass, glass=True))
    return prims


def matte(rgb, two=True):
    """A diffuse material of colour `rgb`, two-sided unless `two` is false."""
    m = {"type": "diffuse", "reflectance": {"type": "rgb", "value": rgb}}
    return twosided(m) if two else m


def bookshelf(mi, glass):
    """A glass-fronted bookshelf under the sky: a wooden case (front at
    x = 0.4, 2 wide, 1.3 high, 0.8 deep) with a shelf, a lamp under its top,
    books, a ball and a box inside, and two glass doors side by side in its
    front frame, a mullion 0.16 wide between them: planar glass in two
    pieces apart, each ringed by wood flush with it."""
    wood = matte([0.45, 0.28, 0.15])
    inner = matte([0.8, 0.75, 0.65])
    prims = [Prim("rectangle", upright(0.12, 1.3, [0.4, -0.94, 0.75]), wood),
             Prim("rectangle", upright(0.12, 1.3, [0.4, 0.94, 0.75]), wood),
             Prim("rectangle", upright(0.16, 1.3, [0.4, 0.0, 0.75]), wood),
             Prim("rectangle", upright(1.76, 0.12, [0.4, 0.0, 1.34]), wood),
             Prim("rectangle", upright(1.76, 0.12, [0.4, 0.0, 0.16]), wood),
             Prim("rectangle", upright(2.0, 1.3, [-0.4, 0.0, 0.75]), inner),
             Prim("rectangle", upright(0.8, 1.3, [0.0, -1.0, 0.75], "y"), wood),
             Prim("rectangle", upright(0.8, 1.3, [0.0, 1.0, 0.75], "y"), wood),
             Prim("rectangle", translate_scale([0, 0, 1.4], [0.4, 1.0, 1]), wood),
             Prim("rectangle", translate_scale([0, 0, 0.1], [0.4, 1.0, 1]), inner),
             Prim("rectangle", translate_scale([0, 0, 0.75], [0.4, 1.0, 1]), inner),
             Prim("cube", translate_scale([0, 0, 0.05], [0.4, 1.0, 0.05]), wood)]
    prims.append(lamp([0.0, 0, 1.39], [0.3, 0.8], [4.0, 3.8, 3.4]))
    prims.append(Prim("sphere", translate_scale([-0.05, -0.5, 0.32], 0.22), checker(mi, [0.9, 0.85, 0.2], [0.8, 0.2, 0.6], 4)))
    prims.append(Prim("cube", translate_scale([0.0, 0.5, 0.28], [0.15, 0.2, 0.18], 20), {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.95, 0.55, 0.15]}}))
    for k, c in enumerate([[0.7, 0.1, 0.1], [0.1, 0.3, 0.7], [0.1, 0.55, 0.2], [0.85, 0.75, 0.2], [0.5, 0.2, 0.6]]):
        prims.append(Prim("cube", translate_scale([-0.1, -0.8 + 0.1 * k, 0.93], [0.22, 0.04, 0.18]), {"type": "diffuse", "reflectance": {"type": "rgb", "value": c}}))
    prims.append(Prim("cube", translate_scale([-0.05, 0.5, 0.93], [0.18, 0.25, 0.18], 15), checker(mi, [0.2, 0.5, 0.9], [0.9, 0.8, 0.2], 3)))
    # The doors: glass only, each in its opening of the frame.
    prims.append(Prim("rectangle", upright(0.8, 1.06, [0.4, -0.48, 0.75]), glass, glass=True))
    prims.append(Prim("rectangle", upright(0.8, 1.06, [0.4, 0.48, 0.75]), glass, glass=True))
    return prims


def house(mi, glass):
    """A house under the sky: walls 1.2 high around a 1.6 x 1.2 floor, a flat
    roof, a lamp under it, a ball and a box inside; one window in the front
    wall (x = 0.8) and one in the side wall (y = 0.6), each 0.5 high and set
    in its wall: two pieces of planar glass at a right angle, seen together
    from the corner between them."""
    wall = matte([0.82, 0.78, 0.68])
    roof = matte([0.5, 0.15, 0.12])
    prims = [Prim("rectangle", upright(0.3, 1.2, [0.8, -0.45, 0.6]), wall),
             Prim("rectangle", upright(0.3, 1.2, [0.8, 0.45, 0.6]), wall),
             Prim("rectangle", upright(0.6, 0.4, [0.8, 0.0, 0.2]), wall),
             Prim("rectangle", upright(0.6, 0.3, [0.8, 0.0, 1.05]), wall),
             Prim("rectangle", upright(0.45, 1.2, [-0.575, 0.6, 0.6], "y"), wall),
             Prim("rectangle", upright(0.45, 1.2, [0.575, 0.6, 0.6], "y"), wall),
             Prim("rectangle", upright(0.7, 0.4, [0.0, 0.6, 0.2], "y"), wall),
             Prim("rectangle", upright(0.7, 0.3, [0.0, 0.6, 1.05], "y"), wall),
             Prim("rectangle", upright(1.2, 1.2, [-0.8, 0.0, 0.6]), wall),
             Prim("rectangle", upright(1.6, 1.2, [0.0, -0.6, 0.6], "y"), wall),
             Prim("rectangle", translate_scale([0, 0, 1.2], [0.8, 0.6, 1]), roof)]
    prims.append(lamp([0.0, 0, 1.19], [0.25, 0.2], [5.0, 4.7, 4.2]))
    prims.append(Prim("sphere", translate_scale([0.2, 0.05, 0.25], 0.25), checker(mi, [0.9, 0.85, 0.2], [0.8, 0.2, 0.6], 4)))
    prims.append(Prim("cube", translate_scale([-0.35, 0.2, 0.3], [0.15, 0.15, 0.3], 20), {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.95, 0.55, 0.15]}}))
    # The windows: glass only, each in its opening.
    prims.append(Prim("rectangle", upright(0.6, 0.5, [0.8, 0.0, 0.65]), glass, glass=True))
    prims.append(Prim("rectangle", upright(0.7, 0.5, [0.0, 0.6, 0.65], "y"), glass, glass=True))
    return prims


def garage(mi, glass):
    """The vehicle inside an open-fronted garage (open at +x): a checkered
    back wall at x = -1.5, side walls at y = +-1.3 reaching x = 0.9, a roof
    at z = 1.6 with a lamp under it, a workbench and boxes along the walls:
    planar glass whose reflections are of near geometry (the paper's
    near-field kind), the side windows 0.75 from the walls they mirror."""
    back = twosided(checker(mi, [0.85, 0.82, 0.7], [0.35, 0.35, 0.4], 6))
    side = twosided(checker(mi, [0.3, 0.45, 0.7], [0.85, 0.85, 0.8], 5))
    prims = [Prim("rectangle", upright(2.6, 1.6, [-1.5, 0.0, 0.8]), back),
             Prim("rectangle", upright(2.4, 1.6, [-0.3, -1.3, 0.8], "y"), side),
             Prim("rectangle", upright(2.4, 1.6, [-0.3, 1.3, 0.8], "y"), side),
             Prim("rectangle", translate_scale([-0.3, 0, 1.6], [1.2, 1.3, 1]), matte([0.7, 0.7, 0.7]))]
    prims.append(lamp([-0.3, 0, 1.59], [0.4, 0.2], [6.0, 5.6, 5.0]))
    prims.append(Prim("cube", translate_scale([-1.3, 0.0, 0.4], [0.18, 0.8, 0.4]), matte([0.45, 0.28, 0.15], False)))
    prims.append(Prim("cube", translate_scale([-0.6, 1.1, 0.2], [0.15, 0.15, 0.2], 10), checker(mi, [0.2, 0.5, 0.9], [0.9, 0.8, 0.2], 3)))
    prims.append(Prim("cube", translate_scale([0.3, -1.1, 0.25], [0.15, 0.15, 0.25], 35), checker(mi, [0.9, 0.3, 0.3], [0.95, 0.95, 0.95], 3)))
    # A quarter larger than `vehicle`'s, so that its windows span more pixels.
    return prims + [q.transformed(np.diag([1.25, 1.25, 1.25, 1.0])) for q in vehicle(mi, glass)]


def display(mi, glass):
    """A monitor on a desk under the sky (the paper's "computer"): a dark
    case, a lit screen showing a coloured pattern, and a pane of glass 0.03 in
    front of it (facing +x), a box and a ball beside it: planar glass over
    a textured surface close behind it."""
    dark = matte([0.06, 0.06, 0.07], False)
    prims = [Prim("cube", translate_scale([0.0, 0.0, 0.35], [0.45, 1.0, 0.35]), matte([0.45, 0.28, 0.15], False)),
             Prim("cube", translate_scale([-0.12, 0.0, 1.22], [0.05, 0.72, 0.44]), dark),
             Prim("cube", translate_scale([-0.15, 0.0, 0.74], [0.04, 0.05, 0.05]), dark),
             Prim("rectangle", upright(1.3, 0.76, [-0.065, 0.0, 1.22]), {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.05, 0.05, 0.05]}},
                  emitter={"type": "area", "radiance": {"type": "checkerboard", "color0": {"type": "rgb", "value": [1.0, 0.65, 0.15]}, "color1": {"type": "rgb", "value": [0.15, 0.35, 0.9]}, "to_uv": mi.ScalarTransform4f().scale([3, 3, 1])}}),
             Prim("sphere", translate_scale([0.1, 0.75, 0.82], 0.12), checker(mi, [0.9, 0.85, 0.2], [0.8, 0.2, 0.6], 4)),
             Prim("cube", translate_scale([0.1, -0.75, 0.8], [0.1, 0.12, 0.1], 20), {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.95, 0.55, 0.15]}})]
    prims.append(Prim("rectangle", upright(1.36, 0.82, [-0.035, 0.0, 1.22]), glass, glass=True))
    return prims


def build(mi, name, reflection=True):
    if name not in SCENES:
        raise ValueError(f"unknown scene '{name}'")
    glass = {"type": "thindielectric", "int_ior": 1.5}
    if not reflection:
        glass["specular_reflectance"] = 0.0
    prims = [Prim("rectangle", translate_scale([0, 0, 0], [200, 200, 1]), checker(mi, [0.75, 0.78, 0.72], [0.30, 0.42, 0.36], 400))]
    palette = [([0.9, 0.2, 0.2], [0.95, 0.85, 0.2]), ([0.2, 0.4, 0.9], [0.9, 0.9, 0.9]), ([0.2, 0.75, 0.3], [0.9, 0.5, 0.1]),
               ([0.8, 0.3, 0.8], [0.2, 0.8, 0.8]), ([0.95, 0.6, 0.1], [0.3, 0.2, 0.6]), ([0.1, 0.5, 0.5], [0.9, 0.8, 0.7])]
    if name != "globe_far":
        for k, (c0, c1) in enumerate(palette):
            a = 2 * math.pi * (k + 0.25) / len(palette)
            h = 0.6 + 0.3 * (k % 3)
            prims.append(Prim("cube", translate_scale([6.0 * math.cos(a), 6.0 * math.sin(a), h], [0.5, 0.5, h], math.degrees(a)), checker(mi, c0, c1, 3)))
    if name == "bookshelf":
        prims += bookshelf(mi, glass)
    elif name == "house":
        prims += house(mi, glass)
    elif name == "garage":
        prims += garage(mi, glass)
    elif name == "display":
        prims += display(mi, glass)
    elif name in FRONT_ONLY:
        prims += room(mi, 0.4)
    elif name == "vehicle":
        prims += vehicle(mi, glass)
    else:
        centre = [0.2, -0.15, 0.35] if name == "cabinet" else [0.25, -0.15, 0.35]
        prims.append(Prim("sphere", translate_scale(centre, 0.35), checker(mi, [0.9, 0.85, 0.2], [0.8, 0.2, 0.6], 4)))
        prims.append(Prim("cube", translate_scale([-0.3, 0.3, 0.4], [0.15, 0.15, 0.4], 20), {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.95, 0.55, 0.15]}}))
    if name in ("globe", "globe_far"):
        prims.append(Prim("sphere", translate_scale([0, 0, 0.95], 0.95), glass, glass=True))
    elif name == "pane":
        # A 2.4 x 1.4 pane standing upright between the two middle objects.
        prims.append(Prim("rectangle", upright(2.4, 1.4, [0.0, 0.0, 0.7]), glass, glass=True))
    elif name == "dome":
        # A hemisphere: the sphere's lower half is under the floor.
        prims.append(Prim("sphere", translate_scale([0, 0, 0], 1.1), glass, glass=True))
        for k in range(4):
            a = math.pi / 4 + k * math.pi / 2
            prims.append(Prim("cube", translate_scale([2.0 * math.cos(a), 2.0 * math.sin(a), 0.7], [0.12, 0.12, 0.7], 30 * k),
                              checker(mi, [0.95, 0.95, 0.9], [0.25, 0.25, 0.3], 4)))
    elif name == "globe_near":
        # The globe among nearby objects: the dome's pillars and two boxes.
        prims.append(Prim("sphere", translate_scale([0, 0, 0.95], 0.95), glass, glass=True))
        for k in range(4):
            a = k * math.pi / 2
            prims.append(Prim("cube", translate_scale([1.7 * math.cos(a), 1.7 * math.sin(a), 0.6], [0.12, 0.12, 0.6], 30 * k),
                              checker(mi, [0.95, 0.95, 0.9], [0.25, 0.25, 0.3], 4)))
        prims.append(Prim("cube", translate_scale([1.3, 1.3, 0.25], [0.25, 0.25, 0.25], 15), checker(mi, [0.2, 0.5, 0.9], [0.9, 0.8, 0.2], 3)))
        prims.append(Prim("cube", translate_scale([-1.3, -1.2, 0.3], [0.3, 0.2, 0.3], 40), checker(mi, [0.9, 0.3, 0.3], [0.95, 0.95, 0.95], 3)))
    elif name == "cabinet":
        prims.append(Prim("cube", translate_scale([0, 0, 0.61], [0.7, 0.7, 0.6], 25), glass, glass=True))
    elif name == "pyramid":
        # A glass pyramid over the two objects, among near pillars (the
        # paper's "pyramid of glass"): closed glass of four flat faces.
        prims.append(Prim("triangles", translate_scale([0, 0, 0.002], 1.0, 15), glass, glass=True, tris=pyramid_faces(1.2, 1.6)))
        for k in range(4):
            a = k * math.pi / 2 + 0.3
            prims.append(Prim("cube", translate_scale([2.4 * math.cos(a), 2.4 * math.sin(a), 0.7], [0.12, 0.12, 0.7], 30 * k),
                              checker(mi, [0.95, 0.95, 0.9], [0.25, 0.25, 0.3], 4)))
    elif name == "cylinder":
        prims.append(Prim("cylinder", translate_scale([0, 0, 0.005], [0.85, 0.85, 1.3]), glass, glass=True))
    elif name == "facade":
        prims.append(Prim("rectangle", upright(2.8, 1.5, [0.4, 0.0, 0.75]), glass, glass=True))
    elif name == "windshield":
        # Axis at x = -1.6, radius 2: the apex at x = 0.4, the edges at y = +-1.4.
        half = math.asin(1.4 / 2.0)
        prims.append(Prim("arc", translate_scale([-1.6, 0, 0], [2.0, 2.0, 1.5]), glass, glass=True, half_angle=half))
    return prims


def c2w_look_at(o, target, up=(0.0, 0.0, 1.0)):
    """Camera-to-world in the dataset's axes (x right, y up, looking along -z)."""
    o, target, up = (np.asarray(v, float) for v in (o, target, up))
    f = target - o
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = r, u, -f, o
    return m


def cameras(n, offset, rng, front=False):
    """An orbit around the middle; `front`: azimuths within 50 degrees of +x
    only (the scenes whose glass is the front of a room), lower and aimed at
    the room's middle."""
    out = []
    for i in range(n):
        u = (i * 0.618034 + offset) % 1.0
        az = math.radians(-50 + 100 * u) if front else 2 * math.pi * u
        el = math.radians(rng.uniform(8, 30) if front else rng.uniform(20, 50))
        rad = rng.uniform(3.6, 4.4)
        o = [rad * math.cos(el) * math.cos(az), rad * math.cos(el) * math.sin(az), rad * math.sin(el)]
        out.append(c2w_look_at(o, [0, 0, 0.7] if front else [0, 0, 0.5]))
    return out


def rays(c2w, res, fov, sub):
    """World rays through a sub x sub grid in every pixel (pixel-major order)."""
    f = 0.5 * res / math.tan(0.5 * fov)
    s = (np.arange(sub) + 0.5) / sub
    px = np.arange(res)
    u = (px[None, :, None, None] + s[None, None, None, :]).repeat(res, 0).repeat(sub, 2)
    v = (px[:, None, None, None] + s[None, None, :, None]).repeat(res, 1).repeat(sub, 3)
    d = np.stack([(u - 0.5 * res) / f, -(v - 0.5 * res) / f, -np.ones_like(u)], -1).reshape(-1, 3)
    d = d @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(c2w[:3, 3], d.shape)
    return o, d


def first_hit(prims, o, d):
    """Each ray's first hit: its distance (inf: none), normal, whether it is
    glass, and the index in `prims` of what it hit (-1: nothing)."""
    t = np.full(len(o), np.inf)
    n = np.zeros_like(d)
    g = np.zeros(len(o), bool)
    k = np.full(len(o), -1)
    for i, p in enumerate(prims):
        tp, np_ = p.intersect(o, d)
        closer = tp < t
        t = np.where(closer, tp, t)
        n = np.where(closer[:, None], np_, n)
        g = np.where(closer, p.glass, g)
        k = np.where(closer, i, k)
    return t, n, g, k


def write_8bit(mi, path, image, srgb, quality=-1):
    """8-bit PNG or JPEG (by `path`'s extension; JPEG `quality`) of a float image (sRGB-encoded when `srgb`), by Mitsuba's Bitmap."""
    fmt = mi.Bitmap.PixelFormat.RGB if image.shape[2] == 3 else mi.Bitmap.PixelFormat.Y
    mi.Bitmap(np.ascontiguousarray(image, dtype=np.float32)).convert(fmt, mi.Struct.Type.UInt8, srgb_gamma=srgb).write(path, quality=quality)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--scene", action="append", choices=SCENES + ["suite", "paper"], help="repeatable; suite: issue 42's glass scenes; paper: the paper's kinds added since (vehicle, globe_near, bookshelf, house, pyramid); default: all")
    ap.add_argument("--res", type=int, default=200)
    ap.add_argument("--spp", type=int, default=128)
    ap.add_argument("--train", type=int, default=60)
    ap.add_argument("--test", type=int, default=12)
    ap.add_argument("--no-reflection", action="store_true", help="glass transmits only; writes NAME_norefl")
    ap.add_argument("--sampler-seed", type=int, default=0, help="0: the default seeds; N >= 1 other ones (the same images up to Monte Carlo noise)")
    ap.add_argument("--split", choices=["both", "train", "test"], default="both", help="which views to render")
    ap.add_argument("--median-of", type=int, default=1, metavar="K", help="each image the per-pixel median of K renderings of --spp samples (no fireflies; biased: drops the sun's caustics through the glass)")
    ap.add_argument("--compact", action="store_true", help="JPEG images (quality 95) and half-float EXR normals: ~10x smaller, for datasets that travel (perf/suite/gpu_paper.sh)")
    ap.add_argument("--face", type=int, metavar="F", help="with --piece K of a cube and --whole: its face F alone (0..5: +x, -x, +y, -y, +z, -z), as a user marks a glass box face by face")
    ap.add_argument("--whole", action="store_true", help="with --piece: the piece's whole outline, what stands in front of it ignored (the corners a user clicks around an occluder)")
    ap.add_argument("--piece", type=int, metavar="K", help="with --train-masks: the masks of the scene's K-th glass primitive alone (a pane of `vehicle`), for marking each piece of glass as its own region")
    ap.add_argument("--mask-share", type=float, default=1.0, metavar="F", help="with --train-masks: the share of a pixel's 16 rays that must hit glass (default 1: all)")
    ap.add_argument("--train-masks", metavar="DATASET", help="only write DATASET's training views' glass masks into --out (one --scene)")
    a = ap.parse_args()
    if not 0 <= a.sampler_seed <= 1000:
        raise SystemExit(f"--sampler-seed must be in 0..=1000, not {a.sampler_seed}")
    if not 1 <= a.median_of <= 9:
        raise SystemExit(f"--median-of must be in 1..=9, not {a.median_of}")
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    if a.train_masks:
        return train_masks(mi, a)
    fov = math.pi / 4
    names = []
    for n in a.scene or SCENES:
        for m in (SUITE if n == "suite" else PAPER if n == "paper" else [n]):
            if m not in names:
                names.append(m)
    for name in names:
        root = os.path.join(a.out, name + ("_norefl" if a.no_reflection else ""))
        if any(os.path.exists(os.path.join(root, f"transforms_{sp}.json")) for sp in ("train", "test")):
            raise SystemExit(f"{root} already holds a dataset; this script never writes over one (remove it or pick another --out)")
        prims = build(mi, name, not a.no_reflection)
        scene_d = {"type": "scene", "integrator": {"type": "path", "max_depth": 12}, "sky": {"type": "sunsky", "sun_direction": [0.45, -0.35, 0.82], "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}}
        with tempfile.TemporaryDirectory() as tmp:
            for k, p in enumerate(prims):
                scene_d[f"shape{k:02}"] = p.mitsuba(mi, tmp)
            scene = mi.load_dict(scene_d)
        rng = np.random.default_rng({"globe": 1, "pane": 2, "diffuse": 3}.get(name, 100 + SCENES.index(name)))  # the first three as before
        for split, n, offset in (("train", a.train, 0.0), ("test", a.test, 0.37)):
            # The cameras come from one stream: drawn for every split, rendered for the chosen.
            poses = cameras(n, offset, rng, name in FRONT_ONLY)
            if a.split not in ("both", split):
                continue
            os.makedirs(os.path.join(root, split), exist_ok=True)
            frames = []
            for i, c2w in enumerate(poses):
                t0 = time.time()
                o = c2w[:3, 3]
                sensor = mi.load_dict({"type": "perspective", "fov": math.degrees(fov), "fov_axis": "x",
                                       "to_world": mi.ScalarTransform4f().look_at(origin=o.tolist(), target=(o - c2w[:3, 2]).tolist(), up=c2w[:3, 1].tolist()),
                                       "sampler": {"type": "independent", "sample_count": a.spp, "seed": 1000 * (split == "test") + i + 100_000 * a.sampler_seed},
                                       "film": {"type": "hdrfilm", "width": a.res, "height": a.res, "pixel_format": "rgb"}})
                # The per-pixel median of --median-of renderings (the first is the plain one).
                img = np.median([np.array(mi.render(scene, sensor=sensor, seed=i + 100_000 * a.sampler_seed + 10_000 * k))[:, :, :3] for k in range(a.median_of)], axis=0)
                stem = f"{split}/r_{i}"
                write_8bit(mi, os.path.join(root, stem + (".jpg" if a.compact else ".png")), img, True, quality=95 if a.compact else -1)
                frame = {"file_path": "./" + stem + (".jpg" if a.compact else ""), "transform_matrix": c2w.tolist()}
                if split == "test":
                    ro, rd = rays(c2w, a.res, fov, 1)
                    t, nrm, _, _ = first_hit(prims, ro, rd)
                    nrm = np.where((nrm * rd).sum(1, keepdims=True) > 0, -nrm, nrm)
                    nrm[~np.isfinite(t)] = 0
                    nrm = nrm.reshape(a.res, a.res, 3).astype(np.float32)
                    npath = stem + ("_normal.exr" if a.compact else "_normal.npy")
                    if a.compact:
                        mi.Bitmap(nrm, mi.Bitmap.PixelFormat.RGB).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.Float16, srgb_gamma=False).write(os.path.join(root, npath))
                    else:
                        np.save(os.path.join(root, npath), nrm)
                    ro, rd = rays(c2w, a.res, fov, 4)
                    _, _, g, _ = first_hit(prims, ro, rd)
                    mask = g.reshape(a.res, a.res, 16).all(2)
                    write_8bit(mi, os.path.join(root, stem + "_mask.png"), mask.astype(np.float32)[:, :, None], False)
                    frame["normal_path"] = "./" + npath
                    frame["mask_path"] = "./" + stem + "_mask.png"
                frames.append(frame)
                print(f"{os.path.basename(root)} {stem}: {time.time() - t0:.1f} s", flush=True)
            with open(os.path.join(root, f"transforms_{split}.json"), "w") as fh:
                json.dump({"camera_angle_x": fov, "frames": frames}, fh, indent=1)


def train_masks(mi, a):
    """`--train-masks`: the glass masks of an existing dataset's training views."""
    if not a.scene or len(a.scene) != 1 or a.scene[0] == "suite":
        raise SystemExit("--train-masks needs exactly one --scene NAME (the scene DATASET was made of)")
    name = a.scene[0]
    if not 0.0 < a.mask_share <= 1.0:
        raise SystemExit(f"--mask-share {a.mask_share}: a share of a pixel's rays, in (0, 1]")
    path = os.path.join(a.train_masks, "transforms_train.json")
    try:
        t = json.load(open(path))
    except (OSError, ValueError) as e:
        raise SystemExit(f"{path}: {e}")
    prims = build(mi, name)
    glass = [i for i, p in enumerate(prims) if p.glass]
    if a.piece is not None and not 0 <= a.piece < len(glass):
        raise SystemExit(f"--piece {a.piece}: {name} has {len(glass)} glass primitives (0..{len(glass) - 1})")
    face = None
    if a.face is not None:
        if a.piece is None or not a.whole or prims[glass[a.piece]].kind != "cube" or not 0 <= a.face < 6:
            raise SystemExit("--face F (0..5: +x, -x, +y, -y, +z, -z) needs --piece K of a cube and --whole")
        # The face as a rectangle: its own u, v axes and the cube's axis as its normal, out at that side.
        axis, sign = a.face // 2, 1.0 - 2.0 * (a.face % 2)
        e = np.eye(4)
        local = np.zeros((4, 4))
        local[:3, 0], local[:3, 1], local[:3, 2] = e[:3, (axis + 1) % 3] * sign, e[:3, (axis + 2) % 3], e[:3, axis] * sign
        local[:3, 3], local[3, 3] = e[:3, axis] * sign, 1.0
        face = Prim("rectangle", prims[glass[a.piece]].m @ local, None)
    os.makedirs(a.out, exist_ok=True)
    for f in t["frames"]:
        stem = os.path.basename(f["file_path"])
        stem = os.path.splitext(stem)[0] if stem.endswith((".png", ".jpg")) else stem
        out = os.path.join(a.out, stem + ".png")
        if os.path.exists(out):
            raise SystemExit(f"{out} exists; this script never writes over a file (remove it or pick another --out)")
        img = os.path.join(a.train_masks, f["file_path"] + ("" if f["file_path"].endswith((".png", ".jpg")) else ".png"))
        w, h = mi.Bitmap(img).size()
        if w != h:
            raise SystemExit(f"{img}: {w}x{h}; this script's cameras make square images")
        ro, rd = rays(np.array(f["transform_matrix"], float), w, t["camera_angle_x"], 4)
        if face is not None:
            g = np.isfinite(face.intersect(ro, rd)[0])
        elif a.piece is not None and a.whole:
            # The piece's whole outline: rays that meet its primitive, whatever stands before it.
            g = np.isfinite(prims[glass[a.piece]].intersect(ro, rd)[0])
        else:
            _, _, g, k = first_hit(prims, ro, rd)
            if a.piece is not None:
                # The piece alone: rays whose first hit is its primitive.
                g = k == glass[a.piece]
        write_8bit(mi, out, (g.reshape(w, w, 16).mean(2) >= a.mask_share - 1e-9).astype(np.float32)[:, :, None], False)
    if face is not None or (a.piece is not None and prims[glass[a.piece]].kind == "rectangle"):
        # The pane's corners in order around it, for a replay that clicks them (mark_glass.py --flat).
        m = (face or prims[glass[a.piece]]).m
        corners = [(m @ np.array([x, y, 0.0, 1.0]))[:3].tolist() for x, y in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        json.dump({"corners": corners}, open(os.path.join(a.out, "corners.json"), "w"))
    print(f"{len(t['frames'])} masks of {name} in {a.out}")


if __name__ == "__main__":
    main()
