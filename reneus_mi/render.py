"""Render a scene with its integrator: ``python -m reneus_mi.render scene.xml -o out.png``.

With ``--field`` the ``reneus`` integrator's field is replaced by a saved one
(a ``.npz`` written by ``Field.save`` or a reconstruction's checkpoint).
EXR keeps every channel (linear or gamma-encoded as the integrator outputs,
AOVs included); PNG takes R, G, B as they are, clipped to [0, 1].
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

import reneus_mi  # noqa: F401  (selects the variant, registers the plugins)
import mitsuba as mi

from reneus_mi import guards
from reneus_mi.errors import ReneusError, exit_on_error, user_message
from reneus_mi.io import atomic_path
from reneus_mi.mesh import check_container

#: Image files :func:`write_image` writes.
IMAGE_EXTENSIONS = ('.exr', '.png')
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


def check_scene_containers(scene: mi.Scene, where: str) -> None:
    """Every dielectric mesh of ``scene`` (the container) must be closed, face outward,
    and be made of parts that do not overlap.

    This is the geometry Mitsuba traces, after the scene's transforms and
    ``flip_normals`` (and after Mitsuba merged shapes that share a BSDF): the
    check catches what the XML points to, whatever file the dataset names.
    """
    import trimesh
    parts = []
    for shape in scene.shapes():
        if not isinstance(shape, mi.Mesh) or not str(shape.bsdf()).startswith('SmoothDielectric'):
            continue
        vertices = np.array(shape.vertex_positions_buffer()).reshape(-1, 3)
        faces = np.array(shape.faces_buffer()).reshape(-1, 3)
        if shape.has_flipped_normals():
            faces = faces[:, ::-1]
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
        check_container(mesh, f"{where}: shape '{shape.id() or 'container'}'")
        merged = mesh.copy()
        merged.merge_vertices()
        parts += merged.split(only_watertight=False)
    _check_disjoint(parts, where)


def _check_disjoint(parts, where: str) -> None:
    """Container parts may sit apart or one inside another as its cavity (inward
    normals: a hollow vessel), never cut through each other or nest glass in glass,
    where a ray would enter glass it is already in."""
    from reneus_mi.mesh import inside, signed_volume
    for i, a in enumerate(parts):
        for b in parts[i + 1:]:
            if not (np.all(a.bounds[0] <= b.bounds[1]) and np.all(b.bounds[0] <= a.bounds[1])):
                continue
            for inner, outer in ((a, b), (b, a)):
                if signed_volume(outer.vertices, outer.faces) < 0:
                    outer = outer.copy()   # parity is blind to orientation; inside() is not
                    outer.invert()
                within = inside(_probes(inner), outer)
                cavity = signed_volume(inner.vertices, inner.faces) < 0
                if within.any() and not (within.all() and cavity):
                    c = np.round(0.5 * (inner.bounds[0] + inner.bounds[1]), 3).tolist()
                    raise ReneusError(f'{where}: container parts overlap (the part centred at {c} '
                                      'reaches into another); expected disjoint parts, or a cavity '
                                      'with inward normals inside its part')


def _probes(mesh) -> np.ndarray:
    """Points of a mesh's surface that tell whether it reaches into another: vertices and face centres."""
    return np.concatenate([mesh.vertices, mesh.triangles_center])


def write_image(image: np.ndarray, path: str) -> None:
    """Write ``image`` (H, W, C) atomically as EXR (all channels) or 8-bit PNG (RGB)."""
    ext = os.path.splitext(path)[1].lower()
    if ext == '.exr':
        bitmap = mi.Bitmap(image.astype(np.float32))
    elif ext == '.png':
        rgb = np.clip(image[..., :3], 0.0, 1.0)
        bitmap = mi.Bitmap((rgb * 255.0 + 0.5).astype(np.uint8), pixel_format=mi.Bitmap.PixelFormat.RGB)
    else:
        raise ReneusError(f"output {path}: expected a file ending in {' or '.join(IMAGE_EXTENSIONS)}")
    with atomic_path(path) as tmp:
        bitmap.write(tmp)


def check_render_size(scene: mi.Scene, spp: int, where: str) -> None:
    """Refuse a render whose samples exceed 32-bit indices or the machine's memory."""
    sensor = scene.sensors()[0]
    w, h = sensor.film().crop_size()
    spp = spp or sensor.sampler().sample_count()
    guards.check_index_range(w * h * spp, f'{where}: {w}x{h} pixels at {spp} spp')
    guards.check_memory(w * h * spp * BYTES_PER_SAMPLE, f'{where}: {w}x{h} pixels at {spp} spp')


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.render', description=__doc__.splitlines()[0])
    parser.add_argument('scene', help='Mitsuba scene XML')
    parser.add_argument('-o', '--output', default='render.exr', help='output image (.exr or .png)')
    parser.add_argument('--field', help='saved field (.npz) or checkpoint to render with')
    parser.add_argument('--spp', type=int, default=0, help='samples per pixel (default: the scene\'s sampler)')
    parser.add_argument('--seed', type=int, default=0, help='sampler seed')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing output file')
    args = parser.parse_args(argv)

    with exit_on_error(RuntimeError):
        if args.spp < 0:
            raise ReneusError(f'--spp {args.spp}: expected >= 0')
        guards.check_output_file(args.output, inputs=[args.scene, args.field],
                                 overwrite=args.overwrite, extensions=IMAGE_EXTENSIONS)
        scene = load_scene(args.scene)
        integrator = scene.integrator()
        if args.field:
            from reneus_mi.fields import load_field
            if not hasattr(integrator, 'field'):
                raise ReneusError(f'--field needs a scene with <integrator type="reneus">, '
                                  f'{args.scene} has {type(integrator).__name__}')
            guards.check_npz_file(args.field, 'field', keys=('header',))
            integrator.configure(field=load_field(args.field))
        check_render_size(scene, args.spp, args.scene)
        try:
            image = np.array(mi.render(scene, spp=args.spp, seed=args.seed))
        except (ValueError, RuntimeError) as e:
            raise ReneusError(f'{args.scene}: {user_message(e)}') from None
        write_image(image, args.output)
    h, w = image.shape[:2]
    print(f'wrote {args.output} ({w}x{h}, {image.shape[2]} channels)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
