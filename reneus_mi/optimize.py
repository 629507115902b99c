"""Reconstruct the object in a container: ``python -m reneus_mi.optimize scene.xml``.

The scene XML describes the container (a shape with a ``dielectric`` BSDF),
the ambient light and ``<integrator type="reneus">`` (mode, D_re, samples,
field); the integrator's ``dataset`` names the folder of photographs and
cameras (``--data`` overrides it; ``python -m reneus_mi.scene DATA -o
scene.xml`` writes such a scene). Results go to the output folder (see
:mod:`reneus_mi.trainer`); ``--resume`` continues a killed run.

With ``--demo`` (and no scene) it reconstructs the embedded demo: a small
dataset of a statuette in a glass block that it first renders with Mitsuba's
path tracer.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys

from reneus_mi import cli
from reneus_mi.config import TrainConfig

#: The embedded demo: object, dataset size, and a field and sampling sized for a CPU.
DEMO_OBJECT = 'statuette'
DEMO_DATA = {'views': 16, 'res': 32, 'spp': 256}
DEMO_INTEGRATOR = {'field_hidden': 32, 'field_layers': 4, 'field_n_features': 8,
                   'field_color_hidden': 32, 'field_color_layers': 2, 'field_multires': 4,
                   'field_multires_view': 2, 'field_init_radius': 0.3,
                   'n_coarse': 32, 'n_fine': 16, 'n_upsample_steps': 2}
DEMO_TRAIN = {'iterations': 300, 'batch_rays': 256, 'learning_rate': 2e-3, 'warm_up': 50,
              'validate_every': 100, 'mesh_resolution': 128}


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
    write_scene(load_dataset(data), scene, mode=mode, **DEMO_INTEGRATOR)
    return scene


def load(scene_path: str, data: str | None):
    """The scene and its dataset, with errors that name the file."""
    import reneus_mi  # noqa: F401  (variant, plugins)
    from reneus_mi.data import load_dataset
    from reneus_mi.render import load_scene
    scene = load_scene(scene_path)
    integrator = scene.integrator()
    if not hasattr(integrator, 'trace'):
        raise ValueError(f'{scene_path}: the integrator is {type(integrator).__name__}; '
                         'expected <integrator type="reneus">')
    data = data or integrator.dataset
    if not data:
        raise ValueError(f'{scene_path}: no dataset: give the integrator '
                         '<string name="dataset" value="FOLDER"/> or pass --data')
    if not os.path.isabs(data):
        data = os.path.join(os.path.dirname(os.path.abspath(scene_path)), data)
    return scene, load_dataset(data, need_container=integrator.mode != 'neus')


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog='python -m reneus_mi.optimize',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('scene', nargs='?', help='Mitsuba scene XML with <integrator type="reneus">')
    parser.add_argument('--data', help="dataset folder (overrides the integrator's 'dataset')")
    parser.add_argument('-o', '--output', help='output folder (default: runs/<scene name>)')
    parser.add_argument('--resume', action='store_true', help="continue the output folder's run")
    parser.add_argument('--demo', action='store_true', help='reconstruct the embedded demo scene')
    parser.add_argument('--quiet', action='store_true', help='no progress bar')
    cli.add_arguments(parser, TrainConfig)
    args = parser.parse_args(argv)

    try:
        summary = run(args)
    except (ValueError, OSError) as e:
        raise SystemExit(f'error: {e}') from None
    except KeyboardInterrupt:
        raise SystemExit('interrupted: checkpoint written; continue with --resume') from None
    print(summary)
    return 0


def run(args) -> str:
    from reneus_mi.errors import user_message
    from reneus_mi.trainer import Trainer, TrainingError
    from reneus_mi.io import atomic_write_text
    from reneus_mi import guards

    if args.scene is None and not (args.demo or args.resume):
        raise ValueError('no scene given: expected SCENE.xml (python -m reneus_mi.scene DATA -o '
                         'scene.xml writes one), or --demo for the embedded demo')
    demo = args.demo or args.scene is None
    base = TrainConfig(**DEMO_TRAIN) if demo else TrainConfig()
    out = args.output or os.path.join('runs', 'demo' if demo else
                                      os.path.splitext(os.path.basename(args.scene))[0])
    config_path = os.path.join(out, 'config.json')
    if args.resume:
        if not os.path.isfile(config_path):
            raise ValueError(f'{out}: nothing to resume (no config.json)')
        saved = guards.load_json(config_path, 'run configuration')
        guards.check_keys(saved.get('train', {}), [f.name for f in dataclasses.fields(TrainConfig)],
                          f"{config_path}: 'train'")
        base = TrainConfig(**saved['train'])
        scene_path, data = saved['scene'], args.data or saved['data']
        if args.scene and os.path.abspath(args.scene) != scene_path:
            raise ValueError(f'--resume continues the run of {scene_path}, but {args.scene} was '
                             'given: expected no scene, or the same one')
        guards.check_run_dir(out, inputs=[scene_path, data], resume=True)
    else:
        if os.path.isfile(os.path.join(out, 'checkpoint.npz')):
            raise ValueError(f'{out} already holds a run; continue it with --resume or choose '
                             'another --output')
        guards.check_run_dir(out, inputs=[args.scene, args.data])
        scene_path = make_demo(os.path.join(out, 'data')) if demo else args.scene
        data = args.data
    cfg = cli.from_arguments(TrainConfig, args, base)

    try:
        scene, dataset = load(scene_path, data)
    except RuntimeError as e:
        raise ValueError(user_message(e)) from None
    guards.check_run_dir(out, inputs=[scene_path, dataset.root], resume=True)
    guards.check_batch(cfg.batch_rays, scene.integrator())
    if scene.bbox().valid():
        guards.check_field_reaches(scene.integrator().field_center, scene.integrator().field_scale,
                                   scene.bbox().min, scene.bbox().max, scene_path)
    if args.resume and 'dataset' in saved:
        guards.check_same_dataset(saved['dataset'], dataset, config_path)
    trainer = Trainer(scene, dataset, cfg, out)
    os.makedirs(out, exist_ok=True)
    with guards.RunLock(out):
        guards.remove_stray_temporaries(out)
        if args.resume:
            guards.check_npz_file(trainer.checkpoint_path, 'checkpoint')
            trainer.resume()
        atomic_write_text(config_path, json.dumps({
            'train': dataclasses.asdict(cfg), 'scene': os.path.abspath(scene_path),
            'data': os.path.abspath(dataset.root), 'dataset': guards.dataset_fingerprint(dataset),
            'integrator': scene.integrator().to_string()}, indent=2))
        try:
            result = trainer.run(progress=not args.quiet)
        except TrainingError as e:
            raise ValueError(str(e)) from None
    psnr = result['psnr']
    if psnr != psnr:  # no step ran (a finished run resumed): the log has the figure
        psnr = guards.recent_psnr(guards.read_log(os.path.join(out, 'log.jsonl'))) or float('nan')
    renders = f"; renders {os.path.join(out, 'images')}" if cfg.validate_every else ''
    lines = [f"done: {result['iterations']} iterations in {result['seconds']:.0f} s, "
             f"PSNR {psnr:.2f} dB (last 100 steps); mesh {result['mesh']}{renders}"]
    if dataset.gt_mesh:
        from reneus_mi.evaluate import chamfer, load_mesh
        c = chamfer(load_mesh(result['mesh']), load_mesh(dataset.gt_mesh))
        lines.append(f"Chamfer-L1 x100 to the ground truth: {c['chamfer']:.3f} "
                     f"(postprocess {cfg.postprocess})")
    return '\n'.join(lines)


if __name__ == '__main__':
    sys.exit(main())
