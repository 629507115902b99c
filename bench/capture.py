"""Full-size photographs to a dataset: the capture command's time and memory at 6, 12 and 24
megapixels, and a run's memory on the dataset it made.

    python bench/capture.py [--megapixels 6 12 24] [--views 48] [--max-size 960 | 0] [--train-steps 20]
                            [--doc docs/capture.md]

The generator's capture (``reneus_mi.capture.simulation``: Mitsuba's ``path``, the insect in a
50x35x25 mm block on a 12x9 board, lens distortion, exposure drift, noise, JPEG) is rendered
once at 960x640 and each photograph scaled up (bicubic) to the size of a camera of each
megapixel count, 3:2, written as a JPEG of quality 92 as a camera writes it: the pixels are
softer than a camera's, the work per pixel (decoding, finding the board, refining its corners,
reducing) is the same. Each size runs ``python -m reneus_mi.capture`` in a process of its own,
timed from start to exit, its peak resident memory read from the operating system; ``--max-size
0`` keeps the photographs' own pixels (the dataset: windows around the container, at full
resolution). With ``--train-steps N``, ``python -m reneus_mi.scene`` (``fast``) and ``N`` steps of
``python -m reneus_mi.optimize`` on each dataset, the optimiser's peak memory measured alike. The table
goes to the ``bench`` section of ``--doc``; figures taken when the load average before a run
was above 1.5 are marked as from a loaded machine.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

import cv2
import numpy as np

from reneus_mi.capture.simulation import Rig, simulate
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


#: Runs a command and prints its peak resident memory (KiB): the largest of this process's
#: children alone, where the bench's own would be the largest of all it ran so far.
PEAK = ('import resource, subprocess, sys; subprocess.run(sys.argv[1:], check=True, stderr=subprocess.DEVNULL, '
        'stdout=subprocess.DEVNULL); print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)')


def measured(command: list[str]) -> tuple[float, float]:
    """Wall seconds and peak memory (GiB) of ``command``."""
    start = time.perf_counter()
    out = subprocess.run([sys.executable, '-c', PEAK, *command], check=True, capture_output=True, text=True)
    return time.perf_counter() - start, int(out.stdout.split()[-1]) / 2 ** 20


def one_capture(photos: str, out: str, max_size: int, train_steps: int) -> dict:
    """The capture command on ``photos`` (``max_size`` 0: full resolution): wall seconds, peak
    memory (GiB), views, the report, the dataset's size; then, with ``train_steps``, a run's."""
    shutil.rmtree(out, ignore_errors=True)
    load = os.getloadavg()[0]
    reduce = ['--max-size', str(max_size)] if max_size else []
    wall, peak = measured([sys.executable, '-m', 'reneus_mi.capture', photos, '-o', out, *reduce, '--quiet'])
    with open(os.path.join(out, 'report.json')) as f:
        report = json.load(f)
    window = report['views'][0]['window_px'][2:]
    row = {'wall': wall, 'peak_gib': peak, 'load': load, 'views': len(report['views']),
           'rms': report['camera']['rms_px'], 'residual': report['container']['residual_px'],
           'frame': report['camera']['size'], 'window': window,
           'dataset_mp': len(report['views']) * window[0] * window[1] / 1e6}
    if train_steps:
        scene = os.path.join(os.path.dirname(out), 'scene', 'scene.xml')    # no command writes into a dataset
        shutil.rmtree(os.path.dirname(scene), ignore_errors=True)
        os.makedirs(os.path.dirname(scene))
        subprocess.run([sys.executable, '-m', 'reneus_mi.scene', out, '-o', scene, '--preset', 'fast'], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        row['train_wall'], row['train_gib'] = measured([
            sys.executable, '-m', 'reneus_mi.optimize', scene, '-o', os.path.join(os.path.dirname(scene), 'run'),
            '--iterations', str(train_steps)])
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--megapixels', type=float, nargs='+', default=[6.0, 12.0, 24.0])
    p.add_argument('--views', type=int, default=48)
    p.add_argument('--max-size', type=int, default=960, help="the dataset's largest side (0: the photographs')")
    p.add_argument('--train-steps', type=int, default=0, help='steps of a run on each dataset (0: none)')
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
        r = {'mp': mp, 'size': size, **one_capture(folder, os.path.join(args.data, 'dataset'), args.max_size,
                                                    args.train_steps)}
        rows.append(r)
        print(r, flush=True)
    loaded = max(r['load'] for r in rows) > LOADED
    scale = f'at {args.max_size} px' if args.max_size else 'at the photographs\' resolution'
    train = (f'; then `scene --preset fast` and `optimize --iterations {args.train_steps}` on it'
             if args.train_steps else '')
    lines = [f'`{command}`: {args.views} photographs of the generator\'s capture (scaled up from 960x640), '
             f'dataset {scale}{train}, {os.cpu_count()} cores'
             + (' (**a loaded machine**: load average above 1.5 before a run)' if loaded else ' (otherwise idle)')
             + '.', '',
             '| photographs | size | wall s | peak memory GiB | views kept | calibration RMS px | container px '
             '| dataset: frame, window | dataset MP |' + (' run s | run peak GiB |' if args.train_steps else ''),
             '| --- ' * (9 + 2 * bool(args.train_steps)) + '|']
    for r in rows:
        lines.append(f"| {r['mp']:g} MP | {r['size'][0]}x{r['size'][1]} | {r['wall']:.0f} | {r['peak_gib']:.2f} | "
                     f"{r['views']} | {r['rms']:.3f} | {r['residual']:.2f} | {r['frame'][0]}x{r['frame'][1]}, "
                     f"{r['window'][0]}x{r['window'][1]} | {r['dataset_mp']:.0f} |"
                     + (f" {r['train_wall']:.0f} | {r['train_gib']:.2f} |" if args.train_steps else ''))
    text = '\n'.join(lines)
    print(text)
    write_section(args.doc, 'bench' if args.max_size else 'bench-full', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
