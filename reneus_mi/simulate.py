"""Render a photographer's capture with Mitsuba: ``python -m reneus_mi.simulate PHOTOS
--truth TRUTH [--specimen insect] [--views 16]``.

The photographs and ``capture.json`` go to PHOTOS, the ground truth to TRUTH
(:mod:`reneus_mi.capture.simulation`: the set-up, the camera's degradations, what each file holds).
"""
from __future__ import annotations

import argparse
import sys

from reneus_mi.capture.simulation import Rig, simulate
from reneus_mi.utils import cli
from reneus_mi.utils.errors import exit_on_error


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.simulate',
                                     description="A photographer's capture, rendered by Mitsuba's path tracer.")
    parser.add_argument('photos', metavar='PHOTOS', help='folder for the photographs and capture.json (new or empty)')
    parser.add_argument('--truth', required=True, help='folder for the ground truth (new or empty)')
    cli.add_arguments(parser, Rig, title='the capture')
    args = parser.parse_args(argv)
    rig = Rig(**cli.given_arguments(Rig, args))
    with exit_on_error(RuntimeError):
        result = simulate(rig, args.photos, args.truth)
    print(f"wrote {len(result['views'])} photographs to {args.photos}, the truth to {args.truth}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
