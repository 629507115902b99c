"""Memory per photograph pixel of loading a dataset and of a run's pixel sampler.

    python bench/memory.py [--views 8] [--size 1024] [--format png|jpg|tif]

Writes a dataset of ``--views`` random RGBA photographs of ``--size`` x ``--size`` pixels
(a box container; no masks agree with it, so the views' mask check is skipped by writing
RGB files), then, each in a fresh process, measures the peak resident memory above the one
after the imports: of ``load_dataset`` and of ``load_dataset`` + ``PixelSampler``. Divided
by the pixels, these are the figures that ``reneus_mi.data.images.LOAD_BYTES_PER_PIXEL``
(+ ``DECODE_BYTES_PER_PIXEL`` for the largest photograph) and
``reneus_mi.train.pixel_sampler.BYTES_PER_PIXEL`` must stay above.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

MEASURE = """
import resource, sys
import reneus_mi
from reneus_mi.data import load_dataset
from reneus_mi.train.pixel_sampler import PixelSampler
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
ds = load_dataset(sys.argv[1])
if sys.argv[2] == 'sampler':
    PixelSampler(ds)
print((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base) * 1024)
"""


def write_dataset(root: str, views: int, size: int, fmt: str) -> None:
    import cv2
    import trimesh
    os.makedirs(os.path.join(root, 'images'))
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(os.path.join(root, 'container.ply'))
    rng = np.random.default_rng(0)
    frames = []
    for v in range(views):
        angle = 2 * np.pi * v / views
        eye = np.array([4 * np.cos(angle), 4 * np.sin(angle), 1.0])
        forward = -eye / np.linalg.norm(eye)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, up, -forward], axis=1)   # OpenGL axes
        c2w[:3, 3] = eye
        name = f'images/{v:03d}.{fmt}'
        cv2.imwrite(os.path.join(root, name), rng.integers(0, 255, (size, size, 3), dtype=np.uint8))
        frames.append({'file_path': name, 'transform_matrix': c2w.tolist()})
    meta = {'camera_angle_x': 0.6, 'mesh_outside': 'container.ply', 'IOR': 1.5, 'frames': frames}
    with open(os.path.join(root, 'transforms.json'), 'w') as f:
        json.dump(meta, f)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--views', type=int, default=8)
    parser.add_argument('--size', type=int, default=1024)
    parser.add_argument('--format', default='png', choices=('png', 'jpg', 'tif'))
    args = parser.parse_args()
    from reneus_mi.data.images import DECODE_BYTES_PER_PIXEL, LOAD_BYTES_PER_PIXEL
    from reneus_mi.train.pixel_sampler import BYTES_PER_PIXEL
    with tempfile.TemporaryDirectory() as root:
        write_dataset(root, args.views, args.size, args.format)
        pixels = args.views * args.size ** 2
        print(f'python bench/memory.py --views {args.views} --size {args.size} --format {args.format}')
        for what, budget in (('load', LOAD_BYTES_PER_PIXEL + DECODE_BYTES_PER_PIXEL / args.views),
                             ('sampler', LOAD_BYTES_PER_PIXEL + BYTES_PER_PIXEL
                              + DECODE_BYTES_PER_PIXEL / args.views)):
            out = subprocess.run([sys.executable, '-c', MEASURE, root, what], capture_output=True, text=True,
                                 check=True).stdout
            peak = int(out.split()[-1])
            print(f'{what:8s} peak {peak / pixels:6.1f} B/pixel   checked at {budget:6.1f} B/pixel')


if __name__ == '__main__':
    main()
