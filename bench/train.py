"""Training speed and peak memory of one reconstruction step (Trainer.step).

    python bench/train.py [--presets fast small] [--batch 1024 256] [--steps 5]

For each preset (reneus_mi.presets) and batch size, a fresh process builds the
scene of the embedded demo dataset (the statuette in its glass block, 16 views
at 32x32, rendered once into ``--data``), runs ``--warmup`` steps (they
compile the kernels; timed apart) and then ``--steps`` timed steps of
``reneus_mi.train.trainer.Trainer.step`` (random batch, trace, loss, backward, Adam;
each ends with ``dr.sync_thread``). It prints iterations and camera rays per
second and the child's peak resident memory (``ru_maxrss``).

Presets: ``fast`` (hash grid, 24 + 8 samples), ``small`` (NeuS 32x4, 32 + 16 samples per inside segment), ``cpu``
(NeuS 64x4, 32 + 32), ``paper`` (NeuS 256x8 with 256 features, radiance
256x4, 64 + 64 samples in 4 up-sampling rounds). All render with D_re = 2.
``--timeout`` bounds each child: a setting that
does not finish its warm-up and steps in time is reported as such.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

def child(args) -> None:
    """One setting, one batch size: print one JSON line."""
    import drjit as dr
    import mitsuba as mi

    import reneus_mi  # noqa: F401
    from reneus_mi import runs
    from reneus_mi.data import load_dataset
    from reneus_mi.data.synthetic import demo_scene
    from reneus_mi.data.scene_xml import write_scene

    scene_path = demo_scene(args.data)
    xml = os.path.join(args.data, f'scene_bench_{args.one}.xml')
    write_scene(load_dataset(os.path.join(os.path.dirname(scene_path), 'box')), xml, preset=args.one)
    with tempfile.TemporaryDirectory() as out:
        trainer = runs.prepare(out, xml, train={'batch_rays': args.one_batch, 'iterations': 10 ** 6,
                                                'validate_every': 0, 'checkpoint_every': 0}).trainer()
        scene = trainer.scene
        warm = []
        for _ in range(args.warmup):
            start = time.perf_counter()
            trainer.step()
            warm.append(time.perf_counter() - start)
        times = []
        for _ in range(args.steps):
            start = time.perf_counter()
            stats = trainer.step()
            times.append(time.perf_counter() - start)
    total = sum(times)
    print(json.dumps({
        'settings': args.one, 'batch': args.one_batch, 'warmup_s': warm, 'steps': len(times),
        'it_per_s': len(times) / total, 'rays_per_s': len(times) * args.one_batch / total,
        'step_s_min': min(times), 'step_s_max': max(times), 'loss': stats.loss,
        'peak_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        'variant': mi.variant(), 'threads': dr.thread_count(),
        'integrator': scene.integrator().to_string()}))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    from reneus_mi.presets import PRESETS
    p.add_argument('--presets', nargs='+', choices=sorted(PRESETS), default=['fast', 'small'])
    p.add_argument('--batch', nargs='+', type=int, default=[1024, 256], help='camera rays per step')
    p.add_argument('--steps', type=int, default=5, help='timed steps')
    p.add_argument('--warmup', type=int, default=2, help='untimed first steps (compilation)')
    p.add_argument('--data', default=os.path.join(tempfile.gettempdir(), 'reneus_bench_demo'),
                   help='folder of the demo dataset (rendered there once)')
    p.add_argument('--timeout', type=float, default=900, help='seconds per setting and batch')
    p.add_argument('--one', help=argparse.SUPPRESS)
    p.add_argument('--one-batch', type=int, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.one:
        child(args)
        return 0

    command = 'python bench/train.py ' + ' '.join(sys.argv[1:] if argv is None else argv)
    print(f'command: {command}'.rstrip())
    env = {**os.environ, 'PYTHONUNBUFFERED': '1'}
    for name in args.presets:
        for batch in args.batch:
            cmd = [sys.executable, os.path.abspath(__file__), '--one', name, '--one-batch', str(batch),
                   '--steps', str(args.steps), '--warmup', str(args.warmup), '--data', args.data]
            start = time.perf_counter()
            try:
                proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout, env=env)
            except subprocess.TimeoutExpired:
                print(f'{name:6s} batch {batch:5d}: did not finish {args.warmup} warm-up + {args.steps} '
                      f'steps in {args.timeout:.0f} s')
                continue
            lines = [line for line in proc.stdout.splitlines() if line.startswith('{')]
            if proc.returncode != 0 or not lines:
                print(f'{name:6s} batch {batch:5d}: failed (exit {proc.returncode}): '
                      f'{proc.stderr.strip().splitlines()[-1:]}')
                continue
            r = json.loads(lines[-1])
            if name == args.presets[0] and batch == args.batch[0]:
                print(f"variant {r['variant']}, {r['threads']} threads, {os.cpu_count()} CPUs, "
                      f"load average {os.getloadavg()[0]:.1f} (other processes share the CPU)")
            warm = ', '.join(f'{w:.1f}' for w in r['warmup_s'])
            print(f"{name:6s} batch {batch:5d}: {r['it_per_s']:.3f} it/s, {r['rays_per_s']:.0f} rays/s "
                  f"(step {r['step_s_min']:.3f}-{r['step_s_max']:.3f} s over {r['steps']} steps; "
                  f"warm-up steps {warm} s); peak RSS {r['peak_rss_mb']:.0f} MB; "
                  f"{r['integrator']}; process {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == '__main__':
    sys.exit(main())
