"""Render speed and peak memory of the reneus integrator on the example scene.

    python bench/render.py [--res 256] [--field sphere|neus] [--repeat 3]

Renders scenes/glass_sphere.xml (glass block IOR 1.45, D_re = 2, 64 + 64
samples per inside segment, 1 spp) and prints camera rays per second (after a
warm-up render that compiles the kernels) and the process's peak resident
memory. ``--field neus`` swaps the analytic sphere for an untrained NeuS field
of the given size (the paper's is 256 x 8).
"""
import argparse
import os
import resource
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import reneus_mi  # noqa: F401  (variant, plugins)
from reneus_mi.fields.neus import NeuSField

SCENE = os.path.join(os.path.dirname(__file__), '..', 'scenes', 'glass_sphere.xml')


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--res', type=int, default=256)
    p.add_argument('--field', choices=['sphere', 'neus'], default='sphere')
    p.add_argument('--hidden', type=int, default=64, help='NeuS width (--field neus)')
    p.add_argument('--layers', type=int, default=4, help='NeuS depth (--field neus)')
    p.add_argument('--repeat', type=int, default=3)
    args = p.parse_args()

    scene = mi.load_file(SCENE)
    sensor = scene.sensors()[0]
    params = mi.traverse(sensor)
    params['film.size'] = [args.res, args.res]
    params.update()
    integrator = scene.integrator()
    if args.field == 'neus':
        integrator.field = NeuSField(hidden=args.hidden, layers=args.layers, n_features=64,
                                     color_hidden=64, color_layers=2, init_radius=0.3)
    start = time.perf_counter()
    mi.render(scene, spp=1)
    dr.sync_thread()
    warm = time.perf_counter() - start
    times = []
    for i in range(args.repeat):
        start = time.perf_counter()
        image = mi.render(scene, spp=1, seed=i + 1)
        dr.eval(image)
        dr.sync_thread()
        times.append(time.perf_counter() - start)
    t = float(np.median(times))
    rays = args.res * args.res
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f'command: python bench/render.py --res {args.res} --field {args.field}'
          + (f' --hidden {args.hidden} --layers {args.layers}' if args.field == 'neus' else ''))
    print(f'variant {mi.variant()}, threads {dr.thread_count()}, {integrator.to_string()}')
    print(f'first render (compiles) {warm:.2f} s; render {t:.3f} s (median of {args.repeat}) '
          f'= {rays / t / 1e3:.1f} k camera rays/s; peak RSS {peak_mb:.0f} MB')


if __name__ == '__main__':
    main()
