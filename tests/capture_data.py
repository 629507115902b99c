"""The simulated capture the capture tests share (rendered once per session), and Mitsuba's
path tracer on a capture's dataset.

Mitsuba's path tracer renders a glass block (50x35x25 mm) with an insect inside standing on a
12x9 ChArUco board, 16 views at 640x480 on three elevations with four portrait shots, lens
distortion, an off-centre principal point, exposure jitter, noise and JPEG
(:mod:`reneus_mi.capture.simulation`). About 40 s on two cores.
"""
from __future__ import annotations

import json
import os

import numpy as np

from reneus_mi.capture.simulation import Rig, simulate

#: The capture of the tests: the generator's defaults, fewer samples (the noise is the sensor's).
RIG = Rig(spp=16)


def capture(root) -> dict:
    """``{'photos', 'truth', 'meta'}`` of the capture under ``root`` (rendered if missing)."""
    photos, truth = os.path.join(root, 'photos'), os.path.join(root, 'truth')
    if not os.path.isfile(os.path.join(truth, 'truth.json')):
        simulate(RIG, photos, truth)
    with open(os.path.join(truth, 'truth.json')) as f:
        return {'photos': photos, 'truth': truth, 'meta': json.load(f)}


def path_render(xml, ds, view: int, spp: int = 16, specimen: str | None = None, inner: bool = True) -> np.ndarray:
    """``path`` through the dataset's camera ``view``, display values: the backdrop and light of
    the scene ``xml``, the dataset's container shaded as reneus shades it (its crease rule), as
    the simulator rendered it, with its inner interfaces (``inner``) and the diffuse
    ``specimen`` mesh (vertex colours) where given."""
    import mitsuba as mi
    from reneus_mi.data.scene_xml import sensor_dict
    from reneus_mi.geometry.container import shading_mesh
    scene = mi.load_file(str(xml))
    parts = {f'backdrop_{i}': s for i, s in enumerate(scene.shapes()) if s.is_emitter()}
    outside = ds.ior
    parts['container'] = shading_mesh(ds.container, bsdf={'type': 'dielectric', 'int_ior': ds.ior, 'ext_ior': 1.0})
    for i, interface in enumerate(ds.inner if inner else ()):
        parts[f'inner_{i}'] = shading_mesh(interface.mesh, bsdf={'type': 'dielectric', 'int_ior': interface.ior,
                                                                 'ext_ior': outside})
        outside = interface.ior
    if specimen is not None:
        parts['specimen'] = {'type': 'ply', 'filename': str(specimen), 'bsdf': {
            'type': 'diffuse', 'reflectance': {'type': 'mesh_attribute', 'name': 'vertex_color'}}}
    path = mi.load_dict({'type': 'scene', 'integrator': {'type': 'path', 'max_depth': 10},
                         'tent': scene.environment(), **parts})
    sensor = mi.load_dict(sensor_dict(ds.K[view], ds.c2w[view], ds.width, ds.height))
    image = np.array(mi.render(path, sensor=sensor, spp=spp, seed=view))
    return np.clip(image, 0.0, 1.0) ** (1.0 / 2.2)
