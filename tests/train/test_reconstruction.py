"""End to end: photographs of a statuette in a glass block → mesh.

The data come from Mitsuba's own path tracer (reneus_mi.synth), never from
the model being fitted: 16 views at 32x32 of a textureless statuette in a
solid glass block (IOR 1.45) in ambient light 0.8. The same short
reconstruction runs with the paper's renderer (``reneus``) and with plain
NeuS, which ignores the glass; the meshes are compared with the ground truth
by Chamfer-L1 x100 (the paper's metric and post-processing).
"""

import pytest

from reneus_mi.train import runs
from reneus_mi.config import replace
from reneus_mi.data import load_dataset
from reneus_mi.geometry.chamfer import chamfer
from reneus_mi.geometry.mesh import load_mesh
from reneus_mi.train.runs import spec_of_scene
from reneus_mi.data.scene_xml import write_scene
from reneus_mi.data.synth import make_dataset

ITERATIONS = 200


@pytest.fixture(scope='module')
def data(tmp_path_factory):
    folder = tmp_path_factory.mktemp('statuette')
    make_dataset('statuette', str(folder), views=16, res=32, spp=256, subsets=('box',))
    return folder


def reconstruct(folder, mode, iterations, preset='small'):
    ds = load_dataset(str(folder / 'box'))
    xml = str(folder / f'scene_{preset}_{mode}.xml')
    write_scene(ds, xml, preset=preset, mode=mode)
    spec = spec_of_scene(xml, None)
    spec.config = replace(spec.config, **{'train.iterations': iterations, 'train.validate_every': 0,
                                          'train.checkpoint_every': 0, 'train.mesh_resolution': 96})
    trainer = runs.make_trainer(spec, str(folder / f'run_{preset}_{mode}'))
    gt = load_mesh(ds.gt_mesh)
    initial = chamfer(trainer.write_mesh(str(folder / f'initial_{preset}_{mode}.ply'), resolution=96), gt)
    result = trainer.run(progress=False)
    final = chamfer(load_mesh(result['mesh']), gt)
    return initial['chamfer'], final['chamfer'], result['psnr']


@pytest.mark.slow
def test_reneus_reconstructs_and_explains_the_photographs_neus_cannot(data):
    sphere, reneus, psnr_reneus = reconstruct(data, 'reneus', ITERATIONS)
    _, neus, psnr_neus = reconstruct(data, 'neus', ITERATIONS)
    print(f'Chamfer-L1 x100: initial sphere {sphere:.2f}, reneus {reneus:.2f}, neus {neus:.2f}; '
          f'PSNR (last 100 steps) reneus {psnr_reneus:.1f} dB, neus {psnr_neus:.1f} dB')
    assert reneus < 0.85 * sphere
    # NeuS, ignoring the glass, cannot render the photographs: measured 24.5 against 20.4 dB
    # (the vase: 20.3 against 17.9). At this size (200 steps, 16 views of 32 px) the two
    # Chamfer distances are within seed noise of each other (7.62 vs 6.89, an earlier seed
    # 7.66 vs 8.75), so their order is not asserted; docs/comparison.md compares them.
    assert psnr_reneus > psnr_neus + 2.0


@pytest.mark.slow
def test_fast_preset_reconstructs_in_a_fraction_of_the_time(data):
    """The hash-grid field on the same photographs: at least the MLP's margin over the sphere.

    Measured: 2.1 after 300 steps in 52 s, where the small NeuS field reaches 7.6 after
    200 steps in about 2 minutes.
    """
    sphere, fast, _ = reconstruct(data, 'reneus', ITERATIONS, preset='fast')
    print(f'Chamfer-L1 x100: initial sphere {sphere:.2f}, fast preset {fast:.2f}')
    assert fast < 0.5 * sphere
