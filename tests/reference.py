"""Shared scene builders for comparing the reneus integrator with Mitsuba's path tracer."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

SPHERE_RADIUS = 0.3
SPHERE_COLOR = (0.9, 0.35, 0.1)
AMBIENT = 0.8


#: Where the glass block stands: rotated 25 degrees about y (its size is its own).
BLOCK_ROTATION = mi.ScalarTransform4f().rotate([0, 1, 0], 25)
#: Half-extents of the glass block.
BLOCK_HALF = (0.55, 0.45, 0.5)


def container(ior=1.45, mesh=None, to_world=None):
    """The glass block (Mitsuba's ``cube``: flat faces, rotated and scaled), or the container
    in the mesh file ``mesh`` (PLY or OBJ) placed by ``to_world``."""
    bsdf = {'type': 'dielectric', 'int_ior': ior}
    if mesh is not None:
        from reneus_mi.data.container import mesh_type
        shape = {'type': mesh_type(mesh), 'filename': str(mesh), 'bsdf': bsdf}
        return shape if to_world is None else {**shape, 'to_world': to_world}
    return {'type': 'cube', 'to_world': BLOCK_ROTATION.scale(list(BLOCK_HALF)), 'bsdf': bsdf}


def sensor(res):
    return {'type': 'perspective', 'fov': 28,
            'to_world': mi.ScalarTransform4f().look_at(origin=[2.2, 1.6, 3.4], target=[0, 0, 0], up=[0, 1, 0]),
            'film': {'type': 'hdrfilm', 'width': res, 'height': res, 'rfilter': {'type': 'box'}}}


def reneus_scene(res=24, ior=1.45, mesh=None, to_world=None, **integrator):
    settings = {'type': 'reneus', 'gamma': 1.0, **integrator}
    if settings.setdefault('field', 'sphere') == 'sphere':
        settings = {'field_radius': SPHERE_RADIUS, 'field_color': SPHERE_COLOR,
                    'field_inv_s': 4000.0, **settings}
    return mi.load_dict({'type': 'scene', 'integrator': settings, 'sensor': sensor(res),
                         'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': AMBIENT}},
                         'container': container(ior, mesh, to_world)})


def path_scene(res=24, ior=1.45, max_depth=3, mesh=None):
    """The same scene for ``path``: the sphere is an emitter behind a black BSDF.

    Its radiance is c·η²: inside glass a path tracer scales radiance by η² at
    each refraction, which the paper's model (and ours) folds into c.
    """
    eta = ior / 1.000277  # Mitsuba's default exterior medium is air
    c = [v * eta * eta for v in SPHERE_COLOR]
    return mi.load_dict({'type': 'scene', 'integrator': {'type': 'path', 'max_depth': max_depth},
                         'sensor': sensor(res),
                         'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': AMBIENT}},
                         'container': container(ior, mesh),
                         'sphere': {'type': 'sphere', 'radius': SPHERE_RADIUS,
                                    'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': 0.0}},
                                    'emitter': {'type': 'area', 'radiance': {'type': 'rgb', 'value': c}}}})


def pixel_rays(scene) -> mi.Ray3f:
    """One ray through the centre of every pixel of the scene's sensor (row-major)."""
    s = scene.sensors()[0]
    w, h = s.film().size()
    idx = dr.arange(mi.UInt32, w * h)
    pos = mi.Vector2f(mi.Float(idx % w) + 0.5, mi.Float(idx // w) + 0.5) / mi.ScalarVector2f(w, h)
    ray, _ = s.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    return ray


def path_reference(scene, spp: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error of ``path`` along the pixel-centre rays: (P, 3) each."""
    ray = pixel_rays(scene)
    n = dr.width(ray.o)
    ray_all = mi.Ray3f(dr.repeat(ray.o, spp), dr.repeat(ray.d, spp))
    sampler = mi.load_dict({'type': 'independent'})
    sampler.seed(seed, n * spp)
    L, _, _ = scene.integrator().sample(scene, sampler, ray_all)
    L = np.array(L).T.reshape(n, spp, 3)
    return L.mean(axis=1), L.std(axis=1) / np.sqrt(spp)


def reneus_pixels(scene) -> np.ndarray:
    result = scene.integrator().render_rays(scene, pixel_rays(scene))
    return np.array(result.L).T
