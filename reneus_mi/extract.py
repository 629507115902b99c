"""Mesh of a reconstruction: ``python -m reneus_mi.extract CHECKPOINT -o mesh.ply``.

Marching cubes on the field's SDF inside the container's bounding box (the
field is fitted only there), post-processed (the paper keeps the largest
connected component), with vertices in the dataset's world coordinates. The
checkpoint carries the field, its frame and the container, so nothing else is
needed.
"""
from __future__ import annotations

import argparse
import sys

from reneus_mi.fields import load_field
from reneus_mi.geometry.mesh import MESH_EXTENSIONS, write_mesh
from reneus_mi.geometry.surface import POSTPROCESS_MODES, check_resolution, components, field_mesh
from reneus_mi.train import checkpoint
from reneus_mi.utils import guards
from reneus_mi.utils.errors import exit_on_error
from reneus_mi.utils.io import check_npz_file


def main(argv=None) -> int:

    parser = argparse.ArgumentParser(prog='python -m reneus_mi.extract', description=__doc__.splitlines()[0])
    parser.add_argument('checkpoint', help='checkpoint.npz of a reconstruction')
    parser.add_argument('-o', '--output', default='mesh.ply', help='mesh file (.ply, .obj, .stl, .off)')
    parser.add_argument('--resolution', type=int, default=512, help='marching-cubes grid points along the longest side of the box that holds the surface')
    parser.add_argument('--postprocess', choices=POSTPROCESS_MODES, default='clean',
                        help="'clean' (join pieces the field joins within its blur 1/s, drop floating fragments, "
                             "keep cut-off thin parts), 'largest' connected "
                             "component (the paper), 'crop' to the container, or 'none' (default: %(default)s)")
    parser.add_argument('--overwrite', action='store_true', help='replace an existing output file')
    args = parser.parse_args(argv)
    with exit_on_error():
        check_resolution(args.resolution)
        guards.check_output_file(args.output, inputs=[args.checkpoint], overwrite=args.overwrite,
                                 extensions=MESH_EXTENSIONS)
        check_npz_file(args.checkpoint, 'checkpoint')
        frame, container = checkpoint.load_frame(args.checkpoint)
        field = load_field(args.checkpoint)
        mesh = field_mesh(field, frame, args.resolution, args.postprocess, container)
        write_mesh(mesh, args.output)
    print(f'wrote {args.output}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces, '
          f'{components(mesh)} component(s) (resolution {args.resolution}, postprocess {args.postprocess})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
