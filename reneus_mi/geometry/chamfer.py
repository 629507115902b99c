"""The paper's geometry metric, Chamfer-L1 x 100, with F-score.

Both surfaces are represented by N points sampled uniformly by area, with
N = max(10000, 0.2 · number of GT vertices) as in the paper; distances are
nearest-neighbour distances between the two point sets:

- accuracy: mean distance from a predicted point to the GT points;
- completeness: mean distance from a GT point to the predicted points;
- Chamfer-L1 x 100 = 100 · (accuracy + completeness) / 2;
- precision / recall: share of predicted / GT points closer than ``threshold``
  to the other set, and their harmonic mean, the F-score; the same at further distances
  (``at``: a curator's 0.1 and 0.2 mm, one and two pixels' footprint);
- extents: the sizes of both point sets along the GT's principal axes (length, width across
  the legs, height), and the predicted one's error in % of the GT's: what a surface that
  lost its legs or antennae misses, where Chamfer averages it away.

Point-to-point distances have a floor: two independent uniform samples of the
same surface of area A are ≈ 0.5 · sqrt(A / N) apart on average (the mean
nearest-neighbour distance of N random points per area A), e.g. Chamfer x 100 ≈
0.9 for a sphere of radius 0.5 at N = 10000. Both meshes are sampled with the
same seed, so two meshes with the same triangles in the same order (a mesh and
a moved copy) get matching samples and no floor.

``python -m reneus_mi.evaluate`` measures two mesh files.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree
import trimesh

from reneus_mi.geometry.container import inside
from reneus_mi.utils import limits
from reneus_mi.utils.errors import ReneusError

#: The paper's minimum number of sample points.
MIN_POINTS = 10000
#: Bytes per sample point of a measurement: both meshes' points (float64 x 3), their
#: nearest-neighbour trees, distances and indices (docs/constants.md).
BYTES_PER_POINT = 224


def _sample(mesh: trimesh.Trimesh, n: int, seed: int, name: str) -> np.ndarray:
    if len(mesh.faces) == 0 or not mesh.area > 0.0:
        raise ReneusError(f'{name} mesh has no surface to sample (faces={len(mesh.faces)}, area={mesh.area})')
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points)


def chamfer(pred: trimesh.Trimesh, gt: trimesh.Trimesh, *, n_points: int | None = None, seed: int = 0,
            threshold: float = 0.01, at: tuple[float, ...] = (),
            container: trimesh.Trimesh | None = None) -> dict:
    """Chamfer-L1 x 100, accuracy, completeness, precision, recall and F-score of ``pred`` against ``gt``.

    ``n_points`` overrides the paper's N; ``threshold`` is the F-score distance
    in scene units (objects are scaled into the unit sphere, so 0.01 is 1 %);
    predicted points outside the closed ``container`` are dropped before
    measuring (the "fake walls" on the glass). The same ``seed`` gives the same
    numbers. Returns a dict of floats plus ``n_points`` and ``n_pred`` (the
    predicted points kept), ``at`` (precision and recall at each distance of ``at``, by its
    text) and ``extents`` (:func:`extents`).
    """

    if n_points is None:
        n_points = max(MIN_POINTS, int(0.2 * len(gt.vertices)))
    if n_points < 1:
        raise ReneusError(f'n_points={n_points}: expected a positive number')
    limits.check_memory(n_points * BYTES_PER_POINT, f'{n_points} surface points per mesh (--points)')
    for d in (threshold, *at):
        if not d > 0.0:
            raise ReneusError(f'threshold={d}: expected a positive distance')
    pred_points = _sample(pred, n_points, seed, 'predicted')
    gt_points = _sample(gt, n_points, seed, 'ground-truth')
    pred_vertices = np.asarray(pred.vertices)
    if container is not None:
        pred_points = pred_points[inside(pred_points, container)]
        if len(pred_points) == 0:
            raise ReneusError('every predicted point lies outside the container')
        pred_vertices = pred_vertices[inside(pred_vertices, container)]

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
        'at': {f'{d:g}': {'precision': float(np.mean(d_pred < d)), 'recall': float(np.mean(d_gt < d))}
               for d in at},
        'extents': extents(pred_vertices, np.asarray(gt.vertices), gt_points),
    }


def extents(pred_points: np.ndarray, gt_points: np.ndarray, gt_surface: np.ndarray | None = None) -> dict:
    """Sizes of both point sets along the principal axes of the GT's surface (``gt_surface``:
    points spread over it by area; ``gt_points`` by default), longest first, and the
    predicted sizes' error in % of the GT's. Given the meshes' vertices, the sizes are exact:
    a mesh's extreme along any direction is a vertex, where a sample of 10,000 points
    misses a thin leg's tip by a share of its length (1-3 % of the extent measured)."""
    surface = gt_points if gt_surface is None else gt_surface
    centred = surface - surface.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2]
    gt_size = np.ptp(gt_points @ axes.T, axis=0)
    pred_size = np.ptp(pred_points @ axes.T, axis=0)
    # A flat truth has no size across: its error there is not a share of anything.
    error = np.divide(100.0 * (pred_size - gt_size), gt_size, out=np.full(3, np.nan), where=gt_size > 0)
    return {'gt': gt_size.tolist(), 'pred': pred_size.tolist(), 'error_pct': error.tolist()}
