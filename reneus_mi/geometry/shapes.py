"""Shapes by their signed distance, meshed: the containers of the generator and of a
capture (a glass block, a block with rounded edges, a cylinder jar), and the parts the
synthetic objects are blended from.

A box is exact (eight corners, flat faces); the jar is its profile turned about its axis
in :data:`JAR_SEGMENTS` steps, with the exact normals of the profile; the rounded block is a
box with a sphere rolled round it, the convex hull of a sphere's octant at each corner in
:data:`EDGE_SEGMENTS` steps a quarter circle, with the sphere's normals. The renderers shade the smooth ones with these normals
(:func:`write_container` keeps them in the file).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.fields.base import Field
from reneus_mi.geometry.surface import extract_mesh
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_path


def round_cylinder(p, center, radius, half_height, rounding):
    """Vertical cylinder (axis z) with edges rounded by ``rounding``."""
    q = p - mi.Vector3f(*center)
    dx = dr.sqrt(q.x * q.x + q.y * q.y) - radius + rounding
    dz = dr.abs(q.z) - half_height + rounding
    outside = dr.sqrt(dr.square(dr.maximum(dx, 0.0)) + dr.square(dr.maximum(dz, 0.0)))
    return outside + dr.minimum(dr.maximum(dx, dz), 0.0) - rounding


class _DistanceField(Field):
    """A :class:`Field` whose SDF is a Python function of a Dr.Jit point, so that
    the project's Marching Cubes (:func:`extract_mesh`) meshes it."""

    def __init__(self, distance):
        self._distance = distance

    def geometry(self, x):
        return self._distance(mi.Vector3f(x)), []


def mesh_sdf(distance, lo, hi, pitch: float) -> trimesh.Trimesh:
    """Marching cubes of ``distance`` (a Python function of a Dr.Jit point) over the box
    ``lo``..``hi`` at ``pitch``: one closed surface where blended parts overlap."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    resolution = np.ceil((hi - lo) / pitch).astype(np.int64) + 1
    with dr.suspend_grad():
        mesh = extract_mesh(_DistanceField(distance), lo, hi, resolution)
    # Marching Cubes emits duplicate vertices at grid edges shared by cells.
    mesh.merge_vertices()
    return mesh


#: Container shapes of the generator: a glass block, a block with rounded edges, a cylinder jar.
CONTAINERS = ('box', 'rounded', 'cylinder')
#: Edge radius of the rounded block and the jar's rims, as a fraction of the smallest half-extent.
ROUNDING = 0.3
#: Steps of a quarter circle of the rounded block's edges and corners: its chords stray from
#: the arc by r (1 - cos(pi / 4N)), 0.2 % of the radius (Blender's bevel of the Blender
#: captures: 12 as well).
EDGE_SEGMENTS = 12


def container_mesh(kind: str, half, grow: float = 0.0, edge: float | None = None) -> trimesh.Trimesh:
    """A closed container about the origin around the box of half-extents ``half``.

    ``box`` is that box (flat faces); ``rounded`` the box with edges and corners
    rounded; ``cylinder`` the vertical (z) jar through the box's corners, its rims
    rounded (:func:`_jar`). The smooth ones carry exact vertex normals
    (``vertex_normals``), which the renderers use as shading normals. ``grow`` moves the surface
    that far out everywhere (a box's faces, a smooth one's offset surface): the outside of
    a wall that thick around the container of ``grow`` 0. ``edge``: the radius of the rounded
    edges or rims (0: sharp; None: ROUNDING x the smallest half-extent).
    """
    half = np.asarray(half, np.float64)
    if kind == 'box':
        return trimesh.creation.box(extents=2.0 * (half + grow))
    if kind not in CONTAINERS:
        raise ReneusError(f"container={kind!r}: expected one of {', '.join(CONTAINERS)}")
    r = ROUNDING * half.min() if edge is None else float(edge)
    if kind == 'cylinder':
        return _jar(np.hypot(half[0], half[1]) + grow, half[2] + r + grow, r + grow)
    # Rounding cuts into the box: grow it so the object's corners stay inside.
    size = half + r * (1.0 - 1.0 / np.sqrt(3.0))
    return _rounded_box(size - r, r + grow)


def _rounded_box(core, radius: float) -> trimesh.Trimesh:
    """The box of half-extents ``core`` grown by ``radius`` everywhere (a sphere rolled round
    it: flat faces, quarter-cylinder edges, sphere-octant corners), each vertex with its exact
    normal; a sharp box where ``radius`` is 0 or less (an offset inside the rounding)."""
    if radius <= 0.0:
        return trimesh.creation.box(extents=2.0 * (np.asarray(core) + radius))
    t = np.linspace(0.0, 0.5 * np.pi, EDGE_SEGMENTS + 1)
    polar, azimuth = (a.ravel() for a in np.meshgrid(t, t))
    octant = np.unique(np.round(np.stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth),
                                          np.cos(polar)], axis=1), 12), axis=0)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    normals = np.concatenate([octant * sign for sign in signs])
    centres = np.repeat(signs * np.asarray(core), len(octant), axis=0)
    hull = trimesh.convex.convex_hull(centres + radius * normals)
    # The hull keeps a subset of the points, in its own order: each vertex's normal is its
    # point's direction from the corner it was rolled round.
    mesh = trimesh.Trimesh(hull.vertices, hull.faces, process=False)
    mesh.vertex_normals = (hull.vertices - np.sign(hull.vertices) * np.asarray(core)) / radius
    return mesh


#: Steps of a jar's turn: its side's chords stray from the circle by R (1 - cos(pi / N)),
#: 0.4 micrometres at R = 20 mm (marching cubes cut a sharp rim by a cell, its normals up to
#: 84 degrees wrong within 0.15 mm of the rims of a 28 mm jar).
JAR_SEGMENTS = 512
#: Points along each of a jar's rims (a quarter circle).
RIM_POINTS = 9
#: Radius of a "sharp" rim, as a share of the jar's radius (2 micrometres at 20 mm): the
#: normals turn from side to lid over it, a band no photograph resolves.
SHARP_RIM = 1e-4


def _jar(radius: float, half_height: float, rim: float) -> trimesh.Trimesh:
    """The vertical (z) cylinder ``radius`` x ``2 half_height`` about the origin, its rims
    rounded by ``rim`` (at least :data:`SHARP_RIM` of the radius): the profile (bottom
    centre, bottom rim, side, top rim, top centre) turned about z, each vertex with the
    profile's normal there."""
    rim = max(rim, SHARP_RIM * radius)
    t = np.linspace(0.0, 0.5 * np.pi, RIM_POINTS)
    bottom = np.stack([radius - rim + rim * np.sin(t), -half_height + rim - rim * np.cos(t),
                       np.sin(t), -np.cos(t)], axis=1)
    top = np.stack([radius - rim + rim * np.cos(t), half_height - rim + rim * np.sin(t),
                    np.cos(t), np.sin(t)], axis=1)
    r, z, n_r, n_z = np.concatenate([bottom, top]).T         # the profile, bottom to top
    m = len(r)
    turn = 2.0 * np.pi * np.arange(JAR_SEGMENTS) / JAR_SEGMENTS
    c, s = np.cos(turn)[:, None], np.sin(turn)[:, None]

    def revolved(radial, axial, centres):
        return np.concatenate([np.stack([c * radial, s * radial, np.broadcast_to(axial, (JAR_SEGMENTS, m))],
                                        axis=-1).reshape(-1, 3), centres])
    vertices = revolved(r, z, [[0.0, 0.0, -half_height], [0.0, 0.0, half_height]])
    normals = revolved(n_r, n_z, [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    # Vertex (segment i, profile point j) is i m + j; quads between neighbouring segments.
    i, j = np.meshgrid(np.arange(JAR_SEGMENTS), np.arange(m - 1), indexing='ij')
    i, j = i.ravel(), j.ravel()
    k = (i + 1) % JAR_SEGMENTS
    a0, a1, b0, b1 = i * m + j, i * m + j + 1, k * m + j, k * m + j + 1
    side = np.concatenate([np.stack([a0, b0, b1], 1), np.stack([a0, b1, a1], 1)])
    seg = np.arange(JAR_SEGMENTS)
    nxt = (seg + 1) % JAR_SEGMENTS
    low, high = len(vertices) - 2, len(vertices) - 1
    caps = np.concatenate([np.stack([np.full_like(seg, low), nxt * m, seg * m], 1),
                           np.stack([np.full_like(seg, high), seg * m + m - 1, nxt * m + m - 1], 1)])
    mesh = trimesh.Trimesh(vertices, np.concatenate([side, caps]), process=False)
    mesh.vertex_normals = normals
    return mesh


def write_container(container: trimesh.Trimesh, path: str, normals: bool) -> None:
    """Write the container as most tools write one: shared vertices, and its vertex
    normals where it has exact ones (the smooth containers); a box carries none (the
    crease rule of :mod:`reneus_mi.geometry.container` keeps its faces flat)."""
    data = trimesh.exchange.ply.export_ply(container, vertex_normal=normals)
    with atomic_path(path) as tmp, open(tmp, 'wb') as f:
        f.write(data)
    if normals and not np.allclose(trimesh.load(path, process=False).vertex_normals,
                                   container.vertex_normals, atol=1e-5):
        raise ReneusError(f'{path}: the vertex normals did not survive writing')
