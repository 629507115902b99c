"""Analytic fields with a constant radiance, behind the :class:`Field` interface.

They have exact SDFs and gradients and a fixed sharpness s, and serve tests (a
hard-surfaced emitter that Mitsuba's path tracer can render too) and demos.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import ClassVar

import drjit as dr
import mitsuba as mi

from reneus_mi.fields.base import Field, FieldConfig
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.validate import check_numbers

Vector = tuple[float, float, float]


@dataclass
class AnalyticFieldConfig(FieldConfig):
    color: Vector = (1.0, 1.0, 1.0)
    """Constant linear radiance of the surface."""
    inv_s: float = 2000.0
    """Fixed sharpness s of NeuS's density."""
    center: Vector = (0.0, 0.0, 0.0)
    """Centre of the shape in the field's frame (the unit sphere)."""

    def __post_init__(self):
        for name in ('color', 'center'):
            value = getattr(self, name)
            if len(value) != 3:
                raise ReneusError(f'{self.kind}: {name}={value!r}; expected 3 numbers')
            setattr(self, name, tuple(float(v) for v in value))
        check_numbers(self, positive=('inv_s',))


@dataclass
class SphereFieldConfig(AnalyticFieldConfig):
    kind: ClassVar[str] = 'sphere'
    radius: float = 0.5
    """Radius of the sphere."""

    def __post_init__(self):
        super().__post_init__()
        check_numbers(self, positive=('radius',))


@dataclass
class BoxFieldConfig(AnalyticFieldConfig):
    kind: ClassVar[str] = 'box'
    half_size: Vector = (0.3, 0.3, 0.3)
    """Half the box's extent along x, y and z."""

    def __post_init__(self):
        super().__post_init__()
        if len(self.half_size) != 3 or not all(h > 0 for h in self.half_size):
            raise ReneusError(f'box: half_size={self.half_size!r}; expected 3 positive numbers')
        self.half_size = tuple(float(h) for h in self.half_size)


@dataclass
class TorusFieldConfig(AnalyticFieldConfig):
    kind: ClassVar[str] = 'torus'
    major: float = 0.4
    """Radius of the torus's centre circle (around the z axis)."""
    minor: float = 0.15
    """Radius of the tube."""

    def __post_init__(self):
        super().__post_init__()
        check_numbers(self, positive=('major', 'minor'))


class AnalyticField(Field):
    """Common part: constant radiance ``color`` and fixed sharpness ``inv_s``."""

    Config: ClassVar[type] = AnalyticFieldConfig

    def __init__(self, **kwargs):
        try:
            self.cfg = self.Config(**kwargs)
        except TypeError:
            known = [f.name for f in dataclasses.fields(self.Config)]
            raise ReneusError(f'{self.Config.kind} field: unknown option(s) '
                              f'{sorted(set(kwargs) - set(known))}; expected some of {known}') from None

    def _local(self, x: mi.Point3f) -> mi.Vector3f:
        return mi.Vector3f(x - mi.Point3f(*self.cfg.center))

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
        # Value and gradient stay attached to x, so that renders differentiate in whatever
        # moves the samples (the container's IOR and pose): the gradient's derivative (the
        # Hessian, which NeuS's opacity depends on through cos) from tetrahedral differences.
        value, grad_fd, _ = super().gradient(x)
        return value, dr.replace_grad(grad, grad_fd), []

    def radiance(self, x, v, n, feature):
        return mi.Color3f(*self.cfg.color) + 0.0 * x.x

    def inv_s(self):
        return mi.Float(self.cfg.inv_s)

    def config(self):
        return dataclasses.asdict(self.cfg)


class SphereField(AnalyticField):
    Config = SphereFieldConfig

    def _distance(self, p):
        return dr.norm(p) - self.cfg.radius


class BoxField(AnalyticField):
    Config = BoxFieldConfig

    def _distance(self, p):
        q = dr.abs(p) - mi.Vector3f(*self.cfg.half_size)
        # The clamp keeps the gradient of the norm finite (0, not 0/0) inside.
        outside = dr.sqrt(dr.maximum(dr.squared_norm(dr.maximum(q, 0.0)), 1e-30))
        return outside + dr.minimum(dr.max(q), 0.0)


class TorusField(AnalyticField):
    """Torus around the z axis: major radius ``major``, tube radius ``minor``."""

    Config = TorusFieldConfig

    def _distance(self, p):
        q = dr.sqrt(p.x * p.x + p.y * p.y) - self.cfg.major
        return dr.sqrt(q * q + p.z * p.z) - self.cfg.minor
