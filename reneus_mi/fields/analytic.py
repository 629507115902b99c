"""Analytic fields with a constant radiance, behind the :class:`Field` interface.

They have exact SDFs and gradients and a fixed sharpness s, and serve tests (a
hard-surfaced emitter that Mitsuba's path tracer can render too) and demos.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from reneus_mi.fields.base import Field


class AnalyticField(Field):
    """Common part: constant radiance ``color`` and fixed sharpness ``inv_s``."""

    def __init__(self, color=(1.0, 1.0, 1.0), inv_s: float = 2000.0, center=(0.0, 0.0, 0.0)):
        self.color = tuple(float(c) for c in color)
        self.inv_s_value = float(inv_s)
        self.center = tuple(float(c) for c in center)

    def _local(self, x: mi.Point3f) -> mi.Vector3f:
        return mi.Vector3f(x - mi.Point3f(*self.center))

    def _distance(self, p: mi.Vector3f) -> mi.Float:
        raise NotImplementedError

    def geometry(self, x):
        return self._distance(self._local(x)), []

    def gradient(self, x):
        # Exact, by reverse-mode AD in a private graph: lanes are independent,
        # so one backward pass of the whole array gives every lane's gradient.
        p = dr.detach(self._local(x))
        with dr.isolate_grad(), dr.resume_grad():
            dr.enable_grad(p)
            g = self._distance(p)
            dr.backward(g)
            grad = dr.grad(p)
        return dr.detach(g), grad, []

    def radiance(self, x, v, n, feature):
        return mi.Color3f(*self.color) + 0.0 * x.x

    def inv_s(self):
        return mi.Float(self.inv_s_value)

    def config(self):
        return {'color': list(self.color), 'inv_s': self.inv_s_value, 'center': list(self.center)}


class SphereField(AnalyticField):
    def __init__(self, radius: float = 0.5, **kwargs):
        super().__init__(**kwargs)
        self.radius = float(radius)

    def _distance(self, p):
        return dr.norm(p) - self.radius

    def config(self):
        return {**super().config(), 'radius': self.radius}


class BoxField(AnalyticField):
    def __init__(self, half_size=(0.3, 0.3, 0.3), **kwargs):
        super().__init__(**kwargs)
        self.half_size = tuple(float(h) for h in half_size)

    def _distance(self, p):
        q = dr.abs(p) - mi.Vector3f(*self.half_size)
        # The clamp keeps the gradient of the norm finite (0, not 0/0) inside.
        outside = dr.sqrt(dr.maximum(dr.squared_norm(dr.maximum(q, 0.0)), 1e-30))
        return outside + dr.minimum(dr.max(q), 0.0)

    def config(self):
        return {**super().config(), 'half_size': list(self.half_size)}


class TorusField(AnalyticField):
    """Torus around the z axis: major radius ``major``, tube radius ``minor``."""

    def __init__(self, major: float = 0.4, minor: float = 0.15, **kwargs):
        super().__init__(**kwargs)
        self.major, self.minor = float(major), float(minor)

    def _distance(self, p):
        q = dr.sqrt(p.x * p.x + p.y * p.y) - self.major
        return dr.sqrt(q * q + p.z * p.z) - self.minor

    def config(self):
        return {**super().config(), 'major': self.major, 'minor': self.minor}
