"""Where the runs of a batch run: a local pool, Ray, or Slurm, behind one interface.

An :class:`Engine` places tasks (one specimen's :func:`~reneus_mi.batch.worker.run_task`
each) and reports them as they end; it never decides anything about a run: the
worker does the run, the batch reads its state from disk. What a task needs
(:class:`Resources`: cores, GPUs, memory, time) comes from the run's preset
and is declared to Ray and Slurm, which place the tasks on their machines.

========  ====================================================================
engine    what
========  ====================================================================
local     a pool of worker processes sized to this machine: one run per GPU,
          or on the CPU runs of :data:`CORES_PER_RUN` threads sharing the cores
          (and as many as the memory holds)
ray       a Ray task per specimen (``ray.init(address=...)``, or a local Ray)
          with its CPUs and GPUs declared; ``pip install 'reneus-mi[ray]'``
slurm     a Slurm job array through submitit, one task per specimen, the
          resources as sbatch options; ``pip install 'reneus-mi[slurm]'``
========  ====================================================================

A worker that dies (SIGKILL, out of memory, a lost node, a job past its time)
is reported as ``died`` with a one-line reason; the batch records it in the
run's folder.
"""
from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass

import drjit as dr

from reneus_mi.batch.worker import EXIT_BUSY, TASK_OPTION, run_task
from reneus_mi.train.trainer import training_bytes
from reneus_mi.utils import interrupt
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.limits import MEMORY_FRACTION, physical_memory

ENGINES = ('local', 'ray', 'slurm')
DEVICES = ('auto', 'cpu', 'gpu')
#: Threads one CPU run uses well. Dr.Jit splits a kernel over its threads in blocks of
#: lanes; a training step of the CPU presets (1e5 to 1e6 lanes per kernel, many small
#: kernels) leaves threads idle beyond a few, where a second run keeps them busy.
CORES_PER_RUN = 4
#: Memory of one run beyond its ray batch: Mitsuba, LLVM, the kernels, the dataset (bytes).
BASE_MEMORY = 2 << 30
#: Slurm's time limit for a run without a time budget (minutes; --time overrides it).
DEFAULT_MINUTES = 240


@dataclass
class Resources:
    """What one run needs, declared to the engine."""
    cpus: int
    """Cores (Dr.Jit threads of the run)."""
    gpus: int
    """GPUs (0 on the CPU variant, 1 on CUDA)."""
    mem_gb: float
    """Memory, GiB."""
    minutes: int
    """Wall time (Slurm's time limit)."""

    @property
    def variant(self) -> str:
        return 'cuda_ad_rgb' if self.gpus else 'llvm_ad_rgb'


def run_memory(config) -> int:
    """Bytes one run of ``config`` (a ReconstructionConfig) needs, from its preset's batch."""
    model, train = config.model, config.train
    samples = model.sampler.n_coarse + model.sampler.n_fine + 1
    return 2 * training_bytes(train.batch_rays, samples, model.render.max_depth + 1) + BASE_MEMORY


def resources(configs, *, gpu: bool, cpus: int, minutes: float | None = None) -> Resources:
    """The resources of the largest of ``configs`` (a task of the batch fits any specimen):
    memory from the batch and samples, time from the time budget (``max_minutes``, with
    room for the start and the mesh) or ``minutes``."""
    memory = max(run_memory(c) for c in configs)
    if minutes is None:
        budgets = [c.train.max_minutes for c in configs]
        minutes = max(budgets) * 1.5 + 15 if all(b > 0 for b in budgets) else DEFAULT_MINUTES
    return Resources(cpus=max(1, int(cpus)), gpus=1 if gpu else 0, mem_gb=math.ceil(memory / 2**30 * 10) / 10,
                     minutes=int(math.ceil(minutes)))


def cpu_count() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def local_gpus() -> list[str]:
    """The CUDA devices of this machine, as CUDA_VISIBLE_DEVICES names them (none: [])."""
    if not dr.has_backend(dr.JitBackend.CUDA):
        return []
    visible = os.environ.get('CUDA_VISIBLE_DEVICES')
    if visible is not None:
        return [d for d in visible.split(',') if d.strip()]
    if shutil.which('nvidia-smi'):
        out = subprocess.run(['nvidia-smi', '-L'], capture_output=True, text=True).stdout
        gpus = [str(i) for i, line in enumerate(out.splitlines()) if line.startswith('GPU ')]
        if gpus:
            return gpus
    return ['0']


class Engine:
    """Places tasks and tells which ended. ``submit`` takes what ``free`` allows."""
    name = ''
    threads: int
    """Dr.Jit threads of each run (its declared cores)."""
    variant: str
    """The Mitsuba variant of the runs."""

    def free(self) -> int:
        """How many more tasks it takes now."""
        raise NotImplementedError

    def submit(self, tasks: list[dict]) -> None:
        raise NotImplementedError

    def wait(self, timeout: float) -> list[tuple[dict, dict]]:
        """(task, outcome) of the tasks that ended, waiting up to ``timeout`` s for one. An
        outcome is :func:`~reneus_mi.batch.worker.run_task`'s, or ``{'outcome': 'died',
        'reason': ..., 'seconds': ...}``."""
        raise NotImplementedError

    def running(self) -> int:
        raise NotImplementedError

    def describe(self) -> str:
        raise NotImplementedError

    on_interrupt = 'the runs were stopped'
    """What Ctrl-C in the batch does to the runs out (the interrupted batch's last line)."""

    def abandon(self) -> str | None:
        """The batch ends at once (a second Ctrl-C): end what is still out with it, and say
        what that left (None: nothing was out, :attr:`on_interrupt` holds)."""
        return None

    def close(self) -> list[tuple[dict, dict]]:
        """Stop, as Ctrl-C would, what is still out; (task, outcome) of the tasks that ended
        in doing so (an outcome ``interrupted``: the run keeps its last checkpoint)."""
        return []


class LocalPool(Engine):
    """Worker processes on this machine (``python -m reneus_mi.batch --task TASK_JSON``), ``workers`` at
    a time, each with ``threads`` Dr.Jit threads or one of ``gpus``. A process per run: a
    run's memory goes back when it ends, and a crash takes one specimen down, not the pool.
    The workers run in sessions of their own, so that a terminal's Ctrl-C reaches the batch
    alone and each worker gets exactly one from it (a second would cut its checkpoint)."""
    name = 'local'
    on_interrupt = 'each run wrote its checkpoint and stopped'

    def __init__(self, files_of, *, workers: int, threads: int, gpus: list[str] = ()):
        self.files_of, self.workers, self.threads, self.gpus = files_of, workers, threads, list(gpus)
        self.variant = 'cuda_ad_rgb' if self.gpus else 'llvm_ad_rgb'
        self.slots: dict[int, tuple[subprocess.Popen, dict, float]] = {}

    def free(self) -> int:
        return self.workers - len(self.slots)

    def submit(self, tasks: list[dict]) -> None:
        for task in tasks:
            slot = min(set(range(self.workers)) - set(self.slots))
            env = dict(os.environ, RENEUS_VARIANT=task['variant'])
            if self.gpus:
                env['CUDA_VISIBLE_DEVICES'] = self.gpus[slot % len(self.gpus)]
            files = self.files_of(task['specimen']['name'])
            os.makedirs(files.path, exist_ok=True)
            with open(files.worker_log, 'ab') as log:
                proc = subprocess.Popen([sys.executable, '-m', 'reneus_mi.batch', TASK_OPTION, json.dumps(task)],
                                        stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env,
                                        start_new_session=True)
            self.slots[slot] = (proc, task, time.perf_counter())

    def wait(self, timeout: float) -> list[tuple[dict, dict]]:
        deadline = time.monotonic() + timeout
        while True:
            ended = []
            for slot, (proc, task, start) in list(self.slots.items()):
                code = proc.poll()
                if code is None:
                    continue
                del self.slots[slot]
                seconds = time.perf_counter() - start
                log = self.files_of(task['specimen']['name']).worker_log
                if code == 0:
                    outcome = {'outcome': 'ended', 'seconds': seconds}
                elif code == EXIT_BUSY:
                    outcome = {'outcome': 'busy', 'reason': 'in use by another process', 'seconds': seconds}
                elif code == interrupt.STATUS:
                    outcome = {'outcome': 'interrupted', 'seconds': seconds}
                elif code < 0:
                    outcome = {'outcome': 'died', 'seconds': seconds,
                               'reason': f'worker killed by {signal.Signals(-code).name}'}
                else:
                    outcome = {'outcome': 'died', 'seconds': seconds,
                               'reason': f'worker exited with status {code} (see {log})'}
                ended.append((task, outcome))
            if ended or not self.slots or time.monotonic() >= deadline:
                return ended
            time.sleep(0.1)

    def running(self) -> int:
        return len(self.slots)

    def describe(self) -> str:
        each = f'GPU {", ".join(self.gpus)}' if self.gpus else f'{self.threads} thread(s) each'
        return f'local pool of {self.workers} worker(s), {each}'

    def abandon(self) -> str | None:
        """Kill each worker still running, with everything in its session: a worker must not
        train on, detached, after its batch said it stopped."""
        alive = [proc for proc, _, _ in list(self.slots.values()) if proc.poll() is None]
        for proc in alive:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
        for proc in alive:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(5)
        if not alive:
            return None
        return (f'{len(alive)} run(s) killed at the second Ctrl-C, before their checkpoint: each resumes '
                'from its last one')

    def close(self) -> list[tuple[dict, dict]]:
        """Ctrl-C to each worker still running (it writes its checkpoint, then ends)."""
        for proc, _, _ in self.slots.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc, _, _ in self.slots.values():
            try:
                proc.wait()
            except KeyboardInterrupt:
                proc.kill()
        return self.wait(0.0)


class RayEngine(Engine):
    """A Ray task per specimen with its CPUs, GPUs and memory declared. Ray places them on
    its nodes; the batch folder must be on a drive they all share (and reneus-mi installed
    on them). A task is never retried by Ray: the batch records a dead worker, and the
    next batch resumes its run."""
    name = 'ray'

    def __init__(self, configs, *, address: str | None = None, device: str = 'auto', cpus: int | None = None):
        try:
            import ray
        except ImportError:
            raise ReneusError("--engine ray needs Ray: pip install 'reneus-mi[ray]'") from None
        self.ray, self.refs = ray, {}
        self.started = not ray.is_initialized()
        if self.started:
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False)
            except (ConnectionError, RuntimeError, ValueError) as e:
                raise ReneusError(f'--ray-address {address}: cannot connect ({one_line_of(e)})') from None
        nodes = [n['Resources'] for n in ray.nodes() if n.get('Alive')]
        largest = max(int(n.get('CPU', 1)) for n in nodes)
        gpu = device == 'gpu' or (device == 'auto' and any(n.get('GPU', 0) for n in nodes))
        # A task asking for more cores than any node has would wait for ever.
        self.res = resources(configs, gpu=gpu, cpus=min(cpus or CORES_PER_RUN, largest))
        res = self.res
        self.threads, self.variant = res.cpus, res.variant
        self.remote = ray.remote(run_task)
        self.options = dict(num_cpus=res.cpus, num_gpus=res.gpus, memory=int(res.mem_gb * 2**30), max_retries=0,
                            runtime_env={'env_vars': {'RENEUS_VARIANT': res.variant}})

    def free(self) -> int:
        return 1 << 30

    def submit(self, tasks: list[dict]) -> None:
        for task in tasks:
            options = dict(self.options, name=f"reneus:{task['specimen']['name']}")
            self.refs[self.remote.options(**options).remote(task)] = (task, time.perf_counter())

    def wait(self, timeout: float) -> list[tuple[dict, dict]]:
        if not self.refs:
            return []
        ready, _ = self.ray.wait(list(self.refs), num_returns=1, timeout=timeout)
        if ready:
            ready, _ = self.ray.wait(list(self.refs), num_returns=len(self.refs), timeout=0)
        return self._collect(ready)

    def _collect(self, refs) -> list[tuple[dict, dict]]:
        """(task, outcome) of these ended tasks, no longer out; a cancelled one was interrupted."""
        ended = []
        for ref in refs:
            task, start = self.refs.pop(ref)
            try:
                outcome = self.ray.get(ref)
            except self.ray.exceptions.TaskCancelledError:
                outcome = {'outcome': 'interrupted', 'seconds': time.perf_counter() - start}
            except self.ray.exceptions.RayError as e:
                outcome = {'outcome': 'died', 'reason': _ray_death(self.ray, e),
                           'seconds': time.perf_counter() - start}
            ended.append((task, outcome))
        return ended

    def running(self) -> int:
        return len(self.refs)

    def describe(self) -> str:
        total = self.ray.cluster_resources()
        return (f"Ray ({total.get('CPU', 0):g} CPUs, {total.get('GPU', 0):g} GPUs), "
                f'{self.res.cpus} CPU(s) and {self.res.gpus} GPU(s) per run')

    on_interrupt = 'each run wrote its checkpoint and stopped'

    def abandon(self) -> str | None:
        """Force-cancel each task still out (Ray kills its worker), and a Ray this batch
        started goes with the batch."""
        out = list(self.refs)
        for ref in out:
            with contextlib.suppress(Exception):
                self.ray.cancel(ref, force=True)
        if not out:
            return None
        return (f'{len(out)} run(s) killed at the second Ctrl-C, before their checkpoint: each resumes from '
                'its last one')

    def close(self) -> list[tuple[dict, dict]]:
        """Cancel each task still out: Ray raises KeyboardInterrupt in it, its run writes its
        checkpoint at the end of the step and ends; only then may a Ray this batch started
        go, since shutting it down kills its workers where they are."""
        for ref in self.refs:
            self.ray.cancel(ref)
        done, _ = self.ray.wait(list(self.refs), num_returns=len(self.refs)) if self.refs else ([], [])
        ended = self._collect(done)
        if self.started:
            self.ray.shutdown()
        return ended


def _ray_death(ray, e) -> str:
    kinds = {'WorkerCrashedError': 'worker died (killed, or out of memory)', 'NodeDiedError': 'node lost',
             'OutOfMemoryError': 'killed by Ray: out of memory'}
    return kinds.get(type(e).__name__, f'{type(e).__name__}: {one_line_of(e)}')


class SlurmEngine(Engine):
    """A Slurm job array through submitit (``cluster='local'``: submitit's local executor,
    for tests). The batch folder must be on a drive the nodes share."""
    name = 'slurm'

    def __init__(self, res: Resources, folder: str, *, partition: str | None = None,
                 max_parallel: int | None = None, cluster: str | None = None, poll: float = 2.0):
        try:
            import submitit
        except ImportError:
            raise ReneusError("--engine slurm needs submitit: pip install 'reneus-mi[slurm]'") from None
        self.submitit, self.res, self.jobs, self.poll = submitit, res, {}, poll
        self.threads, self.variant = res.cpus, res.variant
        self.executor = submitit.AutoExecutor(folder=folder, cluster=cluster)
        params = dict(name='reneus-batch', timeout_min=res.minutes, cpus_per_task=res.cpus,
                      gpus_per_node=res.gpus, mem_gb=res.mem_gb,
                      slurm_setup=[f'export RENEUS_VARIANT={res.variant}'])
        if partition:
            params['slurm_partition'] = partition
        if max_parallel:
            params['slurm_array_parallelism'] = max_parallel
        self.executor.update_parameters(**params)

    def free(self) -> int:
        return 1 << 30

    def submit(self, tasks: list[dict]) -> None:
        if tasks:
            for job, task in zip(self.executor.map_array(run_task, tasks), tasks):
                self.jobs[job] = (task, time.perf_counter())

    def wait(self, timeout: float) -> list[tuple[dict, dict]]:
        deadline = time.monotonic() + timeout
        while True:
            ended = []
            for job, (task, start) in list(self.jobs.items()):
                if not job.done():
                    continue
                del self.jobs[job]
                try:
                    outcome = job.result()
                except self.submitit.core.utils.UncompletedJobError:
                    outcome = {'outcome': 'died', 'reason': f'job {job.job_id} ended without a result '
                                                             f'({job.state})'}
                except self.submitit.core.utils.FailedJobError as e:
                    outcome = {'outcome': 'died', 'reason': f'job {job.job_id} failed: {one_line_of(e)}'}
                outcome.setdefault('seconds', time.perf_counter() - start)
                ended.append((task, outcome))
            if ended or not self.jobs or time.monotonic() >= deadline:
                return ended
            time.sleep(min(self.poll, max(0.0, deadline - time.monotonic())))

    def running(self) -> int:
        return len(self.jobs)

    def describe(self) -> str:
        return (f'{self.executor.cluster} job array, {self.res.cpus} CPU(s), {self.res.gpus} GPU(s), '
                f'{self.res.mem_gb:g} GiB, {self.res.minutes} min per run')

    on_interrupt = 'the Slurm jobs go on without the batch'

    def close(self) -> list[tuple[dict, dict]]:
        """Jobs go on without the batch (their runs are locked): the next batch follows them."""
        return []


def one_line_of(e: BaseException) -> str:
    """The last non-empty line of an engine's message (a remote traceback ends with the error)."""
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return lines[-1] if lines else type(e).__name__


def check_options(name: str, *, device: str = 'auto', workers=None, threads=None, cpus=None, minutes=None,
                  max_parallel=None) -> None:
    """Refuse, in one line, an engine's option that no engine could use."""
    for value, label in ((workers, '--workers'), (threads, '--threads'), (cpus, '--cpus-per-run'),
                         (max_parallel, '--max-parallel'), (minutes, '--time')):
        if value is not None and not value > 0:
            raise ReneusError(f'{label} {value:g}: expected a positive number')
    if name not in ENGINES:
        raise ReneusError(f"--engine {name!r}: expected one of {', '.join(ENGINES)}")
    if device not in DEVICES:
        raise ReneusError(f"--device {device!r}: expected one of {', '.join(DEVICES)}")


def make_engine(name: str, configs, files_of, *, tasks: int, device: str = 'auto', workers: int | None = None,
                threads: int | None = None, cpus: int | None = None, minutes: float | None = None,
                ray_address: str | None = None, partition: str | None = None, max_parallel: int | None = None,
                slurm_folder: str = '', slurm_cluster: str | None = None) -> Engine:
    """The engine ``name`` for runs of ``configs`` (their ReconstructionConfigs), sized.

    ``tasks`` runs are to be placed; ``files_of(name)`` is a specimen's
    :class:`~reneus_mi.batch.batch_folder.SpecimenFiles`. Local: one worker per GPU, or on
    the CPU ``cores // CORES_PER_RUN`` workers (at least one; no more than the memory
    holds or the tasks need) sharing the cores as Dr.Jit threads; ``workers`` and
    ``threads`` override. Ray and Slurm: ``cpus`` cores per run (default
    :data:`CORES_PER_RUN`), a GPU with ``device='gpu'`` (Ray's ``auto``: when the
    cluster has GPUs), memory and time from the preset (``minutes`` overrides the time).
    """
    check_options(name, device=device, workers=workers, threads=threads, cpus=cpus, minutes=minutes,
                  max_parallel=max_parallel)
    if name == 'ray':
        return RayEngine(configs, address=ray_address, device=device, cpus=cpus)
    if name == 'slurm':
        res = resources(configs, gpu=device == 'gpu', cpus=cpus or CORES_PER_RUN, minutes=minutes)
        return SlurmEngine(res, slurm_folder, partition=partition, max_parallel=max_parallel,
                           cluster=slurm_cluster)
    cores = cpu_count()
    gpus = local_gpus() if device in ('auto', 'gpu') else []
    if device == 'gpu' and not gpus:
        raise ReneusError('--device gpu: this machine has no CUDA device; expected --device cpu')
    if gpus:
        count = workers or len(gpus)
    else:
        by_memory = int(MEMORY_FRACTION * physical_memory() // max(run_memory(c) for c in configs))
        count = workers or max(1, min(cores // CORES_PER_RUN, by_memory))
    count = max(1, min(count, tasks))
    return LocalPool(files_of, workers=count, threads=threads or max(1, cores // count), gpus=gpus)
