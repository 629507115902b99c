"""Synthetic datasets rendered with Mitsuba's ``path`` integrator (never the ReNeuS model).

The protocol is the paper's (Experiments, Dataset): a Lambertian, textured
object sits at the centre of a solid glass box (dielectric, IOR 1.45) fitted to
it with a margin, everything scaled inside the unit sphere; a constant
environment of 0.8 (linear) lights it; cameras look at the origin from random
points of the sphere of radius 5. Two subsets are rendered with the same
cameras: ``box`` (object in glass) and ``nobox`` (object alone). Both carry the
box masks (pixel-centre rays that hit the box). Images are stored as the
photographs the model is fitted to: ``clip(linear, 0, 1) ** (1 / 2.2)``.

Output of ``make_dataset(obj, DIR)``::

    DIR/gt.ply            object, with linear albedo as the vertex attribute
                          ``vertex_color`` (Mitsuba's name; trimesh reads the geometry)
    DIR/box.ply           the container, as most tools write one: shared vertices, no normals
                          for a box, exact vertex normals for the rounded block and the jar
    DIR/inner.ply         a case's or a jar's inner surface (the air's, the liquid's)
    DIR/box/, DIR/nobox/  Blender format, with scene.xml (reneus_mi.data.scene_xml.write_scene)
    DIR/box_neus/, DIR/nobox_neus/   the same in NeuS format
    DIR/synth.json        settings, spp, max_depth and the measured noise

Command line: ``python -m reneus_mi.synth insect -o DIR --views 60 --res 800`` (:mod:`reneus_mi.synth`).
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import time

import mitsuba as mi
import numpy as np
import trimesh
from tqdm import tqdm

from reneus_mi.data import Dataset, load_dataset, write_dataset
from reneus_mi.data.dataset import Interface
from reneus_mi.data.cameras import focal_from_fov, intrinsics, look_at
from reneus_mi.data.checks import IOR_EXPECTED, valid_ior
from reneus_mi.data.masks import container_masks
from reneus_mi.data.objects import load_object, normalize
from reneus_mi.data.scene_xml import sensor_dict, write_scene
from reneus_mi.geometry.container import container_shape, shading_mesh
from reneus_mi.geometry.mesh import mitsuba_mesh
from reneus_mi.geometry.shapes import CONTAINERS, write_container
from reneus_mi.paper import AMBIENT, GAMMA, IOR
from reneus_mi.geometry.container import absorbing_medium
from reneus_mi.utils import guards, limits
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_folder, atomic_mitsuba_write, atomic_write_text

#: Distance of the cameras from the origin.
CAMERA_DISTANCE = 5.0
#: Samples per pixel: about 0.003 per-pixel noise (display units) inside the
#: box for the insect; each run measures and reports its own (synth.json).
DEFAULT_SPP = 256
#: Path vertices: camera -> glass -> glass -> object -> glass -> glass ->
#: environment needs 6; 12 leaves room for three internal reflections.
DEFAULT_MAX_DEPTH = 12
#: Subsets a dataset can have.
SUBSETS = ('box', 'nobox')
#: Containers as collections hold them, by the shape each is made of: a glass case (a box's
#: walls around air), a jar (a cylinder's glass around a liquid), amber (a block that absorbs).
COLLECTION_SHAPES = {'case': 'box', 'jar': 'cylinder', 'amber': 'box'}
#: Every container the generator makes: the solid shapes and those of collections.
SYNTH_CONTAINERS = CONTAINERS + tuple(COLLECTION_SHAPES)
#: A case's or a jar's glass, as a fraction of the object's largest half-extent.
WALL = 0.1
#: A jar's liquid (ethanol, as wet collections keep specimens).
LIQUID_IOR = 1.36
#: Amber's absorption per unit of the normalised scene: about 74 %, 50 % and 25 % of red, green
#: and blue cross the container.
AMBER = (0.15, 0.35, 0.7)
#: The embedded demo: object, dataset size and preset.
DEMO_OBJECT = 'insect'
DEMO_DATA = {'views': 32, 'res': 64, 'spp': 128}
DEMO_PRESET = 'demo'

# Rays traced per mi.render call: larger renders are split into passes of
# this many lanes, which bounds the memory of one wavefront.
_MAX_LANES = 2**24


def sample_cameras(views: int, res: int, seed: int = 0,
                   distance: float = CAMERA_DISTANCE) -> tuple[np.ndarray, np.ndarray]:
    """Random cameras on the full sphere of ``distance``, looking at the origin.

    Positions are uniform on the sphere (``seed`` fixes them); world z is the
    image's up direction (y near the poles). The field of view is the cone
    tangent to the unit sphere, so the whole scene is in every image. Returns
    ``K`` (N,3,3) and OpenCV ``c2w`` (N,4,4).
    """
    if views < 1 or res < 1:
        raise ReneusError(f"views={views}, res={res}: expected positive numbers")
    if distance <= 1.0:
        raise ReneusError(f"distance={distance}: cameras must be outside the unit sphere")
    rng = np.random.default_rng(seed)
    pos = rng.normal(size=(views, 3))
    pos *= distance / np.linalg.norm(pos, axis=1, keepdims=True)
    # World z is up in the images, except near the poles where it is nearly
    # the viewing direction.
    ups = np.where(np.abs(pos[:, 2:]) > 0.99 * distance, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])
    c2w = np.stack([look_at(p, up=u) for p, u in zip(pos, ups)])
    focal = focal_from_fov(2.0 * np.arcsin(1.0 / distance), res)
    K = np.tile(intrinsics(focal, focal, 0.5 * res, 0.5 * res), (views, 1, 1))
    return K, c2w


def _sensor(K: np.ndarray, c2w: np.ndarray, res: int) -> mi.Sensor:
    """Mitsuba's sensor of an OpenCV camera (:func:`reneus_mi.data.scene_xml.sensor_dict`)."""
    desc = sensor_dict(K, c2w, res, res)
    # Stratified samples: a third of the independent sampler's noise at the
    # same spp inside the glass (measured on the insect at 256 spp).
    desc['sampler'] = {'type': 'multijitter'}
    return mi.load_dict(desc)


def scene_dict(gt_mesh: str, layers: list[Interface], max_depth: int = DEFAULT_MAX_DEPTH, *,
               ambient: float = AMBIENT) -> dict:
    """The Mitsuba scene: object (diffuse, vertex-colour albedo), the container's ``layers``
    (its interfaces, outermost first; none: the object alone), environment.

    The container bends light by the normals the ``reneus`` integrator gives its files
    (:func:`~reneus_mi.geometry.container.shading_mesh`): flat faces stay flat. A layer that
    absorbs holds a medium (amber, a tinted liquid), and ``volpath`` renders the scene."""
    absorbs = any(layer.absorption is not None for layer in layers)
    scene = {
        'type': 'scene',
        # Russian roulette off: it would add noise to exactly the long paths
        # through the glass that the dataset is about.
        'integrator': {'type': 'volpath' if absorbs else 'path', 'max_depth': max_depth,
                       'rr_depth': max_depth},
        'environment': {'type': 'constant',
                        'radiance': {'type': 'rgb', 'value': [ambient] * 3}},
        'object': {'type': 'ply', 'filename': gt_mesh,
                   'bsdf': {'type': 'diffuse', 'reflectance': {
                       'type': 'mesh_attribute', 'name': 'vertex_color'}}},
    }
    outside = 1.0
    for i, layer in enumerate(layers):
        scene[f'container_{i}'] = shading_mesh(
            layer.mesh, bsdf={'type': 'dielectric', 'int_ior': layer.ior, 'ext_ior': outside},
            interior=None if layer.absorption is None else absorbing_medium(layer.absorption))
        outside = layer.ior
    return scene


def render_view(scene: mi.Scene, K: np.ndarray, c2w: np.ndarray, res: int, spp: int,
                seed: int) -> np.ndarray:
    """Linear (res,res,3) float32 image of one camera, at ``spp`` samples per pixel."""
    sensor = _sensor(K, c2w, res)
    passes = max(1, -(-res * res * spp // _MAX_LANES))
    counts = [_stratified(spp // passes + (p < spp % passes)) for p in range(passes)]
    image = np.zeros((res, res, 3), np.float64)
    for p, count in enumerate(counts):
        # Every pass needs its own sample stream; seeds of different calls are
        # kept apart by the caller's stride (see make_dataset).
        img = mi.render(scene, sensor=sensor, spp=count, seed=seed + p)
        image += np.asarray(img, np.float64) * (count / sum(counts))
    return image.astype(np.float32)


def _stratified(spp: int) -> int:
    """The sample count the multijitter sampler takes for ``spp``: an x by y grid of strata,
    x = ceil(sqrt(spp)) (it would round up to it, with a warning per view)."""
    x = math.ceil(math.sqrt(spp))
    return x * math.ceil(spp / x)


def encode(linear: np.ndarray) -> np.ndarray:
    """Display values of linear radiance: ``clip(x, 0, 1) ** (1 / 2.2)``, float32."""
    return (np.clip(linear, 0.0, 1.0) ** (1.0 / GAMMA)).astype(np.float32)


def write_object(mesh: trimesh.Trimesh, path: str) -> None:
    """Write ``mesh`` as a PLY with its linear albedo in Mitsuba's ``vertex_color``."""
    # Vertex colours are display values (like a photograph of the material).
    albedo = (np.asarray(mesh.visual.vertex_colors[:, :3], np.float64) / 255.0) ** GAMMA
    shape = mitsuba_mesh(mesh.vertices, mesh.faces, 'object', normals='recompute')
    shape.add_attribute('vertex_color', 3, mi.Float(albedo.astype(np.float32).ravel()))
    atomic_mitsuba_write(path, shape.write_ply)


def _noise(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Per-image noise std from two independent renders: std(a - b) / sqrt(2)."""
    diff = (a - b)[mask] if mask.any() else (a - b).reshape(-1, 3)
    return float(np.std(diff) / np.sqrt(2.0))


def make_dataset(obj, out_dir: str, *, views: int = 60, res: int = 800, spp: int = DEFAULT_SPP,
                 seed: int = 0, max_depth: int = DEFAULT_MAX_DEPTH, subsets=SUBSETS,
                 margin: float = 0.15, container: str = 'box', ior: float = IOR,
                 ambient: float = AMBIENT, absorption=None, wall: float = WALL,
                 liquid_ior: float = LIQUID_IOR, write: bool = True) -> dict:
    """Render a synthetic dataset of ``obj`` into ``out_dir``.

    ``obj`` is a name of :data:`reneus_mi.data.objects.OBJECTS`, a mesh file or a
    :class:`trimesh.Trimesh` with vertex colours; it is centred and scaled with
    its container by :func:`reneus_mi.data.objects.normalize` (``margin``,
    ``container``: a solid ``box``, ``rounded`` block or ``cylinder``; or a glass ``case``
    around air, a ``jar`` of liquid of IOR ``liquid_ior``, whose glass is ``wall`` thick
    (a fraction of the object's largest half-extent), an ``amber`` block). The glass has IOR
    ``ior``; the medium around the object absorbs ``absorption`` (RGB per unit of the
    normalised scene, whose container is about 2 across; None: clear, :data:`AMBER` for
    amber), the environment radiance ``ambient``. ``seed`` fixes
    the cameras and the sample streams. ``gt.ply``, ``box.ply`` and
    ``synth.json`` are always written; with ``write`` each subset is written in
    the Blender and NeuS formats with a scene XML (see the module docstring).

    Returns a dict: ``images`` ({subset: (N,H,W,3) float32, display values}),
    ``masks`` (N,H,W), ``K``, ``c2w``, ``gt_mesh``, ``container``, ``paths``
    ({subset: {format: folder}}), ``spp``, ``max_depth``, ``noise`` (per-pixel
    std of one image inside the box mask, display units, from two renders of
    view 0 of the first subset) and ``seconds``.
    """
    subsets = tuple(subsets)
    if not subsets or any(s not in SUBSETS for s in subsets) or len(set(subsets)) != len(subsets):
        raise ReneusError(f"subsets={subsets!r}: expected distinct names among {SUBSETS}")
    for name, value in (('spp', spp), ('max_depth', max_depth)):
        if int(value) != value or value < 1:
            raise ReneusError(f"{name}={value!r}: expected a positive integer")
    if not margin >= 0:
        raise ReneusError(f"margin={margin!r}: expected a number >= 0")
    if not valid_ior(ior):
        raise ReneusError(f"ior={ior!r}: expected {IOR_EXPECTED}")
    if not ambient > 0:
        raise ReneusError(f"ambient={ambient!r}: expected a positive radiance")
    if absorption is not None:
        absorption = np.broadcast_to(np.asarray(absorption, np.float64), (3,)).copy()
        if not np.all(np.isfinite(absorption) & (absorption >= 0)):
            raise ReneusError(f"absorption={absorption.tolist()}: expected numbers >= 0 (per unit)")
    start = time.perf_counter()
    K, c2w = sample_cameras(views, res, seed)
    # Every check comes before the first write: a refused run leaves the
    # folder as it found it.
    out_dir = guards.check_output_dir(out_dir, what='synth output folder')
    limits.check_memory(dataset_bytes(views, res, len(subsets)),
                        f'{views} views at {res}x{res}, {len(subsets)} subset(s)')
    mesh = obj.copy() if isinstance(obj, trimesh.Trimesh) else load_object(obj)
    if mesh.visual.kind != 'vertex':
        raise ReneusError("object mesh: expected per-vertex colours (mesh.visual.vertex_colors)")
    if container not in SYNTH_CONTAINERS:
        raise ReneusError(f"container={container!r}: expected one of {', '.join(SYNTH_CONTAINERS)}")
    shape = COLLECTION_SHAPES.get(container, container)
    walled = container in ('case', 'jar')
    if container == 'amber' and absorption is None:
        absorption = np.array(AMBER)
    mesh, box, inside = normalize(mesh, margin=margin, container=shape, wall=wall if walled else 0.0)

    # Made in a temporary folder that becomes out_dir once whole: an interrupted or failed
    # run leaves nothing behind, and the same command starts it again.
    with atomic_folder(out_dir) as work:
        layers = [Interface(os.path.join(work, 'box.ply'), ior, None if walled else absorption)]
        write_container(box, layers[0].mesh, normals=shape != 'box')
        if walled:
            layers.append(Interface(os.path.join(work, 'inner.ply'), 1.0 if container == 'case' else liquid_ior,
                                absorption))
            write_container(inside, layers[1].mesh, normals=shape != 'box')
        rendered = _render(work, mesh, layers, K, c2w, res=res, spp=spp, seed=seed, max_depth=max_depth,
                           subsets=subsets, ambient=ambient)
        images, masks, gt_path, noise = rendered
        paths = _write_subsets(images, masks, K, c2w, gt_path, layers, work, out_dir, ambient) if write else {}
        meta = {'object': 'trimesh' if isinstance(obj, trimesh.Trimesh) else os.fspath(obj),
                'views': views, 'res': res, 'spp': spp, 'max_depth': max_depth, 'seed': seed,
                'margin': margin, 'container': container, 'ior': ior, 'environment': ambient,
                'absorption': None if absorption is None else absorption.tolist(),
                'wall': wall if walled else None, 'liquid_ior': liquid_ior if container == 'jar' else None,
                'gamma': GAMMA, 'camera_distance': CAMERA_DISTANCE, 'noise_std_display': noise,
                'subsets': list(subsets), 'seconds': time.perf_counter() - start,
                'paths': {sub: {fmt: os.path.relpath(folder, out_dir) for fmt, folder in p.items()}
                          for sub, p in paths.items()}}
        atomic_write_text(os.path.join(work, 'synth.json'), json.dumps(meta, indent=2))
    return {'images': images, 'masks': masks, 'K': K, 'c2w': c2w,
            'gt_mesh': os.path.join(out_dir, 'gt.ply'), 'container': os.path.join(out_dir, 'box.ply'),
            'paths': paths, 'spp': spp, 'max_depth': max_depth, 'noise': noise,
            'seconds': meta['seconds']}


def _render(folder, mesh, layers, K, c2w, *, res, spp, seed, max_depth, subsets, ambient):
    """Write the object into ``folder`` and render every subset through the container's
    ``layers``: the display images by subset, the container's masks, the object's file and the
    noise of one image."""
    views = len(K)
    gt_path = os.path.join(folder, 'gt.ply')
    write_object(mesh, gt_path)

    masks = container_masks(layers[0].mesh, K, c2w, res, res)
    # Seeds of renders are spaced by this stride so that no two renders (views,
    # passes, subsets, the noise probe) share a sample stream.
    stride = max(1, -(-res * res * spp // _MAX_LANES))
    base = seed * (len(SUBSETS) + 1) * (views + 1) * stride
    images, noise = {}, None
    for s, subset in enumerate(subsets):
        scene = mi.load_dict(scene_dict(gt_path, layers if subset == 'box' else [], max_depth, ambient=ambient))
        first = base + s * (views + 1) * stride
        linear = [render_view(scene, K[v], c2w[v], res, spp, first + v * stride)
                  for v in tqdm(range(views), desc=f'render {subset}', unit='view', disable=None)]
        images[subset] = encode(np.stack(linear))
        if noise is None:
            again = encode(render_view(scene, K[0], c2w[0], res, spp, first + views * stride))
            noise = _noise(images[subset][0], again, masks[0])
    return images, masks, gt_path, noise


def miscalibrated(ds: Dataset, folder: str, *, ior: float | None = None, inner_ior: float | None = None,
                  absorption=None, offset=None, scale: float | None = None) -> Dataset:
    """``ds`` as a calibration would leave it: the container's IOR taken as ``ior``, the IOR
    inside its innermost interface (a jar's liquid) as ``inner_ior``, its medium's
    absorption as ``absorption`` (RGB per unit), or the
    container shifted by ``offset`` (a fraction of its largest extent, per axis) and scaled
    by ``scale`` about its centre (written to ``folder/container_miscalibrated.ply``). The
    photographs and masks stay the truth; refinement should find its way back to it.

    The data stays as it was made: ``folder`` may not be the dataset's own folder, and the
    mesh may not replace one of its inputs."""
    target = guards.check_output_file(os.path.join(folder, 'container_miscalibrated.ply'),
                                      inputs=[p for p in (ds.root, ds.container) if p],
                                      overwrite=True, what='miscalibrated container')
    out = dataclasses.replace(ds)
    if ior is not None:
        out.ior = ior
    if inner_ior is not None:
        out.inner = (*ds.inner[:-1], dataclasses.replace(ds.inner[-1], ior=inner_ior))
    if absorption is not None:
        out.absorption = np.broadcast_to(np.asarray(absorption, np.float64), (3,)).copy()
    if offset is not None or scale is not None:
        # The file moved as Mitsuba reads it, normals included: the crease rule reads the
        # copy as it read the original.
        shape = container_shape(ds.container)
        params = mi.traverse(shape)
        v = np.array(params['vertex_positions'], np.float64).reshape(-1, 3)
        lo, hi = v.min(axis=0), v.max(axis=0)
        s = 1.0 if scale is None else scale
        shift = np.asarray(offset if offset is not None else (0, 0, 0)) * (hi - lo).max()
        # A uniform scale and a shift leave the normals as they were.
        params['vertex_positions'] = mi.Float(((v - 0.5 * (lo + hi)) * s + 0.5 * (lo + hi) + shift)
                                              .astype(np.float32).ravel())
        params.update()
        out.container = target
        atomic_mitsuba_write(target, shape.write_ply)
    return out


def dataset_bytes(views: int, res: int, subsets: int) -> int:
    """Memory a dataset holds while it is made: linear float32 renders and float64
    accumulators of one view, display images and masks of every view, and the
    read-back for the scene writer."""
    pixels = views * res * res
    return pixels * (subsets * (3 * 4 * 3) + 1) + res * res * (3 * 8 + 3 * 4)


def _write_subsets(images, masks, K, c2w, gt_path, layers, folder, out_dir, ambient) -> dict:
    """Write every subset in both formats, plus its scene XML, into ``folder`` (which becomes
    ``out_dir``); return the subsets' folders as they will be."""
    paths = {}
    for subset, imgs in images.items():
        # The nobox subset keeps the box masks but has no interface to model.
        with_box = subset == 'box'
        ds = Dataset(images=imgs, masks=masks, K=K, c2w=c2w,
                     names=[f'r_{i:03d}' for i in range(len(imgs))],
                     root=os.path.join(folder, subset),
                     container=layers[0].mesh if with_box else None, ior=layers[0].ior if with_box else None,
                     absorption=layers[0].absorption if with_box else None,
                     inner=tuple(layers[1:]) if with_box else (),
                     gt_mesh=gt_path, scale_mat=np.eye(4))
        paths[subset] = {'blender': os.path.join(out_dir, subset),
                         'neus': os.path.join(out_dir, f'{subset}_neus')}
        for fmt, final in paths[subset].items():
            write_dataset(ds, os.path.join(folder, os.path.basename(final)), fmt)
        # Read back, the dataset names the meshes copied into its folder: the scene then
        # refers to nothing outside it, and names the dataset where it will be.
        written = load_dataset(os.path.join(folder, subset), need_container=with_box)
        write_scene(dataclasses.replace(written, root=paths[subset]['blender']),
                    os.path.join(folder, subset, 'scene.xml'), ambient=ambient)
    return paths


def demo_scene(folder: str, *, mode: str = 'reneus') -> str:
    """Render the demo dataset into ``folder`` (once) and return its scene XML."""
    data = os.path.join(folder, 'box')
    if not os.path.isfile(os.path.join(data, 'transforms.json')):
        print(f'rendering the demo dataset ({DEMO_OBJECT}, {DEMO_DATA["views"]} views) into {folder}')
        make_dataset(DEMO_OBJECT, folder, subsets=('box',), **DEMO_DATA)
    scene = os.path.join(folder, f'scene_{mode}.xml')
    write_scene(load_dataset(data), scene, preset=DEMO_PRESET, mode=mode)
    return scene
