"""The bad-input catalogue: every command, refused with one line that names the thing.

Each case runs a command's ``main()`` on a bad input and asserts that it ends
with exactly one line ``error: ...`` (exit status 1, or argparse's 2 for a
malformed option) naming the file, field or value and what was expected, no
traceback, and that every file that existed in the watched folders (the
dataset, the run, the case's own folder) is byte-for-byte unchanged, with no
new file written. A few cases run the command as a real process to check the
exit status and stderr of the interpreter itself.

Everything reuses the 12-view 16x16 statuette dataset (``tiny.py``) and one
2-step run, made once per module; a case copies what it spoils.
Cases that would train are refused during validation, before any step.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import trimesh

from reneus_mi import evaluate, extract, optimize, scene, synth

from reneus_mi import colmap as colmap_command
from reneus_mi.capture import __main__ as capture, photos as capture_photos, pipeline as capture_pipeline
from reneus_mi.data import load_dataset
from reneus_mi.render import __main__ as render
from reneus_mi.train.run_folder import RunFolder
from reneus_mi.utils import interrupt
from reneus_mi.utils.errors import ReneusError
from tiny import assert_same_state, new_trainer, train_state

TRAIN = ['--iterations', '2', '--checkpoint-every', '1', '--batch-rays', '64', '--warm-up', '1',
         '--validate-every', '0', '--mesh-resolution', '16', '--quiet']


# ------------------------------------------------------------------- helpers
def snapshot(*folders) -> dict[str, str]:
    """SHA-256 of every file below ``folders`` (missing folders hold nothing)."""
    sums = {}
    for folder in folders:
        for dirpath, _, names in os.walk(folder):
            for name in names:
                path = os.path.join(dirpath, name)
                with open(path, 'rb') as f:
                    sums[path] = hashlib.sha256(f.read()).hexdigest()
    return sums


def refused(main, argv, *parts, watch=(), capsys=None, code=1) -> str:
    """Run ``main(argv)``: it must exit with one error line holding ``parts`` and touch nothing."""
    before = snapshot(*watch)
    with pytest.raises(SystemExit) as exit_info:
        main([str(a) for a in argv])
    if isinstance(exit_info.value.code, str):
        message, status = exit_info.value.code, 1
    else:  # argparse prints usage and the error itself
        status = exit_info.value.code
        lines = capsys.readouterr().err.strip().splitlines()
        errors = [line for line in lines if 'error:' in line]
        assert len(errors) == 1, lines
        message = errors[0]
    assert status == code
    assert 'error: ' in message and '\n' not in message and 'Traceback' not in message, message
    for part in parts:
        assert str(part) in message, f'{part!r} not in {message!r}'
    after = snapshot(*watch)
    assert after == before, (f'changed: {sorted(k for k in before if before[k] != after.get(k))}, '
                             f'new: {sorted(set(after) - set(before))}')
    return message


def process(module: str, *args) -> subprocess.CompletedProcess:
    env = {**os.environ, 'RENEUS_VARIANT': 'llvm_ad_rgb'}
    return subprocess.run([sys.executable, '-m', f'reneus_mi.{module}', *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=300)


def one_error_line(proc, *parts) -> None:
    assert proc.returncode == 1, proc.stderr
    assert 'Traceback' not in proc.stderr
    lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith('error: '), proc.stderr
    for part in parts:
        assert str(part) in lines[0], f'{part!r} not in {lines[0]!r}'


@pytest.fixture
def small_machine(monkeypatch):
    """8 GiB of memory, whatever this machine has: size limits do not depend on the host."""
    from reneus_mi.utils import limits
    monkeypatch.setattr(limits, 'physical_memory', lambda: 8 * 2**30)


# ------------------------------------------------------------------ fixtures
@pytest.fixture(scope='module')
def world(scene_xml, tmp_path_factory):
    """The tiny dataset (Blender and NeuS), its scene, a 2-step run and its checkpoint."""
    xml = scene_xml
    root = os.path.dirname(xml)
    run = tmp_path_factory.mktemp('bad_inputs') / 'run'
    assert optimize.main([xml, '-o', str(run), *TRAIN]) == 0
    return {'root': str(root), 'scene': xml, 'data': os.path.join(root, 'box'),
            'neus': os.path.join(root, 'box_neus'), 'run': str(run),
            'checkpoint': str(run / 'checkpoint.npz'), 'gt': os.path.join(root, 'gt.ply')}


@pytest.fixture
def data(world, tmp_path):
    """A spoilable copy of the Blender dataset."""
    folder = tmp_path / 'data'
    shutil.copytree(world['data'], folder)
    return folder


@pytest.fixture
def run_copy(world, tmp_path):
    folder = tmp_path / 'run'
    shutil.copytree(world['run'], folder)
    return folder


def edit_frames(folder, edit):
    path = folder / 'transforms.json'
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta))


def edit_poses(folder, edit):
    def each(meta):
        for i, frame in enumerate(meta['frames']):
            frame['transform_matrix'] = edit(i, np.array(frame['transform_matrix'])).tolist()
    edit_frames(folder, each)


def transform_mesh(path, matrix=None, invert=False):
    mesh = trimesh.load(path, force='mesh', process=False)
    if matrix is not None:
        mesh.apply_transform(matrix)
    if invert:
        mesh.invert()
    mesh.export(path)


def train(world, data, tmp_path, *extra):
    """optimize on ``data`` into a fresh folder (watched: the data and tmp_path)."""
    return [world['scene'], '--data', data, '-o', tmp_path / 'out', *TRAIN, *extra]


# ===================================================================== optimize
def test_optimize_output_is_the_dataset_folder(world, tmp_path):
    """Harmful 3: validation renders once overwrote the photographs."""
    refused(optimize.main, [world['scene'], '-o', world['data'], *TRAIN],
            world['data'], 'dataset', 'expected', watch=[world['data']])


def test_optimize_output_inside_the_dataset_folder(world):
    refused(optimize.main, [world['scene'], '-o', os.path.join(world['data'], 'run'), *TRAIN],
            'lies in the dataset folder', watch=[world['data']])


def test_optimize_output_holding_other_files(world, tmp_path):
    (tmp_path / 'mine.txt').write_text('keep')
    refused(optimize.main, [world['scene'], '-o', tmp_path, *TRAIN],
            str(tmp_path), 'is not empty (holds mine.txt)', watch=[tmp_path])


def test_optimize_output_under_a_file(world, tmp_path):
    (tmp_path / 'file').write_text('x')
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'file' / 'out', *TRAIN],
            'is a file, expected a folder', watch=[tmp_path])


def test_optimize_batch_beyond_memory(world, tmp_path):
    """Harmful 5: 10^9 rays grew to 24 GB and were killed without a word."""
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', *TRAIN, '--batch-rays', 10**9],
            '--batch-rays 1000000000', 'expected a smaller value', watch=[tmp_path, world['data']])


def test_optimize_batch_beyond_memory_but_not_indices(world, tmp_path, small_machine):
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', *TRAIN, '--batch-rays', 10**7],
            '--batch-rays 10000000', 'needs about', 'this machine has 8 GiB', watch=[tmp_path])


def test_optimize_without_a_scene_needs_demo(tmp_path):
    refused(optimize.main, ['-o', tmp_path / 'out', *TRAIN], 'no scene given', '--demo',
            watch=[tmp_path])


def test_optimize_missing_scene(tmp_path):
    refused(optimize.main, [tmp_path / 'absent.xml', '-o', tmp_path / 'out', *TRAIN],
            str(tmp_path / 'absent.xml'), 'does not exist', watch=[tmp_path])


@pytest.mark.parametrize('args, expected', [
    (['--refine-light', 'room'], ("light='room'", "'ambient'", "'sh'")),
    (['--refine-ior-range', '2', '1.2'], ('ior_range=[2.0, 1.2]', 'expected 1 < low < high')),
    (['--sample-budget', '-5'], ('sample_budget=-5',)),
    (['--refine-pose', '--set', 'model.render.mode=neus'], ('train.refine', 'needs a container', 'mode is neus')),
    (['--refine-inner-ior'], ('--refine-inner-ior', 'the container has no inner interface')),
], ids=['light_model', 'ior_range', 'sample_budget', 'neus', 'inner_ior_of_a_block'])
def test_optimize_refinement_switches(world, tmp_path, args, expected):
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', *TRAIN, *args], *expected,
            watch=[tmp_path])


@pytest.mark.parametrize('setting, expected', [
    ('model.sampler.n_coarse=many', ("model.sampler.n_coarse='many': expected an integer",)),
    ('train.iteration=3', ('train.iteration: not a setting', 'iterations')),
    ('model.render.gamma=0', ('gamma=0.0; expected a number > 0',)),
    ('n_coarse', ("'n_coarse': expected PATH=VALUE",)),
], ids=['type', 'unknown', 'range', 'no_value'])
def test_optimize_set(world, tmp_path, setting, expected):
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', *TRAIN, '--set', setting], *expected,
            watch=[tmp_path])


def test_optimize_missing_data(world, tmp_path):
    refused(optimize.main, train(world, tmp_path / 'nowhere', tmp_path),
            str(tmp_path / 'nowhere'), 'dataset folder is missing', watch=[tmp_path])


def test_optimize_inverted_container(world, data, tmp_path):
    """Harmful 2: inward normals made the specimen vanish, exit 0."""
    transform_mesh(data / 'container.ply', invert=True)
    refused(optimize.main, train(world, data, tmp_path),
            str(data / 'container.ply'), 'normals point inward', 'expected outward normals',
            watch=[tmp_path])


def test_scene_pointing_to_an_inverted_container(world, tmp_path):
    """The check also covers the mesh the scene XML itself loads."""
    root = tmp_path / 'copy'
    shutil.copytree(world['root'], root, ignore=shutil.ignore_patterns('*_neus', 'nobox*'))
    transform_mesh(root / 'box' / 'container.ply', invert=True)
    xml = root / 'scene_tiny.xml'
    xml.write_text(xml.read_text().replace(world['data'], str(root / 'box')))
    refused(render.main, [xml, '-o', tmp_path / 'r.png'],
            "shape 'container'", 'normals point inward', watch=[tmp_path])


def test_optimize_ior_out_of_range(world, data, tmp_path):
    edit_frames(data, lambda m: m.update(IOR=1e6))
    refused(optimize.main, train(world, data, tmp_path),
            'transforms.json', "'IOR' is 1000000.0", 'expected a number in (1, 3]', watch=[tmp_path])


def test_optimize_opengl_poses_read_as_opencv(world, data, tmp_path):
    edit_poses(data, lambda i, m: m @ np.diag([1.0, -1.0, -1.0, 1.0]))
    refused(optimize.main, train(world, data, tmp_path),
            'r_000.png', 'view 0', 'behind the camera', 'OpenGL', watch=[tmp_path])


def test_optimize_world_to_camera_given(world, data, tmp_path):
    edit_poses(data, lambda i, m: np.linalg.inv(m))
    refused(optimize.main, train(world, data, tmp_path), 'view 0', 'container centre',
            watch=[tmp_path])


def test_optimize_one_view_flipped(world, data, tmp_path):
    edit_poses(data, lambda i, m: m @ np.diag([-1.0, 1.0, -1.0, 1.0]) if i == 7 else m)
    refused(optimize.main, train(world, data, tmp_path), 'r_007.png', 'view 7', 'behind the camera',
            watch=[tmp_path])


def test_optimize_camera_inside_the_container(world, data, tmp_path):
    def inside(i, m):
        if i == 4:
            m[:3, 3] = [0.01, 0.02, 0.03]
        return m
    edit_poses(data, inside)
    refused(optimize.main, train(world, data, tmp_path), 'r_004.png', 'view 4',
            'is inside the container', watch=[tmp_path])


def test_optimize_container_1000x_too_small(world, data, tmp_path):
    transform_mesh(data / 'container.ply', np.diag([1e-3, 1e-3, 1e-3, 1.0]))
    refused(optimize.main, train(world, data, tmp_path), 'view 0', 'the container spans about',
            "cameras' units", watch=[tmp_path])


def test_optimize_container_100_units_away(world, data, tmp_path):
    move = np.eye(4)
    move[:3, 3] = [100.0, 0.0, 0.0]
    transform_mesh(data / 'container.ply', move)
    refused(optimize.main, train(world, data, tmp_path), 'view ', 'container centre',
            watch=[tmp_path])


def test_optimize_mask_disagrees_with_the_container(world, data, tmp_path):
    from reneus_mi.data.images import read_image, write_image
    rgb, _ = read_image(str(data / 'images' / 'r_005.png'))
    alpha = np.zeros(rgb.shape[:2])
    alpha[:2, :2] = 1.0
    write_image(str(data / 'images' / 'r_005.png'), np.concatenate([rgb, alpha[..., None]], -1))
    refused(optimize.main, train(world, data, tmp_path), 'r_005.png', 'view 5', 'IoU',
            watch=[tmp_path])


def test_optimize_nan_in_a_pose(world, data, tmp_path):
    edit_poses(data, lambda i, m: np.where(np.eye(4, k=1) * (i == 3), np.nan, m))
    refused(optimize.main, train(world, data, tmp_path), 'frames[3]', 'entry [0][1] is nan',
            'expected finite numbers', watch=[tmp_path])


def test_optimize_mirrored_pose(world, data, tmp_path):
    edit_poses(data, lambda i, m: m @ np.diag([-4.0, 1.0, 1.0, 1.0]) if i == 2 else m)
    refused(optimize.main, train(world, data, tmp_path), 'frames[2]', 'determinant -4',
            'expected a rotation', watch=[tmp_path])


def test_optimize_neus_views_named_twice(world, tmp_path):
    """Harmful 1: views are paired with cameras by the number in the name, never guessed."""
    data = tmp_path / 'neus'
    shutil.copytree(world['neus'], data)
    os.rename(data / 'image' / '011.png', data / 'image' / '1.png')
    refused(optimize.main, train(world, data, tmp_path), '001.png and 1.png both name view 1',
            watch=[tmp_path])


def test_optimize_neus_name_without_number(world, tmp_path):
    data = tmp_path / 'neus'
    shutil.copytree(world['neus'], data)
    os.rename(data / 'image' / '011.png', data / 'image' / 'last.png')
    refused(optimize.main, train(world, data, tmp_path), 'last.png',
            'expected exactly one view number', watch=[tmp_path])


def test_optimize_neus_nan_camera(world, tmp_path):
    data = tmp_path / 'neus'
    shutil.copytree(world['neus'], data)
    cams = dict(np.load(data / 'cameras_sphere.npz'))
    cams['world_mat_6'][1, 2] = np.nan
    np.savez(data / 'cameras_sphere.npz', **cams)
    refused(optimize.main, train(world, data, tmp_path), 'world_mat_6', 'entry [1][2] is nan',
            watch=[tmp_path])


def test_optimize_bad_option_value(world, tmp_path, capsys):
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', '--iterations', 'many'],
            "--iterations", "'many'", watch=[tmp_path], capsys=capsys, code=2)


def test_optimize_zero_iterations(world, tmp_path):
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', *TRAIN, '--iterations', '0'],
            'iterations=0', 'expected an integer > 0', watch=[tmp_path])


# ----------------------------------------------------------------- resume
def test_resume_unknown_config_key(world, run_copy):
    config = json.loads((run_copy / 'config.json').read_text())
    config['train']['learning_rat'] = 1e-3
    (run_copy / 'config.json').write_text(json.dumps(config))
    refused(optimize.main, ['-o', run_copy, '--resume', '--quiet'], 'config.json',
            "train.learning_rat: unknown setting", watch=[run_copy])


def test_resume_truncated_checkpoint(world, run_copy):
    path = run_copy / 'checkpoint.npz'
    path.write_bytes(path.read_bytes()[:200])
    refused(optimize.main, ['-o', run_copy, '--resume', '--quiet'], str(path),
            'not a whole checkpoint', watch=[run_copy])


def test_resume_with_another_scene(world, run_copy, tmp_path):
    other = tmp_path / 'other.xml'
    shutil.copy(world['scene'], other)
    refused(optimize.main, [other, '-o', run_copy, '--resume', '--quiet'],
            '--resume continues the run recorded in its config.json', str(other), watch=[run_copy])


def test_resume_with_other_data(world, run_copy):
    """A moved dataset is an explicit --data, checked against the run's."""
    refused(optimize.main, ['-o', run_copy, '--resume', '--quiet', '--data', world['neus']],
            'differs from the run', 'names', watch=[run_copy])


def test_resume_while_another_process_holds_the_run(world, run_copy):
    """The lock is the kernel's: another process must hold it (a pid in .lock is not a lock)."""
    hold = ('import sys, time\nfrom reneus_mi.train.run_folder import RunFolder\n'
            'with RunFolder(sys.argv[1]).lock():\n    print("holding", flush=True)\n    time.sleep(600)')
    holder = subprocess.Popen([sys.executable, '-c', hold, str(run_copy)], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, 'RENEUS_VARIANT': 'llvm_ad_rgb'})
    try:
        assert holder.stdout.readline().strip() == 'holding'
        refused(optimize.main, ['-o', run_copy, '--resume', '--quiet', '--iterations', '3'],
                f'in use by process {holder.pid}', watch=[run_copy])
    finally:
        holder.kill()
        holder.wait()


def test_resume_nothing_to_resume(tmp_path):
    refused(optimize.main, ['-o', tmp_path / 'empty', '--resume'], 'nothing to resume',
            watch=[tmp_path])


# ==================================================================== render
def test_render_into_the_dataset_folder(world):
    refused(render.main, [world['scene'], '-o', os.path.join(world['data'], 'r.png')],
            'lies in the dataset folder', watch=[world['data']])


def test_render_over_an_existing_file(world, tmp_path):
    (tmp_path / 'photo.png').write_bytes(b'precious')
    refused(render.main, [world['scene'], '-o', tmp_path / 'photo.png'], 'photo.png',
            'exists', '--overwrite', watch=[tmp_path])


def test_render_over_its_scene(world):
    refused(render.main, [world['scene'], '-o', world['scene'], '--overwrite'],
            'is or lies inside the input', watch=[world['root']])


def test_render_unknown_image_type(world, tmp_path):
    refused(render.main, [world['scene'], '-o', tmp_path / 'r.jpg'], 'r.jpg',
            'expected a file ending in .exr or .png', watch=[tmp_path])


def test_render_negative_spp(world, tmp_path):
    refused(render.main, [world['scene'], '-o', tmp_path / 'r.png', '--spp', '-1'],
            '--spp -1', 'expected >= 0', watch=[tmp_path])


def test_render_beyond_32_bit_indices(world, tmp_path):
    refused(render.main, [world['scene'], '-o', tmp_path / 'r.png', '--spp', 10**8],
            '16x16 pixels at 100000000 spp', '32-bit index limit', watch=[tmp_path])


def test_render_truncated_field(world, tmp_path):
    bad = tmp_path / 'field.npz'
    bad.write_bytes(open(world['checkpoint'], 'rb').read()[:300])
    refused(render.main, [world['scene'], '-o', tmp_path / 'r.png', '--field', bad],
            str(bad), 'not a whole field', watch=[tmp_path])


def test_render_output_under_a_file(world, tmp_path):
    (tmp_path / 'file').write_text('x')
    refused(render.main, [world['scene'], '-o', tmp_path / 'file' / 'r.png'],
            'is a file, expected a folder', watch=[tmp_path])


@pytest.mark.skipif(os.geteuid() == 0, reason='root writes into read-only folders')
def test_render_read_only_folder(world, tmp_path):
    folder = tmp_path / 'ro'
    folder.mkdir()
    folder.chmod(0o555)
    try:
        refused(render.main, [world['scene'], '-o', folder / 'r.png'], 'not writable',
                watch=[tmp_path])
    finally:
        folder.chmod(0o755)


def test_render_integrator_parameter_as_text(world, tmp_path):
    xml = tmp_path / 'scene.xml'
    text = open(world['scene']).read()
    assert '<string name="preset" value="tiny" />' in text
    xml.write_text(text.replace('<string name="preset" value="tiny" />',
                                '<string name="preset" value="tiny" /><string name="n_coarse" value="eight" />')
                .replace('value="box/', f'value="{world["data"]}/'))
    refused(render.main, [xml, '-o', tmp_path / 'r.png'], 'n_coarse', "'eight'", watch=[tmp_path])


# =================================================================== extract
def test_extract_resolution_beyond_indices(world, tmp_path):
    """Harmful 5: --resolution 100000 asked for 3.55 PiB."""
    refused(extract.main, [world['checkpoint'], '-o', tmp_path / 'm.ply', '--resolution', 100000],
            '--resolution 100000', '32-bit index limit', watch=[tmp_path, world['run']])


def test_extract_resolution_beyond_memory(world, tmp_path, small_machine):
    refused(extract.main, [world['checkpoint'], '-o', tmp_path / 'm.ply', '--resolution', 1600],
            '--resolution 1600', 'needs about', 'expected a smaller value', watch=[tmp_path])


def test_extract_resolution_too_small(world, tmp_path):
    refused(extract.main, [world['checkpoint'], '-o', tmp_path / 'm.ply', '--resolution', 4],
            '--resolution 4', 'expected >= 8', watch=[tmp_path])


def test_extract_truncated_checkpoint(world, tmp_path):
    bad = tmp_path / 'checkpoint.npz'
    bad.write_bytes(open(world['checkpoint'], 'rb').read()[:1000])
    refused(extract.main, [bad, '-o', tmp_path / 'm.ply'], str(bad), 'not a whole checkpoint',
            watch=[tmp_path])


def test_extract_missing_checkpoint(tmp_path):
    refused(extract.main, [tmp_path / 'none.npz', '-o', tmp_path / 'm.ply'], 'none.npz',
            'does not exist', watch=[tmp_path])


def test_extract_unknown_mesh_type(world, tmp_path):
    refused(extract.main, [world['checkpoint'], '-o', tmp_path / 'm.xyz'], 'm.xyz',
            'expected a file ending in .ply', watch=[tmp_path])


def test_extract_over_its_checkpoint(world):
    refused(extract.main, [world['checkpoint'], '-o', world['checkpoint'], '--overwrite'],
            'is or lies inside the input', watch=[world['run']])


def test_extract_over_an_existing_file(world, tmp_path):
    (tmp_path / 'mesh.ply').write_text('mine')
    refused(extract.main, [world['checkpoint'], '-o', tmp_path / 'mesh.ply'], 'exists',
            watch=[tmp_path])


# ================================================================== evaluate
def test_evaluate_unknown_mesh_type(world, tmp_path):
    (tmp_path / 'pred.xyz').write_text('0 0 0\n')
    refused(evaluate.main, [tmp_path / 'pred.xyz', world['gt']], 'pred.xyz', 'unknown type .xyz',
            watch=[tmp_path])


def test_evaluate_missing_prediction(world, tmp_path):
    refused(evaluate.main, [tmp_path / 'pred.ply', world['gt']], 'pred.ply', 'does not exist',
            watch=[tmp_path])


def test_evaluate_json_into_the_dataset(world):
    refused(evaluate.main, [world['gt'], world['gt'], '--json', os.path.join(world['data'], 'r.json')],
            'lies in the dataset folder', watch=[world['data']])


def test_evaluate_json_over_an_existing_file(world, tmp_path):
    (tmp_path / 'r.json').write_text('{}')
    refused(evaluate.main, [world['gt'], world['gt'], '--json', tmp_path / 'r.json'], 'exists',
            watch=[tmp_path])


def test_evaluate_inverted_container(world, tmp_path):
    box = tmp_path / 'box.ply'
    shutil.copy(os.path.join(world['data'], 'container.ply'), box)
    transform_mesh(box, invert=True)
    refused(evaluate.main, [world['gt'], world['gt'], '--container', box], str(box),
            'normals point inward', watch=[tmp_path])


def test_evaluate_crop_without_container(world, tmp_path):
    refused(evaluate.main, [world['gt'], world['gt'], '--postprocess', 'crop'], '--container',
            watch=[tmp_path])


# ===================================================================== scene
def test_scene_into_the_dataset_folder(world):
    refused(scene.main, [world['data'], '-o', os.path.join(world['data'], 'scene.xml')],
            'lies in the dataset folder', watch=[world['data']])


def test_scene_over_an_existing_file(world, tmp_path):
    (tmp_path / 'scene.xml').write_text('<scene/>')
    refused(scene.main, [world['data'], '-o', tmp_path / 'scene.xml'], 'exists', watch=[tmp_path])


def test_scene_unknown_extension(world, tmp_path):
    refused(scene.main, [world['data'], '-o', tmp_path / 'scene.txt'],
            'expected a file ending in .xml', watch=[tmp_path])


def test_scene_missing_data(tmp_path):
    refused(scene.main, [tmp_path / 'absent', '-o', tmp_path / 'scene.xml'],
            'dataset folder is missing', watch=[tmp_path])


def test_scene_output_under_a_file(world, tmp_path):
    (tmp_path / 'file').write_text('x')
    refused(scene.main, [world['data'], '-o', tmp_path / 'file' / 'scene.xml'],
            'is a file, expected a folder', watch=[tmp_path])


def _with_board(data, **board):
    """The dataset with a printed board under its container, as a capture writes it (an entry
    of ``board`` given as None is left out)."""
    from reneus_mi.data.images import write_image
    write_image(str(data / 'board.png'), np.kron(np.eye(4), np.ones((4, 4))))
    meta = json.loads((data / 'transforms.json').read_text())
    meta['capture'] = {'units': 'mm', 'board': {'pattern': 'board.png', 'px_per_mm': 4.0, 'white': 0.8,
                                                'black': 0.05, 'to_world': np.eye(4).tolist()}}
    for key, value in board.items():
        if value is None:
            del meta['capture']['board'][key]
        else:
            meta['capture']['board'][key] = value
    (data / 'transforms.json').write_text(json.dumps(meta))
    return data


@pytest.mark.parametrize('board, parts', [
    ({'white': None}, ("capture.board: KeyError('white')", "expected 'pattern'")),
    ({'white': 0.01}, ('capture.board', 'the paper brighter than the ink')),
    ({'pattern': 'print.png'}, ('print.png', 'image file is missing')),
])
def test_scene_bad_board(data, tmp_path, board, parts):
    _with_board(data, **board)
    refused(scene.main, [data, '-o', tmp_path / 'scene.xml'], *parts, watch=[tmp_path])


def test_scene_over_an_existing_board_radiance(data, tmp_path):
    _with_board(data)
    (tmp_path / 'scene_board.exr').write_text('x')
    refused(scene.main, [data, '-o', tmp_path / 'scene.xml'], "board's radiance", 'scene_board.exr', 'exists',
            watch=[tmp_path])


# ===================================================================== synth
def test_synth_into_an_existing_dataset(world, data):
    """Harmful 4: synth -o EXISTING overwrote 7 files before refusing."""
    refused(synth.main, ['sphere', '-o', data, '--views', 2, '--res', 8, '--spp', 1],
            str(data), 'lies in the dataset folder', watch=[data])


def test_synth_into_a_folder_with_files(tmp_path):
    (tmp_path / 'notes.txt').write_text('mine')
    refused(synth.main, ['sphere', '-o', tmp_path, '--views', 2, '--res', 8, '--spp', 1],
            'is not empty (holds notes.txt)', watch=[tmp_path])


def test_synth_beyond_memory(tmp_path, small_machine):
    refused(synth.main, ['sphere', '-o', tmp_path / 'out', '--views', 60, '--res', 100000],
            '60 views at 100000x100000', 'needs about', watch=[tmp_path])


@pytest.mark.parametrize('args, parts', [
    (['sphere', '--views', 0], ['views=0', 'expected positive numbers']),
    (['nope', '--views', 2, '--res', 8], ["'nope'", 'neither an object name']),
    (['sphere', '--spp', 0], ['spp=0', 'expected a positive integer']),
    (['sphere', '--margin', -1], ['margin=-1', 'expected a number >= 0']),
], ids=['no_views', 'unknown_object', 'zero_spp', 'negative_margin'])
def test_synth_refuses(tmp_path, args, parts):
    refused(synth.main, [args[0], '-o', tmp_path / 'out', *args[1:]], *parts, watch=[tmp_path])


# =================================================================== capture
#: The simulated capture's settings as flags (the copies below have no capture.json).
CAPTURE = ['--squares', '12x9', '--square-mm', 20, '--marker-mm', 15, '--size-mm', '50x35x25', '--ior', 1.5]


@pytest.fixture(scope='module')
def shots(simulated_capture):
    """The simulated capture's photographs (rendered once per session)."""
    return simulated_capture['photos']


def photo_copies(shots, folder, n, *, blank=0, settings=False):
    """The first ``n`` photographs (and ``blank`` grey ones) in a new folder."""
    folder.mkdir()
    names = sorted(f for f in os.listdir(shots) if f.endswith('.jpg'))[:n]
    for name in names:
        shutil.copy(os.path.join(shots, name), folder / name)
    for i in range(blank):
        import cv2
        # Each its own grey: byte-identical photographs are one photograph.
        cv2.imwrite(str(folder / f'blank_{i}.jpg'), np.full((480, 640, 3), 128 + i, np.uint8))
    if settings:
        shutil.copy(os.path.join(shots, 'capture.json'), folder / 'capture.json')
    return folder


@pytest.mark.parametrize('flags, parts', [
    (['--dictionary', 'DICT_5X5_100'], ['no ArUco marker of DICT_5X5_100', 'shows markers of DICT_4X4', '--dictionary']),
    (['--squares', '10x8'], ['marker id', 'a 10x8 board has ids 0-39', '--squares']),
    (['--squares', '14x10'], ['do not lie where a 14x10 squares', '--squares']),
    (['--marker-mm', 25], ['marker_mm=25 and square_mm=20 contradict each other']),
    (['--size-mm', '300x35x25'], ['size_mm=300x35x25 and the board (240x180 mm', 'contradict each other']),
    (['--container', 'cylinder'], ['size_mm=50x35x25 for a cylinder', 'diameter x diameter x height']),
    (['--max-size', 320, '--downscale', 2], ['max_size=320 and downscale=2 both given']),
    (['--dictionary', 'DICT_9X9_1'], ["dictionary='DICT_9X9_1'", 'expected an OpenCV ArUco dictionary']),
    (['--squares', '12x9x3'], ["squares='12x9x3'", 'expected 2 numbers like 12x9']),
    (['--wall-mm', 13], ['wall_mm=13 and size_mm=50x35x25 contradict each other', 'thinner than half']),
    (['--wall-mm', -1], ['--wall-mm: wall_mm=-1', 'expected a positive size in millimetres']),
    (['--square-mm', -20], ['--square-mm: square_mm=-20', 'expected a positive size in millimetres']),
    (['--max-size', 0], ['--max-size: max_size=0', 'expected at least 64 pixels']),
    (['--liquid-ior', 1.36], ['liquid_ior=1.36 without wall_mm', '--wall-mm']),
    (['--wall-mm', 2, '--liquid-ior', 0.9], ['liquid_ior=0.9', 'expected a number in (1, 3]']),
], ids=['wrong_dictionary', 'fewer_squares', 'other_layout', 'marker_larger_than_square',
        'container_larger_than_board', 'cylinder_of_two_diameters', 'two_scalings', 'unknown_dictionary',
        'three_numbers', 'wall_thicker_than_the_case', 'negative_wall', 'negative_square', 'no_pixels',
        'liquid_without_walls',
        'liquid_below_air'])
def test_capture_refuses(shots, tmp_path, flags, parts):
    photos = photo_copies(shots, tmp_path / 'photos', 3)
    given = dict(zip(CAPTURE[::2], CAPTURE[1::2]))
    given.update(dict(zip(flags[::2], flags[1::2])))
    argv = [photos, '-o', tmp_path / 'out', *[x for kv in given.items() for x in kv]]
    refused(capture.main, argv, *parts, watch=[tmp_path])


def test_capture_no_board_in_any_photograph(shots, tmp_path):
    photos = photo_copies(shots, tmp_path / 'photos', 0, blank=3)
    refused(capture.main, [photos, '-o', tmp_path / 'out', *CAPTURE],
            'no ArUco marker of DICT_4X4_100 in any of the 3 photographs', 'check --dictionary',
            watch=[tmp_path])


def test_capture_flag_contradicts_the_capture_file(shots, tmp_path):
    photos = photo_copies(shots, tmp_path / 'photos', 3, settings=True)
    refused(capture.main, [photos, '-o', tmp_path / 'out', '--size-mm', '50x35x20'],
            '--size-mm 50x35x20 contradicts', 'capture.json', watch=[tmp_path])


def test_capture_beyond_memory_names_the_flags(shots, tmp_path, monkeypatch):
    from reneus_mi.utils import limits
    monkeypatch.setattr(limits, 'physical_memory', lambda: 2**20)
    photos = photo_copies(shots, tmp_path / 'photos', 3)
    refused(capture.main, [photos, '-o', tmp_path / 'out', *CAPTURE],
            '3 photographs of 640x480', 'needs about', '--max-size N or --downscale F', watch=[tmp_path])


def test_capture_photograph_without_corners_is_left_out(shots, tmp_path):
    """One warning line naming the photograph; the others go on."""
    from reneus_mi.capture.charuco import Board
    photos = photo_copies(shots, tmp_path / 'photos', 2, blank=1)
    shots = capture_photos.orientations(capture_photos.list_photos(str(photos)))
    with pytest.warns(UserWarning) as caught:
        detections, reduced = capture_pipeline.read_all(Board(12, 9, 20.0, 15.0), shots, (320, 240))
    messages = [str(w.message) for w in caught]
    assert messages == ['blank_0.jpg: left out: no board corners found (is the board in the picture, '
                        'sharp and not too oblique?)']
    assert sorted(detections) == sorted(f for f in os.listdir(photos) if f.startswith('IMG'))
    assert {image.shape for image in reduced.values()} == {(240, 320, 3)}


def test_capture_of_too_few_photographs_refused(shots, tmp_path):
    """Three photographs: refused with how many can be used and how many a reconstruction
    needs. Harmful before: a dataset of three views, the lens extrapolated by 22,827 px."""
    photos = photo_copies(shots, tmp_path / 'photos', 3)
    refused(capture.main, [photos, '-o', tmp_path / 'out', *CAPTURE], f'{photos}: 3 photographs can be used',
            'expected at least 8', 'seen all around', watch=[photos])


def test_capture_container_not_found_writes_the_overlays(shots, tmp_path):
    """A container stated 80 mm tall (it is 25): refused, with the overlays there to see why."""
    photos = photo_copies(shots, tmp_path / 'photos', 8)
    given = [x if x != '50x35x25' else '50x35x80' for x in CAPTURE]
    refused(capture.main, [photos, '-o', tmp_path / 'out', *given, '--max-size', 320],
            'container not found', 'check --size-mm', 'overlays in', watch=[photos])
    assert len(os.listdir(tmp_path / 'out' / 'overlays')) == 8
    assert not os.path.exists(tmp_path / 'out' / 'transforms.json')



@pytest.mark.parametrize('size, parts', [
    ('52x35x25', ['size_mm=52x35x25 and the photographs disagree: the outline fits them best at',
                  'expected them within 1 mm']),
    ('80x60x40', ['container not found: placed at', 'off the 240x180 mm board']),
], ids=['two_millimetres_wide', 'far_too_large'])
def test_capture_wrong_size_refused(shots, tmp_path, size, parts):
    """A block measured wrongly (it is 50x35x25 mm) is refused, with the size the photographs
    suggest; the overlays show why."""
    photos = photo_copies(shots, tmp_path / 'photos', 16)
    given = [x if x != '50x35x25' else size for x in CAPTURE]
    message = refused(capture.main, [photos, '-o', tmp_path / 'out', *given], *parts, 'see the overlays',
                      watch=[photos])
    assert not os.path.exists(tmp_path / 'out' / 'transforms.json')
    best = re.search(r'fits them best at ([\d.]+)x([\d.]+)x([\d.]+) mm', message)
    if best:   # the size suggested is the block's
        assert np.abs(np.array(best.groups(), float) - (50.0, 35.0, 25.0)).max() < 0.5, message


def test_capture_measures_the_size_when_asked(shots, tmp_path):
    """--size-mm auto: the block (50x35x25 mm) measured from the photographs, with deviations,
    and the dataset's container made at that size."""
    photos = photo_copies(shots, tmp_path / 'photos', 16)
    given = [x if x != '50x35x25' else 'auto' for x in CAPTURE]
    assert capture.main([str(photos), '-o', str(tmp_path / 'out'), *map(str, given), '--quiet']) == 0
    with open(tmp_path / 'out' / 'report.json') as f:
        report = json.load(f)
    box = report['container']
    assert box['size_measured'] and report['settings']['size_mm'] == 'auto'
    assert np.abs(np.array(box['size_fit_mm']) - (50.0, 35.0, 25.0)).max() < 0.5, box['size_fit_mm']
    assert box['size_mm'] == box['size_fit_mm'] and 0 < min(box['size_fit_std_mm'])
    from reneus_mi.capture.placement import pose_matrix
    block = trimesh.load(tmp_path / 'out' / 'container.ply')
    block.apply_transform(np.linalg.inv(pose_matrix(box['pose'])))
    np.testing.assert_allclose(block.extents, box['size_fit_mm'], atol=1e-3)

def test_capture_report_lists_every_photograph_left_out(shots, tmp_path):
    """Left out before the calibration (no corners) and by it: all in report.json, with why."""
    photos = photo_copies(shots, tmp_path / 'photos', 16, blank=1)
    assert capture.main([str(photos), '-o', str(tmp_path / 'out'), *map(str, CAPTURE), '--quiet']) == 0
    with open(tmp_path / 'out' / 'report.json') as f:
        report = json.load(f)
    assert report['left_out'] == {'blank_0.jpg': capture_pipeline.NO_CORNERS}

def test_capture_settings_errors_all_in_one_line(shots, tmp_path):
    """Every wrong setting of a capture.json at once, each named with where it was given."""
    photos = photo_copies(shots, tmp_path / 'photos', 3)
    with open(photos / 'capture.json', 'w') as f:
        json.dump({'squares': '12x9', 'square_mm': -20, 'marker_mm': 15, 'size_mm': '50x35x25', 'ior': 0.5,
                   'max_size': 10}, f)
    message = refused(capture.main, [photos, '-o', tmp_path / 'out'], '3 problems with the capture settings',
                      'square_mm=-20', 'ior=0.5', 'max_size=10', watch=[tmp_path])
    assert message.count('capture.json: ') == 3, message


def test_capture_blames_the_command_line_for_its_own_values(shots, tmp_path):
    photos = photo_copies(shots, tmp_path / 'photos', 3, settings=True)
    message = refused(capture.main, [photos, '-o', tmp_path / 'out', '--max-size', 0],
                      '--max-size: max_size=0; expected at least 64 pixels', watch=[tmp_path])
    assert 'capture.json' not in message


@pytest.mark.parametrize('kind', ['missing', 'file'])
def test_capture_photos_folder_named_as_such(shots, tmp_path, kind):
    photos = tmp_path / 'photos'
    if kind == 'file':
        shutil.copy(os.path.join(shots, 'IMG_0001.jpg'), photos)
    part = 'photographs folder does not exist' if kind == 'missing' else 'is a file; expected the folder'
    refused(capture.main, [photos, '-o', tmp_path / 'out'], f'{photos}: {part}', watch=[tmp_path])


def _torn(path):
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def _cmyk(path):
    from PIL import Image
    Image.open(path).convert('CMYK').save(path)


def _heic(path):
    shutil.copy(path, path.with_suffix('.HEIC'))


def _inverted(where):
    """48 bytes inverted at ``where`` (a fraction of the file), its length unchanged: data that
    libjpeg, and so Pillow, decode with a warning only."""
    def spoil(path):
        data = bytearray(path.read_bytes())
        start = int(len(data) * where)
        data[start:start + 48] = bytes(b ^ 0xFF for b in data[start:start + 48])
        path.write_bytes(bytes(data))
    return spoil


def _two_names(path):
    """A second photograph whose name differs from the first's only by case."""
    shutil.copy(path.with_name('IMG_0002.jpg'), path.with_name('IMG_0001.JPG'))


@pytest.mark.parametrize('spoil, parts', [
    (_torn, ['IMG_0001.jpg: damaged photograph', 'copy it again']),
    (_inverted(0.97), ['IMG_0001.jpg: damaged photograph', 'copy it again']),
    (_inverted(0.5), ['IMG_0001.jpg: damaged photograph', 'copy it again']),
    (_cmyk, ['IMG_0001.jpg: a CMYK photograph', 'export it again as sRGB']),
    (_heic, ['IMG_0001.HEIC: a HEIC file', 'expected JPEG, PNG or TIFF']),
    (_two_names, ['IMG_0001.JPG and', 'IMG_0001.jpg: two photographs whose names differ only in case',
                  'rename one']),
], ids=['torn', 'damaged_near_the_end', 'damaged_in_the_middle', 'cmyk', 'heic', 'two_names'])
def test_capture_photograph_whole_or_refused_by_name(shots, tmp_path, spoil, parts):
    photos = photo_copies(shots, tmp_path / 'photos', 3)
    spoil(photos / 'IMG_0001.jpg')
    message = refused(capture.main, [photos, '-o', tmp_path / 'out', *CAPTURE], *parts, watch=[photos])
    if spoil is _cmyk:
        assert 'damaged' not in message, message


def test_capture_same_photograph_twice_is_used_once(shots, tmp_path):
    """A photograph copied under a second name (byte for byte, even one that differs from the
    first only by its extension's case) is named and read once; one spoiled near its end is
    caught although Pillow decodes it without a word."""
    from PIL import Image
    photos = photo_copies(shots, tmp_path / 'photos', 3)
    shutil.copy(photos / 'IMG_0002.jpg', photos / 'IMG_0002.JPG')
    shutil.copy(photos / 'IMG_0003.jpg', photos / 'copy of IMG_0003.jpg')
    with pytest.warns(UserWarning, match=r'used once: IMG_0002.jpg \(a copy of IMG_0002.JPG\), '
                                         r'copy of IMG_0003.jpg \(a copy of IMG_0003.jpg\)'):
        files = capture_photos.list_photos(str(photos))
    assert [os.path.basename(f) for f in files] == ['IMG_0001.jpg', 'IMG_0002.JPG', 'IMG_0003.jpg']
    # A PNG and a 16-bit TIFF of a photograph read as the photograph (Pillow, not the JPEG path).
    whole = capture_photos.decode(capture_photos.header(str(photos / 'IMG_0001.jpg')))
    Image.fromarray(whole).save(tmp_path / 'IMG_0001.png')
    Image.fromarray(whole[..., 1].astype(np.uint16) * 257).save(tmp_path / 'IMG_0001.tif')
    assert np.array_equal(capture_photos.decode(capture_photos.header(str(tmp_path / 'IMG_0001.png'))), whole)
    assert np.array_equal(capture_photos.decode(capture_photos.header(str(tmp_path / 'IMG_0001.tif')))[..., 0],
                          whole[..., 1])
    _inverted(0.97)(photos / 'IMG_0001.jpg')
    Image.open(photos / 'IMG_0001.jpg').load()     # what the capture trusted before
    with pytest.raises(ReneusError, match='IMG_0001.jpg: damaged photograph'):
        capture_photos.decode(capture_photos.header(str(photos / 'IMG_0001.jpg')))


def test_capture_damage_anywhere_is_caught(shots, tmp_path):
    """48 bytes inverted at 20 places of each of 4 photographs: libjpeg warns of most; of the
    rest, whose Huffman codes fall back into step, the colour step gives most away (measured
    over the 16 photographs at 40 places: libjpeg 586 of 640, the colour step 48 of the 54
    left; missed: damage within an eighth of a row's end, or in the last rows). No whole
    photograph is refused, nor one whose own straight edge lies along an MCU row's top edge
    (a board's row of squares seen from low, as Blender's photographs showed it)."""
    missed, tried = [], 0
    for name in ['IMG_0001.jpg', 'IMG_0002.jpg', 'IMG_0003.jpg', 'IMG_0015.jpg']:
        whole = tmp_path / name
        shutil.copy(os.path.join(shots, name), whole)
        capture_photos.decode(capture_photos.header(str(whole)))
        for where in np.linspace(0.05, 0.95, 20):
            path = tmp_path / f'spoiled_{where:.3f}_{name}'
            shutil.copy(whole, path)
            _inverted(where)(path)
            tried += 1
            try:
                capture_photos.decode(capture_photos.header(str(path)))
                missed.append(path.name)
            except ReneusError as e:
                assert 'damaged photograph' in str(e)
    assert tried == 80 and len(missed) <= 2, missed
    from PIL import Image
    edge = np.full((480, 640, 3), 230, np.uint8)
    edge[240:, 40:600] = 40                        # rows 240 on: the top edge of MCU row 15
    edge[240:, 300:330] = 230
    Image.fromarray(edge).save(tmp_path / 'edge.jpg', quality=90)
    assert capture_photos.decode(capture_photos.header(str(tmp_path / 'edge.jpg'))).shape == edge.shape


def test_capture_photograph_stored_turned_is_used_as_its_tag_shows_it(shots, tmp_path):
    """A photograph whose pixels were stored turned by 90 degrees, with the EXIF tag that turns
    them back, is read as the others are and named once; one without the tag is refused, naming
    both sizes."""
    from PIL import Image
    photos = photo_copies(shots, tmp_path / 'photos', 3)
    original = capture_photos.decode(capture_photos.header(str(photos / 'IMG_0002.jpg')))
    exif = Image.Exif()
    exif[0x0112] = 6                          # shown turned 90 degrees clockwise
    Image.fromarray(np.rot90(original)).save(photos / 'IMG_0002.jpg', exif=exif.tobytes(), quality=95)
    with pytest.warns(UserWarning, match=r'1 photograph\(s\) stored turned.*\(640x480, as the others\): IMG_0002.jpg'):
        shots_ = capture_photos.orientations(capture_photos.list_photos(str(photos)))
    turned = capture_photos.decode(shots_[1])
    assert turned.shape == original.shape and np.abs(turned.astype(int) - original).mean() < 2.0
    Image.fromarray(np.rot90(original)).save(photos / 'IMG_0002.jpg', quality=95)
    refused(capture.main, [photos, '-o', tmp_path / 'out', *CAPTURE],
            'IMG_0002.jpg: photograph is 480x640, but 2 of the 3 photographs are 640x480', watch=[photos])

@pytest.mark.parametrize('model, params, parts', [
    ('OPENCV_FISHEYE', [100.0, 100.0, 32.0, 24.0, 0.1, 0.0, 0.0, 0.0], ['camera model OPENCV_FISHEYE', 'expected SIMPLE_PINHOLE']),
    ('FULL_OPENCV', [100.0, 100.0, 32.0, 24.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0], ['rational terms k4-k6']),
], ids=['fisheye', 'rational'])
def test_colmap_camera_models_refused(tmp_path, model, params, parts):
    pycolmap = pytest.importorskip('pycolmap')
    import cv2
    (tmp_path / 'images').mkdir()
    cv2.imwrite(str(tmp_path / 'images' / 'a.png'), np.zeros((48, 64, 3), np.uint8))
    rec = pycolmap.Reconstruction()
    camera = pycolmap.Camera.create_from_model_name(1, model, 100.0, 64, 48)
    camera.params = params
    rec.add_camera_with_trivial_rig(camera)
    pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.eye(3)), np.array([0.0, 0.0, 5.0]))
    rec.add_image_with_trivial_frame(pycolmap.Image(name='a.png', camera_id=1, image_id=1), pose)
    (tmp_path / 'sparse').mkdir()
    rec.write_text(str(tmp_path / 'sparse'))
    trimesh.creation.box(extents=(1.0, 1.0, 1.0)).export(tmp_path / 'box.ply')
    refused(colmap_command.main, [tmp_path / 'sparse', '--images', tmp_path / 'images', '--container',
                                  tmp_path / 'box.ply', '--ior', 1.5, '-o', tmp_path / 'out'], *parts,
            watch=[tmp_path])


@pytest.mark.parametrize('edit, parts', [
    ({'camera_model': 'OPENCV_FISHEYE'}, ["camera_model 'OPENCV_FISHEYE'", 'expected one of OPENCV']),
    ({'camera_model': 'OPENCV', 'k1': 0.1, 'k4': 0.2}, ["'k4' is 0.2", 'fisheye']),
    ({'camera_model': 'PINHOLE', 'k1': 0.1}, ['camera_model PINHOLE with distortion', 'expected OPENCV']),
], ids=['fisheye', 'k4', 'pinhole_with_distortion'])
def test_optimize_nerfstudio_lens_refused(world, data, tmp_path, edit, parts):
    edit_frames(data, lambda meta: meta.update(edit))
    refused(optimize.main, train(world, data, tmp_path), *parts, watch=[data, tmp_path])


# =========================================================== real processes
def test_processes_exit_1_with_one_line(world, tmp_path):
    """The interpreter's own exit: status 1, one stderr line, no traceback, nothing written."""
    before = snapshot(world['data'], world['run'])
    one_error_line(process('optimize', world['scene'], '-o', world['data'], *TRAIN),
                   'dataset folder')
    one_error_line(process('extract', world['checkpoint'], '-o', tmp_path / 'm.ply',
                           '--resolution', 100000), '32-bit')
    one_error_line(process('synth', 'sphere', '-o', world['data']), 'dataset folder')
    one_error_line(process('render', world['scene'], '-o', tmp_path / 'r.jpg'), '.exr or .png')
    one_error_line(process('capture', world['data'], '-o', tmp_path / 'out', *CAPTURE), 'no photographs')
    assert snapshot(world['data'], world['run']) == before
    assert os.listdir(tmp_path) == []


# ================================================================== Ctrl-C
#: A sitecustomize for the commands' processes: the first call of ``module:function`` (named
#: in RENEUS_TEST_PAUSE with a marker file and a hold) returns, creates the marker, then holds
#: the process there: a moment of the command that a test can find and interrupt. The hold is
#: some seconds of sleep, or ``spin``: a Dr.Jit kernel that never ends, which Python's own
#: handling of Ctrl-C would wait for (as for a long kernel compilation) for ever.
PAUSE_HOOK = """\
import importlib, os, time
_module, _name, _marker, _hold = os.environ['RENEUS_TEST_PAUSE'].split('|')
_module = importlib.import_module(_module)
_original = getattr(_module, _name)


def _paused(*args, **kwargs):
    result = _original(*args, **kwargs)
    if not os.path.exists(_marker):
        open(_marker, 'w').close()
        if _hold == 'spin':
            import drjit as dr, mitsuba as mi
            x = dr.while_loop(state=(mi.Float(0.0),), cond=lambda x: x >= 0.0, body=lambda x: (x + 1.0,))[0]
            dr.eval(x)
        else:
            time.sleep(float(_hold))
    return result


setattr(_module, _name, _paused)
"""
#: A hold the command never returns from: the interrupt must end it from outside.
SPIN = 'spin'


def start(module, *args, tmp_path, pause=None, importtime=False) -> subprocess.Popen:
    """``python -m reneus_mi.<module>`` as a process; ``pause=('module:function', hold)`` holds
    it once inside that call (``tmp_path / 'paused'`` marks the moment)."""
    env = {**os.environ, 'RENEUS_VARIANT': 'llvm_ad_rgb'}
    if pause:
        hook = tmp_path / 'hook'
        hook.mkdir(exist_ok=True)
        (hook / 'sitecustomize.py').write_text(PAUSE_HOOK)
        env['PYTHONPATH'] = os.pathsep.join(filter(None, [str(hook), env.get('PYTHONPATH')]))
        env['RENEUS_TEST_PAUSE'] = '|'.join([*pause[0].split(':'), str(tmp_path / 'paused'), str(pause[1])])
    flags = ['-X', 'importtime'] if importtime else []
    return subprocess.Popen([sys.executable, *flags, '-m', f'reneus_mi.{module}', *map(str, args)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(proc, ready, limit=300.0) -> None:
    """Wait (bounded) until ``ready()``; the process must still be running then."""
    deadline = time.monotonic() + limit
    while not ready():
        assert proc.poll() is None, f'ended before the moment came: {proc.communicate()}'
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f'the moment never came: {proc.communicate()[1][-3000:]}')
        time.sleep(0.005)


def ctrl_c(proc, times=1) -> str:
    """Send SIGINT; the process must end with status 130 and one line (besides the warnings it
    gave before); return the line."""
    for n in range(times):
        proc.send_signal(signal.SIGINT)
        if n + 1 < times:   # apart: the kernel merges a signal sent while one is pending
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(0.5)
    try:
        _, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:   # a hold that never ends outlives a lost interrupt
        proc.kill()
        pytest.fail(f'the interrupt did not end the process: {proc.communicate()[1][-3000:]}')
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith(('import time:', 'warning: '))]
    assert proc.returncode == interrupt.STATUS and len(lines) == 1, (proc.returncode, err[-3000:])
    assert lines[0].startswith('interrupted: ') and 'Traceback' not in err, err[-3000:]
    return lines[0]


def temporaries(*folders) -> list[str]:
    return [os.path.join(d, f) for folder in folders for d, dirs, files in os.walk(folder)
            for f in files + dirs if f.startswith('.tmp-')]


def said_state(line: str, out) -> None:
    """The line names the state the folder is in now, and what it takes."""
    state = RunFolder(out).state()
    assert line == f'interrupted: {out} is {state}: {state.advice()}', (line, str(state))


CTRL_C_TRAIN = [a if a != '2' else '3' for a in TRAIN]


@pytest.mark.parametrize('module, args', [
    ('optimize', ['{scene}', '-o', '{out}', *TRAIN]),
    ('render', ['{scene}', '-o', '{out}.png']),
    ('extract', ['{checkpoint}', '-o', '{out}.ply']),
    ('evaluate', ['{gt}', '{gt}']),
    ('scene', ['{data}', '-o', '{out}.xml']),
    ('synth', ['sphere', '-o', '{out}', '--views', 2, '--res', 8, '--spp', 1]),
    ('capture', ['{data}', '-o', '{out}']),
], ids=lambda v: v if isinstance(v, str) else None)
def test_ctrl_c_while_starting(world, tmp_path, module, args):
    """Ctrl-C during the imports (Dr.Jit, Mitsuba still loading): one line, nothing written."""
    values = {**world, 'out': tmp_path / 'out'}
    proc = start(module, *[str(a).format(**values) for a in args], tmp_path=tmp_path, importtime=True)
    for line in proc.stderr:      # the imports report as they end; Dr.Jit's come after the handler's
        if re.search(r'\|\s+drjit', line):
            break
    line = ctrl_c(proc)
    assert line == f'interrupted: {interrupt.NOTHING_HALF_WRITTEN}'
    assert os.listdir(tmp_path) == []


def test_ctrl_c_in_the_first_step(world, tmp_path):
    """Inside the first step (where a cold cache compiles the kernels): at once, not when the
    step ends; nothing to continue, and the same command starts the run anew."""
    out = tmp_path / 'run'
    proc = start('optimize', world['scene'], '-o', out, *CTRL_C_TRAIN, tmp_path=tmp_path,
                 pause=('reneus_mi.train.losses:total', SPIN))
    wait_for(proc, (tmp_path / 'paused').exists)
    said_state(ctrl_c(proc), out)
    assert RunFolder(out).state().takes_new_run and not temporaries(tmp_path)
    assert optimize.main([world['scene'], '-o', str(out), *CTRL_C_TRAIN]) == 0
    assert [e['iteration'] for e in RunFolder(out).read_log()] == [1, 2, 3]


@pytest.mark.parametrize('times', [1, 2], ids=['once', 'twice'])
def test_ctrl_c_while_a_checkpoint_is_written(world, tmp_path, times):
    """Once: the checkpoint being written is finished first (it holds a step); twice: at once,
    its temporary removed. Either way the folder says what it takes, and that works."""
    out = tmp_path / 'run'
    proc = start('optimize', world['scene'], '-o', out, *CTRL_C_TRAIN, tmp_path=tmp_path,
                 pause=('numpy:savez', 2.0 if times == 1 else SPIN))
    wait_for(proc, (tmp_path / 'paused').exists)
    assert temporaries(out)               # the checkpoint is being written
    said_state(ctrl_c(proc, times), out)
    assert not temporaries(tmp_path)
    state = RunFolder(out).state()
    if times == 1:
        assert str(state) == 'resumable (checkpoint of step 1)'
        assert optimize.main(['-o', str(out), '--resume', '--quiet']) == 0
    else:
        assert state.name == 'new' and not (out / 'checkpoint.npz').exists()
        assert optimize.main([world['scene'], '-o', str(out), *CTRL_C_TRAIN]) == 0
    assert [e['iteration'] for e in RunFolder(out).read_log()] == [1, 2, 3]


def test_ctrl_c_while_meshing(world, tmp_path):
    """After the last step: at once; the checkpoint holds the run, --resume writes the mesh."""
    out = tmp_path / 'run'
    proc = start('optimize', world['scene'], '-o', out, *CTRL_C_TRAIN, tmp_path=tmp_path,
                 pause=('skimage.measure:marching_cubes', SPIN))
    wait_for(proc, (tmp_path / 'paused').exists)
    said_state(ctrl_c(proc), out)
    assert str(RunFolder(out).state()) == 'resumable (checkpoint of step 3)'
    assert not (out / 'mesh.ply').exists() and not temporaries(tmp_path)
    assert optimize.main(['-o', str(out), '--resume', '--quiet']) == 0
    assert (out / 'mesh.ply').exists() and RunFolder(out).state().name == 'finished'


def test_ctrl_c_during_synth_leaves_nothing(tmp_path):
    """Harmful before: the partial folder made the same command refuse."""
    out = tmp_path / 'data'
    args = ['sphere', '-o', out, '--views', 2, '--res', 8, '--spp', 1]
    proc = start('synth', *args, tmp_path=tmp_path, pause=('reneus_mi.data.synthetic:render_view', SPIN))
    wait_for(proc, (tmp_path / 'paused').exists)
    assert ctrl_c(proc) == f'interrupted: {out} was not written (nothing of it is left); the same command starts again'
    assert sorted(os.listdir(tmp_path)) == ['hook', 'paused']
    assert synth.main([str(a) for a in args]) == 0
    assert (out / 'box' / 'transforms.json').exists()


def test_ctrl_c_while_capture_writes(shots, tmp_path):
    """Harmful before: an interrupt after transforms.json (while the overlays were written) was
    said to leave no dataset, and the same command then refused the folder."""
    out = tmp_path / 'out'
    # At 320 px the outline of the right container lies 2.1 px from the photographs, on the
    # edge of the not-found limit: this test is about the interrupt, so the photographs are larger.
    args = [photo_copies(shots, tmp_path / 'photos', 8), '-o', out, *CAPTURE, '--max-size', 480, '--quiet']
    proc = start('capture', *args, tmp_path=tmp_path, pause=('reneus_mi.capture.writer:write_overlays', SPIN))
    wait_for(proc, (tmp_path / 'paused').exists)
    assert ctrl_c(proc) == (f'interrupted: {out} holds no dataset yet (no transforms.json): '
                            'the same command replaces what it holds')
    assert len(os.listdir(out / 'overlays')) == 8 and not temporaries(tmp_path)
    assert capture.main([str(a) for a in args]) == 0
    assert (out / 'transforms.json').exists()


def test_interrupt_wrapped_by_mitsuba_is_one_line(capsys):
    """In-process (no handler of its own), a KeyboardInterrupt that Mitsuba wrapped in a
    RuntimeError ends as an interrupt, not as 'error: KeyboardInterrupt()'."""
    from reneus_mi.utils.errors import exit_on_error
    with pytest.raises(SystemExit) as exit_info, exit_on_error(RuntimeError):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as e:
            raise RuntimeError('error while performing a custom differentiable operation') from e
    assert exit_info.value.code == interrupt.STATUS
    assert capsys.readouterr().err.strip().startswith('interrupted: ')


# ============================================================ run states
def test_rerun_of_a_run_killed_before_its_first_checkpoint_keeps_no_dead_lines(world, tmp_path):
    """Harmful before: the new run appended its log to the dead attempt's."""
    out = tmp_path / 'run'
    proc = start('optimize', world['scene'], '-o', out, *TRAIN, '--iterations', 100000,
                 '--checkpoint-every', 0, tmp_path=tmp_path)
    wait_for(proc, lambda: len(RunFolder(out).read_log()) >= 2)
    proc.kill()
    proc.communicate()
    assert RunFolder(out).state().name == 'new'
    assert optimize.main([world['scene'], '-o', str(out), *CTRL_C_TRAIN]) == 0
    assert [e['iteration'] for e in RunFolder(out).read_log()] == [1, 2, 3]


#: A loss above 0.5x its lowest value counts as diverging: every step after warm-up does.
DIVERGE = ['--divergence-factor', '0.5']


def test_diverged_before_its_first_checkpoint(world, tmp_path):
    """Harmful before: the message named a checkpoint never written, and the folder then
    refused both a new run and --resume."""
    out = tmp_path / 'run'
    message = refused(optimize.main, [world['scene'], '-o', out, *TRAIN, '--checkpoint-every', 0, *DIVERGE],
                      'step 1: the loss', 'diverging; no checkpoint was written yet', '--learning-rate',
                      f'{out}: nothing to continue: a new run (without --resume) starts in it')
    state = RunFolder(out).state()
    assert state.name == 'failed' and state.reason in message and not state.checkpoint
    refused(optimize.main, ['-o', out, '--resume', '--quiet'], f'{out}: nothing to resume (failed (step 1',
            'a new run (without --resume) starts in it', watch=[out])
    assert optimize.main([world['scene'], '-o', str(out), *TRAIN]) == 0
    assert RunFolder(out).state().name == 'finished'
    assert [e['iteration'] for e in RunFolder(out).read_log()] == [1, 2]


def test_diverged_after_a_checkpoint(world, tmp_path):
    out = tmp_path / 'run'
    refused(optimize.main, [world['scene'], '-o', out, *CTRL_C_TRAIN, '--warm-up', 2, *DIVERGE],
            'step 2: the loss', f'diverging; the checkpoint of step 2 ({out}/checkpoint.npz) is kept',
            f'{out}: continue it from its checkpoint with --resume, after changing what failed')
    assert str(RunFolder(out).state()).startswith('failed (step 2: the loss')
    refused(optimize.main, [world['scene'], '-o', out, *TRAIN], f'{out} already holds a run (failed (step 2',
            'checkpoint of step 2)', 'continue it from its checkpoint with --resume', watch=[out])
    assert optimize.main(['-o', str(out), '--resume', '--quiet', '--divergence-factor', '50']) == 0
    assert RunFolder(out).state().name == 'finished'
    assert [e['iteration'] for e in RunFolder(out).read_log()] == [1, 2, 3]


# ============================================ what a resumed run must survive
def test_resume_finished_run_reports_the_logged_psnr(world, run_copy, capsys):
    """No step is left: the summary takes the PSNR from the log, and names no images/."""
    assert optimize.main(['-o', str(run_copy), '--resume', '--quiet']) == 0
    out = capsys.readouterr().out
    assert 'done: 2 iterations' in out and 'nan' not in out and 'renders' not in out
    logged = [json.loads(line) for line in (run_copy / 'log.jsonl').read_text().splitlines()]
    assert f"PSNR {np.mean([e['psnr'] for e in logged]):.2f} dB" in out


def test_resume_drops_a_torn_log_line(world, run_copy):
    with open(run_copy / 'log.jsonl', 'a') as f:
        f.write('{"iteration": 3, "loss": 0.1')          # a kill mid-line
    assert optimize.main(['-o', str(run_copy), '--resume', '--quiet', '--iterations', '3']) == 0
    steps = [json.loads(line)['iteration'] for line in (run_copy / 'log.jsonl').read_text().splitlines()]
    assert steps == [1, 2, 3]


def test_resume_removes_a_stray_temporary(world, run_copy):
    (run_copy / '.tmp-k1ll3d.npz').write_bytes(b'half a checkpoint')
    assert optimize.main(['-o', str(run_copy), '--resume', '--quiet']) == 0
    assert not (run_copy / '.tmp-k1ll3d.npz').exists() and not (run_copy / '.lock').exists()


def test_interrupted_step_leaves_the_batch_stream_alone(world, tmp_path):
    """Ctrl-C inside a step: redoing it draws what the unbroken run drew (batches depend on the step)."""
    unbroken = new_trainer(world['scene'], tmp_path / 'a')
    unbroken.step()
    trainer = new_trainer(world['scene'], tmp_path / 'b')
    render_rays = trainer.integrator.render_rays

    def interrupted(*args, **kwargs):
        trainer.integrator.render_rays = render_rays
        raise KeyboardInterrupt
    trainer.integrator.render_rays = interrupted
    with pytest.raises(KeyboardInterrupt):
        trainer.step()
    assert trainer.iteration == 0
    trainer.step()
    assert_same_state(train_state(unbroken), train_state(trainer), exact=False)


def test_validation_without_surface_goes_on(world, tmp_path, monkeypatch):
    from reneus_mi.utils.errors import NoSurfaceError
    trainer = new_trainer(world['scene'], tmp_path / 'out')

    def no_surface(*args, **kwargs):
        raise NoSurfaceError('NeuSField has no zero crossing')
    monkeypatch.setattr(trainer, 'write_mesh', no_surface)
    with pytest.warns(UserWarning, match='no mesh snapshot .* training goes on'):
        trainer.validate()
    assert sorted(os.listdir(tmp_path / 'out' / 'images')) == ['000000.png', '000000_normal.png']


def test_optimize_field_sphere_away_from_the_container(world, tmp_path):
    """No ray would reach the field: said before training, not by drjit.backward()."""
    xml = tmp_path / 'scene.xml'
    text = open(world['scene']).read()
    start = text.index('<point name="field_center"')
    end = text.index('/>', start) + 2
    xml.write_text(text[:start] + '<point name="field_center" x="50" y="0" z="0"/>' + text[end:]
                   .replace('value="box/', f'value="{world["data"]}/'))
    refused(optimize.main, [xml, '-o', tmp_path / 'out', *TRAIN],
            'the field sphere (centre [50.0, 0.0, 0.0]', 'no ray would reach the field',
            watch=[tmp_path])


def test_scene_with_overlapping_container_parts(world, tmp_path):
    xml = tmp_path / 'scene.xml'
    text = open(world['scene']).read().replace('value="box/', f'value="{world["data"]}/')
    start = text.index('<shape')
    end = text.index('</shape>', start) + len('</shape>')
    shape = text[start:end]
    moved = shape.replace('id="container"', 'id="second"').replace(
        '</shape>', '<transform name="to_world"><translate x="0.1" y="0.1" z="0.1"/></transform></shape>')
    xml.write_text(text[:end] + moved + text[end:])
    refused(render.main, [xml, '-o', tmp_path / 'r.png'],
            'container parts overlap', "shape 'container' (its surface 1 of 2)",
            "reaches into shape 'container' (its surface 2 of 2)", watch=[tmp_path])    # Mitsuba merged the two


def _hollow(path):
    """The container file as a hollow vessel in one mesh: its surface around a cavity half its size."""
    outer = trimesh.load(path, process=False)
    cavity = outer.copy()
    cavity.apply_scale(0.5)
    cavity.apply_translation(outer.centroid - cavity.centroid)
    cavity.invert()
    trimesh.util.concatenate([outer, cavity]).export(path)


@pytest.mark.parametrize('spoil, parts', [
    ('same_file_twice', ['container parts overlap', 'reaches into', 'the same file twice']),
    ('hollow_in_one_mesh', ['a hollow vessel in one mesh', "entries of their own in 'containers'",
                            'docs/containers.md']),
], ids=['same_file_twice', 'hollow_in_one_mesh'])
def test_scene_checks_the_containers_it_can_see(data, tmp_path, spoil, parts):
    """Before it writes a scene, the scene command refuses containers that optimize would:
    each file and entry named."""
    meta = json.loads((data / 'transforms.json').read_text())
    if spoil == 'same_file_twice':
        edit_frames(data, lambda m: m.update(containers=[
            {'mesh': m['mesh_outside'], 'int_ior': m['IOR'], 'ext_ior': 1.0},
            {'mesh': m['mesh_outside'], 'int_ior': 1.0, 'ext_ior': m['IOR']}]))
    else:
        _hollow(data / meta['mesh_outside'])
    refused(scene.main, [data, '-o', tmp_path / 'scene.xml', '--preset', 'tiny'], *parts,
            str(data / meta['mesh_outside']), watch=[data, tmp_path])


def test_optimize_help_states_each_default_once(capsys):
    with pytest.raises(SystemExit) as exit_info:
        optimize.main(['--help'])
    assert exit_info.value.code == 0
    text = ' '.join(capsys.readouterr().out.split())
    # Training settings default to the preset's values, and say so once each.
    assert text.count("(default: the preset's)") >= 15 and text.count('(default: 3000)') == 0
    assert '(default: None)' not in text


def test_final_mesh_without_surface_says_the_run_can_go_on(world, tmp_path, monkeypatch):
    from reneus_mi.utils.errors import NoSurfaceError
    trainer = new_trainer(world['scene'], tmp_path / 'out')
    trainer.iteration = trainer.cfg.iterations          # nothing left to train

    def no_surface(*args, **kwargs):
        raise NoSurfaceError('NeuSField has no zero crossing')
    monkeypatch.setattr(trainer, 'write_mesh', no_surface)
    result = trainer.run(progress=False)
    assert re.search(r'no zero crossing; .*mesh.ply is empty; the run can go on: --resume with more '
                     r'--iterations', result['failure'])
    assert os.path.isfile(trainer.checkpoint_path)
    assert trimesh.load(result['mesh'], force='mesh').is_empty


def test_resume_with_moved_data(world, run_copy, tmp_path):
    """The same photographs in another folder: an explicit --data is checked and recorded."""
    moved = tmp_path / 'moved'
    shutil.copytree(world['data'], moved)
    assert optimize.main(['-o', str(run_copy), '--resume', '--quiet', '--data', str(moved)]) == 0
    assert json.loads((run_copy / 'config.json').read_text())['data'] == str(moved)


@pytest.mark.parametrize('moved', ['data', 'scene', 'both'])
def test_resume_after_the_scene_or_its_data_moved(world, tmp_path, moved):
    """A scene written by `scene` names the container inside the dataset folder; the run keeps
    a copy of its scene and the files it names, so neither move needs config.json edited."""
    data, xml = tmp_path / 'data', tmp_path / 'scenes' / 'specimen.xml'
    shutil.copytree(world['data'], data)
    (tmp_path / 'scenes').mkdir()
    assert scene.main([str(data), '-o', str(xml), '--preset', 'tiny']) == 0
    out = tmp_path / 'run'
    assert optimize.main([str(xml), '-o', str(out), *TRAIN]) == 0
    more = ['-o', str(out), '--resume', '--quiet', '--iterations', '3']
    if moved in ('data', 'both'):
        os.rename(data, tmp_path / 'moved')
        more += ['--data', str(tmp_path / 'moved')]
    if moved in ('scene', 'both'):
        os.rename(tmp_path / 'scenes', tmp_path / 'elsewhere')
    assert optimize.main(more) == 0
    assert [e['iteration'] for e in RunFolder(out).read_log()] == [1, 2, 3]
    assert RunFolder(out).state().name == 'finished'


# ========================================== sizes checked before they are spent
def png_header(path, width: int, height: int) -> None:
    """A PNG that states ``width`` x ``height`` RGBA in its header and holds no pixels: a
    photograph too large to make in a test, which a check must refuse before decoding it."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack('>I', len(data)) + kind + data + struct.pack('>I', zlib.crc32(kind + data))
    path.write_bytes(b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', width, height, 8, 6, 0, 0, 0))
                     + chunk(b'IDAT', zlib.compress(b'')) + chunk(b'IEND', b''))


def test_optimize_photographs_beyond_memory(world, data, tmp_path, small_machine):
    """Harmful before: photographs were decoded unchecked (four of 6000x4000 peaked at 4-8 GB)."""
    for name in os.listdir(data / 'images'):
        png_header(data / 'images' / name, 6000, 4000)
    refused(optimize.main, train(world, data, tmp_path), 'transforms.json: 12 photographs of 6000x4000',
            'needs about', 'this machine has 8 GiB', 'lower it with --max-image-size N', watch=[tmp_path])
    # The option it names lowers the figure below the machine's: the photographs are then read
    # (and these, which hold no pixels, refused as such).
    refused(optimize.main, train(world, data, tmp_path, '--max-image-size', 1000), 'r_000.png',
            'unreadable image', watch=[tmp_path])


def test_scene_photographs_beyond_memory(world, data, tmp_path, small_machine):
    png_header(data / 'images' / 'r_003.png', 60000, 40000)
    refused(scene.main, [data, '-o', tmp_path / 'scene.xml'], '12 photographs of 16x16',
            'lower it with --max-image-size N', watch=[tmp_path])


def test_optimize_max_image_size_trains_on_reduced_photographs(world, tmp_path):
    out = tmp_path / 'run'
    assert optimize.main([world['scene'], '-o', str(out), *TRAIN, '--max-image-size', '8']) == 0
    fingerprint = json.loads((out / 'config.json').read_text())['data_fingerprint']
    assert (fingerprint['width'], fingerprint['height']) == (8, 8)


@pytest.mark.parametrize('args, parts', [
    (['--mesh-resolution', 100000], ['--mesh-resolution 100000', '32-bit index limit']),
    (['--set', 'model.sampler.occupancy_resolution=2000'],
     ['model.sampler.occupancy_resolution=2000 (8,000,000,000 cells)', '32-bit index limit']),
    (['--set', 'model.field.hidden=100000'], ['a neus field of', 'hidden=100000', 'model.field.<name>',
                                               '32-bit index limit']),
], ids=['mesh_resolution', 'occupancy_grid', 'field_width'])
def test_optimize_sizes_beyond_indices_before_training(world, tmp_path, args, parts):
    """Harmful before: a large --mesh-resolution died with a traceback after the whole training."""
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', *TRAIN, *args], *parts, watch=[tmp_path])


@pytest.mark.parametrize('args, parts', [
    (['--mesh-resolution', 1600], ['--mesh-resolution 1600', 'needs about']),
    (['--set', 'model.field.hidden=20000'], ['a neus field of', 'hidden=20000', 'needs about']),
], ids=['mesh_resolution', 'field_width'])
def test_optimize_sizes_beyond_memory_before_training(world, tmp_path, small_machine, args, parts):
    refused(optimize.main, [world['scene'], '-o', tmp_path / 'out', *TRAIN, *args], *parts,
            'this machine has 8 GiB', watch=[tmp_path])


def test_render_field_beyond_memory(world, tmp_path, small_machine):
    xml = tmp_path / 'scene.xml'
    xml.write_text(open(world['scene']).read().replace(
        '<string name="preset" value="tiny" />', '<string name="preset" value="tiny" /><integer name="field_hidden" '
        'value="20000" />').replace('value="box/', f'value="{world["data"]}/'))
    refused(render.main, [xml, '-o', tmp_path / 'r.png'], 'a neus field of', 'hidden=20000', 'needs about',
            watch=[tmp_path])


def test_evaluate_points_beyond_memory(world, tmp_path, small_machine):
    refused(evaluate.main, [world['gt'], world['gt'], '--points', 10**8],
            '100000000 surface points per mesh (--points)', 'needs about', watch=[tmp_path])


# ======================================================= messages name the cause
@pytest.fixture
def full_disk(monkeypatch):
    """Every atomic write lands on /dev/full: the kernel's own 'No space left on device'."""
    if not os.path.exists('/dev/full'):
        pytest.skip('no /dev/full on this system')
    from reneus_mi.utils import io

    def new_temporary(directory, suffix):
        path = os.path.join(directory, f'{io.TEMPORARY_PREFIX}full{suffix}')
        os.symlink('/dev/full', path)
        return path
    monkeypatch.setattr(io, '_new_temporary', new_temporary)


def test_extract_onto_a_full_disk_names_the_file(world, tmp_path, full_disk):
    refused(extract.main, [world['checkpoint'], '-o', tmp_path / 'm.ply', '--resolution', 16],
            f'{tmp_path}/m.ply: No space left on device', watch=[tmp_path])


def test_render_onto_a_full_disk_names_the_file(world, tmp_path, full_disk):
    """Harmful before: Mitsuba's own image writer reports no error on a full disk (a torn image)."""
    refused(render.main, [world['scene'], '-o', tmp_path / 'r.png'], f'{tmp_path}/r.png: No space left on device',
            watch=[tmp_path])


def test_optimize_opaque_alpha_says_the_mask_is_the_alpha_channel(world, data, tmp_path):
    from reneus_mi.data.images import read_image, write_image
    for name in os.listdir(data / 'images'):
        rgb, _ = read_image(str(data / 'images' / name))
        write_image(str(data / 'images' / name), np.concatenate([rgb, np.ones_like(rgb[..., :1])], -1))
    refused(optimize.main, train(world, data, tmp_path), 'r_000.png: view 0: the mask from its alpha channel '
            'covers the whole image', 'opaque alpha channel', watch=[tmp_path])


@pytest.mark.parametrize('field, parts', [
    ('{tmp}/absent.npz', ["model.field='{tmp}/absent.npz': no such file"]),
    ('{checkpoint}', ["is a saved field, and a setting takes a field kind", '--field {checkpoint}']),
], ids=['missing', 'saved_field'])
@pytest.mark.parametrize('command', ['optimize', 'scene'])
def test_set_field_to_a_file(world, tmp_path, command, field, parts):
    """Harmful before: 'unknown field kind' whether or not the file existed."""
    values = {'tmp': tmp_path, 'checkpoint': world['checkpoint']}
    setting = ['--set', f'model.field={field.format(**values)}']
    argv = ([world['scene'], '-o', tmp_path / 'out', *TRAIN] if command == 'optimize'
            else [world['data'], '-o', tmp_path / 'scene.xml'])
    refused({'optimize': optimize.main, 'scene': scene.main}[command], [*argv, *setting],
            *[p.format(**values) for p in parts], watch=[tmp_path])


def test_scene_naming_a_missing_saved_field(world, tmp_path):
    xml = tmp_path / 'scene.xml'
    xml.write_text(open(world['scene']).read().replace(
        '<string name="preset" value="tiny" />', f'<string name="preset" value="tiny" /><string name="field" '
        f'value="{tmp_path}/gone.npz" />').replace('value="box/', f'value="{world["data"]}/'))
    refused(render.main, [xml, '-o', tmp_path / 'r.png'], f'{tmp_path}/gone.npz: field file does not exist',
            watch=[tmp_path])


def test_evaluate_mesh_with_a_nan_vertex(world, tmp_path):
    """Harmful before: reported as 'no surface to sample'."""
    mesh = trimesh.load(world['gt'], force='mesh', process=False)
    mesh.vertices[3] = [np.nan, 0.0, 0.0]
    mesh.export(tmp_path / 'pred.ply')
    refused(evaluate.main, [tmp_path / 'pred.ply', world['gt']], f'{tmp_path}/pred.ply: the predicted mesh has '
            '1 vertex(es) with non-finite coordinates (first: vertex 3 at [nan, 0.0, 0.0])', watch=[tmp_path])


# ============================================= image formats photographers have
def test_optimize_on_a_neus_folder_of_tiffs(world, tmp_path):
    """Harmful before: a NeuS folder of TIFFs was read as '0 images'. 16-bit and 8-bit TIFFs read
    as the PNGs they were made from."""
    import cv2
    from reneus_mi.data import load_dataset
    data = tmp_path / 'neus'
    shutil.copytree(world['neus'], data)
    for i, png in enumerate(sorted((data / 'image').iterdir())):
        pixels = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png.with_suffix('.tif')), pixels.astype(np.uint16) * 257 if i % 2 else pixels)
        png.unlink()
    for png in (data / 'mask').iterdir():
        cv2.imwrite(str(png.with_suffix('.tif')), cv2.imread(str(png), cv2.IMREAD_UNCHANGED))
        png.unlink()
    from reneus_mi.data.images import as_float
    np.testing.assert_allclose(as_float(load_dataset(str(data)).images), as_float(load_dataset(world['neus']).images),
                               atol=1e-6)
    assert np.array_equal(load_dataset(str(data)).masks, load_dataset(world['neus']).masks)
    assert optimize.main([str(a) for a in train(world, data, tmp_path)]) == 0


def test_dataset_mask_path_honoured(world, data):
    """nerfstudio's per-frame mask_path (white: pixels the loss may use) narrows the container's
    mask; one that is missing is refused by name. Harmful before: silently ignored."""
    import cv2
    meta = json.loads((data / 'transforms.json').read_text())
    h, w = meta['h'], meta['w']
    keep = np.full((h, w), 255, np.uint8)
    keep[:, : w // 2] = 0
    cv2.imwrite(str(data / 'keep_000.png'), keep)
    meta['frames'][0]['mask_path'] = 'keep_000.png'
    (data / 'transforms.json').write_text(json.dumps(meta))
    plain, honoured = load_dataset(world['data']), load_dataset(str(data))
    assert plain.masks[0][:, : w // 2].any() and not honoured.masks[0][:, : w // 2].any()
    assert np.array_equal(honoured.masks[0][:, w // 2:], plain.masks[0][:, w // 2:])
    assert np.array_equal(honoured.masks[1:], plain.masks[1:])
    meta['frames'][1]['mask_path'] = 'keep_001.png'
    (data / 'transforms.json').write_text(json.dumps(meta))
    with pytest.raises(ReneusError, match=r"frames\[1\]: mask_path 'keep_001.png' is missing"):
        load_dataset(str(data))


def test_dataset_photograph_of_another_exposure_named(data):
    """One photograph at 1/1.8 of the others' exposure (linear; brighter, this one's light
    background would clip): a warning names it and the factor. Harmful before: trained on
    without a word."""
    from reneus_mi.data.images import read_image, write_image
    path = data / 'images' / 'r_003.png'
    rgb, alpha = read_image(str(path))
    write_image(str(path), np.concatenate([(rgb ** 2.2 / 1.8) ** (1 / 2.2), alpha[..., None]], -1))
    with pytest.warns(UserWarning, match=r'r_003.png: 0\.5\dx as bright as the median photograph') as caught:
        load_dataset(str(data))
    assert sum('as bright as' in str(w.message) for w in caught) == 1


def test_dataset_overexposed_photograph_named(data):
    """One photograph at 1.8x the others' exposure: its light background clips, so that its
    mean is barely brighter; the share clipped names it. Harmful before: trained on without a
    word."""
    from reneus_mi.data.images import read_image, write_image
    path = data / 'images' / 'r_003.png'
    rgb, alpha = read_image(str(path))
    write_image(str(path), np.concatenate([np.clip(rgb ** 2.2 * 1.8, 0, 1) ** (1 / 2.2), alpha[..., None]], -1))
    with pytest.warns(UserWarning, match=r'r_003.png: (\d+% more of it clipped at white|1\.\d+x as bright)') as caught:
        load_dataset(str(data))
    assert sum('r_003.png' in str(w.message) for w in caught) == 1
    assert not any('r_00' in str(w.message) and 'r_003' not in str(w.message) for w in caught)


@pytest.mark.parametrize('orientation, turn', [(6, 'turn it 90 degrees clockwise'), (3, 'turn it by 180 degrees')])
def test_optimize_exif_orientation_refused_by_name(world, data, tmp_path, orientation, turn):
    from PIL import Image
    path = data / 'images' / 'r_004.png'
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.open(path).save(path, exif=exif.tobytes())
    refused(optimize.main, train(world, data, tmp_path), f'r_004.png: EXIF orientation {orientation} asks to {turn}',
            'expected photographs stored upright (orientation 1)', watch=[tmp_path])


# ======================================================================== batch
def test_batch_output_inside_a_dataset(data):
    from reneus_mi.batch.__main__ import main
    refused(main, [data.parent, '-o', data / 'runs'], 'lies in the dataset folder', watch=[data.parent])


def test_batch_output_inside_the_collection(data):
    """Harmful before: accepted, and the next batch read the runs folder as a stray specimen."""
    from reneus_mi.batch.__main__ import main
    refused(main, [data.parent, '-o', data.parent / 'runs'], 'batch folder', 'lies inside the input',
            str(data.parent), watch=[data.parent])


def test_batch_output_holding_other_files(data, tmp_path_factory):
    from reneus_mi.batch.__main__ import main
    runs = tmp_path_factory.mktemp('elsewhere') / 'runs'
    runs.mkdir()
    (runs / 'mine.txt').write_text('keep')
    refused(main, [data.parent, '-o', runs], 'batch folder', 'holds mine.txt', watch=[runs])


@pytest.mark.parametrize('args, expected', [
    (['--redo', 'zz'], ('--redo zz: not in the collection',)),
    (['--workers', '0'], ('--workers 0: expected a positive number',)),
    (['--set', 'train.iterations=many'], ("train.iterations='many': expected an integer",)),
])
def test_batch_options(data, tmp_path_factory, args, expected):
    from reneus_mi.batch.__main__ import main
    runs = tmp_path_factory.mktemp('elsewhere') / 'runs'
    refused(main, [data.parent, '-o', runs, *args], *expected, watch=[runs.parent, data.parent])


def test_batch_of_one_dataset(data, tmp_path):
    from reneus_mi.batch.__main__ import main
    refused(main, [data, '-o', tmp_path / 'runs'], 'is one specimen', watch=[tmp_path])
