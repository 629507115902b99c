"""Output paths: never in a dataset, over an input or over a file not ours."""
from __future__ import annotations

import os

import pytest

from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError


def dataset_folder(path):
    path.mkdir(parents=True)
    (path / 'transforms.json').write_text('{}')
    return path


def test_output_file_places(tmp_path):
    data = dataset_folder(tmp_path / 'data')
    with pytest.raises(ReneusError, match='lies in the dataset folder'):
        guards.check_output_file(data / 'sub' / 'x.png')
    scene = tmp_path / 'scene.xml'
    scene.write_text('<scene/>')
    with pytest.raises(ReneusError, match='is or lies inside the input'):
        guards.check_output_file(scene, inputs=[scene], overwrite=True)
    with pytest.raises(ReneusError, match=r'exists; expected a new file name \(or --overwrite'):
        guards.check_output_file(scene)
    assert guards.check_output_file(scene, overwrite=True) == str(scene)
    with pytest.raises(ReneusError, match=r'expected a file ending in .png or .exr'):
        guards.check_output_file(tmp_path / 'x.jpg', extensions=('.png', '.exr'))
    with pytest.raises(ReneusError, match='is a file, expected a folder'):
        guards.check_output_file(scene / 'x.png')
    # A symbolic link into the dataset is the dataset.
    os.symlink(data, tmp_path / 'link')
    with pytest.raises(ReneusError, match='lies in the dataset folder'):
        guards.check_output_file(tmp_path / 'link' / 'x.png')


def test_output_dir_places(tmp_path):
    data = dataset_folder(tmp_path / 'data')
    with pytest.raises(ReneusError, match='lies in the dataset folder'):
        guards.check_output_dir(data)
    (tmp_path / 'parent' / 'photos').mkdir(parents=True)
    with pytest.raises(ReneusError, match='contains the input'):
        guards.check_output_dir(tmp_path / 'parent', inputs=[tmp_path / 'parent' / 'photos'])
    (tmp_path / 'used').mkdir()
    (tmp_path / 'used' / 'a.txt').write_text('a')
    with pytest.raises(ReneusError, match=r'is not empty \(holds a.txt\)'):
        guards.check_output_dir(tmp_path / 'used')
    assert guards.check_output_dir(tmp_path / 'used', allow=('a.txt',)) == str(tmp_path / 'used')
    assert guards.check_output_dir(tmp_path / 'new' / 'deeper') == str(tmp_path / 'new' / 'deeper')
    assert not (tmp_path / 'new').exists()
