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

from reneus_mi.data.cameras import pixel_rays
from reneus_mi.errors import ReneusError
from reneus_mi.geometry.surface import load_container

#: Mesh formats that both trimesh and Mitsuba read.
MESH_EXTENSIONS = ('.ply', '.obj')

__all__ = ['MESH_EXTENSIONS', 'mesh_type', 'load_container', 'bounding_sphere', 'container_masks']


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
