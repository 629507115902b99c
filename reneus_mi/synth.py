"""Render a synthetic dataset with Mitsuba's path tracer: ``python -m reneus_mi.synth insect -o DIR``.

The protocol, the files written and the options' meaning are those of
:func:`reneus_mi.data.synthetic.make_dataset`.
"""
from __future__ import annotations

import argparse
import os
import sys

from reneus_mi.data.objects import OBJECTS
from reneus_mi.data.synthetic import (DEFAULT_MAX_DEPTH, DEFAULT_SPP, LIQUID_IOR, SUBSETS, SYNTH_CONTAINERS, WALL,
                                  make_dataset)
from reneus_mi.paper import AMBIENT, IOR
from reneus_mi.utils import interrupt
from reneus_mi.utils.errors import exit_on_error


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
    parser.add_argument('--container', choices=SYNTH_CONTAINERS, default='box',
                        help='glass around the object: a solid block, a block with rounded edges or a '
                             'cylinder; a glass case around air, a jar of liquid, an amber block (default box)')
    parser.add_argument('--wall', type=float, default=WALL,
                        help="a case's or a jar's glass, as a fraction of the object's largest half-extent "
                             f'(default {WALL})')
    parser.add_argument('--liquid-ior', type=float, default=LIQUID_IOR,
                        help=f"IOR of a jar's liquid (default {LIQUID_IOR}: ethanol)")
    parser.add_argument('--ior', type=float, default=IOR, help=f'IOR of the glass (default {IOR})')
    parser.add_argument('--absorption', type=float, nargs='+', metavar='SIGMA',
                        help='the glass absorbs (amber, tinted resin): one coefficient or R G B, per '
                             'unit of the scene, whose container is about 2 across (default: clear)')
    parser.add_argument('--ambient', type=float, default=AMBIENT,
                        help=f'radiance of the uniform environment (default {AMBIENT})')
    parser.add_argument('--subsets', nargs='+', choices=SUBSETS, default=list(SUBSETS),
                        help='subsets to render (default: both)')
    args = parser.parse_args(argv)
    interrupt.leaving(f'{args.out} was not written (nothing of it is left); the same command starts again')
    with exit_on_error():
        result = make_dataset(args.object, args.out, views=args.views, res=args.res,
                              spp=args.spp, seed=args.seed, max_depth=args.max_depth,
                              subsets=args.subsets, margin=args.margin, container=args.container,
                              ior=args.ior, ambient=args.ambient, absorption=args.absorption,
                              wall=args.wall, liquid_ior=args.liquid_ior)
    print(f"wrote {os.path.abspath(args.out)}: {args.views} views at {args.res}x{args.res}, "
          f"{result['spp']} spp, max_depth {result['max_depth']}, noise (per-pixel std inside "
          f"the box, display units) {result['noise']:.4f}, {result['seconds']:.0f} s")
    return 0


if __name__ == '__main__':
    sys.exit(main())
