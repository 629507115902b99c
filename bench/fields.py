"""Points per second of a field's ``gradient`` + ``radiance``, forward and forward+backward.

    python bench/fields.py [--fields neus hashgrid ...] [--points 65536] [--repeat 5]

What the renderer asks of a field at every sample: g, ∇g and the feature
(``field.gradient``), then the radiance. Forward evaluates them; forward+backward
also differentiates a loss shaped like a training step's (the SDF, an Eikonal
term, the colour, each point weighted differently) w.r.t. every parameter.
Points are uniform in [-0.7, 0.7]^3. Each configuration runs once untimed (its
kernels compile, or load from the kernel cache) and then ``--repeat`` times; the
table gives the best wall time and the best process CPU time. On a shared CPU
the CPU time is the steadier measure of work, so the speed-up column is the
ratio of CPU times to the first configuration's.
"""
import argparse
import os
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import reneus_mi  # noqa: F401  (variant)
from reneus_mi.fields import HashGridField, NeuSField

#: The small preset's NeuS field (reneus_mi.presets).
NEUS_DEMO = dict(hidden=32, layers=4, n_features=8, color_hidden=32, color_layers=2, multires=4,
                 multires_view=2, init_radius=0.3)

FIELDS = {
    'neus': lambda: NeuSField(**NEUS_DEMO),
    'hashgrid': lambda: HashGridField(),
    'hashgrid-numerical': lambda: HashGridField(gradient='numerical'),
    'hashgrid-2^15': lambda: HashGridField(log2_hashmap_size=15),
    'hashgrid-2^17': lambda: HashGridField(log2_hashmap_size=17),
    'hashgrid-12-levels': lambda: HashGridField(n_levels=12, finest_resolution=1024),
    'hashgrid-colour-2': lambda: HashGridField(color_layers=2),
    'hashgrid-softplus': lambda: HashGridField(activation='softplus'),
    'hashgrid-ngp': lambda: HashGridField(n_levels=16, log2_hashmap_size=19, finest_resolution=2048,
                                          hidden=64, color_hidden=64, color_layers=2),
    'hashgrid-fp16': lambda: HashGridField(dtype='float16'),
}


def points(n: int):
    rng = np.random.default_rng(0)
    x = mi.Point3f(rng.uniform(-0.7, 0.7, (3, n)).astype(np.float32))
    v = rng.normal(size=(3, n))
    v /= np.linalg.norm(v, axis=0)
    w = mi.Float(rng.uniform(0.5, 1.5, n).astype(np.float32))
    v = mi.Vector3f(v.astype(np.float32))
    # Evaluated here: a Point3f still pointing into a (3, n) NumPy buffer carries n
    # into every kernel that reads it (a new kernel per point count).
    dr.eval(x, v, w)
    return x, v, w


def evaluate(field, x, v, w, backward: bool) -> None:
    params = list(field.params().values())
    if backward:
        for p in params:
            dr.enable_grad(p)
    g, grad, feature = field.gradient(x)
    rgb = field.radiance(x, v, dr.normalize(grad), feature)
    if backward:
        eikonal = dr.square(dr.norm(grad) - 1.0)
        # Weighted: a uniform incoming gradient would take a shortcut in the backward pass.
        dr.backward(dr.sum(w * (g + 0.1 * eikonal + rgb.x + rgb.y + rgb.z)))
        grads = [dr.grad(p) for p in params]
        dr.eval(grads)
        for p in params:
            dr.disable_grad(p)
    else:
        dr.eval(g, grad, rgb)
    dr.sync_thread()


def measure(field, n: int, repeat: int) -> dict:
    x, v, w = points(n)
    out = {}
    for backward in (False, True):
        start = time.perf_counter()
        evaluate(field, x, v, w, backward)
        first = time.perf_counter() - start
        wall, cpu = [], []
        for _ in range(repeat):
            start, start_cpu = time.perf_counter(), time.process_time()
            evaluate(field, x, v, w, backward)
            wall.append(time.perf_counter() - start)
            cpu.append(time.process_time() - start_cpu)
        out['fwd+bwd' if backward else 'fwd'] = dict(first=first, wall=min(wall), cpu=min(cpu))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--fields', nargs='+', choices=list(FIELDS), default=['neus', 'hashgrid', 'hashgrid-numerical'])
    p.add_argument('--points', type=int, default=2 ** 16)
    p.add_argument('--repeat', type=int, default=5)
    args = p.parse_args(argv)
    print('command: python bench/fields.py ' + ' '.join(sys.argv[1:] if argv is None else argv))
    print(f'variant {mi.variant()}, {dr.thread_count()} threads, {os.cpu_count()} CPUs, '
          f'load average {os.getloadavg()[0]:.1f} at the start (other processes share the CPU); '
          f'{args.points} points, best of {args.repeat}')
    print("| field | params | fwd first s | fwd ms | fwd Mpts/s | fwd+bwd first s | fwd+bwd ms "
          "| fwd+bwd cpu ms | fwd+bwd kpts/s | speed-up (cpu) |")
    print('| --- ' * 10 + '|')
    reference = None
    for name in args.fields:
        field = FIELDS[name]()
        r = measure(field, args.points, args.repeat)
        f, b = r['fwd'], r['fwd+bwd']
        reference = reference or b['cpu']
        n_params = sum(dr.width(v) for v in field.params().values())
        print(f"| {name} | {n_params} | {f['first']:.2f} | {f['wall'] * 1e3:.0f} | "
              f"{args.points / f['wall'] / 1e6:.2f} | {b['first']:.2f} | {b['wall'] * 1e3:.0f} | "
              f"{b['cpu'] * 1e3:.0f} | {args.points / b['wall'] / 1e3:.0f} | {reference / b['cpu']:.1f}x |",
              flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
