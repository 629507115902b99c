"""What a container costs a training step: a solid block (the paper), an amber block, a glass
case and a jar of tinted liquid, each at the depth it needs and one more.

    python bench/containers.py [--preset fast] [--rays 4096] [--repeat 5]

Each container holds the untrained field of ``--preset`` in the same place; a step is the
render of ``--rays`` random camera rays that meet the container (forward) and the
backpropagation of their mean radiance to the field (backward), as the trainer's. Printed:
the fastest of ``--repeat`` steps (compilation, if any, only adds) after a pass over the same rays that compiles
every kernel, and its ratio to the
solid block's at D_re 2; the field samples per camera ray beside it.
"""
import argparse
import os
import resource
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

import reneus_mi  # noqa: F401  (variant, plugins)
from reneus_mi.presets import PRESETS, preset
from reneus_mi.geometry.container import absorbing_medium
from reneus_mi.render.interfaces import dielectric, display_case, jar

HALF = (0.55, 0.45, 0.5)
ROTATION = mi.ScalarTransform4f().rotate([0, 1, 0], 25)
#: The containers, each with the depths it is timed at.
CONTAINERS = {
    'block': ({'block': {'type': 'cube', 'to_world': ROTATION.scale(list(HALF)), 'bsdf': dielectric(1.45)}}, (2,)),
    'amber': ({'block': {'type': 'cube', 'to_world': ROTATION.scale(list(HALF)), 'bsdf': dielectric(1.45),
                         'interior': absorbing_medium((0.15, 0.35, 0.7))}}, (2, 3)),
    'case': (display_case(HALF, 0.06, 1.5, ROTATION), (2, 3)),
    'jar': (jar(0.58, 0.5, 0.06, 1.5, 1.36, (0.1, 0.3, 0.9)), (2, 3)),
}


def camera_rays(n: int, seed: int) -> mi.Ray3f:
    """Rays from a sphere of radius 3 aimed at points of the container's middle."""
    rng = np.random.default_rng(seed)
    o = rng.normal(size=(n, 3))
    o *= 3.0 / np.linalg.norm(o, axis=1, keepdims=True)
    target = rng.uniform(-0.4, 0.4, (n, 3))
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32)))


def step_time(scene, rays: int, repeat: int) -> tuple[float, float]:
    integrator = scene.integrator()
    params = {k: v for k, v in integrator.field.params().items() if dr.is_diff_v(v)}
    times = []
    for i in range(repeat + 1):
        for v in params.values():
            dr.enable_grad(v)
        start = time.perf_counter()
        result = integrator.render_rays(scene, camera_rays(rays, i))
        dr.backward(dr.mean(dr.sum(result.L)))
        dr.eval(*(dr.grad(v) for v in params.values()))
        dr.sync_thread()
        times.append(time.perf_counter() - start)
        samples = float(np.mean(np.array(result.n_samples)))
        for v in params.values():
            dr.disable_grad(v)
    return float(np.min(times[1:])), samples


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument('--preset', choices=sorted(PRESETS), default='fast')
    p.add_argument('--rays', type=int, default=4096)
    p.add_argument('--repeat', type=int, default=5)
    args = p.parse_args()
    print(f'command: python bench/{os.path.basename(__file__)} ' + ' '.join(sys.argv[1:]))
    print(f'variant {mi.variant()}, threads {dr.thread_count()}, preset {args.preset}')
    model = preset(args.preset).model
    scenes = {}
    for name, (shapes, depths) in CONTAINERS.items():
        for depth in depths:
            scene = mi.load_dict({'type': 'scene', 'integrator': {'type': 'reneus', 'preset': args.preset,
                                                                  'max_depth': depth},
                                  'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.8}},
                                  **shapes})
            scene.integrator().configure(model)
            scenes[name, depth] = scene
    # A first pass over the same rays compiles every kernel, so that no row pays for compiling.
    for scene in scenes.values():
        step_time(scene, args.rays, args.repeat)
    base = None
    print('| container | D_re | step (s) | x block D2 | field samples / ray |')
    print('| --- | --- | --- | --- | --- |')
    for (name, depth), scene in scenes.items():
        t, samples = step_time(scene, args.rays, args.repeat)
        base = base or t
        print(f'| {name} | {depth} | {t:.3f} | {t / base:.2f} | {samples:.0f} |', flush=True)
    print(f'peak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB')


if __name__ == '__main__':
    main()
