"""The bulge of a solid block's faces (beyond the paper): a polished block is seldom flat.

A face of a cast and polished block bulges by a few tenths of a millimetre at its centre and
not at its edges, and that weak lens moves what is seen through it by pixels: Blender's ant in
a block whose sides and top bulge 0.3 mm, modelled as a flat box, came out 7.2 mm Chamfer-L1
(0.105 modelled bowed; docs/containers.md). The capture's outline does not tell a bowed face
from a flat one, so the bulge is measured from the photographs.

Each face bulges by its own ``bow`` (:mod:`reneus_mi.geometry.bulge`; zero along its edges, so
that a rounding or a sharp edge stays as the capture measured it). The mesh is cut finer once
(:data:`SUBDIVISIONS` halvings of every triangle: a facet's chord lies microns from the bulge)
and its vertices are moved whenever the bulge changes, as the walls' are; light bends at the
bulge's exact normal, the flat block's shading normal tilted by the bulge's slope where the ray
meets it. A ray leaving a bulge must start inside the mesh that bounds it, so the surface
itself moves, not only the hit distance.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.geometry.bulge import bulge, displacement
from reneus_mi.geometry.container import shading_normals
from reneus_mi.utils.errors import ReneusError

#: A mesh filling less of its oriented bounding box is not taken for a block (a jar fills pi/4;
#: a block rounded 2 mm on 22 mm, 0.99).
BLOCK_FILL = 0.95
#: Halvings of every triangle of the block before it bends: a sharp box's face in 8 x 8 pairs of
#: facets, whose chords lie within 0.005 mm of a 0.3 mm bulge (a rounded block's thousands of
#: triangles, 64 times as many).
SUBDIVISIONS = 3


class ContainerBow:
    """The bulge of each face of a solid block, searched from the photographs (scene units)."""

    NAME = 'container.bow'

    def __init__(self, shape, crease_angle: float):
        """Cuts ``shape``'s triangles finer (:data:`SUBDIVISIONS`), in place: build the
        container's other tables (its edges) after; its shading normals are :attr:`table`."""
        if not isinstance(shape, mi.Mesh):
            raise ReneusError(f"model.render.bow: the container '{shape.id()}' is a "
                              f'{shape.class_name()}; expected a block as a triangle mesh (ply, obj)')
        params = mi.traverse(shape)
        v, f = np.array(params['vertex_positions'], np.float64).reshape(-1, 3), np.array(params['faces']).reshape(-1, 3)
        mesh = trimesh.Trimesh(v, f)       # merged: a file may repeat a vertex per face
        to_local, extents = trimesh.bounds.oriented_bounds(mesh)
        fill = abs(mesh.volume) / float(np.prod(extents))
        if not mesh.is_watertight or fill < BLOCK_FILL:
            raise ReneusError(f"model.render.bow: the container '{shape.id()}' fills "
                              f'{100 * fill:.0f} % of its bounding box; expected a block (a box, its '
                              f'edges sharp or rounded: at least {100 * BLOCK_FILL:.0f} %) whose faces '
                              'may bulge')
        # The flat block's shading normals by the container's rule, carried into the finer cut
        # (the cut's vertices in the faces' interiors are one copy each, and would be taken
        # for a smooth surface's).
        v, f, table = _cut(v, f, np.array(shading_normals(shape, crease_angle), np.float64).reshape(-1, 3, 3))
        params['faces'] = mi.UInt32(f.astype(np.uint32).ravel())
        params['vertex_positions'] = mi.Float(v.astype(np.float32).ravel())
        params.update()
        #: The shading normals of the flat block's triangle corners (9 floats per triangle,
        #: :func:`~reneus_mi.geometry.container.shading_normals`' layout), to tilt (:meth:`tilt`).
        self.table = mi.Float(table.astype(np.float32).ravel())
        self.shape = shape
        #: The block's frame: local = rotation @ p + offset (container coordinates).
        self.to_local = to_local
        self.half = 0.5 * np.asarray(extents, np.float64)
        #: Per face (-x, +x, -y, +y, -z, +z of the block's frame): its bulge at the centre.
        self.bow = dr.zeros(mi.Float, 6)
        R = to_local[:3, :3]
        n = np.zeros_like(v)
        n[f.ravel()] = table.reshape(-1, 3)     # a corner's normal: one of its vertex's
        q, n = (v @ R.T + to_local[:3, 3]).T, (n @ R.T).T
        #: The flat block's vertices, and how each moves per unit of each face's bulge (6, V, 3).
        self._flat = v
        self._moves = np.stack([displacement(q, n, np.eye(6)[k], self.half) @ R for k in range(6)])
        self._built = np.zeros(6)
        self._rotation = mi.Matrix3f(R.tolist())
        self._rotation_back = mi.Matrix3f(R.T.tolist())
        self._offset = mi.Vector3f(*to_local[:3, 3].tolist())
        self._half = [float(h) for h in self.half]

    def params(self) -> dict:
        return {self.NAME: self.bow}

    def pieces(self, per_face: np.ndarray) -> np.ndarray:
        """A value per triangle of the block as loaded, for each of the pieces it was cut into
        (they follow one another, each triangle's together)."""
        return np.repeat(per_face, 4 ** SUBDIVISIONS, axis=0)

    def scales(self) -> np.ndarray:
        """Per face, the smaller of its half-sides: how far a bulge of a given curvature goes."""
        h = self.half
        return np.array([min(h[(k // 2 + 1) % 3], h[(k // 2 + 2) % 3]) for k in range(6)])

    def sync(self, container: mi.Scene) -> None:
        """Move the block's vertices where the bulge changed since they were last moved (a host
        read of six values: the ray tracer's acceleration structure is built on the host)."""
        now = np.array(self.bow, np.float64)
        if np.array_equal(now, self._built):
            return
        params = mi.traverse(container)
        params[f'{self.shape.id()}.vertex_positions'] = mi.Float(
            (self._flat + np.tensordot(now, self._moves, axes=1)).astype(np.float32).ravel())
        params.update()
        self._built = now

    def tilt(self, p: mi.Point3f, n_s: mi.Vector3f, valid: mi.Bool) -> mi.Vector3f:
        """The shading normal ``n_s`` of the flat block tilted by the bulge's slope at ``p``
        (container frame); rays that met nothing (not ``valid``) keep theirs."""
        R = self._rotation
        q = R @ mi.Vector3f(dr.select(valid, p, 0.0)) + self._offset
        bow = [dr.gather(mi.Float, self.bow, k) for k in range(6)]
        _, slope = bulge(q, R @ n_s, bow, self._half)
        return dr.select(valid, dr.normalize(n_s - self._rotation_back @ mi.Vector3f(*slope)), n_s)

    def tilted(self, corners: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """:meth:`tilt` of the triangles' corners of the bowed block and their flat normals
        (N, 3 each, container frame): the normals a file of it carries."""
        R, offset = self.to_local[:3, :3], self.to_local[:3, 3]
        _, slope = bulge((corners @ R.T + offset).T, (normals @ R.T).T, np.array(self.bow, np.float64), self.half)
        tilted = normals - np.stack(np.broadcast_arrays(*slope), axis=1) @ R
        return tilted / np.linalg.norm(tilted, axis=1, keepdims=True)


def _cut(v: np.ndarray, f: np.ndarray, table: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each triangle halved :data:`SUBDIVISIONS` times (into 4 each time, its winding kept), its
    corners' normals ``table`` (F, 3, 3) interpolated: vertices, triangles, corner normals."""
    pattern = np.eye(3)[None]
    for _ in range(SUBDIVISIONS):
        a, b, c = pattern[:, 0], pattern[:, 1], pattern[:, 2]
        ab, bc, ca = 0.5 * (a + b), 0.5 * (b + c), 0.5 * (c + a)
        pattern = np.concatenate([np.stack(t, axis=1) for t in
                                  ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    corners = np.einsum('tcj,fjd->ftcd', pattern, v[f]).reshape(-1, 3)
    normals = np.einsum('tcj,fjd->ftcd', pattern, table).reshape(-1, 3)
    # Corners shared by triangles meet at one vertex; the same point reached from two triangles
    # may differ in its last bits.
    scale = float(np.abs(v).max()) or 1.0
    _, first, index = np.unique(np.round(corners / scale, 9), axis=0, return_index=True, return_inverse=True)
    return (corners[first], index.reshape(-1, 3),
            (normals / np.linalg.norm(normals, axis=1, keepdims=True)).reshape(-1, 3, 3))
