"""A small picture of a mesh: what a table of reconstructions shows beside each row.

Mitsuba renders the mesh in a neutral clay (diffuse, 0.6 grey) under a dim
ambient and a key light over the viewer's shoulder, seen from a given
direction (a dataset's first camera, so that the preview looks like its first
photograph) with the mesh filling the frame.
"""
from __future__ import annotations

import os

import mitsuba as mi
import numpy as np

from reneus_mi.geometry.mesh import load_mesh
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_path

#: Vertical field of view of the preview camera (degrees).
FOV = 30.0
#: The mesh's bounding sphere spans the frame's height divided by this.
MARGIN = 1.05


def render_preview(mesh_path: str, out: str, *, direction=(1.0, -1.0, 0.8), up=(0.0, 0.0, 1.0),
                   size: int = 160, spp: int = 16) -> str:
    """Render ``mesh_path`` to the PNG ``out`` (``size`` pixels square), seen along
    ``-direction`` (the camera sits at ``direction`` from the mesh) with ``up`` upwards.

    ==========  ====================================================================
    mesh_path   a triangle mesh Mitsuba reads (.ply, .obj); an empty one is an error
    direction   from the mesh's centre towards the camera (any length)
    up          the image's up direction (any vector not along ``direction``)
    size, spp   image side in pixels, samples per pixel
    ==========  ====================================================================
    """
    mesh = load_mesh(mesh_path)
    lo, hi = mesh.bounds
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    up = np.asarray(up, float)
    if np.linalg.norm(np.cross(d, up)) < 1e-6 * np.linalg.norm(up):
        raise ReneusError(f'preview of {mesh_path}: up={tuple(up)} lies along the view direction')
    distance = radius / np.sin(np.radians(FOV / 2)) * MARGIN
    eye = centre + d * distance
    key = d + np.cross(up, d) / np.linalg.norm(np.cross(up, d)) * 0.6 + up / np.linalg.norm(up) * 0.8
    scene = mi.load_dict({
        'type': 'scene',
        'integrator': {'type': 'direct'},
        'sensor': {'type': 'perspective', 'fov': FOV, 'fov_axis': 'y',
                   'near_clip': max(1e-4, 1e-3 * distance), 'far_clip': 10.0 * distance,
                   'to_world': mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=centre.tolist(),
                                                              up=up.tolist()),
                   'sampler': {'type': 'independent', 'sample_count': spp},
                   'film': {'type': 'hdrfilm', 'width': size, 'height': size, 'pixel_format': 'rgb',
                            'rfilter': {'type': 'gaussian'}}},
        'mesh': {'type': 'ply' if mesh_path.lower().endswith('.ply') else 'obj', 'filename': mesh_path,
                 'face_normals': True,
                 'bsdf': {'type': 'twosided', 'bsdf': {'type': 'diffuse',
                                                       'reflectance': {'type': 'rgb', 'value': 0.6}}}},
        'ambient': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.25}},
        'key': {'type': 'directional', 'direction': (-key / np.linalg.norm(key)).tolist(),
                'irradiance': {'type': 'rgb', 'value': 2.0}},
    })
    image = mi.render(scene, seed=0)
    with atomic_path(out) as tmp:
        mi.util.write_bitmap(tmp, image, write_async=False)
    return os.fspath(out)
