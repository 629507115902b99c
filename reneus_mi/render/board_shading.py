"""The light that reaches the backdrop (the printed board under a container): a refinable
gain on its emission."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

#: Learning rate of the board's log-gains relative to the run's: 1e-2 at the fast preset's
#: 1e-3, a percent of light per step.
SHADING_LR_SCALE = 10.0


class BoardShading:
    """The light that reaches the backdrop, as a gain on its emission: a grid of log-gains over
    its uv square (bilinear), starting at 1.

    The scene's board is its print lit evenly (the capture measures the print away from the
    container), but under and around a container the photographs show it shaded: the glass
    passes (1 - R)^2 of the tent's light, focuses some into caustics, and the specimen casts a
    shadow. Seen from every view through the glass, a board point's gain is one value, so the
    photographs fix it; without it the field can only darken the glass itself, and fog fills
    the block (docs/constants.md). Every backdrop shape shares the grid through its own uv."""

    NAME = 'board.shading'

    def __init__(self, texels: int, aspect: float):
        #: Texels along u and v: ``texels`` along the longer side, square texels.
        self.size = (texels, max(1, round(texels / aspect))) if aspect >= 1 else \
            (max(1, round(texels * aspect)), texels)
        self.log_gain = dr.zeros(mi.Float, self.size[0] * self.size[1])

    def gain(self, uv: mi.Point2f, active: mi.Bool) -> mi.Float:
        w, h = self.size
        x = dr.clip(uv.x * w - 0.5, 0.0, w - 1.0)
        y = dr.clip(uv.y * h - 0.5, 0.0, h - 1.0)
        x0, y0 = mi.UInt32(dr.floor(x)), mi.UInt32(dr.floor(y))
        x1, y1 = dr.minimum(x0 + 1, w - 1), dr.minimum(y0 + 1, h - 1)
        fx, fy = x - dr.floor(x), y - dr.floor(y)
        g = 0.0
        for xi, yi, wt in ((x0, y0, (1 - fx) * (1 - fy)), (x1, y0, fx * (1 - fy)),
                           (x0, y1, (1 - fx) * fy), (x1, y1, fx * fy)):
            g += wt * dr.gather(mi.Float, self.log_gain, yi * w + xi, active)
        return dr.exp(g)


def uv_aspect(shape) -> float:
    """World length of a shape's u side over its v side (a rectangle's, or a quad mesh's)."""
    si = shape.eval_parameterization(mi.Point2f([0.0, 1.0, 0.0], [0.0, 0.0, 1.0]))
    p = np.array(si.p, np.float64).T
    if not np.all(np.array(si.is_valid())):
        return 1.0
    return float(np.linalg.norm(p[1] - p[0]) / max(np.linalg.norm(p[2] - p[0]), 1e-12))
