"""The light around the container (beyond the paper, which takes it as known: Sec. 5):
refinable in place of the scene's emitter.

Light: ``ambient`` is one RGB radiance for every direction (the paper's C_out);
``sh`` a real spherical-harmonics expansion up to order 2 (9 RGB
coefficients), for rooms that are not uniform.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from reneus_mi.utils.errors import ReneusError

#: Light models: the scene's emitter as given, one refinable RGB radiance, order-2 SH.
LIGHTS = ('emitter', 'ambient', 'sh')
#: Y_00, the constant spherical harmonic: an SH light's mean radiance is c_00 Y_00.
_Y00 = 0.282095
#: Directions that project an emitter onto the SH basis (Fibonacci sphere).
_PROJECTION_DIRECTIONS = 4096


def sh_basis(d: mi.Vector3f) -> list:
    """The 9 real spherical harmonics Y_lm (l <= 2) of unit directions ``d``."""
    x, y, z = d.x, d.y, d.z
    return [_Y00 + 0.0 * x,
            0.488603 * y, 0.488603 * z, 0.488603 * x,
            1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3.0 * z * z - 1.0),
            1.092548 * x * z, 0.546274 * (x * x - y * y)]


def fibonacci_directions(n: int) -> np.ndarray:
    """``n`` nearly uniform unit vectors (n,3): equal-weight quadrature on the sphere."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def emitter_radiance(emitter: mi.Emitter, d: mi.Vector3f) -> mi.Color3f:
    """Radiance of an environment emitter seen along ``d``."""
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(d))
    si.wi = -d
    return emitter.eval(si)


class Light:
    """The light around the container: ``ambient`` (one RGB) or ``sh`` (9 RGB coefficients)."""

    def __init__(self, kind: str, emitter: mi.Emitter):
        if kind not in LIGHTS[1:]:
            raise ReneusError(f"light={kind!r}: expected one of {', '.join(LIGHTS)}")
        self.kind = kind
        # Initialised by projecting the scene's emitter (exact for a constant one).
        dirs = fibonacci_directions(_PROJECTION_DIRECTIONS)
        d = mi.Vector3f(*(mi.Float(dirs[:, i].astype(np.float32)) for i in range(3)))
        L = np.broadcast_to(np.array(emitter_radiance(emitter, d), np.float64).reshape(3, -1), (3, len(dirs)))
        if kind == 'ambient':
            values = L.mean(axis=1)
        else:
            Y = np.array([np.broadcast_to(np.array(y, np.float64), (len(dirs),)) for y in sh_basis(d)])
            values = (4.0 * np.pi / len(dirs)) * (Y @ L.T)    # (9, 3)
        self.coefficients = mi.Float(values.astype(np.float32).ravel())

    @property
    def name(self) -> str:
        return 'light.radiance' if self.kind == 'ambient' else 'light.sh'

    def eval(self, d: mi.Vector3f) -> mi.Color3f:
        c = self.coefficients
        if self.kind == 'ambient':
            return mi.Color3f(*(dr.gather(mi.Float, c, i) for i in range(3)))
        L = dr.zeros(mi.Color3f, dr.width(d))
        for k, y in enumerate(sh_basis(d)):
            L += y * mi.Color3f(*(dr.gather(mi.Float, c, 3 * k + i) for i in range(3)))
        # Negative radiance is not light: an SH fit can ring below zero.
        return dr.maximum(L, 0.0)

    def mean(self) -> np.ndarray:
        """Mean radiance over the sphere (RGB): what a uniform room of the same power shows."""
        c = np.array(self.coefficients, np.float64).reshape(-1, 3)
        return c[0] if self.kind == 'ambient' else c[0] * _Y00

