"""Sizes beyond the machine's memory or Dr.Jit's 32-bit indices are refused up front."""
import pytest

from reneus_mi.utils import limits
from reneus_mi.utils.errors import ReneusError


def test_memory_and_indices():
    limits.check_memory(10 * 2**30, 'x', available=16 * 2**30)
    with pytest.raises(ReneusError, match=r'x: needs about 14 GiB, but this machine has 16 GiB'):
        limits.check_memory(14 * 2**30, 'x', available=16 * 2**30)
    limits.check_index_range(2**32 - 1, 'n')
    with pytest.raises(ReneusError, match='n: 4294967296 elements .* 32-bit index limit'):
        limits.check_index_range(2**32, 'n')
    assert limits.physical_memory() > 2**28
