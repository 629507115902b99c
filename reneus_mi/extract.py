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

import drjit as dr

from reneus_mi import guards
from reneus_mi.errors import ReneusError, exit_on_error
from reneus_mi.frame import FieldFrame
from reneus_mi.io import atomic_export
from reneus_mi.mesh import MESH_EXTENSIONS, POSTPROCESS_MODES, components, extract_mesh, postprocess


def field_mesh(field, frame: FieldFrame, resolution: int, mode: str, container: str | None = None):
    """The post-processed mesh of ``field`` in world coordinates.

    Marching cubes runs over the container's box in the field's frame
    (:meth:`FieldFrame.field_box`); ``container`` is the container mesh file,
    needed by ``mode='crop'``.
    """
    lo, hi = frame.field_box()
    with dr.suspend_grad():
        mesh = extract_mesh(field, lo, hi, resolution, to_world=frame.to_world_matrix())
    if mode == 'crop':
        from reneus_mi.data.container import load_container
        if not container:
            raise ReneusError("postprocess 'crop' needs the container mesh, and none is recorded")
        return postprocess(mesh, mode, load_container(container))
    return postprocess(mesh, mode, None)


def write_mesh(mesh, path: str) -> None:
    """Export atomically (the format follows the extension)."""
    atomic_export(mesh, path)


#: Bytes per grid point of marching cubes: the float32 SDF grid, skimage's
#: working copies, the vertices and faces. Measured (peak RSS, a sphere,
#: resolution 64 -> 384): 4.9; doubled and more for surfaces with more faces.
BYTES_PER_GRID_POINT = 12


def check_resolution(resolution: int, what: str = '--resolution') -> None:
    """Refuse a grid below 8 per axis, past 32-bit indices or the machine's memory."""
    if resolution < 8:
        raise ReneusError(f'{what} {resolution}: expected >= 8')
    points = resolution ** 3
    guards.check_index_range(points, f'{what} {resolution}')
    guards.check_memory(points * BYTES_PER_GRID_POINT, f'{what} {resolution}')


def main(argv=None) -> int:
    import reneus_mi  # noqa: F401  (variant)
    from reneus_mi import checkpoint
    from reneus_mi.fields import load_field

    parser = argparse.ArgumentParser(prog='python -m reneus_mi.extract', description=__doc__.splitlines()[0])
    parser.add_argument('checkpoint', help='checkpoint.npz of a reconstruction')
    parser.add_argument('-o', '--output', default='mesh.ply', help='mesh file (.ply, .obj, .stl, .off)')
    parser.add_argument('--resolution', type=int, default=512, help='marching-cubes grid resolution')
    parser.add_argument('--postprocess', choices=POSTPROCESS_MODES, default='clean',
                        help="'clean' (drop floating fragments, keep cut-off thin parts), 'largest' connected "
                             "component (the paper), 'crop' to the container, or 'none' (default: %(default)s)")
    parser.add_argument('--overwrite', action='store_true', help='replace an existing output file')
    args = parser.parse_args(argv)
    with exit_on_error():
        check_resolution(args.resolution)
        guards.check_output_file(args.output, inputs=[args.checkpoint], overwrite=args.overwrite,
                                 extensions=MESH_EXTENSIONS)
        guards.check_npz_file(args.checkpoint, 'checkpoint')
        frame, container = checkpoint.load_frame(args.checkpoint)
        field = load_field(args.checkpoint)
        mesh = field_mesh(field, frame, args.resolution, args.postprocess, container)
        write_mesh(mesh, args.output)
    print(f'wrote {args.output}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces, '
          f'{components(mesh)} component(s) (resolution {args.resolution}, postprocess {args.postprocess})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
