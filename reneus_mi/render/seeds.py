"""The random numbers of a training step: seeds that depend only on (seed, step, stream).

A run resumed at step k draws what the unbroken run drew, with no generator
state to save. Kernels read the seeds from memory (:func:`opaque_seed`), so a
new step's seed is new data, not a new kernel.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: Streams of the step's random numbers: the pixels of the batch, the samples' jitter.
PIXELS, JITTER = 0, 1


def step_seed(seed: int, step: int, stream: int) -> int:
    """A 64-bit PCG32 initial state for one use of one step of a run."""
    return ((seed & 0xFFFFFF) << 40) ^ ((step & 0xFFFFFFFF) << 4) ^ stream


def opaque_seed(seed: int) -> mi.UInt64:
    """A seed that kernels read from memory: a literal would make every step compile anew."""
    return dr.opaque(mi.UInt64, seed)
