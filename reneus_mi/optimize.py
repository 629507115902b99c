"""Reconstruct the object in a container: ``python -m reneus_mi.optimize scene.xml``.

The scene XML describes the container (a shape with a ``dielectric`` BSDF),
the ambient light and ``<integrator type="reneus">`` (its ``preset`` and the
settings that override it: mode, D_re, samples, field); the integrator's
``dataset`` names the folder of photographs and cameras (``--data``
overrides it; ``python -m reneus_mi.scene DATA -o scene.xml --preset cpu``
writes such a scene). Training settings start from the same preset; the
options below override them. Results go to the output folder (see
:mod:`reneus_mi.train.run_folder`); ``--resume`` continues a killed run from its
``config.json``. ``--demo`` reconstructs the embedded demo: a small dataset of
an insect (thin legs) in a glass block that it first renders with Mitsuba's path tracer.
"""
from __future__ import annotations

import argparse
import os
import sys

from reneus_mi.config import TrainConfig
from reneus_mi.data.synthetic import demo_scene
from reneus_mi.geometry.chamfer import chamfer
from reneus_mi.geometry.mesh import load_mesh
from reneus_mi import runs
from reneus_mi.train.run_folder import RunFolder, recent_psnr
from reneus_mi.utils import cli, interrupt
from reneus_mi.utils.errors import ReneusError, exit_on_error


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
    parser.add_argument('--set', dest='settings', metavar='PATH=VALUE', action='append', default=[],
                        help='any setting by its dotted path, after the options below: '
                             'model.sampler.n_coarse=32, train.refine.after=200 (repeatable; typed '
                             'as reneus_mi.config declares it)')
    cli.add_arguments(parser, TrainConfig, default_note="the preset's")
    args = parser.parse_args(argv)
    with exit_on_error(RuntimeError):
        print(run(args))
    return 0


def left_in(folder) -> str:
    """What an interrupted run leaves: the folder's state and what it takes next."""
    if not os.path.isdir(folder.path):
        return 'nothing was written'
    state = folder.recorded_state()
    return f'{folder.path} is {state}: {state.advice()}'


def run(args) -> str:
    if args.scene is None and not args.demo and not args.resume:
        raise ReneusError('no scene given: pass a scene XML (python -m reneus_mi.scene DATA -o '
                          'scene.xml writes one), or --demo for the embedded demo')
    name = 'demo' if args.demo else os.path.splitext(os.path.basename(args.scene or ''))[0]
    out = args.output or os.path.join('runs', name)
    folder = RunFolder(out)
    interrupt.leaving(lambda: left_in(folder))
    # The demo's photographs go beside the run folder: no run ever writes where its inputs are.
    scene = (lambda: demo_scene(os.path.abspath(out).rstrip(os.sep) + '_data')) if args.demo else args.scene
    prepared = runs.prepare(out, scene, args.data, train=cli.given_arguments(TrainConfig, args),
                            settings=args.settings, start='resume' if args.resume else 'new')
    result = prepared.train(progress=not args.quiet)
    if 'failure' in result:
        raise ReneusError(f"{result['failure']}; {out}: {folder.state().advice()}")
    cfg = prepared.spec.config.train
    ended = (f"stopped by the time budget ({cfg.max_minutes:g} min) after {result['iterations']} iterations"
             if result['stopped_by_budget'] else f"done: {result['iterations']} iterations")
    psnr = result['psnr']
    if psnr != psnr:  # no step ran (a finished run resumed): the log has the figure
        psnr = recent_psnr(folder.read_log()) or float('nan')
    lines = [f"{ended} in {result['seconds']:.0f} s"
             + (f", PSNR {psnr:.2f} dB (last 100 steps)" if psnr == psnr else '')
             + f"; mesh {result['mesh']}" + (f" ({result['units']})" if 'units' in result else '')
             + (f" and {result['glb']['path']} (for the web)" if 'glb' in result else '')
             + (f"; renders {folder.images}" if cfg.validate_every else '')]
    gt = result.get('ground_truth')
    if gt:
        c = chamfer(load_mesh(result['mesh']), load_mesh(gt))
        lines.append(f"Chamfer-L1 x100 to the ground truth: {c['chamfer']:.3f} (postprocess {cfg.postprocess}, "
                     f"{result['components']} component(s))")
    return '\n'.join(lines)


if __name__ == '__main__':
    sys.exit(main())
