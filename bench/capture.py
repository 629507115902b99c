"""Full-size photographs to a dataset: the capture command's time and memory at 6, 12 and 24
megapixels.

    python bench/capture.py [--megapixels 6 12 24] [--views 48] [--max-size 960] [--doc docs/capture.md]

The generator's capture (``reneus_mi.capture.simulate``: Mitsuba's ``path``, the insect in a
50x35x25 mm block on a 12x9 board, lens distortion, exposure drift, noise, JPEG) is rendered
once at 960x640 and each photograph scaled up (bicubic) to the size of a camera of each
megapixel count, 3:2, written as a JPEG of quality 92 as a camera writes it: the pixels are
softer than a camera's, the work per pixel (decoding, finding the board, refining its corners,
reducing) is the same. Each size runs ``python -m reneus_mi.capture`` in a process of its own,
timed from start to exit, its peak resident memory read from the operating system. The table
goes to the ``bench`` section of ``--doc``; figures taken when the load average before a run
was above 1.5 are marked as from a loaded machine.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

from reneus_mi.capture.simulate import Rig, simulate
from reneus_mi.utils.io import write_section

#: Load average above which the figures are marked as from a loaded machine.
LOADED = 1.5
#: The rendered capture: 3:2 as a camera's sensor.
RIG = dict(width=960, height=640, focal_px=1050.0, spp=16)


def rendered(folder: str, views: int) -> str:
    """The generator's photographs at 960x640 (rendered once into ``folder``)."""
    photos = os.path.join(folder, 'photos_960')
    if not os.path.isfile(os.path.join(photos, 'capture.json')):
        shutil.rmtree(folder, ignore_errors=True)
        rings = (views * 3 // 8, views * 3 // 8, views - 2 * (views * 3 // 8))
        simulate(Rig(views_per_ring=rings, **RIG), photos, os.path.join(folder, 'truth'))
    return photos


def scaled(photos: str, folder: str, megapixels: float) -> tuple[str, tuple[int, int]]:
    """The photographs scaled up to ``megapixels`` (3:2), as JPEGs, in a folder of their own."""
    height = int(round(np.sqrt(megapixels * 1e6 / 1.5)))
    size = (int(round(1.5 * height)), height)
    out = os.path.join(folder, f'photos_{megapixels:g}mp')
    if not os.path.isdir(out):
        os.makedirs(out + '.tmp', exist_ok=True)
        for name in sorted(os.listdir(photos)):
            if name.endswith('.jpg'):
                image = cv2.resize(cv2.imread(os.path.join(photos, name)), size, interpolation=cv2.INTER_CUBIC)
                cv2.imwrite(os.path.join(out + '.tmp', name), image, [cv2.IMWRITE_JPEG_QUALITY, 92])
        shutil.copy(os.path.join(photos, 'capture.json'), out + '.tmp')
        os.replace(out + '.tmp', out)
    return out, size


def one_capture(photos: str, out: str, max_size: int) -> dict:
    """The capture command on ``photos``: wall seconds, peak memory (GiB), views, the report."""
    shutil.rmtree(out, ignore_errors=True)
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    start = time.perf_counter()
    subprocess.run([sys.executable, '-m', 'reneus_mi.capture', photos, '-o', out, '--max-size', str(max_size),
                    '--quiet'], check=True, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    with open(os.path.join(out, 'report.json')) as f:
        report = json.load(f)
    # ru_maxrss is in KiB on Linux and the largest of all children so far: sizes run in
    # increasing order, so each run's own peak is the new maximum.
    return {'wall': wall, 'peak_gib': max(peak, before) / 2 ** 20, 'load': load, 'views': len(report['views']),
            'rms': report['camera']['rms_px'], 'residual': report['container']['residual_px']}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--megapixels', type=float, nargs='+', default=[6.0, 12.0, 24.0])
    p.add_argument('--views', type=int, default=48)
    p.add_argument('--max-size', type=int, default=960, help="the dataset's largest side")
    p.add_argument('--data', default=os.path.join(tempfile.gettempdir(), 'reneus_bench_capture'),
                   help='folder of the photographs (rendered and scaled there once)')
    p.add_argument('--doc', default=os.path.join(os.path.dirname(__file__), '..', 'docs', 'capture.md'))
    args = p.parse_args(argv)
    command = ' '.join(['python bench/capture.py', *(sys.argv[1:] if argv is None else argv)])
    print(f'command: {command}', flush=True)
    photos = rendered(args.data, args.views)
    rows = []
    for mp in sorted(args.megapixels):
        folder, size = scaled(photos, args.data, mp)
        r = {'mp': mp, 'size': size, **one_capture(folder, os.path.join(args.data, 'dataset'), args.max_size)}
        rows.append(r)
        print(r, flush=True)
    loaded = max(r['load'] for r in rows) > LOADED
    lines = [f'`{command}`: {args.views} photographs of the generator\'s capture (scaled up from 960x640), '
             f'dataset at {args.max_size} px, {os.cpu_count()} cores'
             + (' (**a loaded machine**: load average above 1.5 before a run)' if loaded else ' (otherwise idle)')
             + '.', '',
             '| photographs | size | wall s | peak memory GiB | views kept | calibration RMS px | container px |',
             '| --- | --- | --- | --- | --- | --- | --- |']
    for r in rows:
        lines.append(f"| {r['mp']:g} MP | {r['size'][0]}x{r['size'][1]} | {r['wall']:.0f} | {r['peak_gib']:.2f} | "
                     f"{r['views']} | {r['rms']:.3f} | {r['residual']:.2f} |")
    text = '\n'.join(lines)
    print(text)
    write_section(args.doc, 'bench', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
