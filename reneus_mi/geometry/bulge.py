"""The bulge of a polished block's faces: a product of parabolas across each face, zero along
its edges (what :mod:`reneus_mi.render.bow` measures and ``capture.simulation`` photographs).

Each of the block's six faces ``k`` (axis ``a = k // 2``, side ``s = -1, +1``, in the block's own
frame, half-sizes ``h``) bulges by ``bow[k]`` at its centre times ``(1 - u^2)(1 - v^2)``, ``u`` and
``v`` its other two coordinates over their half-sizes. A point takes each face's share by its
normal, ``max(0, s n_a)^2``: all of its own face's on a flat face, a blend over a rounding.
The functions are plain arithmetic, for NumPy arrays and Dr.Jit arrays alike.
"""
from __future__ import annotations

import numpy as np


def bulge(q, n, bow, half):
    """The bulge's height (along the face's normal) and its slope (3 components, the block's
    frame) at points ``q`` (3 components in the block's frame) on faces of normal ``n``; ``bow``
    the six faces' bulges (-x, +x, -y, +y, -z, +z), ``half`` the block's half-sizes. Plain
    arithmetic: NumPy arrays (the written mesh) and Dr.Jit arrays (the renderer) alike."""
    height = 0.0
    slope = [0.0, 0.0, 0.0]
    for k in range(6):
        a, s = k // 2, 2 * (k % 2) - 1
        share = _positive(s * n[a])
        share = share * share * bow[k]
        b, c = (a + 1) % 3, (a + 2) % 3
        u, v = q[b] / half[b], q[c] / half[c]
        pu, pv = _positive(1.0 - u * u), _positive(1.0 - v * v)
        height = height + share * pu * pv
        # d/dx of (1 - (x/h)^2) is -2x/h^2, where the parabola is not cut off at 0.
        slope[b] = slope[b] - share * pv * 2.0 * u / half[b] * _step(pu)
        slope[c] = slope[c] - share * pu * 2.0 * v / half[c] * _step(pv)
    return height, slope


def _positive(x):
    return 0.5 * (x + abs(x))


def _step(x):
    """1 where ``x`` > 0, else 0 (``x`` >= 0)."""
    return x / (x + 1e-12)


def displacement(q: np.ndarray, n: np.ndarray, bow, half: np.ndarray) -> np.ndarray:
    """How the bulges ``bow`` move points ``q`` of normals ``n`` (3 x N each, the block's frame),
    as (N, 3): each face's along its axis, by the points' share of it."""
    move = np.zeros((q.shape[1], 3))
    for k in range(6):
        height, _ = bulge(q, n, np.eye(6)[k] * bow[k], half)
        move[:, k // 2] += (2 * (k % 2) - 1) * height
    return move
