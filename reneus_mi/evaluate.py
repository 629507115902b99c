"""The paper's geometry metric, Chamfer-L1 x 100, with F-score, and its CLI.

Both surfaces are represented by N points sampled uniformly by area, with
N = max(10000, 0.2 · number of GT vertices) as in the paper; distances are
nearest-neighbour distances between the two point sets:

- accuracy: mean distance from a predicted point to the GT points;
- completeness: mean distance from a GT point to the predicted points;
- Chamfer-L1 x 100 = 100 · (accuracy + completeness) / 2;
- precision / recall: share of predicted / GT points closer than ``threshold``
  to the other set, and their harmonic mean, the F-score.

Point-to-point distances have a floor: two independent uniform samples of the
same surface of area A are ≈ 0.5 · sqrt(A / N) apart on average (the mean
nearest-neighbour distance of N random points per area A), e.g. Chamfer x 100 ≈
0.9 for a sphere of radius 0.5 at N = 10000. Both meshes are sampled with the
same seed, so two meshes with the same triangles in the same order (a mesh and
a moved copy) get matching samples and no floor.

Usage::

    python -m reneus_mi.evaluate pred.ply gt.obj --container box.ply --postprocess crop
"""
from __future__ import annotations

import argparse
import json

import numpy as np
import trimesh

from reneus_mi import guards
from reneus_mi.errors import ReneusError, exit_on_error
from reneus_mi.io import atomic_write_text
from reneus_mi.mesh import POSTPROCESS_MODES, components, inside, load_container, load_mesh, postprocess

#: The paper's minimum number of sample points.
MIN_POINTS = 10000


def _sample(mesh: trimesh.Trimesh, n: int, seed: int, name: str) -> np.ndarray:
    if len(mesh.faces) == 0 or not mesh.area > 0.0:
        raise ReneusError(f'{name} mesh has no surface to sample (faces={len(mesh.faces)}, area={mesh.area})')
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points)


def chamfer(pred: trimesh.Trimesh, gt: trimesh.Trimesh, *, n_points: int | None = None, seed: int = 0,
            threshold: float = 0.01, container: trimesh.Trimesh | None = None) -> dict:
    """Chamfer-L1 x 100, accuracy, completeness, precision, recall and F-score of ``pred`` against ``gt``.

    ``n_points`` overrides the paper's N; ``threshold`` is the F-score distance
    in scene units (objects are scaled into the unit sphere, so 0.01 is 1 %);
    predicted points outside the closed ``container`` are dropped before
    measuring (the "fake walls" on the glass). The same ``seed`` gives the same
    numbers. Returns a dict of floats plus ``n_points`` and ``n_pred`` (the
    predicted points kept).
    """
    from scipy.spatial import cKDTree

    if n_points is None:
        n_points = max(MIN_POINTS, int(0.2 * len(gt.vertices)))
    if n_points < 1:
        raise ReneusError(f'n_points={n_points}: expected a positive number')
    if not threshold > 0.0:
        raise ReneusError(f'threshold={threshold}: expected a positive distance')
    pred_points = _sample(pred, n_points, seed, 'predicted')
    gt_points = _sample(gt, n_points, seed, 'ground-truth')
    if container is not None:
        pred_points = pred_points[inside(pred_points, container)]
        if len(pred_points) == 0:
            raise ReneusError('every predicted point lies outside the container')

    d_pred, _ = cKDTree(gt_points).query(pred_points, workers=-1)
    d_gt, _ = cKDTree(pred_points).query(gt_points, workers=-1)
    accuracy, completeness = float(d_pred.mean()), float(d_gt.mean())
    precision = float(np.mean(d_pred < threshold))
    recall = float(np.mean(d_gt < threshold))
    fscore = 2.0 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {
        'chamfer': 100.0 * (accuracy + completeness) / 2.0,
        'accuracy': accuracy,
        'completeness': completeness,
        'precision': precision,
        'recall': recall,
        'fscore': fscore,
        'threshold': float(threshold),
        'n_points': int(n_points),
        'n_pred': int(len(pred_points)),
    }


def _table(result: dict) -> str:
    rows = [
        ('Chamfer-L1 x100', f"{result['chamfer']:.4f}"),
        ('accuracy', f"{result['accuracy']:.6f}"),
        ('completeness', f"{result['completeness']:.6f}"),
        (f"F-score @ {result['threshold']:g}", f"{result['fscore']:.4f}"),
        ('precision', f"{result['precision']:.4f}"),
        ('recall', f"{result['recall']:.4f}"),
        ('points (pred kept / sampled)', f"{result['n_pred']} / {result['n_points']}"),
        ('connected components', str(result['components'])),
        ('post-processing', result['postprocess']),
    ]
    width = max(len(name) for name, _ in rows)
    return '\n'.join(f'{name:<{width}}  {value}' for name, value in rows)


def main(argv: list[str] | None = None) -> dict:
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
                             "'clean' drops floating fragments only, "
                             "'crop' removes faces outside --container, 'none' measures PRED as is "
                             '(default: %(default)s)')
    parser.add_argument('--threshold', type=float, default=0.01,
                        help='F-score distance in scene units (default: %(default)s, 1%% of the unit sphere)')
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
        if args.postprocess == 'crop' and container is None:
            raise ReneusError('--postprocess crop needs --container')
        pred = postprocess(pred, args.postprocess, container)
        if len(pred.faces) == 0:
            raise ReneusError(f"{args.pred}: nothing is left after --postprocess {args.postprocess}")
        result = chamfer(pred, gt, n_points=args.points, seed=args.seed,
                         threshold=args.threshold, container=container)
        result['postprocess'] = args.postprocess
        result['components'] = components(pred)
        if args.json:
            atomic_write_text(args.json, json.dumps({'pred': args.pred, 'gt': args.gt, **result},
                                                    indent=2))
    print(_table(result))
    return result


if __name__ == '__main__':
    main()
