"""The container mesh: checks, bounding sphere, projected masks and its shading normals.

The paper's method needs the container as a closed triangle mesh in world
coordinates; its silhouette in each view is the mask ``M_in``. Masks are
computed by tracing every pixel-centre ray at the mesh with Mitsuba, one Dr.Jit
launch per view.

**Which normal bends light** (:func:`corner_normals`, the one rule of the package).
A mesh file does not say which of its edges are creases: a box written with 8
shared vertices and no normals (trimesh, Blender's cube, most CAD exports) gets
smooth vertex normals from Mitsuba and would refract like a rounded lens. So the
shading normal of every triangle corner follows the geometry:

- faces meeting at a vertex at more than the crease angle (30 degrees, like
  Blender's auto-smooth) are not smoothed together: a box's faces keep their own
  normals whatever the file looks like;
- where the faces around a vertex all lie within the crease angle of each other the
  surface is smooth there: the file's stored normal is used (rounded blocks, jars),
  or, when the file has none, the angle-weighted mean of those faces' normals.

Vertices are welded by position first, so a mesh written with one vertex per
triangle corner is read like the same mesh with shared vertices.
"""
from __future__ import annotations

import os

import mitsuba as mi
import numpy as np

from reneus_mi.data.cameras import pixel_rays
from reneus_mi.errors import ReneusError
from reneus_mi.mesh import load_container

#: Mesh formats that both trimesh and Mitsuba read.
MESH_EXTENSIONS = ('.ply', '.obj')
#: Faces meeting at more than this angle (degrees) form a crease: light sees them flat.
CREASE_ANGLE = 30.0
#: Vertices closer than this fraction of the mesh's size are one vertex (welding).
_WELD = 1e-6
#: A stored normal is the vertex's own when its copies agree this closely (1 - cos).
_SAME_NORMAL = 1e-4

__all__ = ['MESH_EXTENSIONS', 'CREASE_ANGLE', 'mesh_type', 'load_container', 'bounding_sphere',
           'container_masks', 'corner_normals', 'shading_normals', 'container_shape', 'mitsuba_reads',
           'shading_mesh']


def mesh_type(path: str) -> str:
    """Mitsuba shape plugin name (``ply``/``obj``) for a mesh file, or raise."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_EXTENSIONS:
        raise ReneusError(f"{path}: expected a mesh file ending in {' or '.join(MESH_EXTENSIONS)}")
    return ext[1:]


def bounding_sphere(path: str) -> tuple[np.ndarray, float]:
    """Centre of the mesh's bounding box and the radius that reaches every vertex."""
    vertices = np.asarray(load_container(path).vertices)
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


def container_masks(path: str, K: np.ndarray, c2w: np.ndarray, height: int, width: int,
                    views: list[int] | None = None) -> np.ndarray:
    """Boolean masks (len(views),H,W): pixels whose centre ray hits the container.

    ``K`` (N,3,3) and ``c2w`` (N,4,4) are OpenCV cameras; ``views`` picks some
    of them (all by default).
    """
    scene = mi.load_dict({'type': 'scene', 'container': container_shape(path)})
    views = range(len(K)) if views is None else views
    ys, xs = np.mgrid[:height, :width]
    px = np.stack([xs.ravel(), ys.ravel()], axis=1)
    masks = []
    for v in views:
        o, d = pixel_rays(K, c2w, v, px)
        ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[:, i]) for i in range(3))),
                       mi.Vector3f(*(mi.Float(d[:, i]) for i in range(3))))
        masks.append(np.array(scene.ray_test(ray)).reshape(height, width))
    return np.stack(masks) if masks else np.zeros((0, height, width), bool)


def corner_normals(vertices, faces, normals=None, crease_angle: float = CREASE_ANGLE) -> np.ndarray:
    """The shading normal of every triangle corner (F,3,3) by the rule of this module.

    ``vertices`` (V,3) and ``faces`` (F,3) are the mesh as stored; ``normals`` (V,3)
    the vertex normals it was read with, if any (a copy of a vertex whose copies
    disagree is not taken as stored: Mitsuba computed it from its own faces).
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    corners = v[f]                                              # (F, 3 corners, xyz)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = np.linalg.norm(cross, axis=1)
    # Slivers have no reliable normal: they neither make creases nor weigh in means.
    solid = area > 1e-12 * max(float(np.median(area)), 1e-30)
    n_face = cross / np.maximum(area, 1e-30)[:, None]
    e_next = np.roll(corners, -1, axis=1) - corners
    e_prev = np.roll(corners, 1, axis=1) - corners
    cos_corner = np.einsum('fci,fci->fc', e_next, e_prev) / np.maximum(
        np.linalg.norm(e_next, axis=2) * np.linalg.norm(e_prev, axis=2), 1e-30)
    weight = np.arccos(np.clip(cos_corner, -1.0, 1.0)) * solid[:, None]

    size = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    _, weld = np.unique(np.round(v / (_WELD * max(size, 1e-30))).astype(np.int64), axis=0,
                        return_inverse=True)
    weld = weld.ravel()
    # Every ordered pair (a, b) of corners at one welded vertex, a and b included.
    w = weld[f].ravel()
    order = np.argsort(w, kind='stable')
    count = np.bincount(w)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    degree = count[w[order]]
    a = np.repeat(order, degree)
    offset = np.arange(len(a)) - np.repeat(np.cumsum(degree) - degree, degree)
    b = order[np.repeat(start[w[order]], degree) + offset]
    fa, fb = a // 3, b // 3
    smooth = (np.einsum('pi,pi->p', n_face[fa], n_face[fb]) >= np.cos(np.radians(crease_angle))) | ~solid[fb]
    mean = np.zeros((3 * len(f), 3))
    np.add.at(mean, a[smooth], weight.ravel()[b[smooth], None] * n_face[fb[smooth]])
    length = np.linalg.norm(mean, axis=1, keepdims=True)
    n_corner = np.where(length > 1e-12, mean / np.maximum(length, 1e-30), n_face[np.arange(3 * len(f)) // 3])

    if normals is not None:
        n = np.asarray(normals, np.float64)
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        # A vertex's copies (one per face in a flat-written mesh) must carry one normal.
        ref = np.zeros((weld.max() + 1, 3))
        ref[weld] = n
        agree = np.ones(len(ref), bool)
        np.logical_and.at(agree, weld, np.einsum('vi,vi->v', n, ref[weld]) >= 1.0 - _SAME_NORMAL)
        creased = np.zeros(3 * len(f), bool)
        np.logical_or.at(creased, a, ~smooth)
        stored = n[f.ravel()]
        use = (~creased & agree[w]
               & (np.einsum('ci,ci->c', stored, n_face[np.arange(3 * len(f)) // 3])
                  >= np.cos(np.radians(crease_angle))))
        n_corner[use] = stored[use]
    return n_corner.reshape(-1, 3, 3).astype(np.float32)


def shading_normals(shape: mi.Mesh, crease_angle: float = CREASE_ANGLE) -> mi.Float:
    """:func:`corner_normals` of a Mitsuba mesh as it was loaded: 9 floats per face, the
    normals of its corners in order (what the ``reneus`` integrator interpolates)."""
    params = mi.traverse(shape)
    vertices = np.array(params['vertex_positions']).reshape(-1, 3)
    normals = np.array(params['vertex_normals']).reshape(-1, 3) if shape.has_vertex_normals() else None
    return mi.Float(corner_normals(vertices, np.array(params['faces']).reshape(-1, 3), normals,
                                   crease_angle).ravel())


def container_shape(path: str, bsdf: dict | None = None) -> mi.Mesh:
    """The container file as a Mitsuba mesh: as Mitsuba's own reader loads it (stored
    normals included) where it can; a PLY of polygons, which that reader refuses
    (Blender's default export), triangulated by trimesh instead (without its normals:
    :func:`corner_normals` computes them)."""
    props = {'type': mesh_type(path), 'filename': os.path.abspath(path)}
    if bsdf is not None:
        props['bsdf'] = bsdf
    if mitsuba_reads(path):
        return mi.load_dict(props)
    mesh = load_container(path)
    shape = mi.Mesh('container', len(mesh.vertices), len(mesh.faces),
                    props=_bsdf_props(bsdf), has_vertex_normals=False)
    params = mi.traverse(shape)
    params['vertex_positions'] = mi.Float(np.ravel(mesh.vertices).astype(np.float32))
    params['faces'] = mi.UInt32(np.ravel(mesh.faces).astype(np.uint32))
    params.update()
    return shape


def mitsuba_reads(path: str) -> bool:
    """Whether Mitsuba's own reader loads the mesh file (it takes triangle PLYs only)."""
    try:
        mi.load_dict({'type': mesh_type(path), 'filename': os.path.abspath(path)})
    except RuntimeError:
        return False
    return True


def shading_mesh(path: str, crease_angle: float = CREASE_ANGLE, bsdf: dict | None = None) -> mi.Mesh:
    """The container file as a Mitsuba mesh whose own vertex normals are the rule's: one
    vertex per triangle corner. Mitsuba's ``path`` integrator renders it as ``reneus``
    sees the file (references, synthetic photographs)."""
    loaded = container_shape(path)
    params = mi.traverse(loaded)
    corners = np.array(params['vertex_positions']).reshape(-1, 3)[np.array(params['faces']).reshape(-1, 3)]
    normals = np.array(shading_normals(loaded, crease_angle)).reshape(-1, 3)
    n_faces = len(corners)
    shape = mi.Mesh('container', 3 * n_faces, n_faces, has_vertex_normals=True, props=_bsdf_props(bsdf))
    out = mi.traverse(shape)
    out['vertex_positions'] = mi.Float(corners.astype(np.float32).ravel())
    out['faces'] = mi.UInt32(np.arange(3 * n_faces, dtype=np.uint32))
    out['vertex_normals'] = mi.Float(normals.ravel())
    out.update()
    return shape


def _bsdf_props(bsdf: dict | None) -> mi.Properties:
    props = mi.Properties()
    if bsdf is not None:
        props['bsdf'] = mi.load_dict(bsdf)
    return props
