"""Reference scenes and shapes shared by the tests: scenes that the reneus integrator and
Mitsuba's path tracer both render (optionally with a printed board under the block), a glass
cube for quick renders, a square for distances, points in a ball."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.geometry.container import absorbing_medium

SPHERE_RADIUS = 0.3
SPHERE_COLOR = (0.9, 0.35, 0.1)
AMBIENT = 0.8


#: Where the glass block stands: rotated 25 degrees about y (its size is its own).
BLOCK_ROTATION = mi.ScalarTransform4f().rotate([0, 1, 0], 25)
#: Half-extents of the glass block.
BLOCK_HALF = (0.55, 0.45, 0.5)


def container(ior=1.45, mesh=None, to_world=None, sigma_a=None):
    """The glass block (Mitsuba's ``cube``: flat faces, rotated and scaled), or the container
    in the mesh file ``mesh`` (one Mitsuba reads: PLY or OBJ) placed by ``to_world``; filled
    with a medium that absorbs ``sigma_a`` (RGB per unit) where given (amber)."""
    bsdf = {'type': 'dielectric', 'int_ior': ior}
    if mesh is not None:
        from reneus_mi.geometry.container import mesh_type
        shape = {'type': mesh_type(mesh), 'filename': str(mesh), 'bsdf': bsdf}
        shape = shape if to_world is None else {**shape, 'to_world': to_world}
    else:
        shape = {'type': 'cube', 'to_world': BLOCK_ROTATION.scale(list(BLOCK_HALF)), 'bsdf': bsdf}
    if sigma_a is not None:
        shape['interior'] = absorbing_medium(sigma_a)
    return shape


#: The board under the block: 12 x 12 cells of white and black print (RGB, linear radiance).
BOARD_CELLS, BOARD_WHITE, BOARD_BLACK = 12, (0.9, 0.85, 0.75), (0.05, 0.04, 0.06)
#: Its half-size, and its gap below the block's bottom face (y = -BLOCK_HALF[1]).
BOARD_HALF, BOARD_GAP = 1.5, 0.01


def board():
    """A printed board under the glass block, facing up (+y): an ``area`` emitter whose radiance
    is a random pattern of white and black cells (a bitmap, bilinear), behind a black BSDF."""
    cells = np.random.default_rng(7).random((BOARD_CELLS, BOARD_CELLS)) < 0.5
    # Each cell 4 texels wide: sharp edges, blurred over a quarter of a cell by the filter.
    cells = np.kron(cells, np.ones((4, 4)))[..., None]
    radiance = np.where(cells, BOARD_WHITE, BOARD_BLACK).astype(np.float32)
    to_world = (mi.ScalarTransform4f().translate([0.0, -BLOCK_HALF[1] - BOARD_GAP, 0.0])
                .rotate([1, 0, 0], -90).scale([BOARD_HALF, BOARD_HALF, 1.0]))
    return {'type': 'rectangle', 'to_world': to_world,
            'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': 0.0}},
            'emitter': {'type': 'area', 'radiance': {'type': 'bitmap', 'bitmap': mi.Bitmap(radiance),
                                                     'raw': True}}}


def sensor(res):
    return {'type': 'perspective', 'fov': 28,
            'to_world': mi.ScalarTransform4f().look_at(origin=[2.2, 1.6, 3.4], target=[0, 0, 0], up=[0, 1, 0]),
            'film': {'type': 'hdrfilm', 'width': res, 'height': res, 'rfilter': {'type': 'box'}}}


def reneus_scene(res=24, ior=1.45, mesh=None, to_world=None, with_board=False, sigma_a=None, shapes=None,
                 **integrator):
    """The reneus scene: the sphere field in the glass block (or in the container ``shapes``, a
    dict of shapes of the scene, as :func:`path_scene` takes them)."""
    settings = {'type': 'reneus', 'gamma': 1.0, **integrator}
    if settings.setdefault('field', 'sphere') == 'sphere':
        settings = {'field_radius': SPHERE_RADIUS, 'field_color': SPHERE_COLOR,
                    'field_inv_s': 4000.0, **settings}
    return mi.load_dict({'type': 'scene', 'integrator': settings, 'sensor': sensor(res),
                         'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': AMBIENT}},
                         **(shapes or {'container': container(ior, mesh, to_world, sigma_a)}),
                         **({'board': board()} if with_board else {})})


def path_scene(res=24, ior=1.45, max_depth=3, mesh=None, with_board=False, sigma_a=None, shapes=None,
               probe_ior=None, volume=False):
    """The same scene for ``path``: the sphere is an emitter behind a black BSDF.

    Its radiance is c·η²: inside glass a path tracer scales radiance by η² at
    each refraction, which the paper's model (and ours) folds into c. With ``sigma_a`` the
    block holds an absorbing medium, which ``volpath`` renders. ``shapes`` replace the block
    (``probe_ior``: the IOR around the sphere; ``volume``: some of them hold a medium).
    """
    eta = (probe_ior or ior) / 1.000277  # Mitsuba's default exterior medium is air
    c = [v * eta * eta for v in SPHERE_COLOR]
    integrator = 'volpath' if sigma_a is not None or volume else 'path'
    return mi.load_dict({'type': 'scene', 'integrator': {'type': integrator, 'max_depth': max_depth},
                         'sensor': sensor(res),
                         'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': AMBIENT}},
                         **(shapes or {'container': container(ior, mesh, sigma_a=sigma_a)}),
                         'sphere': {'type': 'sphere', 'radius': SPHERE_RADIUS,
                                    'bsdf': {'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': 0.0}},
                                    'emitter': {'type': 'area', 'radiance': {'type': 'rgb', 'value': c}}},
                         **({'board': board()} if with_board else {})})


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


def render_derivatives(scene, key: str, index: int, h: float = 2e-3) -> tuple[np.ndarray, np.ndarray]:
    """The derivative of every pixel-centre ray's radiance with respect to entry ``index`` of
    the integrator's array ``key``: forward-mode AD and central differences of step ``h``,
    (3, P) each. The rays keep their pixels; what moves is the scene under them."""
    integrator = scene.integrator()
    ray = pixel_rays(scene)
    array = integrator.params()[key]
    value = np.array(array)
    e = np.zeros_like(value)
    e[index] = 1.0
    dr.enable_grad(array)
    dr.set_grad(array, mi.Float(e))
    L = integrator.render_rays(scene, ray).L
    dr.forward_to(L)
    ad = np.array(dr.grad(L))
    dr.disable_grad(array)
    f = []
    for sign in (1, -1):
        mi.set_property(array, mi.Float(value + sign * h * e))
        f.append(np.array(integrator.render_rays(scene, ray).L))
    mi.set_property(array, mi.Float(value))
    return ad, (f[0] - f[1]) / (2 * h)


def derivatives_agree(ad: np.ndarray, fd: np.ndarray) -> np.ndarray:
    """Where AD and central differences agree; a few rays cross an edge within the step, where
    the difference quotient is not a derivative."""
    return np.abs(ad - fd) < 0.01 + 0.05 * np.abs(fd)


def reneus_pixels(scene) -> np.ndarray:
    result = scene.integrator().render_rays(scene, pixel_rays(scene))
    return np.array(result.L).T


def glass_scene(**integrator):
    """A 3x3 view of a glass cube (IOR 1.45) in ambient 0.8 through ``reneus`` (id ``field``)."""
    return mi.load_dict({
        'type': 'scene', 'integrator': {'type': 'reneus', 'id': 'field', **integrator},
        'sensor': {'type': 'perspective', 'fov': 40,
                   'to_world': mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0]),
                   'film': {'type': 'hdrfilm', 'width': 3, 'height': 3}},
        'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.8}},
        'glass': {'type': 'cube', 'bsdf': {'type': 'dielectric', 'int_ior': 1.45}}})


def square(n=20):
    """The unit square in the z = 0 plane, ``n`` x ``n`` cells of two triangles."""
    t = np.linspace(0.0, 1.0, n + 1)
    x, y = np.meshgrid(t, t, indexing='ij')
    verts = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing='ij')
    v00 = (i * (n + 1) + j).ravel()
    v10, v01, v11 = v00 + n + 1, v00 + 1, v00 + n + 2
    faces = np.concatenate([np.stack([v00, v10, v11], 1), np.stack([v00, v11, v01], 1)])
    return trimesh.Trimesh(verts, faces, process=False)


def ball_points(n, seed, r_min=0.0, r_max=1.0):
    """Points with radii uniform in [r_min, r_max] and uniform directions."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(3, n))
    d /= np.linalg.norm(d, axis=0)
    r = rng.uniform(r_min, r_max, n)
    return mi.Point3f((d * r).astype(np.float32)), r
