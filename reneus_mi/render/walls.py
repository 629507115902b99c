"""The thickness of a hollow container's walls (beyond the paper, whose container is one solid
block), refinable: a case's glass, a jar's.

The capture measures a case or a jar by its outer outline; how thick its glass is comes from
the curator (``--wall-mm``), often a guess. Each inner interface (the case's air, the jar's
liquid) lies ``w`` in from the interface around it; refining ``w`` moves that inner surface
along its normals and leaves the outer one where the photographs put it.

The inner meshes are rebuilt at the current thickness before each render (each face moved in
by the change, its vertices along the mitred direction ``D`` with ``n · D = 1`` for every
surface at the vertex, so that a box's faces keep their shape and stay closed), and the hit distance of a
ray on an inner face carries the derivative of a plane moved along its normal,
``dt/dw = -1 / (n · d)``: the interior derivative (how refraction moves with the glass), as
the pose's.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.geometry.container import CREASE_ANGLE, face_normals, offset_directions, scene_of
from reneus_mi.render.step_state import refined
from reneus_mi.utils.errors import ReneusError

class ContainerWalls:
    """The thickness of each inner interface's wall, from the one around it (scene units)."""

    NAME = 'container.wall'

    def __init__(self, shapes: list, groups: list[int], outer: tuple[int, ...]):
        """``shapes``: the container's meshes, ``groups`` the interface of each, ``outer`` the
        region outside each interface (:class:`~reneus_mi.render.interfaces.Interfaces`)."""
        count = max(groups) + 1
        if count < 2:
            raise ReneusError('train.refine.wall (--refine-wall): the container has no inner interface (a '
                              "case's inner faces, a jar's liquid) whose wall could be refined; expected a "
                              'container stated as nested interfaces (docs/containers.md)')
        #: Per inner shape: (its interface, the vertices as loaded, their mitred directions).
        self._inner = []
        #: The smallest radius of the inner surfaces' rounded parts (inf: none): moved in further,
        #: a rounded rim's facets would cross (the exact inset turns it sharp there).
        self.radius = np.inf
        #: The mitred directions on the device, per inner shape (for the derivative of a corner).
        self._mitres = {}
        stated = []
        for g in range(1, count):
            members = [shape for shape, group in zip(shapes, groups) if group == g]
            around = scene_of([shape for shape, group in zip(shapes, groups) if group == outer[g] - 1])
            centres, normals, areas = [], [], []
            for shape in members:
                v, f = _mesh_arrays(shape)
                n, area = face_normals(v, f)
                D = offset_directions(v, f)
                self.radius = min(self.radius, _rounding_radius(v, f))
                self._inner.append((shape, g, v, D))
                self._mitres[shape] = mi.Float(D.astype(np.float32).ravel())
                centres.append(v[f].mean(axis=1))
                normals.append(n)
                areas.append(area)
            stated.append(_thickness(around, np.concatenate(centres), np.concatenate(normals),
                                     np.concatenate(areas), members[0].id()))
        #: The thickness as the scene states it, per inner interface (interface 1 first).
        self.stated = np.array(stated, np.float64)
        self.thickness = mi.Float(self.stated)
        self._built = self.stated.copy()

    def params(self) -> dict:
        return {self.NAME: self.thickness}

    def bounds(self) -> tuple[float, float]:
        """Where a refined thickness may go: from a tenth of the thinnest stated wall to the
        thickest plus half the smallest inner extent (the inside kept from closing) or nine
        tenths of the inner surfaces' smallest rounding radius, whichever is less."""
        inner = min(float(np.ptp(v, axis=0).min()) for _, _, v, _ in self._inner)
        thicker = min(0.25 * inner, 0.9 * self.radius)
        return 0.1 * float(self.stated.min()), float(self.stated.min()) + thicker

    def sync(self, container: mi.Scene) -> None:
        """Rebuild the inner meshes where the thickness changed since they were last built (a
        host read of one value per inner interface: the ray tracer's acceleration structure
        is built on the host)."""
        now = np.array(self.thickness, np.float64)
        if np.array_equal(now, self._built):
            return
        params = mi.traverse(container)
        for shape, g, v, D in self._inner:
            moved = v - (now[g - 1] - self.stated[g - 1]) * D
            params[f'{shape.id()}.vertex_positions'] = mi.Float(moved.astype(np.float32).ravel())
        params.update()
        self._built = now

    def shift(self, group: mi.UInt32, lanes: mi.Bool | None = None) -> mi.Float:
        """Per hit on interface ``group``: the thickness of its wall with its value taken away,
        0 with the derivative of the wall (0 on the outermost interface, which does not move)."""
        w = dr.gather(mi.Float, self.thickness, dr.maximum(group, 1) - 1)
        return dr.select(group > 0, refined(w - dr.detach(w), lanes), 0.0)


    def vertex(self, shift: mi.Float):
        """The corners of the hit triangles where they move with the walls (``shift``: per hit,
        :meth:`shift`), for :func:`~reneus_mi.geometry.container.interpolated_normal`: a curved
        wall's facets shrink as it thickens, and the shading normal at a point with them."""
        def position(shape, index, active):
            p = shape.vertex_position(index, active)
            D = self._mitres.get(shape)
            return p if D is None else p - shift * dr.gather(mi.Vector3f, D, index, active)
        return position


def _mesh_arrays(shape) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(shape, mi.Mesh):
        raise ReneusError(f"train.refine.wall (--refine-wall): the inner interface '{shape.id()}' is a "
                          f'{shape.class_name()}; expected a triangle mesh (ply, obj) that can be moved in')
    params = mi.traverse(shape)
    return (np.array(params['vertex_positions'], np.float64).reshape(-1, 3),
            np.array(params['faces']).reshape(-1, 3))


def _rounding_radius(v: np.ndarray, f: np.ndarray) -> float:
    """The smallest radius of the convex bends of a mesh between faces less than
    :data:`~reneus_mi.geometry.container.CREASE_ANGLE` apart (a rounded rim: the distance of
    two faces' centres over the angle between them; inf where there are none)."""
    mesh = trimesh.Trimesh(v, f, process=True)
    angle = mesh.face_adjacency_angles
    bend = mesh.face_adjacency_convex & (angle > 1e-3) & (angle < np.radians(CREASE_ANGLE))
    if not bend.any():
        return float('inf')
    a, b = mesh.face_adjacency[bend].T
    return float((np.linalg.norm(mesh.triangles_center[a] - mesh.triangles_center[b], axis=1) / angle[bend]).min())


def _thickness(around: mi.Scene, centres: np.ndarray, normals: np.ndarray, areas: np.ndarray,
               name: str) -> float:
    """The wall's thickness: the area-weighted median distance from the inner faces' centres
    along their normals to the interface around them."""
    o = mi.Point3f(*(mi.Float(centres[:, i].astype(np.float32)) for i in range(3)))
    d = mi.Vector3f(*(mi.Float(normals[:, i].astype(np.float32)) for i in range(3)))
    si = around.ray_intersect(mi.Ray3f(o, d))
    t, hit = np.array(si.t, np.float64), np.array(si.is_valid())
    if not hit.any():
        raise ReneusError(f"train.refine.wall (--refine-wall): interface '{name}' has no wall around it")
    order = np.argsort(t[hit])
    cumulative = np.cumsum(areas[hit][order])
    return float(t[hit][order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
