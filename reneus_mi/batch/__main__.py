"""Reconstruct a collection: ``python -m reneus_mi.batch COLLECTION -o RUNS_DIR``.

COLLECTION is a folder of dataset folders (or capture folders: photographs and
capture.json), or a manifest (CSV or JSON: name, data, and per-specimen
settings such as preset, ior, size_mm or any dotted setting like
train.iterations). Each specimen is a run in RUNS_DIR/<name>; RUNS_DIR/summary.csv
and summary.html say where each stands. Run the same command again to resume
the unfinished runs and retry the failed ones; finished runs are left alone
(--redo NAME starts one over). --engine ray places the runs on a Ray cluster
(--ray-address), --engine slurm submits a Slurm job array (--partition, --time).
"""
from __future__ import annotations

import argparse
import functools
import sys
import warnings

from reneus_mi.batch import engines, worker
from reneus_mi.batch.batch_folder import BatchFolder
from reneus_mi.batch.collection import read_collection
from reneus_mi.batch.dispatch import run_batch
from reneus_mi.batch.engines import DEVICES, ENGINES
from reneus_mi.train.run_folder import RunState
from reneus_mi.utils.errors import exit_on_error


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == [worker.TASK_OPTION] and len(argv) == 2:
        return worker.work(argv[1])
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.batch', description=__doc__.split('\n\n')[0],
                                     epilog=__doc__.split('\n\n', 1)[1])
    parser.add_argument('collection', metavar='COLLECTION', help='folder of dataset or capture folders, or a '
                        'manifest (.csv, .json)')
    parser.add_argument('-o', '--output', required=True, metavar='RUNS_DIR', help='the batch folder: a run '
                        'folder per specimen, the summaries')
    parser.add_argument('--preset', default='fast', help="preset of the specimens whose row names none "
                        '(default: %(default)s)')
    parser.add_argument('--set', dest='settings', metavar='PATH=VALUE', action='append', default=[],
                        help="a setting of every specimen's run by its dotted path, under the manifest's "
                             '(train.iterations=500; repeatable)')
    parser.add_argument('--redo', metavar='NAME', action='append', default=[],
                        help="start this specimen's run over, even a finished one ('all': every one; "
                             'repeatable)')
    parser.add_argument('--engine', choices=ENGINES, default='local', help='where the runs run (default: '
                        '%(default)s: a pool on this machine)')
    parser.add_argument('--device', choices=DEVICES, default='auto',
                        help='cpu or gpu runs (auto: local: a GPU when the machine has one; ray: when the '
                             'cluster has GPUs; slurm: cpu)')
    parser.add_argument('--quiet', action='store_true', help='print only the end')
    local = parser.add_argument_group('local engine')
    local.add_argument('--workers', type=int, help='runs at a time (default: one per GPU, or on the CPU one '
                       'per 4 cores, as many as the memory holds)')
    local.add_argument('--threads', type=int, help='Dr.Jit threads per run (default: the cores shared out)')
    cluster = parser.add_argument_group('ray and slurm engines')
    cluster.add_argument('--cpus-per-run', type=int, help='cores declared per run (default: 4, at most a '
                         "Ray node's)")
    cluster.add_argument('--ray-address', help="Ray cluster to join (ray.init(address=...); default: "
                         "RAY_ADDRESS, else a local Ray)")
    cluster.add_argument('--partition', help='Slurm partition')
    cluster.add_argument('--time', type=float, metavar='MINUTES', help='Slurm time limit per run (default: '
                         '1.5 x the time budget + 15 min, or 240)')
    cluster.add_argument('--max-parallel', type=int, help='Slurm array tasks at a time')
    args = parser.parse_args(argv)
    with exit_on_error(RuntimeError):
        states = run(args)
    failed = [n for n, s in states.items() if s.name == 'failed']
    finished = sum(s.name == 'finished' for s in states.values())
    print(f'{finished} of {len(states)} finished' + (f'; failed: {", ".join(failed)}' if failed else ''))
    return 1 if failed else 0


def run(args) -> dict[str, RunState]:
    engines.check_options(args.engine, device=args.device, workers=args.workers, threads=args.threads,
                          cpus=args.cpus_per_run, minutes=args.time, max_parallel=args.max_parallel)
    with warnings.catch_warnings():
        # Every specimen's warning (exit_on_error prints each on one line).
        warnings.simplefilter('always')
        specimens = read_collection(args.collection, preset=args.preset, settings=args.settings)

    def make(configs, files_of, tasks):
        return engines.make_engine(args.engine, configs, files_of, tasks=tasks, device=args.device,
                                   workers=args.workers, threads=args.threads, cpus=args.cpus_per_run,
                                   minutes=args.time, ray_address=args.ray_address, partition=args.partition,
                                   max_parallel=args.max_parallel, slurm_folder=BatchFolder(args.output).slurm)
    say = (lambda _: None) if args.quiet else functools.partial(print, flush=True)
    return run_batch(specimens, args.output, make, redo=args.redo, say=say, collection=args.collection)


if __name__ == '__main__':
    sys.exit(main())
