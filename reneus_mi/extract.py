"""Mesh of a reconstruction: ``python -m reneus_mi.extract CHECKPOINT -o mesh.ply``.

Marching cubes on the field's SDF inside the container's bounding box (the
field is fitted only there), post-processed (the paper keeps the largest
connected component), with vertices in the dataset's world coordinates. The
checkpoint carries the field, its frame and the container, so nothing else is
needed.
"""
from __future__ import annotations

import argparse
import os
import sys

import drjit as dr

from reneus_mi.frame import FieldFrame
from reneus_mi.mesh import POSTPROCESS_MODES, extract_mesh, postprocess


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
            raise ValueError("postprocess 'crop' needs the container mesh, and none is recorded")
        return postprocess(mesh, mode, load_container(container))
    return postprocess(mesh, mode, None)


def write_mesh(mesh, path: str) -> None:
    """Export atomically (the format follows the extension)."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    base, ext = os.path.splitext(path)
    tmp = f'{base}.tmp{ext}'
    mesh.export(tmp)
    os.replace(tmp, path)


def main(argv=None) -> int:
    import reneus_mi  # noqa: F401  (variant)
    from reneus_mi import checkpoint
    from reneus_mi.fields import load_field

    parser = argparse.ArgumentParser(prog='python -m reneus_mi.extract', description=__doc__.splitlines()[0])
    parser.add_argument('checkpoint', help='checkpoint.npz of a reconstruction')
    parser.add_argument('-o', '--output', default='mesh.ply', help='mesh file (.ply, .obj, .stl)')
    parser.add_argument('--resolution', type=int, default=512, help='marching-cubes grid resolution')
    parser.add_argument('--postprocess', choices=POSTPROCESS_MODES, default='largest',
                        help="'largest' connected component (the paper), 'crop' to the container, or 'none'")
    args = parser.parse_args(argv)
    try:
        frame, container = checkpoint.load_frame(args.checkpoint)
        field = load_field(args.checkpoint)
        if args.resolution < 8:
            raise ValueError(f'--resolution {args.resolution}: expected >= 8')
        mesh = field_mesh(field, frame, args.resolution, args.postprocess, container)
        write_mesh(mesh, args.output)
    except ValueError as e:
        raise SystemExit(f'error: {e}') from None
    print(f'wrote {args.output}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces '
          f'(resolution {args.resolution}, postprocess {args.postprocess})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
