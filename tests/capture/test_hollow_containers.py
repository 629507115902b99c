"""The capture path on hollow containers (issue #29): a glass display case (walls around air)
and a jar of ethanol, registered from the photographs by their outer outline as a block is,
written as nested interfaces that describe the photographs."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import trimesh

from capture_data import path_render
from reneus_mi import scene as scene_command
from reneus_mi.capture import __main__ as capture_command
from reneus_mi.capture.simulation import Rig, simulate
from reneus_mi.data import load_dataset

#: The tests' rig, hollow: walls 3 mm thick. 64 samples: a hollow container's floor seen
#: through four interfaces is mostly the path tracer's noise at 16.
HOLLOW = {
    'case': Rig(wall_mm=3.0, spp=64),
    'jar': Rig(container='cylinder', size_mm=(44.0, 44.0, 30.0), wall_mm=3.0, liquid_ior=1.36, spp=64),
}
#: Median display error in the container of ``path`` on the written dataset with the
#: simulated specimen against the photographs (JPEG, noise, both path tracers' noise):
#: measured 0.059 (case) and 0.060 (jar), two views at 16 samples.
MEDIAN_ERROR = 0.075
#: How much worse the same photographs are described as the paper's one solid block of glass:
#: measured 0.144 / 0.059 = 2.4x (case: air inside) and 0.092 / 0.060 = 1.5x (jar: the liquid's
#: 1.36 is nearer the glass's 1.5 than air is).
SOLID_WORSE = {'case': 2.0, 'jar': 1.3}


@pytest.fixture(scope='module', params=list(HOLLOW))
def hollow(request, tmp_path_factory):
    """The capture command on the simulated photographs of a case or a jar."""
    root = tmp_path_factory.mktemp(request.param)
    truth = simulate(HOLLOW[request.param], str(root / 'photos'), str(root / 'truth'))
    assert capture_command.main([str(root / 'photos'), '-o', str(root / 'dataset'), '--quiet']) == 0
    with open(root / 'dataset' / 'report.json') as f:
        report = json.load(f)
    return {'kind': request.param, 'root': root, 'truth': truth, 'report': report,
            'ds': load_dataset(str(root / 'dataset'))}


def test_inner_interface_written_where_the_walls_are(hollow):
    rig, ds = HOLLOW[hollow['kind']], hollow['ds']
    with open(hollow['root'] / 'dataset' / 'transforms.json') as f:
        containers = json.load(f)['containers']
    assert [(c['mesh'], c['int_ior'], c['ext_ior']) for c in containers] == [
        ('container.ply', 1.5, 1.0), ('container_inner.ply', rig.liquid_ior or 1.0, 1.5)]
    assert len(ds.inner) == 1 and ds.inner[0].ior == (rig.liquid_ior or 1.0)
    x, y, _ = hollow['report']['container']['pose']
    assert np.hypot(x - rig.pose[0], y - rig.pose[1]) < 0.5
    # The registered inside against the simulated one: its surface within the registration's error.
    truth = trimesh.load(hollow['root'] / 'truth' / 'container_inner.ply', process=False)
    written = trimesh.load(ds.inner[0].mesh, process=False)
    # Both made by the same function of the stated size: vertex for vertex, they differ by the
    # place (a cylinder's yaw is anyone's: its vertices compared by height and distance from the
    # true axis).
    assert len(truth.vertices) == len(written.vertices)
    t, w = np.asarray(truth.vertices), np.asarray(written.vertices)
    if rig.container == 'cylinder':
        t, w = ([np.hypot(*(v[:, :2] - rig.pose[:2]).T), v[:, 2]] for v in (t, w))
        t, w = np.stack(t, axis=1), np.stack(w, axis=1)
    distance = np.linalg.norm(t - w, axis=1)
    assert np.median(distance) < 0.3 and distance.max() < 1.0, (np.median(distance), distance.max())
    # The field's sphere bounds the space that holds the specimen, not the glass.
    _, radius = ds.normalization()
    assert radius == pytest.approx(np.linalg.norm(written.vertices - written.bounds.mean(axis=0), axis=1).max())


def test_dataset_describes_the_photographs(hollow, tmp_path):
    """``path`` on the scene written from the dataset, with the simulated specimen inside, against
    the photographs; the same as the paper's one solid block misses them (the model matters)."""
    ds = hollow['ds']
    xml = tmp_path / 'scene.xml'
    assert scene_command.main([str(hollow['root'] / 'dataset'), '-o', str(xml)]) == 0
    specimen = hollow['root'] / 'truth' / 'specimen.ply'
    error = {}
    for model in ('nested', 'solid'):
        d = [np.median(np.abs(path_render(xml, ds, view, specimen=specimen, inner=model == 'nested')
                              - ds.image(view)).mean(axis=-1)[ds.masks[view]]) for view in (0, 7)]
        error[model] = float(np.mean(d))
    print(hollow['kind'], error)
    assert error['nested'] < MEDIAN_ERROR and error['solid'] > SOLID_WORSE[hollow['kind']] * error['nested'], error


@pytest.mark.parametrize('guess', [0.5, 1.5])
def test_walls_stated_wrong_are_measured_before_the_field(hollow, guess):
    """Walls stated to the capture at half or one and a half times their 3 mm: the search
    before the field's first step (Trainer.search_walls: the photographs against the empty
    container, the board seen through its glass) finds them within 0.1 mm (issue 41). Measured:
    case 2.994 and 2.992 mm, jar (from 4.5) 2.992. The jar stated 1.5 mm stops short: the
    capture rounds its rims, the inside written at 1.5 mm keeps a rim of about 1.4 mm that its
    offset may not cross (ContainerWalls.bounds), and the search ends there (2.69)."""
    from reneus_mi import runs
    from reneus_mi.data.scene_xml import write_scene
    root, rig = hollow['root'], HOLLOW[hollow['kind']]
    photos, data = root / f'photos_wall_{guess}', root / f'dataset_wall_{guess}'
    shutil.copytree(root / 'photos', photos)
    with open(photos / 'capture.json') as f:
        stated = json.load(f)
    with open(photos / 'capture.json', 'w') as f:
        json.dump({**stated, 'wall_mm': guess * rig.wall_mm}, f)
    assert capture_command.main([str(photos), '-o', str(data), '--quiet']) == 0
    xml = str(root / f'scene_wall_{guess}.xml')
    write_scene(load_dataset(str(data)), xml, preset='fast')
    trainer = runs.prepare(str(root / f'run_wall_{guess}'), xml, str(data), train={'refine.wall': True}).trainer()
    assert trainer.surroundings.walls.stated[0] == pytest.approx(guess * rig.wall_mm, abs=0.01)
    trainer.search_walls()
    found = trainer.refined_values()['container.wall'][0]
    print(hollow['kind'], guess, found)
    if hollow['kind'] == 'jar' and guess < 1.0:
        assert found == pytest.approx(trainer.surroundings.walls.bounds()[1], abs=0.05), found
        assert found > guess * rig.wall_mm + 1.0, found
    else:
        assert abs(found - rig.wall_mm) < 0.1, found


@pytest.mark.parametrize('shape, size', [('cylinder', (40.0, 40.0, 30.0)), ('rounded', (40.0, 30.0, 22.0))])
def test_stated_edge_radius_keeps_the_outer_size(shape, size):
    """A jar's rims or a block's edges as stated: sharp (0) or 2 mm, the mesh keeps the outer size
    (to the marching-cubes cell) and its rims cut off what the radius says; not stated, the
    generator's rounding (0.3 of the inner box's smallest half-size: 3.5 mm for the jar)."""
    from reneus_mi.capture.placement import local_mesh
    cell = 2.0 * max(size) / 2 / 96
    for edge in (0.0, 2.0, None):
        mesh = local_mesh(shape, size, edge=edge)
        assert np.allclose(mesh.extents, size, atol=cell), (edge, mesh.extents)
    if shape == 'cylinder':
        # The rim's rounding leaves the top at the full radius only inside radius - edge.
        top = lambda m: np.linalg.norm(m.vertices[np.isclose(m.vertices[:, 2], -size[2], atol=0.05)][:, :2],  # noqa: E731
                                       axis=1).max()
        assert top(local_mesh(shape, size, edge=0.0)) > 20.0 - cell
        assert abs(top(local_mesh(shape, size, edge=2.0)) - 18.0) < 1.5 * cell
        assert abs(top(local_mesh(shape, size)) - (20.0 - 0.3 * 15.0 / 1.3)) < 1.5 * cell


def test_edge_radius_of_a_box_or_past_half_a_side_is_refused():
    from reneus_mi.capture.settings import CaptureSettings
    from reneus_mi.utils.errors import ReneusError
    given = dict(squares=(10, 7), square_mm=24.0, marker_mm=18.0, size_mm=(40.0, 30.0, 22.0), ior=1.45)
    with pytest.raises(ReneusError, match=r'edge_mm=1 for a box; expected --container rounded'):
        CaptureSettings(container='box', edge_mm=1.0, **given).check('capture.json')
    with pytest.raises(ReneusError, match=r'edge_mm=-1; expected a radius >= 0'):
        CaptureSettings(container='cylinder', edge_mm=-1.0, **given).check('capture.json')
    with pytest.raises(ReneusError, match=r'edge_mm=11 and size_mm=40x30x22 contradict .* below half the smallest side'):
        CaptureSettings(container='rounded', edge_mm=11.0, **given).check('capture.json')
