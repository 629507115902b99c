"""The field's frame: where the unit sphere that the field lives in sits in the world.

Fields are defined in a normalised frame (the object inside the unit sphere,
as NeuS's ``scale_mat`` makes it); the world is the dataset's. A
:class:`FieldFrame` is that mapping plus the container's world bounding box,
which bounds the region that is reconstructed. The integrator owns it (from
its ``field_center``/``field_scale`` properties and the scene's container);
checkpoints record it, so that mesh extraction needs nothing else.
"""
from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from reneus_mi.utils.errors import ReneusError

Vector = tuple[float, float, float]


@dataclass(frozen=True)
class FieldFrame:
    center: Vector = (0.0, 0.0, 0.0)
    """World position of the centre of the field's unit sphere."""
    scale: float = 1.0
    """World radius of the field's unit sphere."""
    bounds: tuple[Vector, Vector] | None = None
    """World bounding box (lo, hi) of the container; None: the unit sphere bounds the field."""

    def __post_init__(self):
        if len(self.center) != 3 or not np.all(np.isfinite(self.center)):
            raise ReneusError(f'field frame: center={self.center!r}; expected 3 finite numbers')
        if not (isinstance(self.scale, (int, float)) and np.isfinite(self.scale) and self.scale > 0):
            raise ReneusError(f'field frame: scale={self.scale!r}; expected a number > 0')
        object.__setattr__(self, 'center', tuple(float(c) for c in self.center))
        object.__setattr__(self, 'scale', float(self.scale))
        if self.bounds is not None:
            object.__setattr__(self, 'bounds', tuple(tuple(float(v) for v in b) for b in self.bounds))

    # -------------------------------------------------------------- mapping
    def to_field(self, p: mi.Point3f) -> mi.Point3f:
        """World points (Dr.Jit) in the field's frame; directions are unchanged."""
        return (p - mi.Point3f(*self.center)) * (1.0 / self.scale)

    def to_world_matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix field frame -> world."""
        m = np.diag([self.scale, self.scale, self.scale, 1.0])
        m[:3, 3] = self.center
        return m

    def field_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The region to reconstruct in the field's frame: the container's box within the unit cube."""
        if self.bounds is None:
            return -np.ones(3), np.ones(3)
        c = np.asarray(self.center)
        lo = np.maximum((np.asarray(self.bounds[0]) - c) / self.scale, -1.0)
        hi = np.minimum((np.asarray(self.bounds[1]) - c) / self.scale, 1.0)
        return lo, hi

    # ---------------------------------------------------------------- files
    def to_dict(self) -> dict:
        return {'center': list(self.center), 'scale': self.scale,
                'bounds': None if self.bounds is None else [list(b) for b in self.bounds]}

    @staticmethod
    def from_dict(d: dict, where: str = 'frame') -> 'FieldFrame':
        try:
            return FieldFrame(center=tuple(d['center']), scale=d['scale'],
                              bounds=None if d.get('bounds') is None else tuple(map(tuple, d['bounds'])))
        except (KeyError, TypeError) as e:
            raise ReneusError(f'{where}: not a field frame ({e!r}); expected center, scale and bounds') from None
