"""Where a training step's time goes, against what this machine can do.

    python bench/profile.py [--scenes insect NAME=SCENE.xml ...] [--preset fast] [--warm 150] [--steps 20]
                            [--batch 1024] [--cold] [--doc docs]

Each scene (``insect``: the speed bench's 128 px insect in its block, rendered into
``runs/speed/data`` if absent; or a board capture's ``scene_fast.xml``) trains in a
fresh process: ``--warm`` steps, so that the occupancy grid has emptied, then
``--steps`` timed steps, then as many again with Dr.Jit's kernel history on. The
history splits each phase of the trainer's step (``Trainer.step``: the batch, the
ray tree's forward trace, the losses, ``dr.backward``, the optimiser, the rest,
which evaluates the gradients and reads the loss) into kernel launches, kernel
execution and code generation (the IR of every launch is assembled and hashed
to find it in the kernel cache); what is left of the phase's wall clock is
Python and Dr.Jit tracing. Recording the history waits for each kernel, so its
step is slower than the timed one; both are printed.

The roofline: this machine's peaks measured with Dr.Jit (FMAs of independent
chains; random gathers from a table in cache and from one in memory; float
atomic scatter-adds; an MLP of the field's shape alone, forward and backward), and
each of the heaviest kernels' FMAs per lane counted
in its LLVM IR (straight-line ones and the trip counts of the MLPs' loops), so
that its achieved rate is a fraction of the FMA peak.

``--cold`` also times a fresh process's first step with an empty kernel cache
(``HOME`` pointed at a new folder) and with the cache warm. Writes
``DOC/profile.md`` with the command and the device.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

#: The phases of ``Trainer.step``, as the methods it calls (the rest is OTHER).
PHASES = (('begin step', 'integrator', 'begin_step'), ('batch', 'pixels', 'batch'),
          ('forward trace', 'integrator', 'render_rays'), ('record', 'pixels', 'record'),
          ('losses', 'losses', 'loss_dict'), ('backward', 'dr', 'backward'), ('optimiser', 'opt', 'step'),
          ('parameters', 'params', 'update'))
OTHER = 'gradients and loss'
#: Kernels listed per scene, the heaviest first.
TOP = 6


def best_time(make, repeats: int = 5) -> float:
    """The shortest of ``repeats`` evaluations of what ``make()`` traces, in seconds (tracing aside)."""
    import drjit as dr
    best = float('inf')
    for _ in range(repeats):
        out = make()
        dr.sync_thread()
        start = time.perf_counter()
        dr.eval(out)
        dr.sync_thread()
        best = min(best, time.perf_counter() - start)
    return best


def peaks() -> dict:
    """This machine's FMA rate, gather rates and atomic scatter-add rate, as Dr.Jit runs them."""
    import drjit as dr
    import mitsuba as mi
    timed = best_time

    n, chains, depth = 1 << 22, 8, 64

    def fmas():
        x = [dr.arange(mi.Float, n) * (1e-7 * (c + 1)) for c in range(chains)]
        for _ in range(depth):
            x = [dr.fma(v, 0.999, 0.001) for v in x]
        return x
    out = {'fma_per_s': n * chains * depth / timed(fmas)}
    rng = mi.PCG32(n)
    index = rng.next_uint32()
    dr.eval(index)
    for name, size in (('gather_cache_per_s', 1 << 18), ('gather_memory_per_s', 1 << 26)):
        table = dr.arange(mi.Float, size)
        dr.eval(table)
        out[name] = n / timed(lambda: dr.gather(mi.Float, table, index & (size - 1)))
    out.update(mlp_rates())
    target = dr.zeros(mi.Float, 1 << 18)
    dr.eval(target)

    def scatter():
        dr.scatter_add(target, 1.0, index & ((1 << 18) - 1), mode=dr.ReduceMode.Direct)
        return target
    out['atomic_add_per_s'] = n / timed(scatter)
    return out


#: The fast preset's SDF network's shape: inputs, hidden widths, outputs.
MLP = (17, 32, 32, 9)


def mlp(dims=MLP):
    """A ``drjit.nn`` MLP of layer widths ``dims`` (ReLU between layers), packed for training."""
    import drjit.nn as nn
    import mitsuba as mi
    layers = []
    for a, b in zip(dims[:-1], dims[1:]):
        layers += [nn.Linear(a, b), nn.ReLU()]
    return nn.pack(nn.Sequential(*layers[:-1]).alloc(mi.TensorXf, dims[0]), layout='training')


def mlp_output(net, x: list, backward: str | None):
    """The MLP's outputs summed over ``x`` (one array per input), or that sum's gradient with
    respect to the ``'weights'`` or the ``'inputs'`` (the weights held): what a kernel evaluates."""
    import drjit as dr
    import drjit.nn as nn
    if backward == 'weights':
        dr.enable_grad(net['weights'])
    x = [dr.detach(v) for v in x]
    if backward == 'inputs':
        dr.enable_grad(x)
    y = list(net(nn.CoopVec(*x)))
    out = sum(y[1:], y[0])
    if not backward:
        return out
    dr.backward(out)
    if backward == 'inputs':
        return dr.grad(x)
    grad = dr.grad(net['weights'])
    dr.disable_grad(net['weights'])
    return grad


def mlp_rates(dims=MLP, n=1 << 16) -> dict:
    """FMAs a second of one MLP of the field's shape alone: forward, and forward with backward
    (counted as three times the forward's FMAs) to the weights and to the inputs alone (counted
    as twice: the weights' outer products are what the first adds)."""
    import drjit as dr
    import mitsuba as mi
    net = mlp(dims)
    x = [dr.arange(mi.Float, n) * (1e-5 * (i + 1)) for i in range(dims[0])]
    fmas = n * sum(a * b for a, b in zip(dims[:-1], dims[1:]))
    forward = best_time(lambda: mlp_output(net, x, backward=None), repeats=4)
    training = best_time(lambda: mlp_output(net, x, backward='weights'), repeats=4)
    inputs = best_time(lambda: mlp_output(net, x, backward='inputs'), repeats=4)
    return {'mlp_forward_fma_per_s': fmas / forward, 'mlp_training_fma_per_s': 3 * fmas / training,
            'mlp_inputs_fma_per_s': 2 * fmas / inputs}


def ir_counts(ir: str) -> dict:
    """Per lane: FMAs (straight-line, and the MLPs' loops' trip counts), other float ops, gathers,
    atomics; and per packet of lanes the MLPs' weight-gradient reductions (a horizontal sum and
    an atomic add for each weight)."""
    body = ir.split('\ndefine internal', 1)[0]
    # Dr.Jit's MLPs on the CPU are loops of two levels named by one prefix: a matrix-vector
    # product (an FMA a trip) or a weight gradient's outer product (a reduction a trip).
    bounds = collections.defaultdict(list)
    for prefix, bound in re.findall(r'%([a-z]\d+)_[ij]_cont = icmp ult i32 %\1_[ij], (\d+)\s', body):
        bounds[prefix].append(int(bound))
    loop_fma = reductions = 0
    for prefix, (outer, inner) in ((k, v) for k, v in bounds.items() if len(v) == 2):
        # The loop's blocks are named l<number> whatever its variables' prefix.
        block = re.search(rf'\nl{prefix[1:]}_body:\n(.*?)\n\n', body, re.S)
        if block and 'vector.reduce.fadd' in block.group(1):
            reductions += outer * inner
        else:
            loop_fma += outer * inner
    return {'fma': len(re.findall(r'@llvm\.fma\.v\d+f32\(', body)) + loop_fma,
            'flop': len(re.findall(r'= f(?:mul|add|sub|div) ', body)),
            'gather': len(re.findall(r'call [^@]*@(?:gather_\w+|llvm\.masked\.gather)', body)),
            'atomic': len(re.findall(r'call [^@]*@reduce_\w+|atomicrmw', body)),
            'reductions': reductions}


def child(args) -> None:
    """One scene: print one JSON line with the step's figures and the kernels."""
    import reneus_mi  # noqa: F401
    from reneus_mi import runs

    train = {'iterations': 10 ** 7, 'validate_every': 0, 'checkpoint_every': 0}
    if args.batch:
        train.update({'batch_rays': args.batch, 'sample_budget': 0})
    with tempfile.TemporaryDirectory(prefix='profile_') as folder:
        print(json.dumps(measure(args, runs.prepare(folder, args.one, train=train).trainer())))


def measure(args, trainer) -> dict:
    """The step's figures and the kernels of ``trainer``'s run (see the module's docstring)."""
    import drjit as dr

    from reneus_mi.train import trainer as trainer_module

    for _ in range(args.warm):
        trainer.step()
    dr.sync_thread()
    wall, samples, rays = 0.0, 0.0, 0
    # The Python thread's CPU time (tracing, code generation, host work; while it waits it may
    # run a kernel's blocks) against all threads' (the kernels' too).
    thread_cpu, process_cpu = time.thread_time(), time.process_time()
    for _ in range(args.steps):
        stats = trainer.step()
        wall, samples, rays = wall + stats.seconds, samples + stats.samples, rays + stats.rays
    thread_cpu, process_cpu = time.thread_time() - thread_cpu, time.process_time() - process_cpu
    step_s = wall / args.steps

    # The step against its batch: what does not grow with the rays is the step's fixed cost.
    batch, sweep = trainer.batch, []
    for size in args.batches:
        trainer.batch = size
        for _ in range(5):
            trainer.step()
        seconds = [trainer.step().seconds for _ in range(args.steps)]
        sweep.append({'batch': size, 'step_ms': 1e3 * float(np.median(seconds))})
    trainer.batch = batch
    for _ in range(5):
        trainer.step()
    slope, fixed = np.polyfit([r['batch'] for r in sweep], [r['step_ms'] for r in sweep], 1)

    # The same steps again, each phase's kernels recorded.
    phases = collections.defaultdict(lambda: {'wall': 0.0, 'kernels': []})
    owners = {'integrator': trainer.integrator, 'pixels': trainer.pixels, 'losses': trainer_module.losses,
              'dr': trainer_module.dr, 'opt': trainer.opt, 'params': trainer.params}

    def wrap(label, owner, name):
        inner = getattr(owner, name)

        def timed(*a, **k):
            phases[OTHER]['kernels'] += dr.kernel_history()
            t = time.perf_counter()
            try:
                return inner(*a, **k)
            finally:
                phases[label]['wall'] += time.perf_counter() - t
                phases[label]['kernels'] += dr.kernel_history()
        setattr(owner, name, timed)
        return lambda: setattr(owner, name, inner)
    restore = [wrap(label, owners[owner], name) for label, owner, name in PHASES]
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    t = time.perf_counter()
    for _ in range(args.steps):
        trainer.step()
    dr.sync_thread()
    recorded_s = (time.perf_counter() - t) / args.steps
    phases[OTHER]['kernels'] += dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    for undo in restore:
        undo()
    phases[OTHER]['wall'] = recorded_s * args.steps - sum(p['wall'] for k, p in phases.items() if k != OTHER)

    n = args.steps
    rows, kernels = [], collections.defaultdict(lambda: {'launches': 0, 'exec_ms': 0.0, 'size': 0})
    for label in [p[0] for p in PHASES] + [OTHER]:
        ks = phases[label]['kernels']
        jit = [k for k in ks if k['type'] == dr.KernelType.JIT]
        rows.append({'phase': label, 'wall_ms': 1e3 * phases[label]['wall'] / n, 'launches': len(ks) / n,
                     'jit': len(jit) / n, 'exec_ms': sum(k.get('execution_time', 0.0) for k in ks) / n,
                     'codegen_ms': sum(k.get('codegen_time', 0.0) + k.get('backend_time', 0.0) for k in jit) / n})
        for k in jit:
            entry = kernels[k['hash'][:8]]
            entry['launches'] += 1
            entry['exec_ms'] += k['execution_time']
            entry['size'] = max(entry['size'], k['size'])
            entry['phase'] = label
            if 'counts' not in entry:
                entry['counts'] = ir_counts(k['ir'].getvalue())
                entry['ops'] = k['operation_count']
    heavy = sorted(kernels.items(), key=lambda kv: -kv[1]['exec_ms'])[:TOP]
    return {
        'scene': args.one, 'batch': rays / n, 'samples_per_ray': samples / rays, 'step_ms': 1e3 * step_s,
        'recorded_step_ms': 1e3 * recorded_s, 'thread_cpu_ms': 1e3 * thread_cpu / args.steps,
        'process_cpu_ms': 1e3 * process_cpu / args.steps, 'rays_per_s': rays / wall, 'samples_per_s': samples / wall,
        'phases': rows, 'sweep': sweep, 'fixed_ms': fixed, 'ms_per_1k_rays': 1e3 * slope,
        'kernels': [{'hash': h, 'phase': k['phase'], 'launches': k['launches'] / n, 'size': k['size'],
                     'exec_ms': k['exec_ms'] / n, 'ops': k['ops'], **k['counts']} for h, k in heavy]}


def first_step(scene: str, cold: bool) -> float:
    """A fresh process's first training step (tracing, compilation, one step), in seconds; ``cold``:
    with an empty kernel cache (Dr.Jit keeps it under ``HOME``)."""
    code = ('import reneus_mi, sys, tempfile; from reneus_mi import runs\n'
            'with tempfile.TemporaryDirectory() as out:\n'
            '    print(runs.prepare(out, sys.argv[1]).trainer().step().seconds)')
    with tempfile.TemporaryDirectory(prefix='drjit_home_') as home:
        env = dict(os.environ, HOME=home) if cold else None
        done = subprocess.run([sys.executable, '-c', code, scene], env=env, capture_output=True, text=True,
                              check=True)
    return float(done.stdout.split()[-1])


def write_doc(results: list[dict], peak: dict, cold: dict, args, command: str, dev: str, load: float) -> str:
    fma = peak['fma_per_s']
    lines = ['# Where a training step goes', '', f'Generated by `{command}` on {time.strftime("%Y-%m-%d")}.', '',
             f'- Device: {dev}; load average before the benchmark {load:.1f}'
             + (' (the machine was shared: figures are pessimistic).' if load > 1.0 else ' (otherwise idle).'),
             f'- Each scene as its scene file states it (`insect`: written with `{args.preset}`), {args.warm} '
             'steps to warm up, then '
             f'{args.steps} timed steps and {args.steps} recorded with Dr.Jit\'s kernel history.', '',
             '## The machine (measured with Dr.Jit)', '',
             '| peak | rate |', '| --- | --- |',
             f'| FMA, 8 independent chains | {fma / 1e9:.1f} G/s ({2 * fma / 1e9:.0f} GFLOP/s) |',
             f'| random gather, 1 MB table (cache) | {peak["gather_cache_per_s"] / 1e6:.0f} M/s |',
             f'| random gather, 256 MB table (memory) | {peak["gather_memory_per_s"] / 1e6:.0f} M/s |',
             f'| float atomic scatter-add, 1 MB table | {peak["atomic_add_per_s"] / 1e6:.0f} M/s |',
             f'| an MLP 17-32-32-9 (`drjit.nn`), forward | {peak["mlp_forward_fma_per_s"] / 1e9:.1f} G FMA/s |',
             f'| the same, forward and backward (3x the forward\'s FMAs) | '
             f'{peak["mlp_training_fma_per_s"] / 1e9:.1f} G FMA/s |',
             f'| the same, forward and backward to the inputs only (2x the forward\'s FMAs) | '
             f'{peak["mlp_inputs_fma_per_s"] / 1e9:.1f} G FMA/s |', '']
    for r in results:
        name = r['label']
        if 'error' in r:
            lines += [f'## {name}', '', f'failed: {r["error"]}', '']
            continue
        lines += [f'## {name}', '', f'`{r["scene"]}`: {r["batch"]:.0f} rays a step, {r["samples_per_ray"]:.1f} '
                  f'field samples a ray; a step {r["step_ms"]:.0f} ms ({r["rays_per_s"]:.0f} rays/s, '
                  f'{r["samples_per_s"] / 1e3:.0f} k samples/s), {r["process_cpu_ms"]:.0f} ms of CPU time in all threads, '
                  f'{r["thread_cpu_ms"]:.0f} ms of them in the Python thread.', '',
                  '| rays a step | ' + ' | '.join(str(b['batch']) for b in r['sweep']) + ' |',
                  '| --- ' * (1 + len(r['sweep'])) + '|',
                  '| step (ms, median) | ' + ' | '.join(f"{b['step_ms']:.0f}" for b in r['sweep']) + ' |', '',
                  f'A line through them: a step costs {r["fixed_ms"]:.0f} ms whatever its batch (tracing, code '
                  f'generation, launches, host work) and {r["ms_per_1k_rays"]:.0f} ms per 1,024 rays; at '
                  f'{r["batch"]:.0f} rays the fixed part is '
                  f'{r["fixed_ms"] / (r["fixed_ms"] + r["ms_per_1k_rays"] * r["batch"] / 1024):.0%} of the step.', '',
                  f'Recorded with the kernel history (which waits for every launch, so that the host\'s share '
                  f'is overstated where launches are many), a step took {r["recorded_step_ms"]:.0f} ms:', '',
                  '| phase | wall (ms) | launches | JIT kernels | kernel execution (ms) | code generation (ms) |',
                  '| --- ' * 6 + '|']
        for p in r['phases']:
            lines.append(f"| {p['phase']} | {p['wall_ms']:.1f} | {p['launches']:.0f} | {p['jit']:.0f} | "
                         f"{p['exec_ms']:.1f} | {p['codegen_ms']:.1f} |")
        total = {k: sum(p[k] for p in r['phases']) for k in ('wall_ms', 'launches', 'jit', 'exec_ms', 'codegen_ms')}
        rest = total['wall_ms'] - total['exec_ms'] - total['codegen_ms']
        lines += [f"| **step** | {total['wall_ms']:.1f} | {total['launches']:.0f} | {total['jit']:.0f} | "
                  f"{total['exec_ms']:.1f} | {total['codegen_ms']:.1f} |", '',
                  f"Of the recorded step's {total['wall_ms']:.0f} ms: kernels {total['exec_ms']:.0f} ms "
                  f"({total['exec_ms'] / total['wall_ms']:.0%}), code generation {total['codegen_ms']:.0f} ms "
                  f"({total['codegen_ms'] / total['wall_ms']:.0%}), Python and Dr.Jit's tracing and the host the "
                  f"rest, {rest:.0f} ms ({rest / total['wall_ms']:.0%}). The CPU backend launches asynchronously: "
                  "a kernel's execution is counted in the phase that launched it, the wait for it in the phase "
                  "that needed its result.", '',
                  '| kernel | phase | launches a step | lanes | ms a step | IR ops | FMAs / lane | other float ops / lane '
                  '| gathers / lane | atomics / lane | weight-gradient reductions / packet | G FMA/s | of the FMA peak |',
                  '| --- ' * 13 + '|']
        for k in r['kernels']:
            rate = k['fma'] * k['size'] * k['launches'] / (k['exec_ms'] * 1e-3) if k['exec_ms'] else 0.0
            lines.append(f"| `{k['hash']}` | {k['phase']} | {k['launches']:.0f} | {k['size']} | {k['exec_ms']:.1f} | "
                         f"{k['ops']} | {k['fma']} | {k['flop']} | {k['gather']} | {k['atomic']} | {k['reductions']} | "
                         f"{rate / 1e9:.1f} | {rate / fma:.0%} |")
        lines.append('')
    if cold:
        lines += ['## The first step of a fresh process', '', '| scene | kernel cache empty (s) | kernel cache warm (s) |',
                  '| --- | --- | --- |']
        lines += [f'| {name} | {c[0]:.1f} | {c[1]:.1f} |' for name, c in cold.items()] + ['']
    return '\n'.join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--scenes', nargs='+', default=['insect'], metavar='NAME=SCENE.xml',
                   help="scenes to profile; 'insect': the speed bench's 128 px scene with --preset")
    p.add_argument('--preset', default='fast', help="the preset of the 'insect' scene")
    p.add_argument('--warm', type=int, default=150, help='steps before the measured ones')
    p.add_argument('--steps', type=int, default=20, help='steps measured, and as many recorded')
    p.add_argument('--batch', type=int, default=0, help='rays a step (0: as the scene states)')
    p.add_argument('--batches', type=int, nargs='+', default=[256, 1024, 4096],
                   help='batches of the sweep that separates the fixed cost of a step')
    p.add_argument('--cold', action='store_true', help='also time a fresh process\'s first step, cache empty and warm')
    p.add_argument('--out', default=os.path.join('runs', 'speed'), help='where the default scene is rendered')
    p.add_argument('--doc', default=os.path.join(ROOT, 'docs'))
    p.add_argument('--one', help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.one:
        child(args)
        return 0
    import speed
    from reneus_mi.utils.io import atomic_write_text
    command = shlex.join(['python', 'bench/profile.py', *(sys.argv[1:] if argv is None else argv)])
    print(f'command: {command}'.rstrip(), flush=True)
    load = os.getloadavg()[0]
    scenes = {}
    for entry in args.scenes:
        if entry == 'insect':
            from reneus_mi.data import load_dataset
            from reneus_mi.data.scene_xml import write_scene
            out = os.path.abspath(args.out)
            data = speed.dataset(argparse.Namespace(out=out, object='insect', views=48, res=128, spp=256))
            xml = os.path.join(out, f'scene_profile_{args.preset}.xml')
            write_scene(load_dataset(data), xml, preset=args.preset)
            scenes[f'insect 128 px, {args.preset}'] = xml
        else:
            name, sep, xml = entry.partition('=')
            if not sep:
                p.error(f'--scenes {entry}: expected NAME=SCENE.xml or insect')
            scenes[name] = xml
    peak = peaks()
    print(json.dumps(peak), flush=True)
    results, cold = [], {}
    for name, xml in scenes.items():
        cmd = [sys.executable, os.path.abspath(__file__), '--one', os.path.abspath(xml), '--warm', str(args.warm),
               '--steps', str(args.steps), '--batch', str(args.batch), '--batches', *map(str, args.batches)]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode:
            result = {'error': (done.stderr.strip().splitlines() or ['exit %d' % done.returncode])[-1]}
        else:
            result = json.loads(done.stdout.strip().splitlines()[-1])
        result['label'] = name
        results.append(result)
        print(json.dumps({k: v for k, v in result.items() if k != 'kernels'}), flush=True)
        if args.cold and 'error' not in result:
            cold[name] = (first_step(os.path.abspath(xml), cold=True), first_step(os.path.abspath(xml), cold=False))
    text = write_doc(results, peak, cold, args, command, speed.device(), load)
    os.makedirs(args.doc, exist_ok=True)
    atomic_write_text(os.path.join(args.doc, 'profile.md'), text)
    print(text)
    return 0


if __name__ == '__main__':
    sys.exit(main())
