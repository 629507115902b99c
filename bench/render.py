"""Render speed and peak memory of the reneus integrator on the example scene.

    python bench/render.py [--res 256] [--field sphere|neus] [--repeat 3]

Renders scenes/glass_sphere.xml (glass block IOR 1.45, D_re = 2, 64 + 64
samples per inside segment, 1 spp) and prints camera rays per second (after a
warm-up render that compiles the kernels) and the process's peak resident
memory. ``--preset NAME`` swaps the analytic sphere for the untrained field and the
sampling of a preset (reneus_mi.presets: demo, cpu, paper, ...).
"""
import argparse
import os
import resource
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import reneus_mi  # noqa: F401  (variant, plugins)
from reneus_mi.presets import PRESETS, preset

SCENE = os.path.join(os.path.dirname(__file__), '..', 'scenes', 'glass_sphere.xml')


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--res', type=int, default=256)
    p.add_argument('--preset', choices=sorted(PRESETS), help="the preset's field and sampling "
                   "(default: the scene's analytic sphere)")
    p.add_argument('--repeat', type=int, default=3)
    args = p.parse_args()

    scene = mi.load_file(SCENE)
    sensor = scene.sensors()[0]
    params = mi.traverse(sensor)
    params['film.size'] = [args.res, args.res]
    params.update()
    integrator = scene.integrator()
    if args.preset:
        integrator.configure(preset(args.preset).model)
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
    print(f'command: python bench/render.py --res {args.res}' + (f' --preset {args.preset}' if args.preset else ''))
    print(f'variant {mi.variant()}, threads {dr.thread_count()}, {integrator.to_string()}')
    print(f'first render (compiles) {warm:.2f} s; render {t:.3f} s (median of {args.repeat}) '
          f'= {rays / t / 1e3:.1f} k camera rays/s; peak RSS {peak_mb:.0f} MB')


if __name__ == '__main__':
    main()
