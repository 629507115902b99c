"""Files are written atomically and read back whole."""
import numpy as np
import pytest

from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import check_npz_file


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


def test_written_files_are_readable_by_the_group(tmp_path):
    """Under the usual umask 022 every writer leaves 0644, as any new file gets (tempfile's
    0600 would shut a team sharing the drive out)."""
    import os
    import trimesh
    from reneus_mi.utils.io import atomic_export, atomic_savez, atomic_write_text
    old = os.umask(0o022)
    try:
        atomic_write_text(tmp_path / 'a.json', '{}')
        atomic_savez(tmp_path / 'b.npz', x=np.zeros(3))
        atomic_export(trimesh.creation.box(), tmp_path / 'c.ply')
        os.umask(0o077)                           # a private umask is honoured too
        atomic_write_text(tmp_path / 'd.json', '{}')
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in tmp_path.iterdir()}
    assert modes == {'a.json': 0o644, 'b.npz': 0o644, 'c.ply': 0o644, 'd.json': 0o600}
