"""Files are written atomically and read back whole."""
import numpy as np
import pytest

from reneus_mi.errors import ReneusError
from reneus_mi.io import check_npz_file


def test_npz_file(tmp_path):
    path = tmp_path / 'c.npz'
    np.savez(path, meta=np.array('{}'), w=np.zeros(1000))
    check_npz_file(path)
    with pytest.raises(ReneusError, match=r"not a reneus-mi checkpoint \(no header\)"):
        check_npz_file(path, keys=('header',))
    path.write_bytes(path.read_bytes()[:300])
    with pytest.raises(ReneusError, match='not a whole checkpoint'):
        check_npz_file(path)
    with pytest.raises(ReneusError, match='checkpoint file does not exist'):
        check_npz_file(tmp_path / 'none.npz')
