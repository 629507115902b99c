"""The container's pose (beyond the paper, which takes it as known: Sec. 5), refinable.

Container pose: a world point x of the container as loaded goes to

    x' = R(r) diag(exp(σ)) (x - c) + c + τ

with ``τ`` the translation, ``r`` a rotation vector (axis x angle), ``σ`` the
per-axis log-scale and ``c`` the centre of the container's bounding box. Rays
are taken into the container's frame, intersected with the mesh as loaded and
their hit distance, point and normals mapped back differentiably: the
derivatives are the interior ones (how refraction moves with the glass).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from reneus_mi.render.step_state import refined


def _cross_matrix(v) -> mi.Matrix3f:
    return mi.Matrix3f(0.0, -v.z, v.y,
                       v.z, 0.0, -v.x,
                       -v.y, v.x, 0.0)


class ContainerPose:
    """A rigid transform and per-axis scale of the container about ``pivot``."""

    def __init__(self, pivot):
        self.pivot = mi.ScalarPoint3f(*map(float, pivot))
        self.translation = dr.zeros(mi.Float, 3)
        self.rotation = dr.zeros(mi.Float, 3)
        self.log_scale = dr.zeros(mi.Float, 3)

    def params(self) -> dict:
        return {'container.translation': self.translation, 'container.rotation': self.rotation,
                'container.log_scale': self.log_scale}

    @staticmethod
    def _vector(array) -> mi.Vector3f:
        return mi.Vector3f(*(dr.gather(mi.Float, array, i) for i in range(3)))

    def _linear(self, lanes=None):
        """(R, s): the rotation matrix (Rodrigues) and the per-axis scale, differentiable at 0
        (from the rays of ``lanes`` alone: :func:`~reneus_mi.render.step_state.refined`)."""
        r = self._vector(self.rotation)
        θ2 = dr.squared_norm(r)
        θ = dr.sqrt(dr.maximum(θ2, 1e-12))
        small = θ2 < 1e-6
        a = dr.select(small, 1.0 - θ2 / 6.0, dr.sin(θ) / θ)
        b = dr.select(small, 0.5 - θ2 / 24.0, (1.0 - dr.cos(θ)) / dr.maximum(θ2, 1e-12))
        K = _cross_matrix(r)
        R = dr.identity(mi.Matrix3f) + a * K + b * (K @ K)
        return refined(R, lanes), refined(dr.exp(self._vector(self.log_scale)), lanes)

    def to_container(self, o: mi.Point3f, d: mi.Vector3f, lanes: mi.Bool | None = None):
        """World rays in the frame of the container as loaded: (origin, unnormalised direction)."""
        R, s = self._linear(lanes)
        c = mi.Point3f(self.pivot)
        Rt = R.T
        o_c = (Rt @ mi.Vector3f(o - c - refined(self._vector(self.translation), lanes))) / s + c
        return mi.Point3f(o_c), mi.Vector3f((Rt @ d) / s)

    def to_world(self, x: mi.Point3f) -> mi.Point3f:
        """A point of the container as loaded, where the pose puts it."""
        R, s = self._linear()
        c = mi.Point3f(self.pivot)
        return mi.Point3f(R @ (s * mi.Vector3f(x - c)) + c + self._vector(self.translation))

    def normal_to_world(self, n: mi.Vector3f, lanes: mi.Bool | None = None) -> mi.Vector3f:
        """A normal of the container as loaded, in the world (inverse transpose of R diag(s))."""
        R, s = self._linear(lanes)
        return dr.normalize(R @ (n / s))

    def matrix(self) -> np.ndarray:
        """The 4x4 world transform of the container (NumPy, for writing the refined mesh)."""
        with dr.suspend_grad():
            R, s = self._linear()
            t = np.array(self._vector(self.translation), np.float64).ravel()
            Rm = np.array(R, np.float64).reshape(3, 3)
            sm = np.array(s, np.float64).ravel()
        c = np.array(self.pivot, np.float64)
        M = np.eye(4)
        M[:3, :3] = Rm * sm[None, :]
        M[:3, 3] = c + t - M[:3, :3] @ c
        return M

