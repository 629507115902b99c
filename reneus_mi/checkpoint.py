"""Checkpoints: everything a killed run needs to continue as if never stopped.

One ``.npz`` holds the field (as ``Field.save``: ``load_field`` reads a
checkpoint too), Adam's moments and step counts, the iteration, the NumPy
generator state, the lowest loss seen and the field's frame. It is written to
a temporary file and renamed, so a kill never leaves a torn checkpoint.
"""
from __future__ import annotations

import json

import numpy as np

from reneus_mi.fields import Field
from reneus_mi.io import atomic_savez


def save(path: str, field: Field, opt, *, iteration: int, rng: np.random.Generator,
         best_loss: float, frame: dict) -> None:
    """``frame``: the field's frame and container, for ``reneus_mi.extract``."""
    arrays = field.arrays()
    for key in opt.keys():
        _, _, _, (t, m, v, _) = opt.state[key]
        arrays[f'adam/{key}/t'] = np.asarray(t, dtype=np.int64).ravel()
        arrays[f'adam/{key}/m'] = np.asarray(m, dtype=np.float32).ravel()
        arrays[f'adam/{key}/v'] = np.asarray(v, dtype=np.float32).ravel()
    meta = {'iteration': iteration, 'rng': rng.bit_generator.state, 'best_loss': best_loss,
            'frame': frame}
    atomic_savez(path, meta=np.array(json.dumps(meta)), **arrays)


def load_meta(path: str) -> dict:
    try:
        with np.load(path, allow_pickle=False) as f:
            return json.loads(str(f['meta']))
    except (OSError, ValueError, KeyError) as e:
        raise ValueError(f'{path}: not a reneus-mi checkpoint ({e})') from None


def restore(path: str, opt) -> dict:
    """Load the optimiser state of ``path`` into ``opt`` (which holds the same keys)."""
    meta = load_meta(path)
    with np.load(path, allow_pickle=False) as f:
        for key in list(opt.keys()):
            value, promoted, lr, (t, m, v, v_max) = opt.state[key]
            if f'adam/{key}/m' not in f:
                raise ValueError(f'{path}: optimiser state of {key!r} missing')
            opt.state[key] = (value, promoted, lr,
                              (type(t)(f[f'adam/{key}/t']), type(m)(f[f'adam/{key}/m']),
                               type(v)(f[f'adam/{key}/v']), v_max))
    return meta
