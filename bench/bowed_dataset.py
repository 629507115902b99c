"""A capture's dataset with its block modelled bowed: what a reconstruction gains from knowing
that a polished block's faces bulge (``bench/blender_capture.py --bow-mm``).

    python bench/bowed_dataset.py DATASET OUT --bow-mm 0.3

copies ``DATASET`` (made by ``python -m reneus_mi.capture``, its block a sharp ``box``) to
``OUT`` with ``container.ply`` replaced by the same block, at the place the capture found,
its four sides and its top bulging out by the bow at their centres as ``blender_capture.py``
bows them (a product of parabolas across each face, the bottom flat), cut into facets of
1/32 of each face's sides. ``bench/quality.py`` then trains it like any capture whose dataset
exists (``--captures`` a name whose ``RUNS/NAME/capture/dataset`` is ``OUT``).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil

import numpy as np
import trimesh

from reneus_mi.capture.placement import local_mesh, pose_matrix
from reneus_mi.geometry.bulge import displacement

#: Halvings of the box's triangles: 2^5 = 32 facets along each side of a face.
SUBDIVISIONS = 5


def bowed_block(size, bow: float) -> trimesh.Trimesh:
    """The block of outer ``size`` (mm) in its own frame (standing on z = 0, up -z), its sides
    and top bulging out by ``bow`` mm at their centres."""
    mesh = local_mesh('box', size)
    for _ in range(SUBDIVISIONS):
        mesh = trimesh.Trimesh(*trimesh.remesh.subdivide(mesh.vertices, mesh.faces))
    half = 0.5 * np.asarray(size, np.float64)
    v = np.asarray(mesh.vertices, np.float64)
    q = v - [0.0, 0.0, -half[2]]
    # The faces -x +x -y +y -z +z; up is -z: the bottom is the +z face.
    out = displacement(q.T, np.asarray(mesh.vertex_normals).T, [bow] * 5 + [0.0], half)
    return trimesh.Trimesh(v + out, mesh.faces, process=False)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog='bench/bowed_dataset.py', description=__doc__.split('\n\n')[0])
    parser.add_argument('dataset', help="a capture's dataset (its block a box)")
    parser.add_argument('out', help='the copy to write (must not exist)')
    parser.add_argument('--bow-mm', type=float, required=True, help='bulge of the sides and top at their centres')
    args = parser.parse_args(argv)
    if os.path.exists(args.out):
        parser.error(f'{args.out}: exists; expected a new folder (nothing is written over)')
    with open(os.path.join(args.dataset, 'transforms.json')) as f:
        container = json.load(f)['capture']['container']
    if container['shape'] != 'box':
        parser.error(f"{args.dataset}: its container is a {container['shape']}; expected a box")
    shutil.copytree(args.dataset, args.out)
    mesh = bowed_block(container['size_mm'], args.bow_mm)
    mesh.apply_transform(pose_matrix(container['pose']))
    mesh.export(os.path.join(args.out, 'container.ply'))
    print(f'wrote {args.out}: the block bowed {args.bow_mm:g} mm, {len(mesh.faces)} triangles')


if __name__ == '__main__':
    main()
