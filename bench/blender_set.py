"""A second-renderer test set: objects in a glass block, rendered by Blender Cycles.

Run with the Python of a venv that has the ``bpy`` wheel, not the project's::

    python3.11 -m venv /work/venvs/bpy && /work/venvs/bpy/bin/pip install bpy==5.0.1 'numpy<2'
    /work/venvs/bpy/bin/python bench/blender_set.py --out /work/data/blender_set [--scenes stool knot]
    /work/venvs/bpy/bin/python bench/blender_set.py --degrade SRC_DATASET DST_DATASET [--seed 0]

It imports neither reneus_mi nor mitsuba: everything the project reads is written
from plain json/numpy (and Blender's own exporters), so the set tests the project
against data it did not make. The objects are built here, procedurally, and are
none of ``reneus_mi/data/objects.py``: four with thin parts (``stool``: a three-legged
stool with a ring stretcher; ``coil``: a wire spring; ``sprig``: a branching twig
with buds; ``ant``: bench/blender_capture.py's ant, legs and antennae 0.03-0.05 of its length
thick, about half a pixel at 128 px) and two smooth closed shapes (``knot``: a trefoil tube; ``blob``:
metaballs). Each is one watertight surface (Blender's voxel remesh of its parts),
Lambertian (Diffuse BSDF) with a procedural albedo (noise through a colour ramp,
in object coordinates).

The block is Blender's cube primitive, scaled into a slab or near-cube, with a Glass BSDF
(IOR 1.45, roughness 0); the world is a constant 0.8 (strength 1); Cycles with the
OpenImageDenoise denoiser, the Standard view transform, 8-bit PNG. 48 cameras (Fibonacci
points of a sphere around the block, world z up) see the whole block. The container file
is written by Blender's own exporters (in Blender's axes, z up), differently per scene:

- ``stool``: near-cube; binary PLY, triangles, no normals (8 shared vertices);
- ``coil``: tall slab; OBJ, triangles, no normals (8 shared vertices);
- ``sprig``: upright slab; ASCII PLY of quads, no normals (Blender's default faces);
- ``knot``: near-cube turned 25 degrees about z; OBJ quads with Blender's per-face normals;
- ``ant``: a slab turned 10 degrees about z; binary PLY, triangles, no normals;
- ``blob``: flat slab; binary PLY, triangles, no normals. Also ``box_vnormals/``: the same
  photographs, the block as a PLY with Blender's vertex normals, which average each
  corner's faces: the file calls the box smooth.

Layout of ``OUT/SCENE/``::

    gt.ply           the object's surface in world coordinates (not in any dataset)
    box/             transforms.json, images/r_NNN.png (RGBA, alpha = the block's mask:
                     pixel-centre rays that hit it), the block file (mesh_outside), IOR
    nobox/           the same object and cameras without the block; alpha is the same mask,
                     and ``scale_mat`` names the block's bounding sphere (the same region)
    box_vnormals/    (blob only) box/'s photographs with the block exported with normals
    scene.json       how it was made: settings, block file, render seconds, noise

``--containers case jar amber`` also photographs each object, with the same cameras, in the
containers collections hold (``OUT/SCENE/KIND/``, transforms.json stating them as the project
reads them): ``case``, the block's faces and inner faces ``WALL`` in around air (a Glass BSDF of
IOR 1/1.45 facing out of the air); ``jar``, a 64-sided cylinder through the block's corners
(side smooth, rims sharp) with a liquid ``WALL`` in (IOR 1.36 in 1.45, a Volume Absorption
``TINT``); ``amber``, the block with a Volume Absorption ``AMBER`` (Cycles absorbs density x
(1 - colour) per unit). The surfaces are written by Blender's PLY exporter (with its normals for
the jar).

``--degrade SRC DST`` writes a camera-like copy of one dataset folder (SRC is only read):
per-photo exposure drift (a factor uniform in 1 +- ``--exposure``), sensor noise (shot and
read noise on linear values), 8-bit JPEG at ``--jpeg-quality``. JPEG has no alpha: the box
variant's masks are then the container's projection, and a nobox copy has none.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shutil
import struct
import sys
import tempfile
import time
import zlib

import numpy as np

try:
    import bpy
    import bmesh
    from mathutils import Matrix
except ImportError:
    sys.exit('error: bench/blender_set.py needs the bpy wheel: run it with /work/venvs/bpy/bin/python '
             "(python3.11 -m venv ... && pip install bpy==5.0.1 'numpy<2')")

#: Index of refraction of the glass block.
IOR = 1.45
#: Containers of collections (``--containers``): a glass case's and a jar's glass (Blender
#: units: the blocks are about 1.2 across), a jar's liquid (ethanol) and its faint tint, amber
#: (absorption per unit, RGB).
CONTAINERS = ('case', 'jar', 'amber')
WALL = 0.05
LIQUID = 1.36
TINT = (0.02, 0.05, 0.15)
AMBER = (0.15, 0.35, 0.7)
#: Radiance of the constant world (linear, every channel).
WORLD = 0.8
#: Camera distance from the block's centre, in units of the block's bounding radius.
CAMERA_DISTANCE = 4.0
#: Edge length of the voxel remesh that makes every object one watertight surface.
VOXEL = 0.005
#: Image names of the frames.
NAME = 'r_{:03d}'
#: Pixels rendered beyond each side of the image and cropped away: the denoiser leaves
#: blotches of up to 10/255 along an image's border, even on a constant background.
PAD = 8

# Scenes (each named after its object in OBJECTS): the box the object is fitted into (half extents), its albedo palette (linear
# RGB, noise value 0 -> 1), and the block: half extents, rotation about z (degrees), and
# how Blender exports it (format, binary/ascii, triangulated, normals).
SCENES = {
    'stool': dict(fit=(0.46, 0.46, 0.44),
                  palette=((0.32, 0.13, 0.04), (0.72, 0.45, 0.18), (0.85, 0.75, 0.55)),
                  block=dict(half=(0.62, 0.60, 0.57), rotate=0.0, format='ply', ascii=False,
                             triangulate=True, normals=False)),
    'coil': dict(fit=(0.38, 0.38, 0.62),
                 palette=((0.55, 0.22, 0.08), (0.80, 0.55, 0.30), (0.12, 0.42, 0.32)),
                 block=dict(half=(0.55, 0.52, 0.80), rotate=0.0, format='obj', ascii=True,
                            triangulate=True, normals=False)),
    'sprig': dict(fit=(0.56, 0.24, 0.58),
                  palette=((0.08, 0.30, 0.06), (0.45, 0.55, 0.12), (0.70, 0.20, 0.12)),
                  block=dict(half=(0.72, 0.40, 0.72), rotate=0.0, format='ply', ascii=True,
                             triangulate=False, normals=False)),
    'knot': dict(fit=(0.44, 0.44, 0.40),
                 palette=((0.06, 0.12, 0.45), (0.55, 0.60, 0.70), (0.85, 0.72, 0.40)),
                 block=dict(half=(0.60, 0.60, 0.56), rotate=25.0, format='obj', ascii=True,
                            triangulate=False, normals=True)),
    'ant': dict(fit=(0.56, 0.40, 0.24),
                palette=((0.10, 0.04, 0.02), (0.40, 0.16, 0.05), (0.65, 0.42, 0.18)),
                block=dict(half=(0.74, 0.56, 0.40), rotate=10.0, format='ply', ascii=False,
                           triangulate=True, normals=False)),
    'blob': dict(fit=(0.58, 0.52, 0.28),
                 palette=((0.55, 0.16, 0.30), (0.85, 0.62, 0.45), (0.30, 0.10, 0.40)),
                 block=dict(half=(0.76, 0.68, 0.40), rotate=0.0, format='ply', ascii=False,
                            triangulate=True, normals=False),
                 extra={'box_vnormals': dict(format='ply', ascii=False, triangulate=True,
                                             normals=True)}),
}


# --- geometry (numpy) -------------------------------------------------------------------

def _perpendicular(t: np.ndarray) -> np.ndarray:
    a = np.array([1.0, 0.0, 0.0]) if abs(t[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    n = np.cross(t, a)
    return n / np.linalg.norm(n)


def tube(points, radius, sides: int = 16, closed: bool = False):
    """A tube of ``sides`` around a polyline (capped unless ``closed``, a loop): (V, F).

    Frames are parallel-transported along the line, so the tube does not twist; a loop's
    remaining twist is spread over its length so that its ends meet."""
    p = np.asarray(points, np.float64)
    n = len(p)
    r = np.broadcast_to(np.asarray(radius, np.float64), (n,))
    nxt = np.roll(p, -1, 0) if closed else np.vstack([p[1:], 2 * p[-1] - p[-2]])
    prv = np.roll(p, 1, 0) if closed else np.vstack([2 * p[0] - p[1], p[:-1]])
    t = nxt - prv
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    normals = [_perpendicular(t[0])]
    for i in range(1, n + closed):
        ti = t[i % n]
        m = normals[-1] - np.dot(normals[-1], ti) * ti
        normals.append(m / np.linalg.norm(m))
    if closed:
        # Angle between the transported frame and the start: undone gradually.
        b0 = np.cross(t[0], normals[0])
        twist = math.atan2(np.dot(normals[-1], b0), np.dot(normals[-1], normals[0]))
        normals = normals[:n]
    else:
        twist = 0.0
    angles = 2 * np.pi * np.arange(sides) / sides
    verts = []
    for i in range(n):
        nn = normals[i]
        bb = np.cross(t[i], nn)
        phi = angles - twist * i / n
        ring = p[i] + r[i] * (np.cos(phi)[:, None] * nn + np.sin(phi)[:, None] * bb)
        verts.append(ring)
    V = np.concatenate(verts)
    F = []
    for i in range(n if closed else n - 1):
        a, b = i * sides, ((i + 1) % n) * sides
        for k in range(sides):
            k1 = (k + 1) % sides
            F += [(a + k, a + k1, b + k1), (a + k, b + k1, b + k)]
    if not closed:
        c0, c1 = len(V), len(V) + 1
        V = np.vstack([V, p[0], p[-1]])
        last = (n - 1) * sides
        for k in range(sides):
            k1 = (k + 1) % sides
            F += [(c0, k1, k), (c1, last + k, last + k1)]
    return V, np.asarray(F, np.int64)


def sphere(centre, radius: float, rings: int = 12):
    """A UV sphere as a capped tube along its axis (radius 0 at the poles)."""
    z = -np.cos(np.linspace(0.0, np.pi, rings + 1))[1:-1]
    pts = np.asarray(centre) + radius * np.stack([0 * z, 0 * z, z], 1)
    return tube(pts, radius * np.sqrt(1 - z ** 2), sides=2 * rings)


def segment(a, b, n: int = 8):
    return np.linspace(np.asarray(a, float), np.asarray(b, float), n)


def stool():
    """A round seat on three splayed thin legs, a ring stretcher between them, ball feet."""
    z = np.linspace(0.18, 0.28, 6)
    parts = [tube(np.stack([0 * z, 0 * z, z], 1), [0.29, 0.315, 0.32, 0.32, 0.315, 0.30], sides=64)]
    top_r, foot_r, top_z, foot_z = 0.2, 0.4, 0.2, -0.5
    ring_z = -0.2
    for k in range(3):
        th = np.pi / 2 + 2 * np.pi * k / 3
        c, s = math.cos(th), math.sin(th)
        leg = segment((top_r * c, top_r * s, top_z), (foot_r * c, foot_r * s, foot_z), 10)
        parts += [tube(leg, np.linspace(0.03, 0.022, 10), sides=12),
                  sphere((foot_r * c, foot_r * s, foot_z), 0.034)]
    ring_r = top_r + (foot_r - top_r) * (top_z - ring_z) / (top_z - foot_z)
    phi = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    parts.append(tube(np.stack([ring_r * np.cos(phi), ring_r * np.sin(phi), ring_z + 0 * phi], 1),
                      0.017, sides=10, closed=True))
    return parts


def coil():
    """A wire spring of five turns whose ends bend to the axis and end in knobs."""
    turns, radius, height, wire = 5.0, 0.30, 0.9, 0.03
    t = np.linspace(0.0, 1.0, 400)
    phi = 2 * np.pi * turns * t
    helix = np.stack([radius * np.cos(phi), radius * np.sin(phi), height * (t - 0.5)], 1)
    ends = [helix[0], helix[-1]]
    parts = [tube(helix, wire, sides=12)]
    for e in ends:
        axis = np.array([0.0, 0.0, e[2]])
        parts += [tube(segment(e, axis, 8), wire, sides=12), sphere(axis, 0.065)]
    return parts


def sprig(seed: int = 7):
    """A twig in a plane (xz, with some depth): tapered branches three levels deep,
    a bud at every tip."""
    rng = np.random.default_rng(seed)
    parts = []

    def rot_y(v, a):
        c, s = math.cos(a), math.sin(a)
        return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])

    def branch(p, d, length, r0, depth):
        pts, q, dd = [p], p.copy(), d.copy()
        for _ in range(9):
            dd = rot_y(dd, rng.normal(0, 0.08))
            dd[1] += rng.normal(0, 0.05)
            dd /= np.linalg.norm(dd)
            q = q + dd * length / 9
            pts.append(q)
        r1 = max(0.65 * r0, 0.014)
        parts.append(tube(pts, np.linspace(r0, r1, len(pts)), sides=12))
        if depth == 0:
            parts.append(sphere(pts[-1], 0.042))
            return
        forks = [(0.5, 1), (0.75, -1), (1.0, 1)] if depth > 1 else [(0.6, -1), (1.0, 1)]
        for frac, side in forks:
            i = int(round(frac * 9))
            a = side * rng.uniform(0.45, 0.75)
            nd = rot_y(dd if frac == 1.0 else (pts[i] - pts[i - 1]) / np.linalg.norm(pts[i] - pts[i - 1]), a)
            nd[1] += rng.normal(0, 0.25)
            nd /= np.linalg.norm(nd)
            ri = r0 + (r1 - r0) * frac
            branch(pts[i], nd, length * rng.uniform(0.6, 0.75), max(0.8 * ri, 0.014), depth - 1)

    branch(np.array([0.0, 0.0, -0.7]), np.array([0.0, 0.0, 1.0]), 0.6, 0.038, 3)
    return parts


def knot():
    """A trefoil (2,3 torus knot) tube."""
    phi = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    rr = 0.30 + 0.13 * np.cos(3 * phi)
    pts = np.stack([rr * np.cos(2 * phi), rr * np.sin(2 * phi), 0.13 * np.sin(3 * phi)], 1)
    return [tube(pts, 0.085, sides=24, closed=True)]


#: Metaballs of the blob: centre and radius.
_BLOB = (((0.0, 0.0, 0.0), 0.50), ((0.36, 0.10, 0.05), 0.40), ((-0.34, 0.16, -0.03), 0.36),
         ((0.05, -0.34, 0.04), 0.34), ((-0.14, -0.14, 0.20), 0.28), ((0.22, 0.30, -0.10), 0.26))


def blob():
    """Six metaballs, flattened along z: converted to a mesh by Blender."""
    mb = bpy.data.metaballs.new('blob')
    mb.resolution = mb.render_resolution = 0.02
    for co, radius in _BLOB:
        e = mb.elements.new()
        e.co, e.radius = co, radius
    ob = bpy.data.objects.new('blob_mb', mb)
    bpy.context.scene.collection.objects.link(ob)
    me = bpy.data.meshes.new_from_object(ob.evaluated_get(bpy.context.evaluated_depsgraph_get()))
    V = np.empty(3 * len(me.vertices))
    me.vertices.foreach_get('co', V)
    V = V.reshape(-1, 3) * (1.0, 1.0, 0.7)
    tris = [tuple(p.vertices) for p in me.polygons]
    F = [(q[0], q[i], q[i + 1]) for q in tris for i in range(1, len(q) - 1)]
    bpy.data.objects.remove(ob)
    return [(V, np.asarray(F, np.int64))]


def ellipsoid(centre, semi, rings: int = 16):
    """An ellipsoid of semi-axes ``semi`` (x, y, z): a scaled :func:`sphere`."""
    V, F = sphere((0.0, 0.0, 0.0), 1.0, rings)
    return np.asarray(centre) + V * np.asarray(semi), F


def limb(points, radii, per_segment: int = 6, sides: int = 12, limbs: list | None = None, name: str = ''):
    """A jointed limb: a tube along the polyline ``points`` (joints), its radius going linearly
    from joint to joint, with a ball at each inner joint. ``limbs``: where its axis is recorded
    as ``(name, joints, radii)``, from the body out (the truth's legs and antennae)."""
    if limbs is not None:
        limbs.append((name, np.asarray(points, float), np.asarray(radii, float)))
    pts, rad = [np.asarray(points[0], float)], [radii[0]]
    for k in range(len(points) - 1):
        pts += list(segment(points[k], points[k + 1], per_segment + 1)[1:])
        rad += list(np.linspace(radii[k], radii[k + 1], per_segment + 1)[1:])
    parts = [tube(np.array(pts), np.array(rad), sides=sides)]
    parts += [sphere(points[k], 1.1 * radii[k], rings=6) for k in range(1, len(points) - 1)]
    return parts


#: Radii (unit) of the ant's leg joints and of its antenna's: the ant of the first captures,
#: and a thin-legged one (legs 0.29-0.12 mm thick, antennae 0.10-0.08 mm, at 12 mm long).
ANT_RADII = {'ant': dict(leg=(0.024, 0.022, 0.019, 0.017), antenna=(0.016, 0.015, 0.016), club=0.022),
             'ant_thin': dict(leg=(0.013, 0.011, 0.008, 0.0055), antenna=(0.0045, 0.004, 0.0036), club=0.006)}


def ant(limbs: list | None = None, radii: dict = ANT_RADII['ant']):
    """Gaster, petiole, thorax and head; six legs that go out and up to the knee, then out and
    down; elbowed antennae. ``radii``: the legs' and antennae's (:data:`ANT_RADII`; the first
    ant's legs 0.048-0.034 of the unit thick, fitted to a length of 12 mm: 0.53 mm at the femur,
    0.37 mm at the tarsus, antennae 0.03: 0.33 mm). ``limbs``: see :func:`limb`."""
    parts = [ellipsoid((-0.30, 0.0, 0.03), (0.20, 0.135, 0.125)),
             ellipsoid((-0.075, 0.0, 0.05), (0.035, 0.03, 0.05)),
             tube(segment((-0.14, 0.0, 0.04), (0.0, 0.0, 0.045), 6), 0.022, sides=12),
             ellipsoid((0.10, 0.0, 0.05), (0.135, 0.058, 0.062)),
             tube(segment((0.2, 0.0, 0.05), (0.28, 0.0, 0.055), 5), 0.03, sides=12),
             ellipsoid((0.335, 0.0, 0.06), (0.085, 0.075, 0.065))]
    for side in (-1.0, 1.0):
        for pair, (x, reach) in enumerate(((0.03, -0.16), (0.10, -0.02), (0.17, 0.13))):
            a = np.array([x, side * 0.045, 0.02])
            knee = a + [0.5 * reach, side * 0.19, 0.09]
            ankle = knee + [0.8 * reach, side * 0.11, -0.23]
            foot = ankle + [0.4 * reach, side * 0.07, -0.05]
            parts += limb([a, knee, ankle, foot], list(radii['leg']), limbs=limbs,
                          name=f"{'hind middle fore'.split()[pair]} leg {'left' if side < 0 else 'right'}")
        # Mandible and antenna (scape up and out, funiculus forward, a club at its tip).
        parts.append(tube(segment((0.39, side * 0.03, 0.04), (0.45, side * 0.012, 0.035), 5),
                             np.linspace(0.018, 0.008, 5), sides=10))
        base = np.array([0.38, side * 0.035, 0.09])
        elbow = base + [0.03, side * 0.07, 0.11]
        tip = elbow + [0.16, side * 0.07, -0.02]
        parts += limb([base, elbow, tip], list(radii['antenna']), limbs=limbs,
                      name=f"antenna {'left' if side < 0 else 'right'}")
        parts.append(sphere(tip, radii['club'], rings=6))
    return parts


OBJECTS = {'stool': stool, 'coil': coil, 'sprig': sprig, 'knot': knot, 'blob': blob, 'ant': ant}


def fit(parts, half):
    """Scale and move the parts uniformly so that their bounding box is centred at the
    origin and fits in ``half`` (half extents)."""
    allv = np.concatenate([v for v, _ in parts])
    lo, hi = allv.min(0), allv.max(0)
    s = float(np.min(np.asarray(half) / (0.5 * (hi - lo))))
    c = 0.5 * (lo + hi)
    return [((v - c) * s, f) for v, f in parts]


def camera_poses(n: int, distance: float) -> np.ndarray:
    """(n,4,4) camera-to-world, OpenGL axes, at Fibonacci points of a sphere of
    ``distance`` around the origin, looking at it, world z up in the image."""
    i = np.arange(n)
    z = 1 - (2 * i + 1) / n
    phi = i * np.pi * (3 - math.sqrt(5))
    rxy = np.sqrt(1 - z ** 2)
    eyes = distance * np.stack([rxy * np.cos(phi), rxy * np.sin(phi), z], 1)
    poses = np.zeros((n, 4, 4))
    for k, eye in enumerate(eyes):
        back = eye / np.linalg.norm(eye)                   # camera +z points away from the target
        right = np.cross([0.0, 0.0, 1.0], back)
        right /= np.linalg.norm(right)
        up = np.cross(back, right)
        poses[k, :3, 0], poses[k, :3, 1], poses[k, :3, 2], poses[k, :3, 3] = right, up, back, eye
        poses[k, 3, 3] = 1
    return poses


def block_masks(tris: np.ndarray, poses: np.ndarray, fov: float, res: int) -> np.ndarray:
    """(n,res,res) bool: pixel-centre rays of each camera that hit one of the triangles
    (Möller-Trumbore), the loader's definition of a container mask."""
    f = 0.5 * res / math.tan(0.5 * fov)
    xs = (np.arange(res) + 0.5 - 0.5 * res) / f
    dx, dy = np.meshgrid(xs, -xs)                          # image rows run down, camera y up
    d_cam = np.stack([dx, dy, -np.ones_like(dx)], -1).reshape(-1, 3)
    a, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    out = []
    for pose in poses:
        d = d_cam @ pose[:3, :3].T
        o = pose[:3, 3]
        pv = np.cross(d[:, None, :], e2[None])             # (P,T,3)
        det = np.einsum('ptk,tk->pt', pv, e1)
        inv = 1.0 / np.where(np.abs(det) < 1e-12, np.nan, det)
        tv = o - a                                         # (T,3)
        u = np.einsum('ptk,tk->pt', pv, tv) * inv
        qv = np.cross(tv, e1)                              # (T,3)
        v = np.einsum('pk,tk->pt', d, qv) * inv
        t = np.einsum('tk,tk->t', e2, qv)[None] * inv
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        out.append(hit.any(1).reshape(res, res))
    return np.stack(out)


# --- files --------------------------------------------------------------------------------

def _atomic_bytes(path: str, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix='.tmp_')
    with os.fdopen(fd, 'wb') as f:
        f.write(data)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


def write_png(path: str, pixels: np.ndarray) -> None:
    """An 8-bit RGB or RGBA PNG from a (H,W,3|4) uint8 array."""
    h, w, c = pixels.shape
    raw = b''.join(b'\x00' + pixels[y].tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack('>I', len(data)) + kind + data + struct.pack('>I', zlib.crc32(kind + data))
    header = struct.pack('>IIBBBBB', w, h, 8, {3: 2, 4: 6}[c], 0, 0, 0)
    _atomic_bytes(path, b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', header)
                  + chunk(b'IDAT', zlib.compress(raw, 9)) + chunk(b'IEND', b''))


def write_ply(path: str, V: np.ndarray, F: np.ndarray) -> None:
    """A binary little-endian PLY of a triangle mesh."""
    head = (f'ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\nproperty float x\n'
            f'property float y\nproperty float z\nelement face {len(F)}\n'
            'property list uchar int vertex_indices\nend_header\n').encode()
    faces = np.zeros(len(F), dtype=[('n', 'u1'), ('i', '<i4', 3)])
    faces['n'], faces['i'] = 3, F
    _atomic_bytes(path, head + V.astype('<f4').tobytes() + faces.tobytes())


def write_json(path: str, data: dict) -> None:
    _atomic_bytes(path, (json.dumps(data, indent=2) + '\n').encode())


def read_float_pixels(path: str) -> np.ndarray:
    """An image file as Blender's loader holds it: (H,W,4) float32, top row first."""
    img = bpy.data.images.load(path)
    try:
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
    finally:
        bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1]


def read_pixels(path: str) -> np.ndarray:
    """An 8-bit image file as (H,W,4) uint8, top row first (Blender's loader: the stored
    bytes, no colour conversion)."""
    return np.round(read_float_pixels(path) * 255).astype(np.uint8)


def write_jpeg(path: str, rgb: np.ndarray, quality: int) -> None:
    """An 8-bit JPEG through Blender's image writer."""
    h, w, _ = rgb.shape
    img = bpy.data.images.new('jpeg', w, h, alpha=False)
    try:
        rgba = np.concatenate([rgb, np.full((h, w, 1), 255, np.uint8)], -1)[::-1]
        img.pixels.foreach_set((rgba.astype(np.float32) / 255).ravel())
        img.file_format = 'JPEG'
        tmp = path + '.tmp.jpg'
        img.filepath_raw = tmp
        img.save(filepath=tmp, quality=quality)
        os.replace(tmp, path)
    finally:
        bpy.data.images.remove(img)


@contextlib.contextmanager
def quiet():
    """Silence Blender's per-tile progress lines on stdout (file descriptor 1)."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, 'wb') as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


# --- Blender scene ------------------------------------------------------------------------

def reset_blender(spp: int) -> bpy.types.Scene:
    with quiet():
        bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = 'CYCLES'
    cy = sc.cycles
    cy.device = 'CPU'
    cy.samples = spp
    cy.use_adaptive_sampling = True
    cy.adaptive_threshold = 0.005
    cy.use_denoising = True
    cy.denoiser = 'OPENIMAGEDENOISE'
    cy.denoising_input_passes = 'RGB_ALBEDO_NORMAL'
    cy.denoising_prefilter = 'ACCURATE'
    # Glass needs deep specular chains; the object behind it is lit only through it, so
    # refractive caustics stay on and nothing is blurred or clamped.
    cy.max_bounces, cy.diffuse_bounces, cy.glossy_bounces = 32, 4, 32
    cy.transmission_bounces, cy.transparent_max_bounces, cy.volume_bounces = 32, 8, 0
    cy.caustics_reflective = cy.caustics_refractive = True
    cy.blur_glossy = 0.0
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    sc.render.resolution_percentage = 100
    sc.render.film_transparent = False
    sc.render.dither_intensity = 0.0
    sc.display_settings.display_device = 'sRGB'
    sc.view_settings.view_transform = 'Standard'
    sc.view_settings.look = 'None'
    sc.view_settings.exposure, sc.view_settings.gamma = 0.0, 1.0
    settings = sc.render.image_settings
    settings.file_format, settings.color_mode, settings.color_depth = 'PNG', 'RGB', '8'
    world = bpy.data.worlds.new('world')
    sc.world = world
    bg = world.node_tree.nodes['Background']
    bg.inputs['Color'].default_value = (WORLD, WORLD, WORLD, 1.0)
    bg.inputs['Strength'].default_value = 1.0
    return sc


def diffuse_material(palette) -> bpy.types.Material:
    """Lambertian, albedo = noise in object coordinates through a three-stop ramp."""
    mat = bpy.data.materials.new('albedo')
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    coords = nodes.new('ShaderNodeTexCoord')
    noise = nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 3.5
    noise.inputs['Detail'].default_value = 3.0
    ramp = nodes.new('ShaderNodeValToRGB')
    stops = ramp.color_ramp.elements
    stops[0].position, stops[1].position = 0.35, 0.5
    stops.new(0.65)
    for stop, colour in zip(stops, palette):
        stop.color = (*colour, 1.0)
    bsdf = nodes.new('ShaderNodeBsdfDiffuse')
    bsdf.inputs['Roughness'].default_value = 0.0
    out = nodes.new('ShaderNodeOutputMaterial')
    links.new(coords.outputs['Object'], noise.inputs['Vector'])
    links.new(noise.outputs['Fac'], ramp.inputs['Fac'])
    links.new(ramp.outputs['Color'], bsdf.inputs['Color'])
    links.new(bsdf.outputs['BSDF'], out.inputs['Surface'])
    return mat


def glass_material(ior: float = IOR, absorption=None, name: str = 'glass') -> bpy.types.Material:
    """Cycles' smooth Glass BSDF of relative IOR ``ior`` (inside over outside, as its normals
    say), and where ``absorption`` (RGB per unit) is given a Volume Absorption inside: Cycles
    absorbs density x (1 - colour) per unit, so the largest channel is the density."""
    mat = bpy.data.materials.new(name)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    glass = nodes.new('ShaderNodeBsdfGlass')
    glass.distribution = 'GGX'
    glass.inputs['Roughness'].default_value = 0.0
    glass.inputs['IOR'].default_value = ior
    glass.inputs['Color'].default_value = (1.0, 1.0, 1.0, 1.0)
    out = nodes.new('ShaderNodeOutputMaterial')
    links.new(glass.outputs['BSDF'], out.inputs['Surface'])
    if absorption is not None:
        density = max(absorption)
        volume = nodes.new('ShaderNodeVolumeAbsorption')
        volume.inputs['Density'].default_value = density
        volume.inputs['Color'].default_value = (*(1.0 - a / density for a in absorption), 1.0)
        links.new(volume.outputs['Volume'], out.inputs['Volume'])
    return mat


def object_mesh(name: str, parts, palette, voxel: float = VOXEL) -> tuple[bpy.types.Object, np.ndarray, np.ndarray]:
    """The parts as one Blender object, voxel-remeshed (``voxel``: the voxel's side, in the
    parts' units) into a single watertight surface and triangulated (so that the ground truth
    is the rendered geometry). Returns the object, its vertices and triangles."""
    V = np.concatenate([v for v, _ in parts])
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    F = np.concatenate([f + o for (_, f), o in zip(parts, offsets)])
    raw = bpy.data.meshes.new(name + '_parts')
    raw.from_pydata(V.tolist(), [], F.tolist())
    ob = bpy.data.objects.new(name, raw)
    bpy.context.scene.collection.objects.link(ob)
    remesh = ob.modifiers.new('remesh', 'REMESH')
    remesh.mode, remesh.voxel_size, remesh.adaptivity = 'VOXEL', voxel, 0.0
    me = bpy.data.meshes.new_from_object(ob.evaluated_get(bpy.context.evaluated_depsgraph_get()))
    ob.modifiers.clear()
    ob.data = me
    bpy.data.meshes.remove(raw)
    bm = bmesh.new()
    bm.from_mesh(me)
    bmesh.ops.triangulate(bm, faces=bm.faces)
    bm.to_mesh(me)
    bm.free()
    me.shade_smooth()
    me.materials.append(diffuse_material(palette))
    Vr = np.empty(3 * len(me.vertices))
    me.vertices.foreach_get('co', Vr)
    Fr = np.empty(3 * len(me.polygons), np.int64)
    me.polygons.foreach_get('vertices', Fr)
    return ob, Vr.reshape(-1, 3), Fr.reshape(-1, 3)


def make_block(half, rotate: float, name: str = 'block', ior: float = IOR,
               absorption=None) -> tuple[bpy.types.Object, np.ndarray]:
    """Blender's cube primitive scaled to ``half`` extents and turned about z by ``rotate``
    degrees, the transform applied to its 8 vertices; returns it and its world triangles."""
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    ob = bpy.context.active_object
    ob.name = name
    ob.scale = half
    ob.rotation_euler = (0.0, 0.0, math.radians(rotate))
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    ob.data.materials.append(glass_material(ior, absorption, name))
    return ob, _triangles(ob)


def make_cylinder(radius: float, half_height: float, name: str, ior: float,
                  absorption=None) -> tuple[bpy.types.Object, np.ndarray]:
    """Blender's cylinder primitive (64 sides, axis z, closed by two n-gons), its side shaded
    smooth and its rims sharp, as a jar is; returns it and its world triangles."""
    bpy.ops.mesh.primitive_cylinder_add(vertices=64, radius=radius, depth=2.0 * half_height)
    ob = bpy.context.active_object
    ob.name = name
    me = ob.data
    for p in me.polygons:
        p.use_smooth = len(p.vertices) == 4
    for e in me.edges:
        ends = [me.vertices[i].co.z for i in e.vertices]
        e.use_edge_sharp = abs(ends[0] - ends[1]) < 1e-9        # the rims
    me.materials.append(glass_material(ior, absorption, name))
    return ob, _triangles(ob)


def _triangles(ob) -> np.ndarray:
    me = ob.data
    V = np.array([v.co[:] for v in me.vertices])
    return np.array([[V[i] for i in (q[0], q[k], q[k + 1])] for q in (p.vertices for p in me.polygons)
                     for k in range(1, len(q) - 1)])


def export_block(ob, folder: str, format: str, ascii: bool, triangulate: bool, normals: bool) -> str:
    """The block (or another container surface) through Blender's own exporter, in Blender's
    world axes (z up): the cameras' frame. Returns the file name."""
    for other in bpy.context.scene.objects:
        other.select_set(other is ob)
    bpy.context.view_layer.objects.active = ob
    name = f'{ob.name}.{format}'
    path = os.path.join(folder, name)
    common = dict(filepath=path, export_selected_objects=True, forward_axis='Y', up_axis='Z',
                  export_normals=normals, export_uv=False, export_triangulated_mesh=triangulate)
    with quiet():
        if format == 'ply':
            bpy.ops.wm.ply_export(**common, export_colors='NONE', ascii_format=ascii)
        else:
            bpy.ops.wm.obj_export(**common, export_materials=False)
    return name


def render(sc, path: str, seed: int) -> np.ndarray:
    """One view through Cycles, as (H,W,3) uint8 display values, the padding cropped."""
    sc.cycles.seed = seed
    sc.render.filepath = path
    with quiet():
        bpy.ops.render.render(write_still=True)
    rgb = read_pixels(path)[PAD:-PAD, PAD:-PAD, :3]
    os.remove(path)
    return rgb


def _photograph(sc, cam, poses, vdir: str, alpha: np.ndarray, base: int, label: str) -> tuple[float, np.ndarray]:
    """Render every view into ``vdir/images`` (RGBA, ``alpha`` the container's masks) with seeds
    from ``base``; returns the seconds it took and the first view (for the noise)."""
    os.makedirs(os.path.join(vdir, 'images'), exist_ok=True)
    start = time.perf_counter()
    first = None
    for i in range(len(poses)):
        cam.matrix_world = Matrix(poses[i].tolist())
        rgb = render(sc, os.path.join(vdir, 'images', '.render.png'), base + i)
        write_png(os.path.join(vdir, 'images', NAME.format(i) + '.png'), np.concatenate([rgb, alpha[i]], -1))
        first = rgb if first is None else first
        print(f'\r{label}: {i + 1}/{len(poses)} views, {time.perf_counter() - start:.0f} s', end='', flush=True)
    print()
    return time.perf_counter() - start, first


def _noise(sc, cam, poses, vdir: str, base: int, first: np.ndarray, mask: np.ndarray) -> float:
    """Residual noise: the first view again with other random numbers (display units)."""
    cam.matrix_world = Matrix(poses[0].tolist())
    again = render(sc, os.path.join(vdir, 'images', '.render.png'), base + 50000).astype(float)
    return float(((again - first)[mask] / 255.0).std() / math.sqrt(2))


def make_containers(kind: str, block, block_spec: dict) -> tuple[list, dict]:
    """The container ``kind`` around the scene's object, as Blender objects outermost first,
    and the dataset keys that state it (files named by the exporter, filled in on export)."""
    half, rotate = np.asarray(block_spec['half']), block_spec['rotate']
    if kind == 'amber':
        amber, _ = make_block(half, rotate, 'amber', IOR, AMBER)
        return [amber], {'IOR': IOR, 'absorption': list(AMBER)}
    if kind == 'case':
        inner, _ = make_block(half - WALL, rotate, 'case_inner', 1.0 / IOR)
        return [block, inner], {'IOR': IOR, 'containers': [{'int_ior': IOR, 'ext_ior': 1.0},
                                                            {'int_ior': 1.0, 'ext_ior': IOR}]}
    radius = float(np.hypot(half[0], half[1]))
    glass, _ = make_cylinder(radius, half[2], 'jar_glass', IOR)
    liquid, _ = make_cylinder(radius - WALL, half[2] - WALL, 'jar_liquid', LIQUID / IOR, TINT)
    return [glass, liquid], {'IOR': IOR, 'containers': [
        {'int_ior': IOR, 'ext_ior': 1.0}, {'int_ior': LIQUID, 'ext_ior': IOR, 'absorption': list(TINT)}]}


def make_scene(name: str, out: str, views: int, res: int, spp: int, containers=()) -> dict:
    spec = SCENES[name]
    folder = os.path.join(out, name)
    os.makedirs(folder, exist_ok=True)
    sc = reset_blender(spp)
    parts = fit(OBJECTS[name](), spec['fit'])
    obj, V, F = object_mesh(name, parts, spec['palette'])
    write_ply(os.path.join(folder, 'gt.ply'), V, F)
    block_spec = spec['block']
    block, tris = make_block(block_spec['half'], block_spec['rotate'])
    corners = tris.reshape(-1, 3)
    centre = 0.5 * (corners.min(0) + corners.max(0))
    radius = float(np.linalg.norm(corners - centre, axis=1).max())

    # The camera renders PAD more pixels each side at the same focal length.
    fov = 2 * math.asin(1.03 / CAMERA_DISTANCE)
    focal = 0.5 * res / math.tan(0.5 * fov)
    sc.render.resolution_x = sc.render.resolution_y = res + 2 * PAD
    cam_data = bpy.data.cameras.new('camera')
    cam_data.sensor_fit = 'HORIZONTAL'
    cam_data.angle = 2 * math.atan((0.5 * res + PAD) / focal)
    cam_data.clip_start, cam_data.clip_end = 0.01, 100.0
    cam = bpy.data.objects.new('camera', cam_data)
    sc.collection.objects.link(cam)
    sc.camera = cam
    poses = camera_poses(views, CAMERA_DISTANCE * radius)
    poses[:, :3, 3] += centre
    masks = block_masks(tris, poses, fov, res)
    alpha = (masks * 255).astype(np.uint8)[..., None]

    record = {'scene': name, 'views': views, 'res': res, 'spp': spp,
              'adaptive_threshold': sc.cycles.adaptive_threshold, 'denoiser': sc.cycles.denoiser,
              'view_transform': sc.view_settings.view_transform, 'ior': IOR, 'world': WORLD,
              'blender': bpy.app.version_string, 'block': {**block_spec, 'centre': centre.tolist(),
                                                           'bounding_radius': radius},
              'gt': {'file': 'gt.ply', 'vertices': len(V), 'triangles': len(F)},
              'camera_distance': CAMERA_DISTANCE * radius, 'camera_angle_x': fov, 'variants': {}}
    frames = [{'file_path': f'images/{NAME.format(i)}.png', 'transform_matrix': p.tolist()}
              for i, p in enumerate(poses)]
    for variant in ('box', 'nobox'):
        block.hide_render = variant == 'nobox'
        vdir = os.path.join(folder, variant)
        base = 100000 * (variant == 'nobox')
        seconds, first = _photograph(sc, cam, poses, vdir, alpha, base, f'{name}/{variant}')
        noise = _noise(sc, cam, poses, vdir, base, first, masks[0])
        meta = {'camera_angle_x': fov}
        if variant == 'box':
            meta.update(IOR=IOR, mesh_outside=export_block(
                block, vdir, **{k: block_spec[k] for k in ('format', 'ascii', 'triangulate', 'normals')}))
        else:
            scale_mat = np.eye(4)
            scale_mat[:3, :3] *= radius
            scale_mat[:3, 3] = centre
            meta['scale_mat'] = scale_mat.tolist()
        meta['frames'] = frames
        write_json(os.path.join(vdir, 'transforms.json'), meta)
        record['variants'][variant] = {'seconds': seconds, 'noise_std_display': noise,
                                       'mesh_outside': meta.get('mesh_outside')}
    for variant, exporter in spec.get('extra', {}).items():
        # The same photographs, the block written another way.
        vdir = os.path.join(folder, variant)
        shutil.copytree(os.path.join(folder, 'box', 'images'), os.path.join(vdir, 'images'),
                        dirs_exist_ok=True)
        meta = json.load(open(os.path.join(folder, 'box', 'transforms.json')))
        meta['mesh_outside'] = export_block(block, vdir, **exporter)
        write_json(os.path.join(vdir, 'transforms.json'), meta)
        record['variants'][variant] = {'photographs': 'box', 'mesh_outside': meta['mesh_outside'],
                                       'exporter': exporter}
    for c, kind in enumerate(containers):
        # The same object and cameras in a container of a collection: its surfaces exported
        # as PLY with Blender's normals (a jar's side is smooth, its rims sharp).
        for ob in bpy.context.scene.objects:
            if ob.type == 'MESH' and ob is not obj:
                ob.hide_render = True
        shells, meta = make_containers(kind, block, block_spec)
        for ob in shells:
            ob.hide_render = False
        vdir = os.path.join(folder, kind)
        kind_masks = block_masks(_triangles(shells[0]), poses, fov, res)
        kind_alpha = (kind_masks * 255).astype(np.uint8)[..., None]
        base = 200000 * (c + 1)
        seconds, first = _photograph(sc, cam, poses, vdir, kind_alpha, base, f'{name}/{kind}')
        noise = _noise(sc, cam, poses, vdir, base, first, kind_masks[0])
        files = [export_block(ob, vdir, format='ply', ascii=False, triangulate=True, normals=kind == 'jar')
                 for ob in shells]
        meta = {'camera_angle_x': fov, 'mesh_outside': files[0], **meta, 'frames': frames}
        for entry, file in zip(meta.get('containers', []), files):
            entry['mesh'] = file
        write_json(os.path.join(vdir, 'transforms.json'), meta)
        record['variants'][kind] = {'seconds': seconds, 'noise_std_display': noise, 'files': files,
                                    **{k: v for k, v in meta.items() if k not in ('frames', 'camera_angle_x')}}
    write_json(os.path.join(folder, 'scene.json'), record)
    return record


# --- degraded copy --------------------------------------------------------------------------

def _srgb_to_linear(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _linear_to_srgb(c):
    c = np.clip(c, 0.0, 1.0)
    return np.where(c <= 0.0031308, 12.92 * c, 1.055 * c ** (1 / 2.4) - 0.055)


def degrade(src: str, dst: str, *, seed: int, noise: float, read_noise: float, exposure: float,
            quality: int) -> None:
    """A camera-like copy of the dataset ``src`` in ``dst`` (see the module docstring)."""
    src, dst = os.path.abspath(src), os.path.abspath(dst)
    meta_path = os.path.join(src, 'transforms.json')
    if not os.path.isfile(meta_path):
        sys.exit(f'error: {src}: no transforms.json; expected a dataset folder')
    if dst == src or dst.startswith(src + os.sep):
        sys.exit(f'error: {dst}: the copy may not go into the dataset it degrades ({src})')
    if os.path.exists(dst) and os.listdir(dst):
        sys.exit(f'error: {dst}: folder exists and is not empty; choose a new one')
    meta = json.load(open(meta_path))
    os.makedirs(os.path.join(dst, 'images'), exist_ok=True)
    rng = np.random.default_rng(seed)
    factors = rng.uniform(1 - exposure, 1 + exposure, len(meta['frames']))
    for frame, k in zip(meta['frames'], factors):
        rgb = read_pixels(os.path.join(src, frame['file_path']))[..., :3] / 255.0
        lin = _srgb_to_linear(rgb) * k
        # Shot noise grows with the signal, read noise does not: sigma^2 = a * x + b^2.
        lin = lin + rng.normal(size=lin.shape) * np.sqrt(noise ** 2 * lin + read_noise ** 2)
        out = np.round(_linear_to_srgb(lin) * 255).astype(np.uint8)
        stem = os.path.splitext(os.path.basename(frame['file_path']))[0]
        frame['file_path'] = f'images/{stem}.jpg'
        write_jpeg(os.path.join(dst, frame['file_path']), out, quality)
    if meta.get('mesh_outside'):
        shutil.copyfile(os.path.join(src, meta['mesh_outside']), os.path.join(dst, meta['mesh_outside']))
    write_json(os.path.join(dst, 'degrade.json'),
               {'source': src, 'seed': seed, 'shot_noise': noise, 'read_noise': read_noise,
                'exposure': exposure, 'jpeg_quality': quality,
                'exposure_factors': factors.round(4).tolist()})
    write_json(os.path.join(dst, 'transforms.json'), meta)


def main(argv=None) -> None:
    global AMBER
    parser = argparse.ArgumentParser(
        prog='bench/blender_set.py',
        description='Render the second-renderer test set with Blender Cycles (run with the bpy '
                    "venv's Python), or write a degraded copy of one of its datasets.")
    parser.add_argument('--out', default='/work/data/blender_set', help='folder of the set (default: %(default)s)')
    parser.add_argument('--scenes', nargs='+', choices=list(SCENES), default=list(SCENES))
    parser.add_argument('--views', type=int, default=48)
    parser.add_argument('--res', type=int, default=128)
    parser.add_argument('--spp', type=int, default=256, help='Cycles samples per pixel (adaptive, at most)')
    parser.add_argument('--overwrite', action='store_true', help='render scenes that are already there again')
    parser.add_argument('--containers', nargs='*', choices=CONTAINERS, default=[],
                        help='also photograph each object in these containers of collections: a glass case '
                             '(walls around air), a jar of tinted ethanol, an amber block')
    parser.add_argument('--amber', type=float, nargs=3, metavar=('R', 'G', 'B'), default=AMBER,
                        help="the amber block's absorption per unit (default: %(default)s)")
    parser.add_argument('--degrade', nargs=2, metavar=('SRC', 'DST'),
                        help='write a camera-like copy of the dataset SRC to the new folder DST')
    parser.add_argument('--seed', type=int, default=0, help='--degrade: random numbers')
    parser.add_argument('--noise', type=float, default=0.02,
                        help='--degrade: shot noise, sigma = noise * sqrt(linear value) (default: %(default)s)')
    parser.add_argument('--read-noise', type=float, default=0.003, help='--degrade: read noise sigma (linear)')
    parser.add_argument('--exposure', type=float, default=0.1, help='--degrade: exposure drift, +- fraction')
    parser.add_argument('--jpeg-quality', type=int, default=85)
    args = parser.parse_args(argv)
    AMBER = tuple(args.amber)
    if args.degrade:
        degrade(*args.degrade, seed=args.seed, noise=args.noise, read_noise=args.read_noise,
                exposure=args.exposure, quality=args.jpeg_quality)
        print(f'wrote {args.degrade[1]}')
        return
    os.makedirs(args.out, exist_ok=True)
    for name in args.scenes:
        done = os.path.join(args.out, name, 'scene.json')
        if os.path.isfile(done) and not args.overwrite:
            print(f'{name}: already there ({done}); --overwrite renders it again')
            continue
        record = make_scene(name, args.out, args.views, args.res, args.spp, args.containers)
        print(f"{name}: " + ', '.join(f"{v} {r['seconds']:.0f} s (noise {r['noise_std_display']:.4f})"
                                     for v, r in record['variants'].items() if 'seconds' in r))


if __name__ == '__main__':
    main()
