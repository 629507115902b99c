"""Fresnel, reflection, refraction and TIR at known angles (reneus_mi.render.optics)."""
import math

import mitsuba as mi
import numpy as np
import pytest

from reneus_mi.render.optics import interface

ETA = 1.45
N = mi.Vector3f(0, 0, 1)  # outward normal of the container


def direction(theta_deg, inside=False):
    """Unit direction hitting the surface z=0 at incidence angle theta (from outside: -z)."""
    t = math.radians(theta_deg)
    return mi.Vector3f(math.sin(t), 0.0, math.cos(t) if inside else -math.cos(t))


def fresnel_unpolarised(theta_i, n1, n2):
    sin_t = n1 / n2 * math.sin(theta_i)
    if sin_t >= 1:
        return 1.0
    ci, ct = math.cos(theta_i), math.sqrt(1 - sin_t ** 2)
    rs = (n1 * ci - n2 * ct) / (n1 * ci + n2 * ct)
    rp = (n1 * ct - n2 * ci) / (n1 * ct + n2 * ci)
    return 0.5 * (rs * rs + rp * rp)


def test_normal_incidence_reflectance():
    R, d_r, d_t = interface(direction(0.0), N, mi.Float(ETA))
    assert R[0] == pytest.approx(((ETA - 1) / (ETA + 1)) ** 2, abs=1e-6)  # 0.0337
    assert R[0] == pytest.approx(0.034, abs=5e-4)
    assert np.allclose(np.array(d_r).ravel(), [0, 0, 1], atol=1e-6)
    assert np.allclose(np.array(d_t).ravel(), [0, 0, -1], atol=1e-6)


@pytest.mark.parametrize('theta', [15.0, 45.0, 70.0, 85.0])
def test_entering_glass(theta):
    R, d_r, d_t = interface(direction(theta), N, mi.Float(ETA))
    assert R[0] == pytest.approx(fresnel_unpolarised(math.radians(theta), 1.0, ETA), abs=1e-5)
    # Law of reflection: mirror of d about the surface.
    assert np.allclose(np.array(d_r).ravel(), np.array(direction(theta)).ravel() * [1, 1, -1], atol=1e-6)
    # Snell: sin θ_t = sin θ_i / η, in the plane of incidence, into the glass.
    t = np.array(d_t).ravel()
    assert t[0] == pytest.approx(math.sin(math.radians(theta)) / ETA, abs=1e-6)
    assert t[1] == pytest.approx(0.0, abs=1e-7) and t[2] < 0
    assert np.linalg.norm(t) == pytest.approx(1.0, abs=1e-6)


def test_leaving_glass_and_total_internal_reflection():
    critical = math.degrees(math.asin(1 / ETA))  # 43.6°
    R, _, d_t = interface(direction(30.0, inside=True), N, mi.Float(ETA))
    assert R[0] == pytest.approx(fresnel_unpolarised(math.radians(30.0), ETA, 1.0), abs=1e-5)
    t = np.array(d_t).ravel()
    assert t[0] == pytest.approx(ETA * math.sin(math.radians(30.0)), abs=1e-6) and t[2] > 0
    R, d_r, _ = interface(direction(critical + 2.0, inside=True), N, mi.Float(ETA))
    assert R[0] == 1.0
    assert np.array(d_r).ravel()[2] < 0  # reflected back inside
    R, _, _ = interface(direction(critical - 2.0, inside=True), N, mi.Float(ETA))
    assert R[0] < 1.0


def test_reciprocity():
    # R is the same for the two directions of one light path (Stokes relations).
    theta_out = 40.0
    R_in, _, d_t = interface(direction(theta_out), N, mi.Float(ETA))
    R_out, _, _ = interface(-d_t, N, mi.Float(ETA))
    # -d_t travels from inside towards the surface: angle θ_t, leaving the glass.
    assert R_out[0] == pytest.approx(R_in[0], abs=1e-5)
