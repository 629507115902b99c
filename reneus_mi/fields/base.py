"""The interface of what lives inside the container: an SDF with a radiance.

A field answers three questions about a point ``x`` (world coordinates):

- :meth:`Field.geometry`: the signed distance g(x) and a feature vector for
  the radiance network;
- :meth:`Field.radiance`: the linear radiance c(x, v, n, feature) leaving ``x``
  towards the viewer (``v`` is the ray direction, pointing away from the viewer);
- :meth:`Field.inv_s`: NeuS's learned sharpness s (the inverse standard
  deviation of the logistic density), a differentiable scalar.

Everything else derives from these. Dr.Jit 1.5 has no second-order autodiff, so
the SDF gradient used for normals, for NeuS's cosine estimate and for the
Eikonal term is a tetrahedral finite difference of :meth:`geometry`: it is first
order in the weights, so it stays differentiable (Neuralangelo does the same for
hash grids). Analytic fields override :meth:`gradient` with the exact one.

Parameters are a flat ``dict`` of Dr.Jit arrays (``params()``/``set_params()``),
which is what both ``mi.traverse`` and ``mi.ad.Adam`` want.
"""
from __future__ import annotations

import dataclasses
import json
import os
from typing import ClassVar

import drjit as dr
import mitsuba as mi
import numpy as np

from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_savez, check_npz_file
from reneus_mi.utils.param_groups import ParamGroup

# Vertices of a regular tetrahedron, |e_k|^2 = 3 and sum_k e_k e_k^T = 4 I.
_TETRA = ((1.0, -1.0, -1.0), (-1.0, -1.0, 1.0), (-1.0, 1.0, -1.0), (1.0, 1.0, 1.0))


class FieldConfig:
    """Base of the field configurations (dataclasses): ``kind`` names the field they build."""

    kind: ClassVar[str] = ''

    @classmethod
    def of_kind(cls, name: str | None, where: str) -> type:
        """The configuration of the field kind ``name``: a setting of this type names its kind
        (:mod:`reneus_mi.utils.settings`)."""
        from reneus_mi.fields import FIELD_CONFIGS   # the package imports this module: a cycle
        if name in FIELD_CONFIGS:
            return FIELD_CONFIGS[name]
        kinds = ', '.join(FIELD_CONFIGS)
        if isinstance(name, str) and (name.endswith('.npz') or os.sep in name or os.path.exists(name)):
            if not os.path.isfile(name):
                raise ReneusError(f'{where}={name!r}: no such file; expected a field kind ({kinds})')
            raise ReneusError(f'{where}={name!r} is a saved field, and a setting takes a field kind ({kinds}); '
                              f'render a saved field with python -m reneus_mi.render SCENE --field {name}, or '
                              f'name it in a scene: <string name="field" value="{name}"/>')
        raise ReneusError(f'{where}.kind={name!r}: unknown field kind; expected one of {kinds}')

    def setup(self) -> 'Field':
        """The field this configuration describes, freshly initialised."""
        from reneus_mi.fields import FIELDS   # the package imports this module: a cycle
        return FIELDS[self.kind](**dataclasses.asdict(self))


class Field:
    """Base class of every field; see the module docstring for the contract."""

    #: Length of the feature vector that geometry() returns.
    n_features: int = 0
    #: Step of the finite-difference gradient, in world units: a Python float, or
    #: an opaque Dr.Jit scalar for a step that changes during training (kernels
    #: then read it from memory instead of being recompiled for each value).
    fd_step: float | mi.Float = 1e-3
    #: Radius of the sphere, centred at the origin, outside which the field is empty.
    bound: float = 1.0

    def geometry(self, x: mi.Point3f) -> tuple[mi.Float, list[mi.Float]]:
        raise NotImplementedError

    def radiance(self, x: mi.Point3f, v: mi.Vector3f, n: mi.Vector3f,
                 feature: list[mi.Float]) -> mi.Color3f:
        raise NotImplementedError

    def inv_s(self) -> mi.Float:
        raise NotImplementedError

    def param_groups(self, learning_rate: float) -> list[ParamGroup]:
        """The keys of :meth:`params` in named groups at their peak learning rates, from
        ``learning_rate`` (the run's): one group ``field`` by default, none without parameters."""
        keys = tuple(self.params())
        return [ParamGroup('field', keys, learning_rate)] if keys else []

    def set_step(self, step: int) -> None:
        """Follow the training schedule (e.g. open hash-grid levels); nothing by default."""

    def detail(self) -> float | None:
        """The size, in the field's frame, of the finest detail the field holds (a hash grid's
        finest cell); None where nothing bounds it."""
        return None

    def sdf(self, x: mi.Point3f) -> mi.Float:
        return self.geometry(x)[0]

    def gradient(self, x: mi.Point3f) -> tuple[mi.Float, mi.Vector3f, list[mi.Float]]:
        """Return ``(g(x), ∇g(x), feature(x))``; ∇g by a tetrahedral stencil.

        With e_k the four tetrahedron vertices (Σ_k e_k e_kᵀ = 4 I),
        Σ_k e_k g(x + h e_k) = 4 h ∇g + O(h²): first order in h (the error is
        h times the off-diagonal Hessian), exact for linear g.
        """
        g, feature = self.geometry(x)
        h = self.fd_step
        grad = mi.Vector3f(0.0)
        for e in _TETRA:
            ev = mi.Vector3f(*e)
            grad += ev * self.sdf(x + ev * h)
        return g, grad * (1.0 / (4.0 * h)), feature

    # ------------------------------------------------------------ parameters
    def params(self) -> dict[str, mi.Float]:
        """Differentiable leaves, keyed by name (empty for analytic fields)."""
        return {}

    def set_params(self, values) -> None:
        """Take new values for the keys of :meth:`params` (a dict or an optimizer)."""
        for key in self.params():
            if key in values:
                self._assign(key, values[key])

    def _assign(self, key: str, value) -> None:
        raise ReneusError(f'{type(self).__name__} has no parameter {key!r}')

    def config(self) -> dict:
        """JSON-serialisable constructor arguments: with params() they rebuild the field."""
        return {}

    # ---------------------------------------------------------------- files
    def arrays(self) -> dict[str, np.ndarray]:
        """The field as named arrays: a JSON header (kind, config) and the parameters."""
        arrays = {f'param/{k}': np.asarray(v, dtype=np.float32).ravel()
                  for k, v in self.params().items()}
        header = json.dumps({'kind': type(self).__name__, 'config': self.config()})
        return {'header': np.array(header), **arrays}

    def save(self, path: str | os.PathLike) -> None:
        """Write the field to one ``.npz`` file, atomically."""
        atomic_savez(path, **self.arrays())


def load_field(path: str | os.PathLike) -> Field:
    """Rebuild a field written by :meth:`Field.save`."""
    from reneus_mi.fields import FIELD_KINDS   # the package imports this module: a cycle
    path = os.fspath(path)
    check_npz_file(path, 'field', keys=('header',))
    try:
        data = np.load(path, allow_pickle=False)
        header = json.loads(str(data['header']))
    except (OSError, ValueError, KeyError) as e:
        raise ReneusError(f'{path}: not a reneus-mi field file ({e})') from None
    kind = header.get('kind')
    if kind not in FIELD_KINDS:
        raise ReneusError(f"{path}: unknown field kind {kind!r}; expected one of {sorted(FIELD_KINDS)}")
    field = FIELD_KINDS[kind](**header['config'])
    expected = field.params()
    values = {}
    for key, cur in expected.items():
        name = f'param/{key}'
        if name not in data:
            raise ReneusError(f'{path}: parameter {key!r} missing')
        arr = data[name]
        if arr.size != dr.width(cur):
            raise ReneusError(f'{path}: parameter {key!r} has {arr.size} values, the field expects {dr.width(cur)}')
        values[key] = type(cur)(arr)
    field.set_params(values)
    return field
