"""Reconstruct the object in a container: ``python -m reneus_mi.optimize scene.xml``.

The scene XML describes the container (a shape with a ``dielectric`` BSDF),
the ambient light and ``<integrator type="reneus">`` (its ``preset`` and the
settings that override it: mode, D_re, samples, field); the integrator's
``dataset`` names the folder of photographs and cameras (``--data``
overrides it; ``python -m reneus_mi.scene DATA -o scene.xml --preset cpu``
writes such a scene). Training settings start from the same preset; the
options below override them. Results go to the output folder (see
:mod:`reneus_mi.trainer`); ``--resume`` continues a killed run from its
``config.json``. ``--demo`` reconstructs the embedded demo: a small dataset of
an insect (thin legs) in a glass block that it first renders with Mitsuba's path tracer.
"""
from __future__ import annotations

import argparse
import os
import sys

from reneus_mi import cli
from reneus_mi.config import TrainConfig
from reneus_mi.errors import ReneusError, exit_on_error

#: The embedded demo: object, dataset size and preset.
DEMO_OBJECT = 'insect'
DEMO_DATA = {'views': 32, 'res': 64, 'spp': 128}
DEMO_PRESET = 'demo'


def make_demo(folder: str, *, mode: str = 'reneus') -> str:
    """Render the demo dataset into ``folder`` (once) and return its scene XML."""
    from reneus_mi.data import load_dataset
    from reneus_mi.scene import write_scene
    from reneus_mi.synth import make_dataset
    data = os.path.join(folder, 'box')
    if not os.path.isfile(os.path.join(data, 'transforms.json')):
        print(f'rendering the demo dataset ({DEMO_OBJECT}, {DEMO_DATA["views"]} views) into {folder}')
        make_dataset(DEMO_OBJECT, folder, subsets=('box',), **DEMO_DATA)
    scene = os.path.join(folder, f'scene_{mode}.xml')
    write_scene(load_dataset(data), scene, preset=DEMO_PRESET, mode=mode)
    return scene


def spec_of_scene(scene_path: str, data: str | None):
    """The run of a scene XML: its integrator's model, its preset's training, its dataset."""
    import reneus_mi  # noqa: F401  (variant, plugins)
    from reneus_mi.config import ReconstructionConfig
    from reneus_mi.presets import preset
    from reneus_mi.render import load_scene
    from reneus_mi.runs import RunSpec
    integrator = load_scene(scene_path).integrator()
    if not hasattr(integrator, 'render_rays'):
        raise ReneusError(f'{scene_path}: the integrator is {type(integrator).__name__}; '
                          'expected <integrator type="reneus">')
    data = data or integrator.dataset
    if not data:
        raise ReneusError(f'{scene_path}: no dataset: give the integrator '
                          '<string name="dataset" value="FOLDER"/> or pass --data')
    if not os.path.isabs(data):
        data = os.path.join(os.path.dirname(os.path.abspath(scene_path)), data)
    config = ReconstructionConfig(model=integrator.model, train=preset(integrator.preset).train)
    return RunSpec(scene_path, data, config, integrator.preset)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.optimize',
                                     description=__doc__.split('\n\n')[0],
                                     epilog=__doc__.split('\n\n', 1)[1])
    parser.add_argument('scene', nargs='?', help='Mitsuba scene XML with <integrator type="reneus">')
    parser.add_argument('--data', help="dataset folder (overrides the integrator's 'dataset'; with "
                        "--resume, the run's own dataset moved elsewhere, checked to be the same)")
    parser.add_argument('-o', '--output', help='output folder (default: runs/<scene name>)')
    parser.add_argument('--resume', action='store_true', help="continue the output folder's run")
    parser.add_argument('--demo', action='store_true', help='reconstruct the embedded demo scene')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    cli.add_arguments(parser, TrainConfig, default_note="the preset's")
    args = parser.parse_args(argv)
    try:
        with exit_on_error(RuntimeError):
            print(run(args))
    except KeyboardInterrupt:
        raise SystemExit('interrupted: checkpoint written; continue with --resume') from None
    return 0


def run(args) -> str:
    from reneus_mi import guards, runs
    from reneus_mi.config import replace
    if args.scene is None and not args.demo and not args.resume:
        raise ReneusError('no scene given: pass a scene XML (python -m reneus_mi.scene DATA -o '
                          'scene.xml writes one), or --demo for the embedded demo')
    name = 'demo' if args.demo else os.path.splitext(os.path.basename(args.scene or ''))[0]
    out = args.output or os.path.join('runs', name)
    if args.resume:
        spec = runs.read_spec(out)
        if args.scene:
            raise ReneusError(f'{out}: --resume continues the run recorded in its config.json '
                              f'(scene {spec.scene}), but {args.scene} was given; expected no scene')
        if args.data:
            spec = spec.with_data(os.path.abspath(args.data))
    else:
        if os.path.isfile(os.path.join(out, runs.CHECKPOINT_FILE)):
            raise ReneusError(f'{out} already holds a run; continue it with --resume or choose '
                              'another --output')
        guards.check_run_dir(out, inputs=[args.scene, args.data])
        # The demo's photographs go beside the run folder: no run ever writes where its inputs are.
        scene = make_demo(os.path.abspath(out).rstrip(os.sep) + '_data') if args.demo else args.scene
        spec = spec_of_scene(scene, args.data)
    given = cli.given_arguments(TrainConfig, args)
    spec.config = replace(spec.config, **{f'train.{k}': v for k, v in given.items()})
    result = runs.run(spec, out, resume=args.resume, progress=not args.quiet)
    if 'failure' in result:
        raise ReneusError(result['failure'])
    cfg = spec.config.train
    ended = (f"stopped by the time budget ({cfg.max_minutes:g} min) after {result['iterations']} iterations"
             if result['stopped_by_budget'] else f"done: {result['iterations']} iterations")
    psnr = result['psnr']
    if psnr != psnr:  # no step ran (a finished run resumed): the log has the figure
        psnr = guards.recent_psnr(guards.read_log(os.path.join(out, 'log.jsonl'))) or float('nan')
    lines = [f"{ended} in {result['seconds']:.0f} s"
             + (f", PSNR {psnr:.2f} dB (last 100 steps)" if psnr == psnr else '')
             + f"; mesh {result['mesh']}"
             + (f"; renders {os.path.join(out, 'images')}" if cfg.validate_every else '')]
    from reneus_mi.data import load_dataset
    gt = load_dataset(spec.data, need_container=False).gt_mesh
    if gt:
        from reneus_mi.evaluate import chamfer, load_mesh
        c = chamfer(load_mesh(result['mesh']), load_mesh(gt))
        lines.append(f"Chamfer-L1 x100 to the ground truth: {c['chamfer']:.3f} (postprocess {cfg.postprocess}, "
                     f"{result['components']} component(s))")
    return '\n'.join(lines)


if __name__ == '__main__':
    sys.exit(main())
