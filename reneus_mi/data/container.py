"""The container mesh: checks, bounding sphere and projected masks.

The paper's method needs the container as a closed triangle mesh in world
coordinates; its silhouette in each view is the mask ``M_in``. Masks are
computed by tracing every pixel-centre ray at the mesh with Mitsuba, one Dr.Jit
launch per view.
"""
from __future__ import annotations

import os

import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.data.cameras import pixel_rays

#: Mesh formats that both trimesh and Mitsuba read.
MESH_EXTENSIONS = ('.ply', '.obj')


def mesh_type(path: str) -> str:
    """Mitsuba shape plugin name (``ply``/``obj``) for a mesh file, or raise."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_EXTENSIONS:
        raise ValueError(f"{path}: expected a mesh file ending in {' or '.join(MESH_EXTENSIONS)}")
    return ext[1:]


def load_container(path: str) -> trimesh.Trimesh:
    """Load a container mesh and check that it is closed, or raise ``ValueError``."""
    mesh_type(path)
    if not os.path.isfile(path):
        raise ValueError(f"{path}: container mesh file is missing")
    try:
        mesh = trimesh.load(path, force='mesh', process=True)
    except Exception as err:  # trimesh raises many types for corrupt files
        raise ValueError(f"{path}: unreadable container mesh ({err})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: container mesh has no triangles")
    if not mesh.is_watertight:
        raise ValueError(f"{path}: container mesh is not closed (not watertight); "
                         "a container must enclose a volume")
    return mesh


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
