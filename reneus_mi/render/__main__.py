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

import mitsuba as mi

from reneus_mi.data.images import WRITE_EXTENSIONS, write_image
from reneus_mi.fields import load_field
from reneus_mi.render.loading import check_render_size, load_scene, reneus_integrator
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError, exit_on_error, user_message
from reneus_mi.utils.io import check_npz_file


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
                                 overwrite=args.overwrite, extensions=WRITE_EXTENSIONS)
        scene = load_scene(args.scene)
        if args.field:
            integrator = reneus_integrator(scene, f'--field needs a reneus scene: {args.scene}')
            check_npz_file(args.field, 'field', keys=('header',))
            integrator.configure(field=load_field(args.field))
        check_render_size(scene, args.spp, args.scene)
        try:
            image = np.array(mi.render(scene, spp=args.spp, seed=args.seed))
        except (ValueError, RuntimeError) as e:
            raise ReneusError(f'{args.scene}: {user_message(e)}') from None
        write_image(args.output, image if os.path.splitext(args.output)[1].lower() == '.exr' else image[..., :3])
    h, w = image.shape[:2]
    print(f'wrote {args.output} ({w}x{h}, {image.shape[2]} channels)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
