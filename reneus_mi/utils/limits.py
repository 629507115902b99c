"""What this machine and Dr.Jit can hold: a request beyond it is refused up front.

A size (a batch, a mesh resolution, an image, a dataset) that would exceed the
machine's memory or Dr.Jit's 32-bit indices is refused with the size it would
need, instead of being killed by the kernel or wrapping an index.
"""
from __future__ import annotations

import os

from reneus_mi.utils.errors import ReneusError

#: Share of the physical memory one request may take.
MEMORY_FRACTION = 0.8
#: Dr.Jit indexes arrays with 32-bit unsigned integers.
MAX_INDEX = 2**32 - 1


def physical_memory() -> int:
    """Bytes of physical memory of this machine."""
    return os.sysconf('SC_PHYS_PAGES') * os.sysconf('SC_PAGE_SIZE')


def format_bytes(n: float) -> str:
    for unit in ('B', 'KiB', 'MiB', 'GiB', 'TiB', 'PiB'):
        if abs(n) < 1024 or unit == 'PiB':
            return f'{n:.3g} {unit}'
        n /= 1024
    raise AssertionError('unreachable')


def check_memory(n_bytes: float, what: str, *, available: int | None = None) -> None:
    """Refuse a request for ``n_bytes`` above :data:`MEMORY_FRACTION` of the memory."""
    limit = MEMORY_FRACTION * (physical_memory() if available is None else available)
    if n_bytes > limit:
        raise ReneusError(f'{what}: needs about {format_bytes(n_bytes)}, but this machine has '
                          f'{format_bytes(limit / MEMORY_FRACTION)} of memory; expected a smaller value')


def check_index_range(count: int, what: str) -> None:
    """Refuse ``count`` elements in one Dr.Jit array (32-bit indices)."""
    if count > MAX_INDEX:
        raise ReneusError(f'{what}: {count} elements in one array exceed the 32-bit index '
                          f'limit {MAX_INDEX}; expected a smaller value')
