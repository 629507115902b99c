"""Chamfer-L1 x100 and F-score of a mesh against the ground truth (the paper's protocol).

Usage::

    python -m reneus_mi.evaluate pred.ply gt.obj --container box.ply --postprocess crop

The measure is :func:`reneus_mi.geometry.chamfer.chamfer` (its docstring says
what the numbers mean and where their floor is).
"""
from __future__ import annotations

import argparse
import json
import sys

from reneus_mi.fields import load_field
from reneus_mi.geometry.chamfer import chamfer
from reneus_mi.geometry.limbs import field_reach, limb_reach
from reneus_mi.geometry.container import load_container
from reneus_mi.geometry.mesh import load_mesh
from reneus_mi.geometry.surface import POSTPROCESS_MODES, components, postprocess
from reneus_mi.train import checkpoint
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError, exit_on_error
from reneus_mi.utils.io import atomic_write_text, check_npz_file, load_json


def _table(result: dict) -> str:
    rows = [
        ('Chamfer-L1 x100', f"{result['chamfer']:.4f}"),
        ('accuracy', f"{result['accuracy']:.6f}"),
        ('completeness', f"{result['completeness']:.6f}"),
        (f"F-score @ {result['threshold']:g}", f"{result['fscore']:.4f}"),
        ('precision', f"{result['precision']:.4f}"),
        ('recall', f"{result['recall']:.4f}"),
        *[(f'precision / recall @ {d}', f"{v['precision']:.4f} / {v['recall']:.4f}")
          for d, v in result['at'].items()],
        ('extents (GT axes)', '  '.join(f'{p:.4g}' for p in result['extents']['pred'])
         + '  vs GT  ' + '  '.join(f'{g:.4g}' for g in result['extents']['gt'])),
        ('extent error %', '  '.join(f'{e:+.1f}' for e in result['extents']['error_pct'])),
        *[(f"{limb['name']}{where}", f"reach {limb['reach']:.4g} of {limb['length']:.4g} ({limb['error_pct']:+.1f} %), "
                                      f"longest gap {limb['longest_gap']:.3g}")
          for key, where in (('limbs', ''), ('field_limbs', ' (field)')) for limb in result.get(key, [])],
        ('points (pred kept / sampled)', f"{result['n_pred']} / {result['n_points']}"),
        ('connected components', str(result['components'])),
        ('post-processing', result['postprocess']),
    ]
    width = max(len(name) for name, _ in rows)
    return '\n'.join(f'{name:<{width}}  {value}' for name, value in rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m reneus_mi.evaluate',
        description='Chamfer-L1 x100 and F-score of a reconstructed mesh against the ground truth '
                    '(the ReNeuS protocol: N = max(10000, 0.2 * GT vertices) surface samples).')
    parser.add_argument('pred', help='reconstructed mesh (any format trimesh reads: ply, obj, stl, ...)')
    parser.add_argument('gt', help='ground-truth mesh, in the same frame and units as PRED')
    parser.add_argument('--container', metavar='MESH',
                        help='closed container mesh: predicted points outside it are not measured, '
                             "and it is what --postprocess crop crops to")
    parser.add_argument('--postprocess', choices=POSTPROCESS_MODES, default='largest',
                        help="clean-up of PRED before measuring: 'largest' keeps the connected component "
                             "with most vertices (the paper's rule, drops real parts of multi-part objects), "
                             "'clean' drops floating fragments only (joining pieces needs the field: extract does it), "
                             "'crop' removes faces outside --container, 'none' measures PRED as is "
                             '(default: %(default)s)')
    parser.add_argument('--threshold', type=float, default=0.01,
                        help='F-score distance in scene units (default: %(default)s, 1%% of the unit sphere)')
    parser.add_argument('--at', type=float, nargs='+', metavar='D',
                        help='further distances for precision and recall (default: THRESHOLD and twice it; '
                             'a capture in mm: 0.1 0.2 and the footprint of one and two pixels)')
    parser.add_argument('--limbs', metavar='TRUTH_JSON',
                        help="a JSON file whose 'limbs' are the specimen's legs and antennae (name, joints_mm, "
                             'radii_mm; bench/blender_capture.py writes them): how far PRED reaches along each, '
                             'within THRESHOLD of its radius')
    parser.add_argument('--field', metavar='CHECKPOINT',
                        help="with --limbs: also how far the run's field itself reaches along each limb (its SDF "
                             'at the axis within the radius and THRESHOLD), before marching cubes and the clean-up: '
                             'a limb the field reaches and PRED misses was lost in meshing')
    parser.add_argument('--points', type=int, default=None,
                        help='number of surface samples per mesh (default: the paper\'s N)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the surface sampling (default: %(default)s)')
    parser.add_argument('--json', metavar='OUT', help='also write the numbers to this JSON file')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing --json file')
    args = parser.parse_args(argv)

    with exit_on_error():
        if args.json:
            guards.check_output_file(args.json, inputs=[args.pred, args.gt, args.container],
                                     overwrite=args.overwrite, extensions=('.json',))
        pred, gt = load_mesh(args.pred, 'predicted mesh'), load_mesh(args.gt, 'ground-truth mesh')
        container = load_container(args.container) if args.container else None
        if args.field:
            if not args.limbs:
                raise ReneusError('--field needs --limbs: the limbs along which the field is probed')
            check_npz_file(args.field, 'checkpoint')
        if args.postprocess == 'crop' and container is None:
            raise ReneusError('--postprocess crop needs --container')
        pred = postprocess(pred, args.postprocess, container)
        if len(pred.faces) == 0:
            raise ReneusError(f"{args.pred}: nothing is left after --postprocess {args.postprocess}")
        result = chamfer(pred, gt, n_points=args.points, seed=args.seed,
                         threshold=args.threshold, container=container,
                         at=tuple(args.at) if args.at else (args.threshold, 2 * args.threshold))
        if args.limbs:
            limbs = load_json(args.limbs, 'limbs file').get('limbs')
            if not limbs:
                raise ReneusError(f"{args.limbs}: no 'limbs'; expected a list of legs and antennae")
            result['limbs'] = limb_reach(pred, limbs, tolerance=args.threshold)
            if args.field:
                result['field_limbs'] = field_reach(load_field(args.field), checkpoint.load_frame(args.field)[0],
                                                    limbs, tolerance=args.threshold)
        result['postprocess'] = args.postprocess
        result['components'] = components(pred)
        if args.json:
            atomic_write_text(args.json, json.dumps({'pred': args.pred, 'gt': args.gt, **result},
                                                    indent=2))
    print(_table(result))
    return 0


if __name__ == '__main__':
    sys.exit(main())
