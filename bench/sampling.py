"""Where a training step's sampling cost goes, and what empty-space skipping saves.

On the demo (a statuette in a glass block, the demo's field and sampling) it
traces batches of camera rays through the trained field and reports

- inside segments per camera ray, by generation of the ray tree (generation 1:
  the camera ray refracted into the block; 2 and up: internal reflections,
  since a ray refracted out of a convex block never comes back), with their
  mean weight β;
- the share of those segments that the occupancy grid skips, and the share of
  the segment length it clips away;
- SDF and radiance evaluations per camera ray, with and without the grid;
- wall time of a forward + backward trace, with and without the grid, and of
  a grid refresh.

    python bench/sampling.py                 # trains the demo first (runs/bench_sampling)
    python bench/sampling.py --run runs/demo # a finished demo run (its data/ and checkpoint.npz)
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import shlex
import sys
import time

import numpy as np


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument('--run', default=os.path.join('runs', 'bench_sampling'),
                        help='folder of a demo run; trained here first if it holds no checkpoint')
    parser.add_argument('--iterations', type=int, default=None,
                        help="training iterations when the run is trained here (default: the demo's)")
    parser.add_argument('--rays', type=int, default=256, help='camera rays per batch (the demo trains with 256)')
    parser.add_argument('--repeats', type=int, default=5, help='timed batches per setting (after one warm-up)')
    parser.add_argument('--resolution', type=int, default=64, help='occupancy grid cells per axis')
    parser.add_argument('--inv-s', type=float, default=None,
                        help="override the trained field's sharpness s (e.g. a converged field's few hundred)")
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args(argv)

    import reneus_mi  # noqa: F401  (variant, plugins)
    import drjit as dr
    import mitsuba as mi
    from reneus_mi import optimize
    from reneus_mi.data import load_dataset
    from reneus_mi.fields import load_field
    from reneus_mi.render.loading import load_scene

    checkpoint = os.path.join(args.run, 'checkpoint.npz')
    if not os.path.isfile(checkpoint):
        train = ['--demo', '-o', args.run, '--quiet']
        if args.iterations:
            train += ['--iterations', str(args.iterations)]
        print('training the demo:', 'python -m reneus_mi.optimize', ' '.join(train))
        try:
            optimize.main(train)
        except SystemExit as e:  # e.g. no mesh from a short run: the checkpoint is what we need
            if not os.path.isfile(checkpoint):
                raise
            print(f'training ended with: {e}')
    # The demo's photographs and scene lie beside its run folder.
    data = os.path.abspath(args.run).rstrip(os.sep) + '_data'
    scene = load_scene(os.path.join(data, 'scene_reneus.xml'))
    ds = load_dataset(os.path.join(data, 'box'))
    integrator = scene.integrator()
    integrator.field = field = load_field(checkpoint)
    if args.inv_s:  # NeuS's s = exp(10 variance)
        field.set_params({'variance': mi.Float(math.log(args.inv_s) / 10.0)})
    plain = integrator.sampler
    grid = dataclasses.replace(plain.config, occupancy_resolution=args.resolution).setup()

    rng = np.random.default_rng(args.seed)
    pixels = np.flatnonzero(ds.masks.reshape(-1))

    def batch():
        index = pixels[rng.integers(0, len(pixels), args.rays)]
        view, rest = np.divmod(index, ds.height * ds.width)
        y, x = np.divmod(rest, ds.width)
        o, d = (a.astype(np.float32) for a in ds.rays(view, np.stack([x, y], axis=1)))
        return mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T)), mi.Float(rng.random(args.rays).astype(np.float32))

    # -------------------------------------------------------------- counting
    counts = {'sdf': 0, 'radiance': 0}

    def counting(method, key):
        def wrapped(x, *rest):
            counts[key] += dr.width(x)
            return method(x, *rest)
        return wrapped

    generations = []  # per _render_inside call of a trace: [segments, Σβ, skipped, length, clipped length]

    def render_inside(rays, t_far, inside, *rest):
        seg = dr.compress(inside)
        stats = [dr.width(seg), 0.0, 0, 0.0, 0.0]
        if stats[0]:
            stats[1] = float(dr.sum(dr.gather(mi.Float, dr.detach(rays.β), seg))[0])
            if integrator.sampler.grid is not None:
                s = rays.take(seg)
                o = (s.o - mi.Point3f(*integrator.field_center)) / integrator.field_scale
                t = dr.gather(mi.Float, t_far, seg) / integrator.field_scale
                kept = integrator.sampler.clip(field, o, s.d, dr.zeros(mi.Float, stats[0]), t)
                stats[2] = stats[0] - dr.width(kept.index)
                stats[3] = float(dr.sum(t)[0])
                stats[4] = stats[3] - float(dr.sum(kept.t_far - kept.t_near)[0]) if dr.width(kept.index) else stats[3]
        generations.append(stats)
        return original_render_inside(rays, t_far, inside, *rest)

    original_render_inside = integrator._render_inside
    field.geometry, field.sdf = counting(field.geometry, 'sdf'), counting(field.sdf, 'sdf')
    field.radiance = counting(field.radiance, 'radiance')
    integrator._render_inside = render_inside

    n_batches = max(args.repeats, 1)
    table = {}
    for name, sampler in (('no grid', plain), (f'grid {args.resolution}^3', grid)):
        integrator.sampler = sampler
        sampler.update(field, 0)
        counts.update(sdf=0, radiance=0)
        per_gen = []
        with dr.suspend_grad():
            for _ in range(n_batches):
                generations.clear()
                ray, jitter = batch()
                integrator.trace(scene, ray, jitter=jitter)
                per_gen.append(np.array(generations))
        table[name] = (np.sum(per_gen, axis=0), counts['sdf'] / (n_batches * args.rays),
                       counts['radiance'] / (n_batches * args.rays))
    integrator._render_inside = original_render_inside
    del field.geometry, field.sdf, field.radiance

    # ---------------------------------------------------------------- timing
    opt = mi.ad.Adam(lr=0.0, params=field.params())

    def step():
        ray, jitter = batch()
        field.set_params(opt)
        r = integrator.trace(scene, ray, jitter=jitter)
        loss = dr.mean(dr.sum(integrator.tonemap(r.L))) + dr.sum(r.sparsity) + dr.sum(r.eikonal)
        dr.backward(loss)
        dr.eval([dr.grad(opt[k]) for k in opt.keys()])
        dr.sync_thread()

    # Two warm-up steps per setting (a batch with and one without skipped
    # segments take different kernels), then the settings alternate, so that
    # the load of the shared machine falls on both alike.
    settings = {'no grid': plain, f'grid {args.resolution}^3': grid}
    for sampler in settings.values():
        sampler.update(field, 0)
        integrator.sampler = sampler
        step()
        step()
    times = dict.fromkeys(settings, 0.0)
    for _ in range(n_batches):
        for name, sampler in settings.items():
            integrator.sampler = sampler
            start = time.perf_counter()
            step()
            times[name] += (time.perf_counter() - start) / n_batches
    grid.update(field, 0)
    dr.sync_thread()
    start = time.perf_counter()
    for _ in range(3):
        grid.update(field, 0)
    dr.sync_thread()
    refresh = (time.perf_counter() - start) / 3

    # ---------------------------------------------------------------- report
    cfg = plain.config
    rays = n_batches * args.rays
    print(f'\ncommand: python bench/sampling.py {" ".join(map(shlex.quote, argv or sys.argv[1:]))}')
    print(f'demo field {type(field).__name__}, inv_s {float(field.inv_s()[0]):.1f}, samples '
          f'{cfg.n_coarse}+{cfg.n_fine}, D_re {integrator.max_depth}, {args.rays} camera rays x {n_batches} '
          f'batches, device {mi.variant()}, {os.cpu_count()} CPU threads (shared, loaded machine)')
    gen_stats, _, _ = table[f'grid {args.resolution}^3']
    print(f'grid {args.resolution}^3: {100 * grid.grid.fraction():.1f} % of the cells occupied, '
          f'threshold {grid.grid.threshold(float(field.inv_s()[0])):.3f} (field units)\n')
    print('| generation | inside segments / camera ray | mean β | skipped by the grid | length clipped |')
    print('| --- | --- | --- | --- | --- |')
    for g, (n, beta, skipped, length, clipped) in enumerate(gen_stats):
        if g == 0 and n == 0:
            continue
        kind = 'refracted in (camera)' if g == 1 else 'internal reflection'
        print(f'| {g} ({kind}) | {n / rays:.3f} | {beta / max(n, 1):.3f} | {100 * skipped / max(n, 1):.1f} % '
              f'| {100 * clipped / max(length, 1e-9):.1f} % |')
    print()
    print('| setting | SDF evaluations / camera ray | radiance evaluations / camera ray | fwd+bwd per batch | camera rays/s |')
    print('| --- | --- | --- | --- | --- |')
    for name, (_, sdf, rad) in table.items():
        print(f'| {name} | {sdf:.0f} | {rad:.0f} | {1e3 * times[name]:.0f} ms | {args.rays / times[name]:.0f} |')
    print(f'\ngrid refresh ({args.resolution}^3 SDF evaluations): {1e3 * refresh:.0f} ms, every '
          f'{grid.config.occupancy_update_every} steps: {1e3 * refresh / grid.config.occupancy_update_every:.1f} ms/step')
    return 0


if __name__ == '__main__':
    sys.exit(main())
