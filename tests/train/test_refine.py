"""Refining the container's IOR and pose and the light with the field (beyond the paper).

Recovery runs on photographs from the path tracer (IOR 1.45, ambient 0.8):
started wrong, the run must end near the truth and mesh the object better than
the same run with the wrong value held fixed; the silhouette term; miscalibrated
data. The parts the integrator owns (light, pose, render derivatives) are
checked in ``render/test_surroundings.py``.
"""
import dataclasses
import json
import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import trimesh

from reneus_mi.data import load_dataset
from reneus_mi.data.scene_xml import write_scene
from reneus_mi.data.synthetic import make_dataset, miscalibrated
from reneus_mi.geometry.chamfer import chamfer
from reneus_mi.geometry.mesh import load_mesh
from reneus_mi.render.pose import ContainerPose
from reneus_mi import runs
from reneus_mi.train.pixel_sampler import PixelSamplerConfig
from reneus_mi.train.silhouette import SilhouetteLoss
from reneus_mi.utils.errors import ReneusError


# ------------------------------------------------------------ recovery runs
VIEWS, RES = 24, 96
#: Steps per run. The IOR's estimate follows the field's sharpness: it overshoots while the
#: field is blurred and settles as inv_s grows (300 steps ended at 1.458 to 1.463, on the edge
#: of the tolerance, 500 at 1.4604, 600 at 1.4619; 1000 steps at 1.4546 to 1.4555 in three
#: runs; learning from the uniform rays alone, StepState.refining, 1.4504). The light and the pose settle within 100 steps of starting to move (200 steps:
#: ambient 0.7972, pose errors 0.0015 / 0.0014 / 0.003 rad, half their tolerances); the light's
#: run goes on to 400 steps, for its mesh to differ from the fixed one's beyond the runs' spread
#: (200 steps: 1.540 and 1.600 fixed, 1.535 refined; 400: 1.25 fixed, 1.10 refined), and as the
#: field sharpens there it stays at 0.797 (learning from the uniform rays alone, StepState.refining;
#: from every ray it fell to 0.782). The
#: absorption, from a grey guess, settles by step 350 of 600 (0.1625, 0.358, 0.703 for the true
#: 0.15, 0.35, 0.70; 300 steps ended at 0.116, 0.301, 0.548, still on its way). The liquid's
#: IOR, from water's 1.33, is weakly seen through the jar's wall: 600 steps ended at 1.3486
#: (1.3479 in CI), 1000 at 1.3532 for the true 1.36, level from step 900, with uniform batches
#: (the turned jar: level from step 650 at 1.3518 and 1.3521 here, 1.3499 in CI; with the
#: rays jittered in their pixels 1.3521, so not the pixels' footprint; the field takes part of
#: the liquid's magnification, and the estimate ends two thirds of the way from the guess):
#: drawn half by error (train.pixels, the default since the legs came back) they weigh the badly
#: fitted pixels more and the liquid settles low (1.3411 at 1000 steps, 1.3458 at 1500; without
#: the jitter 1.3473), so its runs draw as before, uniformly, through the pixels' centres. Weighing the error-drawn rays back to the
#: uniform loss took the thin parts' gain away (Blender's ant, 4 min: recall at 0.2 mm 65 %).
#: Nor is it the liquid's own gradient: learning from the uniform rays alone (StepState.refining)
#: with the field on error-drawn ones, it ended at 1.276 (and the fixed run's mesh in fog).
ITERATIONS = {'ior': 1000, 'ambient': 400, 'pose': 200, 'absorption': 600, 'inner_ior': 1000}
#: The amber photographs' absorption per unit (the block is about 2 across: it keeps about 74 %,
#: 50 % and 25 % of red, green and blue), and the guess a run starts from.
AMBER, AMBER_GUESS = (0.15, 0.35, 0.7), (0.3, 0.3, 0.3)
#: The jar's liquid (ethanol) and the guess a run starts from (water).
LIQUID, LIQUID_GUESS = 1.36, 1.33
#: The guesses the absorption's own fit starts from: none stated, and three times the truth.
MEDIA_GUESSES = {'none': None, 'thrice': tuple(3 * a for a in AMBER)}
#: The miscalibrated container: shifted by this fraction of its size, scaled by SCALE.
OFFSET, SCALE = (0.02, -0.01, 0.005), 1.02


@pytest.fixture(scope='module')
def photographs(tmp_path_factory):
    folder = tmp_path_factory.mktemp('refine')
    make_dataset('statuette', str(folder), views=VIEWS, res=RES, spp=64, subsets=('box',))
    return folder


@pytest.fixture(scope='module')
def amber_photographs(tmp_path_factory):
    folder = tmp_path_factory.mktemp('amber')
    make_dataset('statuette', str(folder), views=VIEWS, res=RES, spp=64, subsets=('box',), absorption=AMBER)
    return folder


@pytest.fixture(scope='module')
def jar_photographs(tmp_path_factory):
    folder = tmp_path_factory.mktemp('jar')
    make_dataset('statuette', str(folder), views=VIEWS, res=RES, spp=64, subsets=('box',), container='jar',
                 liquid_ior=LIQUID)
    return folder


@pytest.fixture(scope='module')
def amber_insect(tmp_path_factory):
    folder = tmp_path_factory.mktemp('amber_insect')
    make_dataset('insect', str(folder), views=VIEWS, res=RES, spp=64, subsets=('box',), absorption=AMBER)
    return folder


#: The photographs each quantity is refined on.
PHOTOGRAPHS = {'absorption': 'amber_photographs', 'inner_ior': 'jar_photographs'}


def _reconstruct(folder, quantity: str, refine: bool) -> tuple[float, dict, str]:
    ds = load_dataset(str(folder / 'box'))
    settings = {}
    if quantity == 'ior':
        ds = miscalibrated(ds, str(folder), ior=1.40)
    elif quantity == 'absorption':
        ds = miscalibrated(ds, str(folder), absorption=AMBER_GUESS)
    elif quantity == 'inner_ior':
        ds = miscalibrated(ds, str(folder), inner_ior=LIQUID_GUESS)
    elif quantity == 'ambient':
        settings['ambient'] = 0.7
    else:
        ds = miscalibrated(ds, str(folder), offset=OFFSET, scale=SCALE)
    xml = str(folder / f'scene_{quantity}.xml')
    write_scene(ds, xml, preset='fast', **settings)
    train = {'iterations': ITERATIONS[quantity], 'batch_rays': 512, 'validate_every': 0,
             'checkpoint_every': 0, 'mesh_resolution': 128, 'log_every': 50}
    if refine:
        train.update({'ior': {'refine.ior': True}, 'ambient': {'refine.light': 'ambient'},
                      'pose': {'refine.pose': True}, 'absorption': {'refine.absorption': True},
                      'inner_ior': {'refine.inner_ior': True}}[quantity])
    if quantity == 'absorption':
        # The field's own refinement, from a grey guess (the fit before it, from none:
        # test_the_absorption_is_measured_before_the_field; with it this run ended 0.174, 0.368,
        # 0.711: it starts where the photographs' noise puts that fit, 10 % high).
        train['refine.media_steps'] = 0
    if quantity == 'inner_ior':
        # Both runs, as before the error-driven batches (see ITERATIONS).
        train['pixels'] = PixelSamplerConfig(jitter=False, error_share=0.0)
    out = str(folder / f'run_{quantity}_{"refined" if refine else "fixed"}')
    result = runs.prepare(out, xml, str(folder / 'box'), train=train).train(progress=False)
    gt = load_mesh(load_dataset(str(folder / 'box')).gt_mesh)
    return chamfer(load_mesh(result['mesh']), gt)['chamfer'], result, out


def _pose_errors(values: dict, truth_container: str) -> tuple[float, float, float]:
    """(shift error / container size, largest scale error, rotation angle) of a refined pose.

    The container was moved by ``OFFSET`` x size and scaled by ``SCALE`` about its centre, and
    the pose's pivot is the moved container's centre: the truth is a shift of -OFFSET x size,
    a scale of 1/SCALE and no rotation."""
    size = trimesh.load(truth_container).extents.max()
    shift = np.array(values['container.translation']) + np.array(OFFSET) * size
    scale = np.array(values['container.scale']) * SCALE - 1.0
    return (float(np.linalg.norm(shift) / size), float(np.abs(scale).max()),
            float(np.linalg.norm(values['container.rotation'])))


@pytest.mark.slow
@pytest.mark.parametrize('quantity', ['ior', 'ambient', 'pose', 'absorption', 'inner_ior'])
def test_refining_recovers_the_truth_and_the_shape(quantity, request):
    photographs = request.getfixturevalue(PHOTOGRAPHS.get(quantity, 'photographs'))
    if quantity == 'pose':
        # On two threads the order of float sums varies, and over 200 steps it can carry the
        # pose's estimate (y scale 0.0044, rotation 0.0059 rad in one suite run; 0.0007-0.0012
        # and 0.003 in five others): one thread makes the run the same every time.
        request.getfixturevalue('one_thread')
    fixed, _, _ = _reconstruct(photographs, quantity, refine=False)
    refined, result, out = _reconstruct(photographs, quantity, refine=True)
    values = result['refined']
    print(f'{quantity}: Chamfer-L1 x100 fixed {fixed:.3f}, refined {refined:.3f}; {values}')
    with open(os.path.join(out, 'log.jsonl')) as f:
        assert set(values) <= set(json.loads(f.readline()))   # logged along the way
    if quantity == 'ior':
        assert abs(values['container.eta'] - 1.45) < 0.01
    elif quantity == 'ambient':
        assert np.abs(np.array(values['light.radiance']) - 0.8).max() < 0.01
    elif quantity == 'absorption':
        assert np.abs(np.array(values['container.sigma_a']) - AMBER).max() < 0.03
    elif quantity == 'inner_ior':
        assert abs(values['container.inner_ior'][-1] - LIQUID) < 0.5 * abs(LIQUID_GUESS - LIQUID)
    else:
        shift, scale, angle = _pose_errors(values, str(photographs / 'box.ply'))
        print(f'pose errors: shift {shift:.4f} of the size, scale {scale:.4f}, rotation {angle:.4f} rad')
        # From a 2.3 % shift and a 2 % scale error (measured at 96 px: 0.07 % and 0.14 %; at
        # 64 px the masks' pixels limit the silhouette term to about 0.25 %).
        assert shift < 0.003 and scale < 0.003 and angle < 0.01
    assert refined < fixed


@pytest.mark.parametrize('guess', MEDIA_GUESSES)
def test_the_absorption_is_measured_before_the_field(amber_insect, guess):
    """From no absorption stated, or from one three times too high, the fit before the field's
    first step (train.refine.media_steps) finds amber's within 50 % a channel, where held off it
    stays at the guess (0: -100 %). These photographs are path-traced, each path absorbed or
    not, and the fit lands high: 39, 18, 10 % (from none) and 28, 18, 7 % (from 3x), not yet
    explained. Cycles' denoised amber ant: within 4 % (docs/containers.md)."""
    ds = load_dataset(str(amber_insect / 'box'))
    ds = (dataclasses.replace(ds, absorption=None) if MEDIA_GUESSES[guess] is None
          else miscalibrated(ds, str(amber_insect), absorption=MEDIA_GUESSES[guess]))
    xml = str(amber_insect / f'scene_{guess}.xml')
    write_scene(ds, xml, preset='fast')
    trainer = runs.prepare(str(amber_insect / f'run_{guess}'), xml, str(amber_insect / 'box'),
                           train={'refine.absorption': True}).trainer()
    trainer.fit_media()
    found = np.array(trainer.refined_values()['container.sigma_a'])
    print(f'from {guess}: {found} for {AMBER}')
    assert np.all(np.abs(found / AMBER - 1.0) < 0.5)


def test_silhouette_is_least_at_the_true_pose(photographs):
    ds = load_dataset(str(photographs / 'box'))
    assert ds.masks_measured
    truth = trimesh.load(ds.container, process=False)
    pose = ContainerPose(truth.bounds.mean(axis=0))
    loss = SilhouetteLoss(ds, truth)
    at_truth = float(loss(0, pose)[0])
    pose.translation = mi.Float(0.03, 0.0, 0.0)
    dr.enable_grad(pose.translation)
    moved = loss(0, pose)
    dr.backward(moved)
    assert at_truth < 0.5 < float(moved[0])        # pixels
    assert dr.grad(pose.translation)[0] > 0.0      # descending moves it back


def test_miscalibrated_leaves_the_dataset_alone(photographs):
    ds = load_dataset(str(photographs / 'box'))
    before = sorted(os.listdir(ds.root))
    with pytest.raises(ReneusError, match='miscalibrated container .*box'):
        miscalibrated(ds, ds.root, offset=OFFSET)
    assert sorted(os.listdir(ds.root)) == before
