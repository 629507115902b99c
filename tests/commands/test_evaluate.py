"""python -m reneus_mi.evaluate: the numbers printed and written, bad files named."""
import json
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from reference import square
from reneus_mi.evaluate import main


def write(mesh, path):
    mesh.export(path)
    return str(path)


def test_cli_prints_and_writes_the_numbers(tmp_path):
    gt = square()
    pred = write(gt.copy().apply_translation([0, 0, 0.02]), tmp_path / 'pred.ply')
    out = tmp_path / 'out.json'
    proc = subprocess.run([sys.executable, '-m', 'reneus_mi.evaluate', pred, write(gt, tmp_path / 'gt.ply'),
                           '--postprocess', 'none', '--json', str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = dict(line.rsplit('  ', 1) for line in proc.stdout.strip().splitlines())
    lines = {k.strip(): v.strip() for k, v in lines.items()}
    assert float(lines['Chamfer-L1 x100']) == pytest.approx(2.0, rel=1e-4)
    assert float(lines['F-score @ 0.01']) == 0.0
    assert lines['post-processing'] == 'none'
    saved = json.loads(out.read_text())
    assert saved['chamfer'] == pytest.approx(2.0, rel=1e-4) and saved['postprocess'] == 'none'


def test_cli_bad_files_name_the_file(tmp_path, capsys):
    gt = write(trimesh.creation.icosphere(subdivisions=2), tmp_path / 'gt.ply')
    empty = tmp_path / 'empty.ply'
    empty.write_text('')

    def error(argv) -> str:
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = e.value.code
        assert isinstance(err, str) and '\n' not in err and err.startswith('error: ')
        return err

    for bad in (str(empty), str(tmp_path / 'missing.obj')):
        assert bad in error([bad, gt])
    assert '--container' in error([gt, gt, '--postprocess', 'crop'])
    # An open container has no inside.
    open_box = trimesh.creation.box()
    open_box.update_faces(np.arange(len(open_box.faces)) > 0)
    path = write(open_box, tmp_path / 'open.ply')
    err = error([gt, gt, '--container', path])
    assert path in err and 'closed' in err
