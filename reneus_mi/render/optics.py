"""Optics of a smooth interface: the paper's 𝓡𝓔 operator (Eq. 8) with Fresnel weights."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi


def interface(d: mi.Vector3f, n: mi.Vector3f, eta: mi.Float):
    """Split a ray of direction ``d`` hitting a surface of normal ``n``.

    ``n`` is the container's outward normal and ``eta`` its relative IOR
    (inside / outside); the side the ray comes from follows from the sign of
    dot(d, n). Returns ``(R, d_r, d_t)``: the unpolarised ("natural light")
    Fresnel reflectance, the reflected and the refracted directions. Under
    total internal reflection R = 1 (and ``d_t`` is meaningless).
    """
    wi = -d
    R, cos_t, _, eta_ti = mi.fresnel(dr.dot(wi, n), eta)
    return R, mi.reflect(wi, n), mi.refract(wi, n, cos_t, eta_ti)
