"""The container's masks ``M_in``: the pixels of each view whose centre ray meets it.

Computed by tracing every pixel-centre ray at the container with Mitsuba, one
Dr.Jit launch per view. A dataset without masks of its own gets these; a
synthetic one is made with them.
"""
from __future__ import annotations

import mitsuba as mi
import numpy as np

from reneus_mi.data.cameras import pixel_rays
from reneus_mi.geometry.container import container_shape

#: Pixels whose rays are traced in one launch.
ROWS_PIXELS = 1 << 20


def container_masks(path: str, K: np.ndarray, c2w: np.ndarray, height: int, width: int,
                    views: list[int] | None = None) -> np.ndarray:
    """Boolean masks (len(views),H,W): pixels whose centre ray hits the container.

    ``K`` (N,3,3) and ``c2w`` (N,4,4) are OpenCV cameras; ``views`` picks some
    of them (all by default).
    """
    scene = mi.load_dict({'type': 'scene', 'container': container_shape(path)})
    views = list(range(len(K)) if views is None else views)
    masks = np.zeros((len(views), height, width), bool)
    # Rows at a time: a photograph's rays in float64 would take ~150 bytes per pixel at once.
    rows = max(1, ROWS_PIXELS // width)
    for n, v in enumerate(views):
        for top in range(0, height, rows):
            ys, xs = np.mgrid[top:min(top + rows, height), :width]
            o, d = pixel_rays(K, c2w, v, np.stack([xs.ravel(), ys.ravel()], axis=1))
            ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[:, i]) for i in range(3))),
                           mi.Vector3f(*(mi.Float(d[:, i]) for i in range(3))))
            masks[n, top:top + rows] = np.array(scene.ray_test(ray)).reshape(ys.shape)
    return masks
