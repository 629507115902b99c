"""Shapes by their signed distance, meshed: the containers of the generator and of a
capture (a glass block, a block with rounded edges, a cylinder jar), and the parts the
synthetic objects are blended from.

A box is exact (eight corners, flat faces); the smooth containers are marching cubes of
their SDF at :data:`CONTAINER_CELLS` cells across, with the SDF's gradient as their exact
vertex normals, which the renderers use as shading normals (:func:`write_container` keeps
them in the file).
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
#: Marching-cubes cells across the smooth containers' largest extent.
CONTAINER_CELLS = 96


def round_box(p, half, rounding):
    q = dr.abs(p) - mi.Vector3f(*(float(h - rounding) for h in half))
    outside = dr.norm(dr.maximum(q, 0.0))
    return outside + dr.minimum(dr.maximum(dr.maximum(q.x, q.y), q.z), 0.0) - rounding


def container_mesh(kind: str, half, grow: float = 0.0, edge: float | None = None) -> trimesh.Trimesh:
    """A closed container about the origin around the box of half-extents ``half``.

    ``box`` is that box (flat faces); ``rounded`` the box with edges and corners
    rounded; ``cylinder`` the vertical (z) jar through the box's corners, its rims
    rounded. The smooth ones carry exact vertex normals (``vertex_normals``, from
    their SDF), which the renderers use as shading normals. ``grow`` moves the surface
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
    if kind == 'rounded':
        # Rounding cuts into the box: grow it so the object's corners stay inside.
        size = half + r * (1.0 - 1.0 / np.sqrt(3.0))
        def surface(p): return round_box(p, size, float(r))
    else:
        size = np.array([np.hypot(half[0], half[1])] * 2 + [half[2] + r])
        def surface(p): return round_cylinder(p, (0.0, 0.0, 0.0), float(size[0]), float(size[2]), float(r))

    def distance(p):
        return surface(p) - grow
    outer = size + grow
    pitch = 2.0 * outer.max() / CONTAINER_CELLS
    mesh = mesh_sdf(distance, -outer - 2 * pitch, outer + 2 * pitch, pitch)
    # Exact normals: the SDF's gradient (central differences) at the vertices.
    v = np.asarray(mesh.vertices, np.float64)
    h = 1e-3 * outer.max()

    def at(points):
        return np.asarray(distance(mi.Vector3f(*(mi.Float(np.ascontiguousarray(c, np.float32))
                                                 for c in points.T))), np.float64)
    grad = np.stack([at(v + h * e) - at(v - h * e) for e in np.eye(3)], axis=1) / (2 * h)
    mesh.vertex_normals = grad / np.linalg.norm(grad, axis=1, keepdims=True)
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
