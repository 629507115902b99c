"""A dataset from photographs posed by COLMAP: ``python -m reneus_mi.colmap SPARSE_DIR
--images IMAGES_DIR --container MESH --ior 1.5 -o DATASET_DIR [--max-size N | --downscale F]``.

For photographs posed by structure from motion on their surroundings instead of a board
(:mod:`reneus_mi.capture.colmap_model`); needs ``pip install 'reneus-mi[colmap]'``.
"""
from __future__ import annotations

import argparse
import sys

from reneus_mi.capture.colmap_model import convert
from reneus_mi.utils.errors import exit_on_error


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.colmap',
                                     description='A reneus-mi dataset from photographs posed by a COLMAP sparse model.')
    parser.add_argument('sparse', metavar='SPARSE_DIR', help='COLMAP sparse model folder (e.g. sparse/0)')
    parser.add_argument('--images', required=True, help='folder of the photographs the model names')
    parser.add_argument('--container', required=True, help='container mesh (.ply/.obj) in the model\'s frame')
    parser.add_argument('--ior', type=float, required=True, help='index of refraction of the container')
    parser.add_argument('-o', '--output', required=True, help='dataset folder to write (new or empty)')
    parser.add_argument('--max-size', type=int, help='largest side in pixels of the dataset\'s images')
    parser.add_argument('--downscale', type=float, help='divide the photographs\' size by this factor')
    args = parser.parse_args(argv)
    with exit_on_error(RuntimeError):
        n = convert(args.sparse, args.images, args.container, args.ior, args.output,
                    max_size=args.max_size, downscale=args.downscale)
    print(f'wrote {args.output}: {n} views')
    return 0


if __name__ == '__main__':
    sys.exit(main())
