"""Objects for the synthetic datasets, made procedurally (nothing is downloaded).

Every object is a closed :class:`trimesh.Trimesh` with per-vertex colours. The
colours are display values (8-bit, gamma 2.2, like a photograph); the renderer
turns them into linear albedo. The catalogue (:data:`OBJECTS`):

- ``insect``: a body of three blended ellipsoids with six thin, jointed legs
  and two antennae, banded: the paper's hard case (thin structures);
- ``statuette``: a smooth, texture-less figure of blended spheres and limbs on
  a round base, one uniform colour;
- ``vase``: a hollow surface of revolution (concave inside), patterned;
- ``sphere``: a patterned sphere, for tests.

Shapes built from blended primitives are signed distance functions written in
Dr.Jit and meshed with :func:`reneus_mi.geometry.shapes.mesh_sdf` (Marching Cubes), so
that overlapping parts become one clean, watertight surface.

:func:`normalize` centres an object, fits the glass box around it with a margin
and scales both into the unit sphere, as in the paper's Dataset section.
"""
from __future__ import annotations

import functools
import os

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.geometry.mesh import load_mesh
from reneus_mi.geometry.shapes import container_mesh, mesh_sdf, round_cylinder
from reneus_mi.utils.errors import ReneusError


# ----------------------------------------------------------------- SDF parts
def _ellipsoid(p, center, radii):
    """Approximate distance to an ellipsoid: exact zero set, scaled by the
    smallest radius so that it stays close to a distance near the surface."""
    q = (p - mi.Vector3f(*center)) / mi.Vector3f(*radii)
    return (dr.norm(q) - 1.0) * min(radii)


def _capsule(p, a, b, radius):
    a, b = mi.Vector3f(*a), mi.Vector3f(*b)
    pa, ba = p - a, b - a
    h = dr.clip(dr.dot(pa, ba) / dr.dot(ba, ba), 0.0, 1.0)
    return dr.norm(pa - ba * h) - radius


def _smooth_union(a, b, k):
    """Polynomial smooth minimum: blends the parts over a width ``k`` instead
    of leaving a crease where they meet."""
    h = dr.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return dr.lerp(b, a, h) - k * h * (1.0 - h)


# ------------------------------------------------------------------ textures
def _two_tone(t: np.ndarray, color0, color1) -> np.ndarray:
    """RGBA uint8 colours blending ``color0`` (t = 0) and ``color1`` (t = 1)."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)[:, None]
    rgb = (1.0 - t) * np.asarray(color0, dtype=np.float64) + t * np.asarray(color1, dtype=np.float64)
    alpha = np.full((len(rgb), 1), 255.0)
    return np.round(np.concatenate([rgb, alpha], axis=1)).astype(np.uint8)


def procedural_colors(vertices: np.ndarray, period: float = 0.25,
                      color0=(60, 90, 160), color1=(235, 215, 150)) -> np.ndarray:
    """A smooth 3D checker pattern (RGBA uint8 per vertex), for meshes without colours.

    ``period`` is the size of one light/dark cycle in the mesh's units.
    """
    w = 2.0 * np.pi / period
    v = np.asarray(vertices, dtype=np.float64)
    t = 0.5 + 0.5 * np.sin(w * v[:, 0]) * np.sin(w * v[:, 1]) * np.sin(w * v[:, 2])
    return _two_tone(t, color0, color1)


# ------------------------------------------------------------------- objects
# Legs of the insect: hip on the thorax, knee up and out, foot down below the
# body, so that each leg is a thin bent tube that stands free of the body.
_LEGS = (  # hip x, knee (dx, y, z), foot (dx, y, z)
    (0.22, (0.12, 0.36, 0.20), (0.34, 0.52, -0.26)),
    (0.12, (0.00, 0.40, 0.22), (0.02, 0.60, -0.26)),
    (0.02, (-0.14, 0.36, 0.20), (-0.38, 0.54, -0.26)),
)
_FEMUR_RADIUS, _TIBIA_RADIUS, _ANTENNA_RADIUS = 0.024, 0.018, 0.013


def _insect_distance(p):
    body = _ellipsoid(p, (-0.36, 0.0, 0.06), (0.38, 0.18, 0.15))               # abdomen
    body = _smooth_union(body, _ellipsoid(p, (0.12, 0.0, 0.07), (0.17, 0.12, 0.11)), 0.05)  # thorax
    body = _smooth_union(body, _ellipsoid(p, (0.37, 0.0, 0.09), (0.10, 0.09, 0.085)), 0.03)  # head
    for hip_x, (kx, ky, kz), (fx, fy, fz) in _LEGS:
        for side in (-1.0, 1.0):
            hip = (hip_x, 0.06 * side, 0.02)
            knee = (hip_x + kx, ky * side, kz)
            foot = (hip_x + fx, fy * side, fz)
            leg = dr.minimum(_capsule(p, hip, knee, _FEMUR_RADIUS),
                             _capsule(p, knee, foot, _TIBIA_RADIUS))
            body = _smooth_union(body, leg, 0.02)
    for side in (-1.0, 1.0):
        base = (0.43, 0.04 * side, 0.14)
        bend = (0.60, 0.14 * side, 0.32)
        tip = (0.80, 0.30 * side, 0.30)
        antenna = dr.minimum(_capsule(p, base, bend, _ANTENNA_RADIUS),
                             _capsule(p, bend, tip, _ANTENNA_RADIUS))
        body = _smooth_union(body, antenna, 0.015)
    return body


def _insect_body_distance(p):
    body = _ellipsoid(p, (-0.36, 0.0, 0.06), (0.38, 0.18, 0.15))
    body = dr.minimum(body, _ellipsoid(p, (0.12, 0.0, 0.07), (0.17, 0.12, 0.11)))
    return dr.minimum(body, _ellipsoid(p, (0.37, 0.0, 0.09), (0.10, 0.09, 0.085)))


def insect_limbs(points: np.ndarray, container: str = 'box', margin: float = 0.15) -> np.ndarray:
    """Which ``points`` of the normalised insect (as :func:`normalize` places it in its
    container) lie on its legs and antennae: farther than ``LIMB_GAP`` of its own size from the
    body's ellipsoids. What a reconstruction that keeps only the body misses."""
    obj = insect()
    lo, hi = obj.bounds
    scale = normalize(obj, margin=margin, container=container)[0].extents.max() / obj.extents.max()
    own = np.asarray(points) / scale + 0.5 * (lo + hi)
    body = _insect_body_distance(mi.Point3f(*own.T.astype(np.float32)))
    return np.asarray(body) > LIMB_GAP


#: Distance from the insect's body (in its own units, 1.66 long) beyond which a point is a limb's.
LIMB_GAP = 0.06


def insect() -> trimesh.Trimesh:
    """Body along +x (head forward), six legs reaching below it, two antennae."""
    mesh = mesh_sdf(_insect_distance, (-0.80, -0.66, -0.32), (0.86, 0.66, 0.38), pitch=0.006)
    # Bands across the body axis, like a wasp's, also on legs and antennae.
    t = 0.5 + 0.5 * np.sin(2.0 * np.pi * mesh.vertices[:, 0] / 0.16)
    mesh.visual.vertex_colors = _two_tone(t, (70, 40, 20), (230, 170, 40))
    return mesh


def _statuette_distance(p):
    d = round_cylinder(p, (0.0, 0.0, -0.56), 0.30, 0.06, 0.025)               # base
    for center, radius in (((0.0, 0.0, -0.32), 0.17),                         # hips
                           ((0.0, 0.0, -0.08), 0.19),                         # waist
                           ((0.0, 0.02, 0.12), 0.17),                         # chest
                           ((0.0, 0.04, 0.38), 0.11)):                        # head
        d = _smooth_union(d, dr.norm(p - mi.Vector3f(*center)) - radius, 0.08)
    # One arm raised, one lowered: a figure without a mirror symmetry, so that
    # a flipped camera shows in the images.
    d = _smooth_union(d, _capsule(p, (0.13, 0.0, 0.20), (0.30, 0.06, 0.46), 0.05), 0.05)
    d = _smooth_union(d, _capsule(p, (-0.14, 0.0, 0.18), (-0.24, 0.06, -0.10), 0.05), 0.05)
    return d


def statuette() -> trimesh.Trimesh:
    """A smooth figure on a round base, in one colour (no texture to match)."""
    mesh = mesh_sdf(_statuette_distance, (-0.36, -0.36, -0.66), (0.40, 0.36, 0.56), pitch=0.01)
    mesh.visual.vertex_colors = _two_tone(np.zeros(len(mesh.vertices)), (205, 195, 180), (0, 0, 0))
    return mesh


def vase() -> trimesh.Trimesh:
    """A hollow vase: outer wall, lip, inner wall and floor revolved about z."""
    wall = 0.035
    z_out = np.linspace(-0.5, 0.5, 80)
    # A round belly, a narrow neck, a flared lip.
    r_out = 0.22 + 0.12 * np.sin(np.pi * (z_out + 0.5) * 1.15) ** 2 \
        - 0.10 * np.exp(-((z_out - 0.28) / 0.1) ** 2) + 0.06 * np.clip(z_out - 0.38, 0.0, None) / 0.12
    z_in = z_out[::-1]
    keep = z_in > -0.5 + 2.0 * wall
    r_in = (r_out[::-1] - wall)[keep]
    # A closed, counter-clockwise (r, z) profile that starts and ends on the
    # axis: revolving it gives a closed mesh with outward normals.
    profile = np.concatenate([[[0.0, -0.5]], np.c_[r_out, z_out],
                              np.c_[r_in, z_in[keep]], [[0.0, z_in[keep][-1]]]])
    mesh = trimesh.creation.revolve(profile, sections=128)
    v = mesh.vertices
    angle = np.arctan2(v[:, 1], v[:, 0])
    t = 0.5 + 0.5 * np.sin(6.0 * angle) * np.sin(2.0 * np.pi * v[:, 2] / 0.25)
    mesh.visual.vertex_colors = _two_tone(t, (40, 70, 150), (240, 235, 220))
    return mesh


def sphere() -> trimesh.Trimesh:
    """A patterned sphere of radius 0.5."""
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    mesh.visual.vertex_colors = procedural_colors(mesh.vertices)
    return mesh


#: Objects by name: functions returning a new mesh.
OBJECTS = {'insect': insect, 'statuette': statuette, 'vase': vase, 'sphere': sphere}


@functools.lru_cache(maxsize=None)
def _cached(name: str) -> trimesh.Trimesh:
    return OBJECTS[name]()


def load_object(name_or_path: str | os.PathLike) -> trimesh.Trimesh:
    """Return a new coloured mesh: an object of :data:`OBJECTS` or a mesh file.

    A file is read with trimesh; a texture is baked into vertex colours, and a
    mesh without colours gets :func:`procedural_colors` (scaled to its size).
    """
    key = os.fspath(name_or_path)
    if key in OBJECTS:
        return _cached(key).copy()
    if not os.path.isfile(key):
        raise ReneusError(f"{key!r}: neither an object name ({', '.join(OBJECTS)}) "
                         f"nor an existing mesh file")
    mesh = load_mesh(key)
    if not np.all(np.isfinite(mesh.vertices)):
        raise ReneusError(f"{key}: mesh has non-finite vertex positions")
    if mesh.visual.kind == 'texture':
        mesh.visual = mesh.visual.to_color()
    elif mesh.visual.kind != 'vertex':
        mesh.visual.vertex_colors = procedural_colors(mesh.vertices, period=0.25 * mesh.scale)
    return mesh


def normalize(mesh: trimesh.Trimesh, margin: float = 0.15, radius: float = 0.95,
              container: str = 'box', wall: float = 0.0) -> tuple[trimesh.Trimesh, trimesh.Trimesh, trimesh.Trimesh | None]:
    """Centre ``mesh``, fit a container around it and scale both into a sphere.

    The container (:func:`~reneus_mi.geometry.shapes.container_mesh`) is fitted to the object's bounding
    box grown on every side by ``margin`` times the object's largest
    half-extent (so a flat object still sits in a thick slab of glass); with ``wall`` (a
    fraction of the same) that is the inside of a wall that thick around it (a case's air, a
    jar's liquid). The container's farthest point then lies on the sphere of ``radius``
    (< 1: everything inside the unit sphere). Returns ``(object, container, inside)``, new
    meshes (``inside`` None without a wall); the containers are watertight with outward normals.
    """
    if not 0.0 <= margin:
        raise ReneusError(f"margin={margin}: expected a non-negative fraction of the object's size")
    if not 0.0 < radius <= 1.0:
        raise ReneusError(f"radius={radius}: expected a value in (0, 1]")
    lo, hi = mesh.bounds
    center, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    fitted = half + margin * half.max()
    box = container_mesh(container, fitted, grow=wall * half.max())
    inside = container_mesh(container, fitted) if wall > 0 else None
    scale = radius / np.linalg.norm(box.vertices, axis=1).max()
    obj = mesh.copy()
    obj.apply_translation(-center)
    obj.apply_scale(scale)
    for shape in (box, inside):
        if shape is not None:
            normals = shape.vertex_normals.copy() if container != 'box' else None
            shape.apply_scale(scale)
            if normals is not None:
                shape.vertex_normals = normals
    return obj, box, inside
