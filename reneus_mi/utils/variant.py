"""Choice of the Mitsuba variant, made once per process.

``cuda_ad_rgb`` when Dr.Jit sees a CUDA device, ``llvm_ad_rgb`` otherwise. The
environment variable ``RENEUS_VARIANT`` overrides the choice.

Dr.Jit's expansion of scatter-reductions is switched off for the process
(:data:`EXPAND_THRESHOLD`): the LLVM backend would otherwise copy a
scatter-add's target per thread and compile the target's width into the
kernel. The reverse mode of every gather is such a scatter-add, and the ray
tree's arrays (live rays, inside segments) change width every step: once a
refined IOR or pose sends gradients through them, a kernel would be compiled anew
at almost every step (docs/constants.md).
"""
from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi

from reneus_mi.utils.errors import ReneusError

SUPPORTED = ('llvm_ad_rgb', 'cuda_ad_rgb')
#: Targets larger than this are never expanded (Dr.Jit's default: 1M entries); see above.
EXPAND_THRESHOLD = 0
#: Called after each set_variant (:func:`on_set`).
_ON_SET: list = []


def default_variant() -> str:
    requested = os.environ.get('RENEUS_VARIANT')
    if requested:
        if requested not in SUPPORTED:
            raise ReneusError(f"RENEUS_VARIANT={requested!r}: expected one of {', '.join(SUPPORTED)}")
        return requested
    return 'cuda_ad_rgb' if dr.has_backend(dr.JitBackend.CUDA) else 'llvm_ad_rgb'


def set_variant(name: str | None = None) -> str:
    """Activate ``name`` (or the default), then call the :func:`on_set` hooks."""
    name = name or default_variant()
    if name not in SUPPORTED:
        raise ReneusError(f"variant {name!r}: expected one of {', '.join(SUPPORTED)}")
    if mi.variant() != name:
        mi.set_variant(name)
    dr.set_expand_threshold(EXPAND_THRESHOLD)
    for hook in _ON_SET:
        hook()
    return name


def on_set(hook) -> None:
    """Call ``hook()`` after every :func:`set_variant`, and now if a variant is set: the
    package registers its Mitsuba plugins so (a plugin's class derives from the variant's own
    classes), from above this layer."""
    _ON_SET.append(hook)
    if mi.variant() in SUPPORTED:
        hook()


def ensure_variant() -> str:
    """Keep a variant the caller already chose; otherwise pick the default."""
    current = mi.variant()
    return set_variant(current if current in SUPPORTED else None)


def is_cuda() -> bool:
    return mi.variant().startswith('cuda')
