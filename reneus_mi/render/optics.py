"""Optics of a smooth interface: the paper's 𝓡𝓔 operator (Eq. 8) with Fresnel weights."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: cos² of the refracted angle under which a ray counts as at the critical angle: there Fresnel's
#: R and the refracted direction change without bound with the angle (dR/dcos_i 84 at 0.1 degree
#: from it, 1210 at 0.001 for glass 1.45 to ethanol 1.36, infinite where cos_t rounds to 0), and
#: such a ray passes its value but no derivative on. 1e-6 (cos_t under 0.001): the rays near the
#: critical angle say most of a liquid's IOR, and 1e-3 took the jar's refined liquid from 1.3486
#: to 1.3408 for the true 1.36 (tests/train/test_refine.py).
CRITICAL_COS2 = 1e-6


def interface(d: mi.Vector3f, n: mi.Vector3f, eta: mi.Float):
    """Split a ray of direction ``d`` hitting a surface of normal ``n``.

    ``n`` is the container's outward normal and ``eta`` its relative IOR
    (inside / outside); the side the ray comes from follows from the sign of
    dot(d, n). Returns ``(R, d_r, d_t)``: the unpolarised ("natural light")
    Fresnel reflectance, the reflected and the refracted directions. Under
    total internal reflection R = 1 (and ``d_t`` is meaningless). Derivatives
    stop at rays within :data:`CRITICAL_COS2` of the critical angle.
    """
    wi = -d
    cos_i = dr.dot(wi, n)
    eta_ti = dr.select(cos_i >= 0.0, dr.rcp(eta), eta)
    cos_t2 = dr.detach(1.0 - eta_ti * eta_ti * (1.0 - cos_i * cos_i))
    critical = (cos_t2 >= 0.0) & (cos_t2 < CRITICAL_COS2)
    wi, n, eta = (dr.select(critical, dr.detach(x), x) for x in (wi, n, eta))
    R, cos_t, _, eta_ti = mi.fresnel(dr.dot(wi, n), eta)
    return R, mi.reflect(wi, n), mi.refract(wi, n, cos_t, eta_ti)
