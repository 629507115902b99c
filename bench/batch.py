"""Specimens per hour of a batch: the local pool against a local Ray, one worker against two.

    python bench/batch.py [--specimens 4] [--preset tiny] [--iterations 30] [--workers 1 2]
                          [--engines local ray] [--doc docs/batch.md]

A synthetic dataset (the statuette in its glass block, ``--views`` at ``--res``,
rendered once into ``--data`` by Mitsuba's path tracer) is copied into a
collection of ``--specimens`` specimens; each engine and worker count runs the
whole batch (``reneus_mi.batch.dispatch.run_batch``: worker start, the run, the
mesh, Chamfer and the preview) into a fresh folder. N workers share the
machine's cores: N runs at a time of cores / N Dr.Jit threads each (Ray: a
local Ray of N CPUs, tasks of one CPU's share each). The wall time of the batch
gives specimens per hour; Ray's own start is timed apart (a cluster is up
before a batch comes). The table goes to the ``bench`` section of ``--doc``;
figures taken when the load average before the benchmark was above 1.5 are marked as from a
loaded machine.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time

import reneus_mi  # noqa: F401
from reneus_mi.batch import engines
from reneus_mi.batch.collection import read_collection
from reneus_mi.batch.dispatch import run_batch
from reneus_mi.utils.io import write_section

#: Load average above which the figures are marked as from a loaded machine.
LOADED = 1.5


def dataset(folder: str, views: int, res: int) -> str:
    """The synthetic dataset's folder (rendered once)."""
    from reneus_mi.data.synthetic import make_dataset
    data = os.path.join(folder, 'box')
    if not os.path.isfile(os.path.join(data, 'transforms.json')):
        make_dataset('statuette', folder, views=views, res=res, spp=32, subsets=('box',))
    return data


def one_batch(collection: str, out: str, engine: str, workers: int, args) -> dict:
    cores = engines.cpu_count()
    threads = max(1, cores // workers)
    specimens = read_collection(collection, preset=args.preset,
                                settings=[f'train.iterations={args.iterations}'])
    shutdown, ray_start = (lambda: None), 0.0
    if engine == 'ray':
        import ray
        start = time.perf_counter()
        ray.init(num_cpus=workers * threads, include_dashboard=False, log_to_driver=False)
        ray_start, shutdown = time.perf_counter() - start, ray.shutdown

    def make(configs, files_of, tasks):
        return engines.make_engine(engine, configs, files_of, tasks=tasks, workers=workers, threads=threads,
                                   cpus=threads)
    loads = [os.getloadavg()[0]]
    start = time.perf_counter()
    try:
        states = run_batch(specimens, out, make, say=lambda _: None)
    finally:
        wall = time.perf_counter() - start
        shutdown()
    loads.append(os.getloadavg()[0])
    finished = sum(s.name == 'finished' for s in states.values())
    return {'engine': engine, 'workers': workers, 'threads': threads, 'wall': wall, 'finished': finished,
            'per_hour': finished / wall * 3600, 'ray_start': ray_start, 'load': max(loads)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--specimens', type=int, default=4)
    p.add_argument('--preset', default='tiny')
    # At 100 steps the tiny preset loses the statuette's surface (no zero crossing: the run
    # fails, honestly, and a throughput of failures is no figure).
    p.add_argument('--iterations', type=int, default=30)
    p.add_argument('--views', type=int, default=12)
    p.add_argument('--res', type=int, default=32)
    p.add_argument('--workers', type=int, nargs='+', default=[1, 2])
    p.add_argument('--engines', nargs='+', choices=['local', 'ray'], default=['local', 'ray'])
    p.add_argument('--data', default=os.path.join(tempfile.gettempdir(), 'reneus_bench_batch'),
                   help='folder of the synthetic dataset (rendered there once)')
    p.add_argument('--doc', default=os.path.join(os.path.dirname(__file__), '..', 'docs', 'batch.md'))
    args = p.parse_args(argv)
    command = 'python bench/batch.py ' + ' '.join(sys.argv[1:] if argv is None else argv)
    print(f'command: {command}', flush=True)
    # The batches load the machine themselves (their runs fill the cores): only the load
    # before them says whether something else was running.
    load_before = os.getloadavg()[0]
    data = dataset(args.data, args.views, args.res)
    work = tempfile.mkdtemp(prefix='reneus_bench_batch_')
    collection = os.path.join(work, 'collection')
    for i in range(args.specimens):
        shutil.copytree(data, os.path.join(collection, f'specimen_{i:02d}'))
    rows = []
    try:
        for engine in args.engines:
            for workers in args.workers:
                r = one_batch(collection, os.path.join(work, f'runs_{engine}_{workers}'), engine, workers, args)
                rows.append(r)
                print(r, flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    base = {r['engine']: r['per_hour'] for r in rows if r['workers'] == min(args.workers)}
    loaded = load_before > LOADED
    lines = [f'`{command}`: {args.specimens} specimens (the statuette, {args.views} views at {args.res}x{args.res}), '
             f'preset `{args.preset}` with {args.iterations} iterations each, on {engines.cpu_count()} cores'
             + f'; load average {load_before:.1f} before it'
             + (' (**a loaded machine**: other processes shared the cores)' if loaded else ' (otherwise idle)')
             + '; the column is the load while each batch ran, its own runs included.', '',
             '| engine | workers x threads | batch wall s | specimens per hour | vs 1 worker | engine start s | '
             'load average |', '| --- | --- | --- | --- | --- | --- | --- |']
    for r in rows:
        ratio = f"{r['per_hour'] / base[r['engine']]:.2f}x" if base[r['engine']] else '—'
        ray_start = f"{r['ray_start']:.1f}" if r['engine'] == 'ray' else ''
        lines.append(f"| {r['engine']} | {r['workers']} x {r['threads']} | {r['wall']:.1f} | {r['per_hour']:.0f} | "
                     f"{ratio} | {ray_start} | {r['load']:.1f} |")
    text = '\n'.join(lines)
    print(text)
    write_section(args.doc, 'bench', text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
