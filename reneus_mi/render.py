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

from reneus_mi.errors import user_message


def load_scene(path: str) -> mi.Scene:
    """``mi.load_file`` with errors that name the file."""
    if not os.path.isfile(path):
        raise SystemExit(f'error: scene file {path!r} does not exist')
    try:
        return mi.load_file(path)
    except Exception as e:  # Mitsuba reports parse and plugin errors as RuntimeError
        raise SystemExit(f'error: cannot load scene {path!r}:\n{user_message(e)}') from None


def write_image(image: np.ndarray, path: str) -> None:
    """Write ``image`` (H, W, C) as EXR (all channels) or 8-bit PNG (RGB)."""
    ext = os.path.splitext(path)[1].lower()
    if ext == '.exr':
        mi.Bitmap(image.astype(np.float32)).write(path)
    elif ext == '.png':
        rgb = np.clip(image[..., :3], 0.0, 1.0)
        mi.Bitmap((rgb * 255.0 + 0.5).astype(np.uint8), pixel_format=mi.Bitmap.PixelFormat.RGB).write(path)
    else:
        raise SystemExit(f'error: output {path!r}: expected a .exr or .png file')


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.render', description=__doc__.splitlines()[0])
    parser.add_argument('scene', help='Mitsuba scene XML')
    parser.add_argument('-o', '--output', default='render.exr', help='output image (.exr or .png)')
    parser.add_argument('--field', help='saved field (.npz) or checkpoint to render with')
    parser.add_argument('--spp', type=int, default=0, help='samples per pixel (default: the scene\'s sampler)')
    parser.add_argument('--seed', type=int, default=0, help='sampler seed')
    args = parser.parse_args(argv)

    scene = load_scene(args.scene)
    integrator = scene.integrator()
    if args.field:
        from reneus_mi.fields import load_field
        if not hasattr(integrator, 'field'):
            raise SystemExit(f'error: --field needs a scene with <integrator type="reneus">, '
                             f'{args.scene!r} has {type(integrator).__name__}')
        try:
            integrator.field = load_field(args.field)
        except ValueError as e:
            raise SystemExit(f'error: {e}') from None
    if args.spp < 0:
        raise SystemExit(f'error: --spp {args.spp}: expected >= 0')
    try:
        image = np.array(mi.render(scene, spp=args.spp, seed=args.seed))
    except (ValueError, RuntimeError) as e:
        raise SystemExit(f'error: {args.scene}: {user_message(e)}') from None
    write_image(image, args.output)
    h, w = image.shape[:2]
    print(f'wrote {args.output} ({w}x{h}, {image.shape[2]} channels)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
