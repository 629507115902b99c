"""The container: the closed glass mesh the rays pass through, its checks and its masks.

The paper's method needs the container as a closed, outward-facing triangle
mesh in world coordinates (:func:`check_container`; as a scene holds it:
:func:`check_scene_containers`); its silhouette in each view is the mask
``M_in`` (:func:`container_masks`: every pixel-centre ray traced at the mesh
with Mitsuba, one Dr.Jit launch per view).

The point-in-container test (:func:`inside`) is a parity ray cast with
Mitsuba, which needs no optional trimesh dependency (rtree, embree) and works
for any closed container.
"""
from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.data.cameras import pixel_rays
from reneus_mi.errors import ReneusError
from reneus_mi.geometry.mesh import load_mesh, mitsuba_mesh, signed_volume

#: Mesh formats that both trimesh and Mitsuba read.
CONTAINER_EXTENSIONS = ('.ply', '.obj')

# Directions of the parity rays in :func:`inside`: three independent, generic
# directions, so that a ray grazing an edge or a vertex of the container (the
# only way a parity count goes wrong) is outvoted by the other two.
_RAY_DIRECTIONS = ((0.5366, 0.6104, 0.5826), (-0.7213, 0.2871, 0.6303), (0.1947, -0.8626, 0.4668))


def mesh_type(path: str) -> str:
    """Mitsuba shape plugin name (``ply``/``obj``) for a mesh file, or raise."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in CONTAINER_EXTENSIONS:
        raise ReneusError(f"{path}: expected a mesh file ending in {' or '.join(CONTAINER_EXTENSIONS)}")
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
    scene = mi.load_dict({'type': 'scene',
                          'container': {'type': mesh_type(path), 'filename': path}})
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


def load_container(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a container mesh and check it (:func:`check_container`)."""
    mesh = load_mesh(path, 'container mesh')
    check_container(mesh, os.fspath(path))
    return mesh


def check_container(container, name: str = 'container') -> None:
    """Raise naming ``name`` unless ``container`` is a closed, outward-facing triangle mesh.

    Inward normals would make the renderer take entering the glass for
    leaving it (the specimen vanishes from the renders), so they are refused
    rather than guessed at: the file itself must be fixed, because Mitsuba
    reads the file, not this copy.
    """
    if not isinstance(container, trimesh.Trimesh) or len(container.faces) == 0:
        raise ReneusError(f'{name}: expected a closed triangle mesh with faces, got {container!r}')
    # Meshes written per face (e.g. for flat shading) duplicate vertices; the
    # surface is still closed once they are merged.
    merged = container.copy()
    merged.merge_vertices()
    if not merged.is_watertight:
        raise ReneusError(f'{name}: container mesh is not closed (not watertight), so '
                          'inside/outside is undefined; expected a mesh enclosing a volume')
    volume = signed_volume(container.vertices, container.faces)
    if not volume > 0.0:
        raise ReneusError(f'{name}: container normals point inward (signed volume {volume:.4g}); '
                          'expected outward normals: reverse the winding of its faces '
                          '(trimesh: mesh.invert())')


def inside(points, container: trimesh.Trimesh) -> np.ndarray:
    """Boolean mask of the ``(N, 3)`` ``points`` that lie inside the closed ``container``.

    A point is inside when a ray from it crosses the surface an odd number of
    times; the answer is the majority over three ray directions.
    """
    check_container(container)
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ReneusError(f'points: expected an (N, 3) array, got shape {points.shape}')
    if len(points) == 0:
        return np.zeros(0, dtype=bool)

    scene = mi.load_dict({'type': 'scene', 'container': mitsuba_mesh(container)})

    # Every crossing is a distinct face, so a ray that has not left the
    # container after this many hits is stuck re-hitting one spot.
    max_hits = len(container.faces) + 1
    origin = mi.Point3f(*(points.T.astype(np.float32)))
    votes = mi.UInt32(0)
    for direction in _RAY_DIRECTIONS:
        votes += _parity(scene, origin, mi.Vector3f(*direction), max_hits)
    return np.asarray(votes) >= 2


@dr.syntax
def _parity(scene, origin, direction, max_hits):
    """1 where a ray from ``origin`` along ``direction`` crosses ``scene`` an odd number of times."""
    ray = mi.Ray3f(origin, dr.normalize(direction))
    hits = mi.UInt32(0)
    active = mi.Bool(True)
    while active:
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid() & (hits < max_hits)
        hits = dr.select(active, hits + 1, hits)
        # Lanes that stop here never read the ray again.
        ray = si.spawn_ray(ray.d)
    return hits & 1


def check_scene_containers(scene: mi.Scene, where: str) -> None:
    """Every dielectric mesh of ``scene`` (the container) must be closed, face outward,
    and be made of parts that do not overlap.

    This is the geometry Mitsuba traces, after the scene's transforms and
    ``flip_normals`` (and after Mitsuba merged shapes that share a BSDF): the
    check catches what the XML points to, whatever file the dataset names.
    """
    parts = []
    for shape in scene.shapes():
        if not isinstance(shape, mi.Mesh) or not str(shape.bsdf()).startswith('SmoothDielectric'):
            continue
        vertices = np.array(shape.vertex_positions_buffer()).reshape(-1, 3)
        faces = np.array(shape.faces_buffer()).reshape(-1, 3)
        if shape.has_flipped_normals():
            faces = faces[:, ::-1]
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
        check_container(mesh, f"{where}: shape '{shape.id() or 'container'}'")
        merged = mesh.copy()
        merged.merge_vertices()
        parts += merged.split(only_watertight=False)
    _check_disjoint(parts, where)


def _check_disjoint(parts, where: str) -> None:
    """Container parts may sit apart or one inside another as its cavity (inward
    normals: a hollow vessel), never cut through each other or nest glass in glass,
    where a ray would enter glass it is already in."""
    for i, a in enumerate(parts):
        for b in parts[i + 1:]:
            if not (np.all(a.bounds[0] <= b.bounds[1]) and np.all(b.bounds[0] <= a.bounds[1])):
                continue
            for inner, outer in ((a, b), (b, a)):
                if signed_volume(outer.vertices, outer.faces) < 0:
                    outer = outer.copy()   # parity is blind to orientation; inside() is not
                    outer.invert()
                within = inside(_probes(inner), outer)
                cavity = signed_volume(inner.vertices, inner.faces) < 0
                if within.any() and not (within.all() and cavity):
                    c = np.round(0.5 * (inner.bounds[0] + inner.bounds[1]), 3).tolist()
                    raise ReneusError(f'{where}: container parts overlap (the part centred at {c} '
                                      'reaches into another); expected disjoint parts, or a cavity '
                                      'with inward normals inside its part')


def _probes(mesh) -> np.ndarray:
    """Points of a mesh's surface that tell whether it reaches into another: vertices and face centres."""
    return np.concatenate([mesh.vertices, mesh.triangles_center])
