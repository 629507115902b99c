"""Scene writer: Mitsuba parses the XML, and its sensor casts the dataset's rays."""
import dataclasses
import os
import xml.etree.ElementTree as ET

import mitsuba as mi
import numpy as np
import pytest
import trimesh

from reneus_mi.data import Dataset, write_dataset
from reneus_mi.data.cameras import intrinsics, look_at
from reneus_mi.data.masks import container_masks
from reneus_mi.data.scene_xml import sensor_dict, write_scene
from reneus_mi.geometry.container import medium_absorption
from reneus_mi.scene import main

H, W = 12, 16


def make_dataset(folder, ior=1.5) -> Dataset:
    """One view of a box container; off-centre principal point to test the sensor offsets."""
    mesh = os.path.join(folder, 'meshes', 'box.ply')
    os.makedirs(os.path.dirname(mesh), exist_ok=True)
    trimesh.creation.box(extents=(1.0, 0.8, 0.6)).apply_translation((0.2, -0.1, 0.05)).export(mesh)
    K = intrinsics(15.0, 15.0, 9.25, 4.5)[None]
    c2w = look_at((2.5, -1.5, 1.2), target=(0.1, 0.0, 0.1))[None]
    # The loader checks masks against the container's projection.
    return Dataset(images=np.full((1, H, W, 3), 0.5, np.float32),
                   masks=container_masks(mesh, K, c2w, H, W), K=K, c2w=c2w,
                   names=['a.png'], root=str(folder), container=mesh, ior=ior)


def test_path_scene_loads_and_renders(tmp_path):
    ds = make_dataset(tmp_path)
    xml = tmp_path / 'scenes' / 'scene.xml'
    os.makedirs(xml.parent)
    write_scene(ds, str(xml), integrator='path', max_depth=6)
    root = ET.parse(xml).getroot()
    assert root.get('version') == '3.0.0'
    assert root.find('shape/string').get('value') == os.path.join('..', 'meshes', 'box.ply')
    assert [(e.tag, e.get('name')) for e in root.find('integrator')] == [('integer', 'max_depth')]

    scene = mi.load_file(str(xml))
    params = mi.traverse(scene)
    assert params['container.bsdf.eta'] == pytest.approx(1.5)
    sensor = scene.sensors()[0]
    assert tuple(sensor.film().size()) == (W, H)

    # Pixel-centre rays of the sensor (and of sensor_dict's) are the dataset's rays.
    ys, xs = np.mgrid[:H, :W]
    px = np.stack([xs.ravel(), ys.ravel()], axis=1)
    pos = mi.Point2f(mi.Float((px[:, 0] + 0.5) / W), mi.Float((px[:, 1] + 0.5) / H))
    o, d = ds.rays(0, px)
    for cam in (sensor, mi.load_dict(sensor_dict(ds.K[0], ds.c2w[0], W, H))):
        ray, _ = cam.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
        assert np.abs(np.array(ray.d).T - d).max() < 1e-5
        # Mitsuba starts rays on the near-clip plane: the origin moves along the ray.
        offset = np.array(ray.o).T - o
        assert np.linalg.norm(np.cross(offset, d), axis=1).max() < 1e-5
        assert np.all(np.einsum('ij,ij->i', offset, d) < 0.1)

    # A dielectric in a uniform environment conserves energy: the image is the ambient 0.8.
    image = np.array(mi.render(scene, spp=32, seed=0))
    assert image.shape == (H, W, 3)
    assert abs(image.mean() - 0.8) < 0.02


def test_reneus_integrator_properties(tmp_path):
    ds = make_dataset(tmp_path, ior=None)
    xml = tmp_path / 'scene.xml'
    with pytest.warns(UserWarning, match="states no container IOR; using 1.45"):
        write_scene(ds, str(xml), max_depth=3, upsample_s=64.0, aovs=True, field='neus')
    root = ET.parse(xml).getroot()
    assert root.find('shape/bsdf/float[@name="int_ior"]').get('value') == '1.45'
    integ = root.find('integrator')
    assert integ.get('type') == 'reneus' and integ.get('id') == 'field'
    props = {e.get('name'): (e.tag, e.attrib) for e in integ}
    assert props['dataset'][1]['value'] == str(tmp_path)
    centre, radius = ds.normalization()
    assert np.allclose([float(props['field_center'][1][a]) for a in 'xyz'], centre)
    assert np.allclose(centre, (0.2, -0.1, 0.05))
    assert float(props['field_scale'][1]['value']) == pytest.approx(radius)
    assert [props[k][0] for k in ('max_depth', 'upsample_s', 'aovs', 'field')] == [
        'integer', 'float', 'boolean', 'string']
    assert props['aovs'][1]['value'] == 'true'


def test_bad_settings_write_nothing(tmp_path):
    ds = make_dataset(tmp_path)
    xml = tmp_path / 'scene.xml'
    with pytest.raises(ValueError, match=r"integrator setting spp=\[1\]: expected a bool"):
        write_scene(ds, str(xml), spp=[1])
    with pytest.raises(ValueError, match=r"integrator settings \['field_scale'\]: set by "
                                         "write_scene"):
        write_scene(ds, str(xml), field_scale=2.0)
    assert not xml.exists()


def test_scene_without_container(tmp_path):
    """The paper's w/o box data: no shape, and no complaint about the IOR."""
    ds = make_dataset(tmp_path)
    no_box = Dataset(**{**vars(ds), 'container': None, 'ior': None, 'scale_mat': np.eye(4)})
    xml = tmp_path / 'scene.xml'
    write_scene(no_box, str(xml), integrator='path')
    scene = mi.load_file(str(xml))
    assert len(scene.shapes()) == 0
    assert np.allclose(np.array(mi.render(scene, spp=1)), 0.8)


def test_cli_without_container_writes_a_neus_scene(tmp_path, capsys):
    # The README's path on "w/o box" data: plain NeuS, which optimize accepts without a
    # container; asking for the ray tree through a container the data lacks is refused.
    ds = make_dataset(tmp_path / 'src')
    no_box = Dataset(**{**vars(ds), 'container': None, 'ior': None, 'scale_mat': np.eye(4)})
    write_dataset(no_box, str(tmp_path / 'data'), 'neus')
    xml = tmp_path / 'scene.xml'
    main([str(tmp_path / 'data'), '-o', str(xml), '--preset', 'tiny'])
    # A warning as the commands print them: one line, no source file and line.
    (warning,) = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert warning.startswith('warning: ') and 'renders plain NeuS' in warning and '.py:' not in warning
    assert mi.load_file(str(xml)).integrator().model.render.mode == 'neus'
    with pytest.raises(SystemExit) as exit_info:
        main([str(tmp_path / 'data'), '-o', str(tmp_path / 'bad.xml'), '--set', 'model.render.mode=reneus'])
    assert "no container mesh (no 'mesh_outside')" in str(exit_info.value.code)
    assert not (tmp_path / 'bad.xml').exists()


def test_cli(tmp_path, capsys):
    ds = make_dataset(tmp_path / 'src')
    write_dataset(ds, str(tmp_path / 'data'), 'neus')
    xml = tmp_path / 'scene.xml'
    main([str(tmp_path / 'data'), '-o', str(xml), '--integrator', 'path',
          '--set', 'max_depth=5', '--set', 'hide_emitters=true'])
    integ = ET.parse(xml).getroot().find('integrator')
    assert [(e.tag, e.get('value')) for e in integ] == [('integer', '5'), ('boolean', 'true')]
    assert tuple(mi.load_file(str(xml)).sensors()[0].film().size()) == (W, H)

    # The reneus integrator's settings, by their dotted paths, typed as its configuration
    # declares them, written under their XML names.
    reneus = tmp_path / 'reneus.xml'
    main([str(tmp_path / 'data'), '-o', str(reneus), '--preset', 'cpu', '--set', 'model.render.max_depth=3',
          '--set', 'model.sampler.upsample_s=32', '--set', 'model.field.hidden=48',
          '--set', 'model.render.terminal=black'])
    integ = ET.parse(reneus).getroot().find('integrator')
    props = {e.get('name'): (e.tag, e.get('value')) for e in integ}
    assert props['preset'] == ('string', 'cpu') and props['max_depth'] == ('integer', '3')
    assert props['upsample_s'] == ('float', '32.0') and props['field_hidden'] == ('integer', '48')
    assert props['terminal'] == ('string', 'black')
    assert mi.load_file(str(reneus)).integrator().model.render.max_depth == 3
    # Another field kind, then a setting of its own.
    grid = tmp_path / 'grid.xml'
    main([str(tmp_path / 'data'), '-o', str(grid), '--preset', 'cpu', '--set', 'model.field=hashgrid',
          '--set', 'model.field.n_levels=4'])
    assert mi.load_file(str(grid)).integrator().model.field.n_levels == 4
    for bad, message in (('model.sampler.n_coarse=many', "model.sampler.n_coarse='many': expected an integer"),
                         ('model.render.max_detph=3', 'model.render.max_detph: not a setting'),
                         ('model.render.max_depth=-1', 'max_depth=-1; expected an integer >= 0'),
                         ('model.field=nerf', "model.field.kind='nerf': unknown field kind"),
                         ('train.iterations=5', 'train.iterations: not a setting of the reneus integrator')):
        with pytest.raises(SystemExit) as exit_info:
            main([str(tmp_path / 'data'), '-o', str(tmp_path / 'bad.xml'), '--set', bad])
        assert message in str(exit_info.value.code)
        assert not (tmp_path / 'bad.xml').exists()

    with pytest.raises(SystemExit) as exit_info:
        main([str(tmp_path / 'absent'), '-o', str(tmp_path / 'other.xml')])
    assert str(exit_info.value.code).startswith('error: ') and 'dataset folder is missing' in str(exit_info.value.code)
    assert not (tmp_path / 'other.xml').exists()


@pytest.mark.parametrize('kind', ['quads.ply', 'stl', 'off'])
def test_container_mitsuba_cannot_read_gets_a_triangulated_copy(tmp_path, kind):
    # Blender writes PLY quads, which Mitsuba's PLY reader refuses, and CAD tools STL or OFF,
    # which it has no reader for: the scene names a triangle PLY beside itself, the same
    # surface, and leaves the dataset alone.
    blender = os.path.join(os.path.dirname(__file__), '..', 'fixtures', 'containers', 'blender_cube.ply')
    ds = make_dataset(tmp_path / 'data')
    if kind == 'quads.ply':
        with open(blender, 'rb') as src, open(ds.container, 'wb') as dst:
            dst.write(src.read())
    else:
        os.remove(ds.container)
        ds.container = os.path.splitext(ds.container)[0] + '.' + kind
        trimesh.load(blender).export(ds.container)
    ds.masks = container_masks(ds.container, ds.K, ds.c2w, H, W)
    before = sorted(os.listdir(tmp_path / 'data' / 'meshes'))
    xml = tmp_path / 'scene.xml'
    write_scene(ds, str(xml), integrator='path')
    copy = tmp_path / 'scene_container.ply'
    assert ET.parse(xml).getroot().find('shape/string').get('value') == 'scene_container.ply'
    assert sorted(os.listdir(tmp_path / 'data' / 'meshes')) == before
    loaded = mi.load_file(str(xml)).shapes()[0]
    assert loaded.face_count() == 12
    assert np.allclose(np.array(loaded.bbox().max), [0.55, 0.45, 0.5])
    # A second write refuses to replace the copy unless asked.
    with pytest.raises(Exception, match='exists'):
        write_scene(ds, str(tmp_path / 'scene.xml'), integrator='path')
    write_scene(ds, str(xml), integrator='path', overwrite=True)
    assert copy.is_file()


def test_absorbing_container_is_written_as_its_interior_medium(tmp_path):
    # The scene gives Mitsuba the medium volpath renders, and the integrator reads it back.
    ds = dataclasses.replace(make_dataset(tmp_path), absorption=np.array([0.05, 0.2, 1.7]))
    xml = str(tmp_path / 'scene.xml')
    write_scene(ds, xml)
    scene = mi.load_file(xml)
    container = [s for s in scene.shapes() if s.id() == 'container'][0]
    assert container.interior_medium().class_name() == 'HomogeneousMedium'
    assert np.allclose(medium_absorption(container), [0.05, 0.2, 1.7], rtol=1e-6)
    clear = str(tmp_path / 'clear.xml')
    write_scene(dataclasses.replace(ds, absorption=None), clear)
    assert medium_absorption([s for s in mi.load_file(clear).shapes() if s.id() == 'container'][0]) is None


def test_hollow_container_gets_one_more_interface_event(tmp_path):
    """A case's (or a jar's) scene follows one interface event more than a block's: the
    specimen's reflection in the far inner wall (scene_xml.hollow_depth); --set keeps its own."""
    from reneus_mi.data.dataset import Interface
    ds = make_dataset(tmp_path)
    cavity = str(tmp_path / 'meshes' / 'cavity.ply')
    trimesh.creation.box(extents=(0.8, 0.6, 0.4)).apply_translation((0.2, -0.1, 0.05)).export(cavity)
    hollow = dataclasses.replace(ds, inner=(Interface(cavity, 1.0),))

    def depth(xml):
        found = ET.parse(xml).getroot().find("integrator/integer[@name='max_depth']")
        return None if found is None else int(found.get('value'))
    for name, data, settings, expected in (('block', ds, {}, None), ('case', hollow, {}, 3),
                                           ('given', hollow, {'max_depth': 2}, 2)):
        xml = str(tmp_path / f'{name}.xml')
        write_scene(data, xml, **settings)
        assert depth(xml) == expected, name
    assert mi.load_file(str(tmp_path / 'case.xml')).integrator().model.render.max_depth == 3
