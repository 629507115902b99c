"""A scene for the ``reneus`` integrator, loaded and checked before anything is rendered.

:func:`load_scene` names the file in every error and checks the container
(closed, outward normals, parts apart: :func:`~reneus_mi.geometry.container.check_scene_containers`);
:func:`reneus_integrator` is the one check that a scene renders with ``reneus``;
:func:`check_render_size` and :func:`check_field_reaches` refuse a render or a
reconstruction that cannot work before it starts.
"""
from __future__ import annotations

import os

import mitsuba as mi
import numpy as np

from reneus_mi.geometry.container import check_scene_containers
from reneus_mi.utils import limits
from reneus_mi.utils.errors import ReneusError, user_message

#: Bytes per sample of a render in flight: ray, surface interaction, colour
#: and the integrator's per-lane state. An estimate (not measured) that only
#: has to tell a render that fits from one that cannot.
BYTES_PER_SAMPLE = 512


def load_scene(path: str) -> mi.Scene:
    """``mi.load_file`` with errors that name the file; checks the containers' orientation."""
    if not os.path.isfile(path):
        raise ReneusError(f'{path}: scene file does not exist')
    try:
        scene = mi.load_file(path)
    except Exception as e:  # Mitsuba reports parse and plugin errors as RuntimeError
        message = user_message(e)
        if 'is this a triangle mesh' in message or 'trailing tokens after end of PLY' in message:
            message += (' (Mitsuba reads PLY files of triangles only: export the mesh triangulated, '
                        'or write the scene with python -m reneus_mi.scene, which does)')
        raise ReneusError(f'{path}: cannot load the scene: {message}') from None
    check_scene_containers(scene, path)
    return scene


def reneus_integrator(scene: mi.Scene, where: str):
    """The scene's ``reneus`` integrator; an error naming ``where`` if it has another."""
    integrator = scene.integrator()
    if not hasattr(integrator, 'render_rays'):
        raise ReneusError(f'{where}: the integrator is {type(integrator).__name__}; '
                          'expected <integrator type="reneus">')
    return integrator


def check_render_size(scene: mi.Scene, spp: int, where: str) -> None:
    """Refuse a render whose samples exceed 32-bit indices or the machine's memory."""
    sensor = scene.sensors()[0]
    w, h = sensor.film().crop_size()
    spp = spp or sensor.sampler().sample_count()
    limits.check_index_range(w * h * spp, f'{where}: {w}x{h} pixels at {spp} spp')
    limits.check_memory(w * h * spp * BYTES_PER_SAMPLE, f'{where}: {w}x{h} pixels at {spp} spp')


def check_field_reaches(center, scale: float, lo, hi, where: str) -> None:
    """Refuse a field sphere (``center``, radius ``scale``) that misses the box ``[lo, hi]``.

    The field lives in that sphere and the rays that matter run inside the
    container: if the two do not meet, no ray reaches the field and training
    has nothing to fit.
    """
    c, lo, hi = (np.asarray(v, dtype=np.float64) for v in (center, lo, hi))
    gap = float(np.linalg.norm(np.maximum(lo - c, 0.0) + np.maximum(c - hi, 0.0)))
    if not scale > 0 or gap >= scale:
        raise ReneusError(f'{where}: the field sphere (centre {np.round(c, 4).tolist()}, radius '
                          f'{scale:.4g}) does not meet the container (bounds {np.round(lo, 4).tolist()}'
                          f' .. {np.round(hi, 4).tolist()}), so no ray would reach the field; '
                          'expected field_center/field_scale around the container (python -m '
                          'reneus_mi.scene writes them)')
