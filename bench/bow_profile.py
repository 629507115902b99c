"""The bulge of a polished block's faces, shared by ``blender_capture.py --bow-mm`` (which renders
it) and ``bowed_dataset.py`` (which models it): numpy only, for the bpy venv and the project's."""
import numpy as np


def bulge(q: np.ndarray, bow: float, top: float) -> np.ndarray:
    """Outward displacements (N, 3) of points ``q`` (N, 3) on a box's surface, in coordinates
    that put its faces at -1 and 1: its four sides and its top (the face at z = ``top``) bulge
    out by ``bow`` at their centres and not at their edges (a product of parabolas across the
    face); the bottom, standing on the board, stays flat."""
    out = np.zeros_like(q, dtype=np.float64)
    for a in range(3):
        face = np.abs(np.abs(q[:, a]) - 1.0) < 1e-6
        if a == 2:
            face &= np.sign(q[:, 2]) == np.sign(top)
        others = [b for b in range(3) if b != a]
        out[face, a] = np.sign(q[face, a]) * bow * np.prod(1.0 - q[face][:, others] ** 2, axis=1)
    return out
