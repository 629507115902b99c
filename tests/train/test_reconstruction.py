"""End to end: photographs of a statuette in a glass block → mesh.

The data come from Mitsuba's own path tracer (reneus_mi.synth), never from
the model being fitted: 16 views at 32x32 of a textureless statuette in a
solid glass block (IOR 1.45) in ambient light 0.8. The same short
reconstruction runs with the paper's renderer (``reneus``) and with plain
NeuS, which ignores the glass; the meshes are compared with the ground truth
by Chamfer-L1 x100 (the paper's metric and post-processing).
"""

import pytest

from reneus_mi.data import load_dataset
from reneus_mi.data.scene_xml import write_scene
from reneus_mi.data.synthetic import make_dataset
from reneus_mi.geometry.chamfer import chamfer
from reneus_mi.geometry.mesh import load_mesh
from reneus_mi import runs

ITERATIONS = 200


@pytest.fixture(scope='module')
def data(tmp_path_factory):
    folder = tmp_path_factory.mktemp('statuette')
    make_dataset('statuette', str(folder), views=16, res=32, spp=256, subsets=('box',))
    return folder


def reconstruct(folder, mode, iterations, preset):
    ds = load_dataset(str(folder / 'box'))
    xml = str(folder / f'scene_{preset}_{mode}.xml')
    write_scene(ds, xml, preset=preset, mode=mode)
    trainer = runs.prepare(str(folder / f'run_{preset}_{mode}'), xml,
                           train={'iterations': iterations, 'validate_every': 0, 'checkpoint_every': 0,
                                  'mesh_resolution': 96}).trainer()
    gt = load_mesh(ds.gt_mesh)
    initial = chamfer(trainer.write_mesh(str(folder / f'initial_{preset}_{mode}.ply'), resolution=96), gt)
    result = trainer.run(progress=False)
    final = chamfer(load_mesh(result['mesh']), gt)
    return initial['chamfer'], final['chamfer'], result['psnr']


@pytest.fixture(scope='module')
def fast_reneus(data):
    """The fast preset's reconstruction through the glass (shared by the tests below)."""
    return reconstruct(data, 'reneus', ITERATIONS, preset='fast')


@pytest.mark.slow
def test_reneus_reconstructs_and_explains_the_photographs_neus_cannot(data, fast_reneus):
    """The same field and steps with plain NeuS, which ignores the glass. Measured: PSNR 29.3
    against 24.0 dB; Chamfer-L1 x100 1.95 against 3.57 from a sphere at 12.7. (The paper's MLP
    field, the `small` preset, took 7 minutes of the suite for the same claim; the fields'
    own tests and bench/compare.py's table cover it.)"""
    sphere, reneus, psnr_reneus = fast_reneus
    _, neus, psnr_neus = reconstruct(data, 'neus', ITERATIONS, preset='fast')
    print(f'Chamfer-L1 x100: initial sphere {sphere:.2f}, reneus {reneus:.2f}, neus {neus:.2f}; '
          f'PSNR (last 100 steps) reneus {psnr_reneus:.1f} dB, neus {psnr_neus:.1f} dB')
    # At this size (200 steps, 16 views of 32 px) the Chamfer order is close to seed noise
    # (the MLP field: 7.62 vs 6.89, another seed 7.66 vs 8.75), so only the photographs decide.
    assert psnr_reneus > psnr_neus + 2.0


@pytest.mark.slow
def test_fast_preset_reconstructs_in_a_fraction_of_the_time(fast_reneus):
    """The hash-grid field through the glass: at least half of the way from the sphere.

    Measured: 1.95 from 12.7 after 200 steps, in about a minute.
    """
    sphere, fast, _ = fast_reneus
    print(f'Chamfer-L1 x100: initial sphere {sphere:.2f}, fast preset {fast:.2f}')
    assert fast < 0.5 * sphere
