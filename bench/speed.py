"""Training speed and time to quality, per preset and device.

    python bench/speed.py [--presets fast cpu paper fast:train.refine.ior=true] [--minutes 10]
                          [--points 0.5 1 2 5 10]
                          [--views 48] [--res 128] [--object insect] [--out runs/speed] [--doc docs]
                          [--set train.sample_budget=49152 model.render.rr_threshold=0.2 ...]

On one synthetic scene of the generator (``reneus_mi.data.synthetic``: the object in
its glass block, Mitsuba's path tracer, rendered once into ``OUT/data``) each
preset trains in a fresh process for ``--minutes`` of wall clock, counted from
its first step with the kernels compiled (the compilation is timed apart: the
first step's time minus a steady step's). At each of ``--points`` (minutes) the
mesh is extracted and compared with the ground truth (Chamfer-L1 x100, largest
component); that evaluation is not counted in the wall clock. Reported per
preset (a row ``PRESET:PATH=VALUE,...`` is a preset with settings of its own, e.g. a
refining run): step time, camera rays/s, field samples/s, peak resident memory,
compile time and the Chamfer curve. Writes ``DOC/speed.md`` (with the command
and the device) and ``DOC/speed.png`` (the curves; needs matplotlib).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))


def device() -> str:
    import drjit as dr
    import mitsuba as mi
    import reneus_mi  # noqa: F401
    if mi.variant().startswith('cuda'):
        name = subprocess.run(['nvidia-smi', '--query-gpu=name', '--format=csv,noheader'],
                              capture_output=True, text=True).stdout.strip() or 'NVIDIA GPU'
        return f'{name} (`{mi.variant()}`)'
    return (f'{os.cpu_count()}-core CPU {platform.processor() or platform.machine()}, '
            f'{dr.thread_count()} threads (`{mi.variant()}`)')


def dataset(args) -> str:
    from reneus_mi.data.synthetic import make_dataset
    folder = os.path.join(args.out, 'data')
    if not os.path.isfile(os.path.join(folder, 'box', 'transforms.json')):
        print(f'rendering {args.object}, {args.views} views at {args.res} px into {folder}', flush=True)
        make_dataset(args.object, folder, views=args.views, res=args.res, spp=args.spp, subsets=('box',))
    return os.path.join(folder, 'box')


def row(entry: str) -> tuple[str, list[str]]:
    """``PRESET[:PATH=VALUE,...]``: the preset and the row's own settings."""
    name, _, settings = entry.partition(':')
    return name, [item for item in settings.split(',') if item]


def child(args) -> None:
    """One preset: train, evaluate at the time points, print one JSON line."""
    import drjit as dr

    import reneus_mi  # noqa: F401
    from reneus_mi import runs
    from reneus_mi.data import load_dataset
    from reneus_mi.geometry.chamfer import chamfer
    from reneus_mi.geometry.mesh import load_mesh
    from reneus_mi.geometry.surface import components
    from reneus_mi.data.scene_xml import write_scene

    data = dataset(args)
    name, own = row(args.one)
    tag = args.one.replace(':', '_').replace('=', '-').replace(',', '_')
    xml = os.path.join(args.out, f'scene_{tag}.xml')
    write_scene(load_dataset(data), xml, preset=name)
    run_dir = os.path.join(args.out, tag)
    trainer = runs.prepare(run_dir, xml, train={'iterations': 10 ** 7, 'validate_every': 0, 'checkpoint_every': 0},
                           settings=args.set + own).trainer()
    gt = load_mesh(load_dataset(data).gt_mesh)
    points = sorted(args.points)
    curve, steps = [], []
    start = time.perf_counter()
    first = trainer.step().seconds
    clock, evaluated, samples, rays = 0.0, 0, 0.0, 0
    while clock < 60.0 * args.minutes:
        stats = trainer.step()
        clock += stats.seconds
        steps.append(stats.seconds)
        samples += stats.samples
        rays += stats.rays
        while evaluated < len(points) and clock >= 60.0 * points[evaluated]:
            try:
                # The run's own clean-up (the preset's postprocess) on the mesh it would write.
                mesh = trainer.write_mesh(os.path.join(run_dir, f'mesh_{points[evaluated]}min.ply'),
                                          resolution=args.mesh_resolution)
                value, pieces = chamfer(mesh, gt)['chamfer'], components(mesh)
            except ValueError:   # no surface yet
                value, pieces = float('nan'), 0
            curve.append({'minutes': points[evaluated], 'iterations': trainer.iteration, 'chamfer': value,
                          'components': pieces})
            print(f'[{args.one}] {points[evaluated]} min, {trainer.iteration} it: Chamfer x100 {value:.3f}, '
                  f'{pieces} component(s)', file=sys.stderr, flush=True)
            evaluated += 1
    dr.sync_thread()
    steady = float(np.median(steps))
    print(json.dumps({
        'preset': args.one, 'batch': rays / len(steps), 'step_s': steady, 'rays_per_s': rays / len(steps) / steady,
        'samples_per_s': samples / sum(steps), 'compile_s': max(first - steady, 0.0),
        'iterations': trainer.iteration, 'wall_s': time.perf_counter() - start,
        'peak_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        'curve': curve, 'integrator': trainer.integrator.to_string()}))


def write_doc(results: list[dict], args, command: str, dev: str, load: float) -> None:
    from reneus_mi.utils.io import atomic_write_text
    lines = ['# Training speed and time to quality', '',
             f'Generated by `{command}` on {time.strftime("%Y-%m-%d")}.', '',
             f'- Device: {dev}; load average before the benchmark {load:.1f}'
             + (' (the machine was shared: figures are pessimistic).' if load > 1.0 else ' (otherwise idle).'),
             f'- Scene: the generator\'s {args.object} in a glass block (IOR 1.45, ambient 0.8), '
             f'{args.views} views at {args.res} px, {args.spp} spp; D_re = 2.',
             '- Wall clock from the first step with compiled kernels; mesh evaluation (marching cubes at '
             f'{args.mesh_resolution}^3, the run\'s clean-up, Chamfer-L1 x100 and in brackets the '
             'connected components) not counted.', '',
             '| preset | device | step (s) | camera rays/s | samples/s | peak RSS (MB) | compile (s) | '
             + ' | '.join(f'CD @ {p:g} min' for p in sorted(args.points)) + ' |',
             '| --- ' * (7 + len(args.points)) + '|']
    for r in results:
        if 'error' in r:
            lines.append(f"| {r['preset']} | {dev} | {r['error']} |")
            continue
        cds = {c['minutes']: c for c in r['curve']}
        cells = ' | '.join('—' if not np.isfinite(cds.get(p, {}).get('chamfer', np.nan))
                           else f"{cds[p]['chamfer']:.2f} ({cds[p]['components']})" for p in sorted(args.points))
        lines.append(f"| {r['preset']} | {dev} | {r['step_s']:.3f} | {r['rays_per_s']:.0f} | "
                     f"{r['samples_per_s'] / 1e3:.0f} k | {r['peak_rss_mb']:.0f} | {r['compile_s']:.1f} | {cells} |")
    lines += ['', '`—`: no surface yet (or the run did not reach that point).', '',
              '![Chamfer against wall clock](speed.png)', '']
    os.makedirs(args.doc, exist_ok=True)
    atomic_write_text(os.path.join(args.doc, 'speed.md'), '\n'.join(lines))
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        print('matplotlib is not installed: no figure (pip install -e .[notebooks])')
        return
    fig, ax = plt.subplots(figsize=(5, 3.2))
    for r in results:
        if 'curve' in r:
            ax.plot([c['minutes'] for c in r['curve']], [c['chamfer'] for c in r['curve']], 'o-', label=r['preset'])
    ax.set_xscale('log')
    ax.set_xlabel('wall clock (min)')
    ax.set_ylabel('Chamfer-L1 x100')
    ax.set_title(dev, fontsize=8)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(args.doc, 'speed.png'), dpi=120)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--presets', nargs='+', default=['fast', 'cpu', 'paper'],
                   help='rows: a preset, or PRESET:PATH=VALUE,... for one with its own settings '
                        '(e.g. fast:train.refine.ior=true)')
    p.add_argument('--minutes', type=float, default=10.0, help='wall clock of training per preset')
    p.add_argument('--points', nargs='+', type=float, default=[0.5, 1, 2, 5, 10],
                   help='minutes at which the mesh is evaluated')
    p.add_argument('--object', default='insect')
    p.add_argument('--views', type=int, default=48)
    p.add_argument('--res', type=int, default=128, help='image size (the issue: 128 on CPU, 400 on GPU)')
    p.add_argument('--spp', type=int, default=256, help="samples per pixel of the photographs")
    p.add_argument('--mesh-resolution', type=int, default=128)
    p.add_argument('--out', default=os.path.join('runs', 'speed'))
    p.add_argument('--doc', default=os.path.join(ROOT, 'docs'))
    p.add_argument('--set', nargs='*', default=[], metavar='PATH=VALUE',
                   help='settings for every preset (e.g. train.sample_budget=49152, '
                        'model.render.rr_threshold=0.2)')
    p.add_argument('--one', help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    args.out = os.path.abspath(args.out)
    if args.one:
        child(args)
        return 0
    import reneus_mi  # noqa: F401
    from reneus_mi.presets import PRESETS
    unknown = [n for n in args.presets if row(n)[0] not in PRESETS]
    if unknown:
        p.error(f"--presets {' '.join(unknown)}: expected some of {', '.join(PRESETS)}")
    command = 'python bench/speed.py ' + ' '.join(sys.argv[1:] if argv is None else argv)
    print(f'command: {command}'.rstrip(), flush=True)
    load = os.getloadavg()[0]
    dataset(args)
    dev = device()
    results = []
    for name in args.presets:
        cmd = [sys.executable, os.path.abspath(__file__), *(sys.argv[1:] if argv is None else argv), '--one', name]
        proc = subprocess.run(cmd, stdout=subprocess.PIPE, text=True)
        lines = [line for line in proc.stdout.splitlines() if line.startswith('{')]
        r = json.loads(lines[-1]) if proc.returncode == 0 and lines else \
            {'preset': name, 'error': f'failed (exit {proc.returncode})'}
        results.append(r)
        if 'error' not in r:
            print(f"{name}: {r['rays_per_s']:.0f} camera rays/s, {r['samples_per_s'] / 1e3:.0f} k samples/s, "
                  f"step {r['step_s']:.3f} s, compile {r['compile_s']:.1f} s, peak {r['peak_rss_mb']:.0f} MB; "
                  + ', '.join(f"{c['minutes']:g} min: {c['chamfer']:.2f}" for c in r['curve']), flush=True)
    write_doc(results, args, command, dev, load)
    print(f"wrote {os.path.join(args.doc, 'speed.md')}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
