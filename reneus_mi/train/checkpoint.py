"""Checkpoints: everything a killed run needs to continue as if never stopped.

One ``.npz`` holds the field (as ``Field.save``: ``load_field`` reads a
checkpoint too), Adam's moments and step counts under the integrator's parameter
names, the refined IOR, pose and light, the loss scaler's scale (CUDA), and a JSON ``meta``: the iteration, the
lowest loss seen, the seconds trained (a time budget's share spent), the field's frame and the container mesh. Random numbers
depend only on (seed, step), so no generator state is needed. It is written
to a temporary file and renamed, so a kill never leaves a torn checkpoint.
"""
from __future__ import annotations

import json
import zipfile

import numpy as np

from reneus_mi.fields import Field
from reneus_mi.geometry.frame import FieldFrame
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_savez


def save(path: str, field: Field, opt, names: dict[str, str], *, iteration: int, best_loss: float,
         frame: FieldFrame, container: str | None, scaler=None, surroundings: dict | None = None,
         batch: int | None = None, elapsed: float = 0.0, pixels: dict | None = None) -> None:
    """``names`` maps the optimiser's keys to the integrator's parameter names; ``surroundings``
    holds the IOR, pose and light arrays (:meth:`Surroundings.params`), ``pixels`` the pixel
    sampler's state (:meth:`PixelSampler.state`)."""
    arrays = field.arrays()
    for name, value in (pixels or {}).items():
        arrays[f'pixels/{name}'] = value
    for name, value in (surroundings or {}).items():
        arrays[f'surroundings/{name}'] = np.asarray(value, dtype=np.float32).ravel()
    for key, name in names.items():
        _, _, _, (t, m, v, _) = opt.state[key]
        arrays[f'adam/{name}/t'] = np.asarray(t, dtype=np.int64).ravel()
        arrays[f'adam/{name}/m'] = np.asarray(m, dtype=np.float32).ravel()
        arrays[f'adam/{name}/v'] = np.asarray(v, dtype=np.float32).ravel()
    if scaler is not None:
        arrays['scaler/scale'] = np.asarray(scaler.scale_factor, dtype=np.float32).ravel()
        arrays['scaler/it'] = np.array([scaler.it], dtype=np.int64)
    meta = {'iteration': iteration, 'best_loss': best_loss, 'frame': frame.to_dict(),
            'container': container, 'batch': batch, 'elapsed': elapsed}
    atomic_savez(path, meta=np.array(json.dumps(meta)), **arrays)


def load_meta(path: str) -> dict:
    try:
        with np.load(path, allow_pickle=False) as f:
            return json.loads(str(f['meta']))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as e:
        raise ReneusError(f'{path}: not a reneus-mi checkpoint ({e})') from None


def load_group(path: str, group: str) -> dict[str, np.ndarray]:
    """The arrays saved in a checkpoint under ``group/`` (``surroundings``: the IOR, pose and
    light; ``pixels``: the pixel sampler's), by name."""
    with np.load(path, allow_pickle=False) as f:
        return {k[len(group) + 1:]: f[k] for k in f.files if k.startswith(group + '/')}


def load_surroundings(path: str) -> dict[str, np.ndarray]:
    """The IOR, pose and light arrays saved in a checkpoint, by name."""
    return load_group(path, 'surroundings')


def load_frame(path: str) -> tuple[FieldFrame, str | None]:
    """The field frame and the container mesh recorded in a checkpoint."""
    meta = load_meta(path)
    if 'frame' not in meta:
        raise ReneusError(f'{path}: the checkpoint records no field frame')
    return FieldFrame.from_dict(meta['frame'], f'{path}: frame'), meta.get('container')


def restore(path: str, opt, names: dict[str, str], scaler=None) -> dict:
    """Load the optimiser (and scaler) state of ``path`` into ``opt``; return the meta."""
    meta = load_meta(path)
    with np.load(path, allow_pickle=False) as f:
        for key, name in names.items():
            value, promoted, lr, (t, m, v, v_max) = opt.state[key]
            if f'adam/{name}/m' not in f:
                raise ReneusError(f'{path}: optimiser state of {name!r} missing')
            opt.state[key] = (value, promoted, lr,
                              (type(t)(f[f'adam/{name}/t']), type(m)(f[f'adam/{name}/m']),
                               type(v)(f[f'adam/{name}/v']), v_max))
        if scaler is not None and 'scaler/scale' in f:
            scaler.scale_factor = type(scaler.scale_factor)(f['scaler/scale'])
            scaler.it = int(f['scaler/it'][0])
    return meta
