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
    DIR/box/, DIR/nobox/  Blender format, with scene.xml (reneus_mi.scene.write_scene)
    DIR/box_neus/, DIR/nobox_neus/   the same in NeuS format
    DIR/synth.json        settings, spp, max_depth and the measured noise

Command line: ``python -m reneus_mi.synth insect -o DIR --views 60 --res 800``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import mitsuba as mi
import numpy as np
import trimesh
from tqdm import tqdm

from reneus_mi import guards
from reneus_mi.data import Dataset, load_dataset, write_dataset
from reneus_mi.data.cameras import focal_from_fov, intrinsics, look_at
from reneus_mi.data.container import container_masks, container_shape, shading_mesh
from reneus_mi.errors import ReneusError, exit_on_error
from reneus_mi.io import atomic_export, atomic_path, atomic_write_text
from reneus_mi.objects import CONTAINERS, OBJECTS, load_object, normalize
from reneus_mi.scene import sensor_dict, write_scene

#: Index of refraction of the glass box.
IOR = 1.45
#: Radiance of the constant environment (linear, every channel).
ENVIRONMENT = 0.8
#: Exponent of the display encoding of the stored images.
GAMMA = 2.2
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
    """Mitsuba's sensor of an OpenCV camera (:func:`reneus_mi.scene.sensor_dict`)."""
    desc = sensor_dict(K, c2w, res, res)
    # Stratified samples: a third of the independent sampler's noise at the
    # same spp inside the glass (measured on the insect at 256 spp).
    desc['sampler'] = {'type': 'multijitter'}
    return mi.load_dict(desc)


def scene_dict(gt_mesh: str, box_mesh: str | None, max_depth: int = DEFAULT_MAX_DEPTH, *,
               ior: float = IOR, ambient: float = ENVIRONMENT) -> dict:
    """The Mitsuba scene: object (diffuse, vertex-colour albedo), glass container, environment.

    The container bends light by the normals the ``reneus`` integrator gives its file
    (:func:`~reneus_mi.data.container.shading_mesh`): flat faces stay flat."""
    scene = {
        'type': 'scene',
        # Russian roulette off: it would add noise to exactly the long paths
        # through the glass that the dataset is about.
        'integrator': {'type': 'path', 'max_depth': max_depth, 'rr_depth': max_depth},
        'environment': {'type': 'constant',
                        'radiance': {'type': 'rgb', 'value': [ambient] * 3}},
        'object': {'type': 'ply', 'filename': gt_mesh,
                   'bsdf': {'type': 'diffuse', 'reflectance': {
                       'type': 'mesh_attribute', 'name': 'vertex_color'}}},
    }
    if box_mesh is not None:
        scene['box'] = shading_mesh(box_mesh, bsdf={'type': 'dielectric', 'int_ior': ior, 'ext_ior': 1.0})
    return scene


def render_view(scene: mi.Scene, K: np.ndarray, c2w: np.ndarray, res: int, spp: int,
                seed: int) -> np.ndarray:
    """Linear (res,res,3) float32 image of one camera, at ``spp`` samples per pixel."""
    sensor = _sensor(K, c2w, res)
    passes = max(1, -(-res * res * spp // _MAX_LANES))
    counts = [spp // passes + (p < spp % passes) for p in range(passes)]
    image = np.zeros((res, res, 3), np.float64)
    for p, count in enumerate(counts):
        # Every pass needs its own sample stream; seeds of different calls are
        # kept apart by the caller's stride (see make_dataset).
        img = mi.render(scene, sensor=sensor, spp=count, seed=seed + p)
        image += np.asarray(img, np.float64) * (count / spp)
    return image.astype(np.float32)


def encode(linear: np.ndarray) -> np.ndarray:
    """Display values of linear radiance: ``clip(x, 0, 1) ** (1 / 2.2)``, float32."""
    return (np.clip(linear, 0.0, 1.0) ** (1.0 / GAMMA)).astype(np.float32)


def write_object(mesh: trimesh.Trimesh, path: str) -> None:
    """Write ``mesh`` as a PLY with its linear albedo in Mitsuba's ``vertex_color``."""
    vertices = np.asarray(mesh.vertices, np.float32)
    faces = np.asarray(mesh.faces, np.uint32)
    # Vertex colours are display values (like a photograph of the material).
    albedo = (np.asarray(mesh.visual.vertex_colors[:, :3], np.float64) / 255.0) ** GAMMA
    shape = mi.Mesh('object', len(vertices), len(faces), has_vertex_normals=True)
    params = mi.traverse(shape)
    params['vertex_positions'] = mi.Float(vertices.ravel())
    params['faces'] = mi.UInt32(faces.ravel())
    params.update()
    shape.recompute_vertex_normals()
    shape.add_attribute('vertex_color', 3, mi.Float(albedo.astype(np.float32).ravel()))
    with atomic_path(path) as tmp:
        shape.write_ply(tmp)


def write_container(container: trimesh.Trimesh, path: str, normals: bool) -> None:
    """Write the container as most tools write one: shared vertices, and its vertex
    normals where it has exact ones (the smooth containers); a box carries none (the
    crease rule of :mod:`reneus_mi.data.container` keeps its faces flat)."""
    data = trimesh.exchange.ply.export_ply(container, vertex_normal=normals)
    with atomic_path(path) as tmp, open(tmp, 'wb') as f:
        f.write(data)
    if normals and not np.allclose(trimesh.load(path, process=False).vertex_normals,
                                   container.vertex_normals, atol=1e-5):
        raise ReneusError(f'{path}: the vertex normals did not survive writing')


def _noise(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """Per-image noise std from two independent renders: std(a - b) / sqrt(2)."""
    diff = (a - b)[mask] if mask.any() else (a - b).reshape(-1, 3)
    return float(np.std(diff) / np.sqrt(2.0))


def make_dataset(obj, out_dir: str, *, views: int = 60, res: int = 800, spp: int = DEFAULT_SPP,
                 seed: int = 0, max_depth: int = DEFAULT_MAX_DEPTH, subsets=SUBSETS,
                 margin: float = 0.15, container: str = 'box', ior: float = IOR,
                 ambient: float = ENVIRONMENT, write: bool = True) -> dict:
    """Render a synthetic dataset of ``obj`` into ``out_dir``.

    ``obj`` is a name of :data:`reneus_mi.objects.OBJECTS`, a mesh file or a
    :class:`trimesh.Trimesh` with vertex colours; it is centred and scaled with
    its container by :func:`reneus_mi.objects.normalize` (``margin``,
    ``container``: ``box``, ``rounded`` or ``cylinder``). The glass has IOR
    ``ior``, the environment radiance ``ambient``. ``seed`` fixes
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
    if not 1.0 < ior <= 3.0:
        raise ReneusError(f"ior={ior!r}: expected a number in (1, 3]")
    if not ambient > 0:
        raise ReneusError(f"ambient={ambient!r}: expected a positive radiance")
    start = time.perf_counter()
    K, c2w = sample_cameras(views, res, seed)
    # Every check comes before the first write: a refused run leaves the
    # folder as it found it.
    out_dir = guards.check_output_dir(out_dir, what='synth output folder')
    guards.check_memory(dataset_bytes(views, res, len(subsets)),
                        f'{views} views at {res}x{res}, {len(subsets)} subset(s)')
    mesh = obj.copy() if isinstance(obj, trimesh.Trimesh) else load_object(obj)
    if mesh.visual.kind != 'vertex':
        raise ReneusError("object mesh: expected per-vertex colours (mesh.visual.vertex_colors)")
    mesh, box = normalize(mesh, margin=margin, container=container)

    os.makedirs(out_dir, exist_ok=True)
    gt_path, box_path = os.path.join(out_dir, 'gt.ply'), os.path.join(out_dir, 'box.ply')
    write_object(mesh, gt_path)
    write_container(box, box_path, normals=container != 'box')

    masks = container_masks(box_path, K, c2w, res, res)
    # Seeds of renders are spaced by this stride so that no two renders (views,
    # passes, subsets, the noise probe) share a sample stream.
    stride = max(1, -(-res * res * spp // _MAX_LANES))
    base = seed * (len(SUBSETS) + 1) * (views + 1) * stride
    images, noise = {}, None
    for s, subset in enumerate(subsets):
        scene = mi.load_dict(scene_dict(gt_path, box_path if subset == 'box' else None, max_depth,
                                        ior=ior, ambient=ambient))
        first = base + s * (views + 1) * stride
        linear = [render_view(scene, K[v], c2w[v], res, spp, first + v * stride)
                  for v in tqdm(range(views), desc=f'render {subset}', unit='view', disable=None)]
        images[subset] = encode(np.stack(linear))
        if noise is None:
            again = encode(render_view(scene, K[0], c2w[0], res, spp, first + views * stride))
            noise = _noise(images[subset][0], again, masks[0])

    paths = {}
    if write:
        paths = _write_subsets(images, masks, K, c2w, out_dir, gt_path, box_path, ior, ambient)
    result = {'images': images, 'masks': masks, 'K': K, 'c2w': c2w, 'gt_mesh': gt_path,
              'container': box_path, 'paths': paths, 'spp': spp, 'max_depth': max_depth,
              'noise': noise, 'seconds': time.perf_counter() - start}
    meta = {'object': 'trimesh' if isinstance(obj, trimesh.Trimesh) else os.fspath(obj),
            'views': views, 'res': res, 'spp': spp, 'max_depth': max_depth, 'seed': seed,
            'margin': margin, 'container': container, 'ior': ior, 'environment': ambient, 'gamma': GAMMA,
            'camera_distance': CAMERA_DISTANCE, 'noise_std_display': noise,
            'subsets': list(subsets), 'seconds': result['seconds'],
            'paths': {sub: {fmt: os.path.relpath(folder, out_dir) for fmt, folder in p.items()}
                      for sub, p in paths.items()}}
    atomic_write_text(os.path.join(out_dir, 'synth.json'), json.dumps(meta, indent=2))
    return result


def miscalibrated(ds: Dataset, folder: str, *, ior: float | None = None, offset=None,
                  scale: float | None = None) -> Dataset:
    """``ds`` as a calibration would leave it: the container's IOR taken as ``ior``, or the
    container shifted by ``offset`` (a fraction of its largest extent, per axis) and scaled
    by ``scale`` about its centre (written to ``folder/container_miscalibrated.ply``). The
    photographs and masks stay the truth; refinement should find its way back to it.

    The data stays as it was made: ``folder`` may not be the dataset's own folder, and the
    mesh may not replace one of its inputs."""
    import dataclasses
    target = guards.check_output_file(os.path.join(folder, 'container_miscalibrated.ply'),
                                      inputs=[p for p in (ds.root, ds.container) if p],
                                      overwrite=True, what='miscalibrated container')
    out = dataclasses.replace(ds)
    if ior is not None:
        out.ior = ior
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
        with atomic_path(target) as tmp:
            shape.write_ply(tmp)
    return out


def dataset_bytes(views: int, res: int, subsets: int) -> int:
    """Memory a dataset holds while it is made: linear float32 renders and float64
    accumulators of one view, display images and masks of every view, and the
    read-back for the scene writer."""
    pixels = views * res * res
    return pixels * (subsets * (3 * 4 * 3) + 1) + res * res * (3 * 8 + 3 * 4)


def _write_subsets(images, masks, K, c2w, out_dir, gt_path, box_path, ior, ambient) -> dict:
    """Write every subset in both formats, plus its scene XML; return the folders."""
    paths = {}
    for subset, imgs in images.items():
        # The nobox subset keeps the box masks but has no interface to model.
        with_box = subset == 'box'
        ds = Dataset(images=imgs, masks=masks, K=K, c2w=c2w,
                     names=[f'r_{i:03d}' for i in range(len(imgs))],
                     root=os.path.join(out_dir, subset),
                     container=box_path if with_box else None, ior=ior if with_box else None,
                     gt_mesh=gt_path, scale_mat=np.eye(4))
        paths[subset] = {'blender': os.path.join(out_dir, subset),
                         'neus': os.path.join(out_dir, f'{subset}_neus')}
        for fmt, folder in paths[subset].items():
            write_dataset(ds, folder, fmt)
        # Read back, the dataset names the meshes copied into its folder:
        # the scene then refers to nothing outside it.
        folder = paths[subset]['blender']
        write_scene(load_dataset(folder, need_container=with_box),
                    os.path.join(folder, 'scene.xml'), ambient=ambient)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m reneus_mi.synth',
        description='Render a synthetic ReNeuS dataset (object in a glass box, and without '
                    "the box) with Mitsuba's path tracer.")
    parser.add_argument('object', help=f"object name ({', '.join(OBJECTS)}) or a mesh file "
                                       "readable by trimesh (centred and scaled like the others)")
    parser.add_argument('-o', '--out', required=True, help='output folder')
    parser.add_argument('--views', type=int, default=60, help='number of views (default 60)')
    parser.add_argument('--res', type=int, default=800,
                        help='image width and height in pixels (default 800)')
    parser.add_argument('--spp', type=int, default=DEFAULT_SPP,
                        help=f'samples per pixel (default {DEFAULT_SPP})')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the camera poses and of the sample streams (default 0)')
    parser.add_argument('--max-depth', type=int, default=DEFAULT_MAX_DEPTH,
                        help=f'path length limit of the path tracer (default {DEFAULT_MAX_DEPTH})')
    parser.add_argument('--margin', type=float, default=0.15,
                        help="glass around the object, as a fraction of the object's largest "
                             'half-extent (default 0.15)')
    parser.add_argument('--container', choices=CONTAINERS, default='box',
                        help='glass around the object: a block, a block with rounded edges or a '
                             'cylinder jar (default box)')
    parser.add_argument('--ior', type=float, default=IOR, help=f'IOR of the glass (default {IOR})')
    parser.add_argument('--ambient', type=float, default=ENVIRONMENT,
                        help=f'radiance of the uniform environment (default {ENVIRONMENT})')
    parser.add_argument('--subsets', nargs='+', choices=SUBSETS, default=list(SUBSETS),
                        help='subsets to render (default: both)')
    args = parser.parse_args(argv)
    with exit_on_error():
        result = make_dataset(args.object, args.out, views=args.views, res=args.res,
                              spp=args.spp, seed=args.seed, max_depth=args.max_depth,
                              subsets=args.subsets, margin=args.margin, container=args.container,
                              ior=args.ior, ambient=args.ambient)
    print(f"wrote {os.path.abspath(args.out)}: {args.views} views at {args.res}x{args.res}, "
          f"{result['spp']} spp, max_depth {result['max_depth']}, noise (per-pixel std inside "
          f"the box, display units) {result['noise']:.4f}, {result['seconds']:.0f} s")
    return 0


if __name__ == '__main__':
    sys.exit(main())
