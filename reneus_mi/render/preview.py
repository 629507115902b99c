"""A small picture of a mesh: what a table of reconstructions shows beside each row.

Mitsuba renders the mesh in a neutral clay (diffuse, 0.6 grey) under a dim
ambient and a key light over the viewer's shoulder, seen from a given
direction (a dataset's first camera, so that the preview looks like its first
photograph) with the mesh filling the frame. Seen by a dataset's camera through its
container (:func:`render_view` with ``through``), Mitsuba's path tracer renders the clay
inside the container's glass under the ambient alone: refracted as the photograph shows
the specimen, at the same place and size.
"""
from __future__ import annotations

import os

import mitsuba as mi
import numpy as np

from reneus_mi.data.scene_xml import sensor_dict
from reneus_mi.geometry.container import shading_mesh
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
    sensor = {'type': 'perspective', 'fov': FOV, 'fov_axis': 'y',
              'near_clip': max(1e-4, 1e-3 * distance), 'far_clip': 10.0 * distance,
              'to_world': mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=centre.tolist(),
                                                         up=up.tolist()),
              'film': {'type': 'hdrfilm', 'width': size, 'height': size}}
    return _render(mesh_path, out, sensor, d, up, spp)


#: Light paths through a container (its glass in front of and behind the specimen, a case's
#: or a jar's inner faces), the ambient that lights the clay there and the clay's albedo (darker
#: than the preview's: lit by the ambient alone, it stands out against it).
THROUGH_DEPTH, THROUGH_AMBIENT, THROUGH_CLAY = 16, 0.8, 0.3


def render_view(mesh_path: str, out: str, K: np.ndarray, c2w: np.ndarray, size: tuple[int, int],
                spp: int = 16, through: list[tuple[str, float]] = ()) -> str:
    """Render ``mesh_path`` to the PNG ``out`` as a dataset's camera (``K``, ``c2w`` with
    OpenCV axes, an image of ``size``) sees it: the model beside the photograph of that view.
    ``through``: the container's interfaces, outermost first, as (mesh file, IOR inside it):
    the model is then seen through them, as the photograph sees the specimen."""
    sensor = sensor_dict(np.asarray(K, float), np.asarray(c2w, float), *map(int, size))
    if not through:
        return _render(mesh_path, out, sensor, np.asarray(c2w[:3, 2], float) * -1.0,
                       np.asarray(c2w[:3, 1], float) * -1.0, spp)
    scene = {'type': 'scene', 'integrator': {'type': 'path', 'max_depth': THROUGH_DEPTH, 'rr_depth': THROUGH_DEPTH},
             'sensor': {**sensor, 'sampler': {'type': 'independent', 'sample_count': spp},
                        'film': {**sensor['film'], 'pixel_format': 'rgb', 'rfilter': {'type': 'gaussian'}}},
             'mesh': _clay(mesh_path, THROUGH_CLAY),
             'ambient': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': THROUGH_AMBIENT}}}
    outside = 1.0
    for i, (interface, ior) in enumerate(through):
        scene[f'interface_{i}'] = shading_mesh(interface, bsdf={'type': 'dielectric', 'int_ior': float(ior),
                                                                'ext_ior': outside})
        outside = float(ior)
    return _write(mi.render(mi.load_dict(scene), seed=0), out)


def _clay(mesh_path: str, albedo: float = 0.6) -> dict:
    return {'type': 'ply' if mesh_path.lower().endswith('.ply') else 'obj', 'filename': mesh_path,
            'face_normals': True,
            'bsdf': {'type': 'twosided', 'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': albedo}}}}


def _write(image, out: str) -> str:
    with atomic_path(out) as tmp:
        mi.util.write_bitmap(tmp, image, write_async=False)
    return os.fspath(out)


def _render(mesh_path: str, out: str, sensor: dict, d: np.ndarray, up: np.ndarray, spp: int) -> str:
    """The clay mesh seen by ``sensor`` (looking along ``-d``, ``up`` upwards), lit from over
    the viewer's shoulder, to the PNG ``out``."""
    d, up = d / np.linalg.norm(d), up / np.linalg.norm(up)
    key = d + np.cross(up, d) / np.linalg.norm(np.cross(up, d)) * 0.6 + up * 0.8
    sensor = {**sensor, 'sampler': {'type': 'independent', 'sample_count': spp},
              'film': {**sensor['film'], 'pixel_format': 'rgb', 'rfilter': {'type': 'gaussian'}}}
    scene = mi.load_dict({
        'type': 'scene',
        'integrator': {'type': 'direct'},
        'sensor': sensor,
        'mesh': _clay(mesh_path),
        'ambient': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.25}},
        'key': {'type': 'directional', 'direction': (-key / np.linalg.norm(key)).tolist(),
                'irradiance': {'type': 'rgb', 'value': 2.0}},
    })
    return _write(mi.render(scene, seed=0), out)
