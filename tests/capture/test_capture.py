"""From photographs with no poses to a dataset (issue #16): calibration, undistortion, the
container found, exposure and light, against the simulated capture's ground truth."""
from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest

from capture_data import path_render
from reneus_mi.capture import __main__ as capture_command, pipeline, settings
from reneus_mi.capture.crops import CROP_MARGIN
from reneus_mi.capture.simulation import Rig, distort_image
from reneus_mi.data import load_dataset
from reneus_mi.data.undistort import undistort


@pytest.fixture(scope='module')
def shot(simulated_capture):
    return simulated_capture


@pytest.fixture(scope='module')
def made(shot, tmp_path_factory):
    """The capture command run on the photographs alone (the settings from capture.json)."""
    out = tmp_path_factory.mktemp('capture') / 'dataset'
    assert capture_command.main([shot['photos'], '-o', str(out), '--quiet']) == 0
    with open(out / 'report.json') as f:
        return {'out': out, 'report': json.load(f)}


def _angle(R) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def test_calibration_against_the_truth(shot, made):
    truth, report = shot['meta'], made['report']
    K, K_est = np.array(truth['K']), np.array(report['camera']['K_photo'])
    for i, j in ((0, 0), (1, 1), (0, 2), (1, 2)):
        assert abs(K_est[i, j] / K[i, j] - 1.0) < 0.005, (i, j, K_est[i, j], K[i, j])
    cameras = {v['name']: np.array(v['c2w']) for v in truth['views']}
    assert len(report['views']) == len(cameras) and not report['left_out']
    for view in report['views']:
        T, C = cameras[view['photo']], np.array(view['c2w'])
        assert _angle(T[:3, :3].T @ C[:3, :3]) < 0.1, view['photo']
        assert np.linalg.norm(T[:3, 3] - C[:3, 3]) < 0.5, view['photo']
        assert view['rms_px'] < 0.3 and view['corners_used'] >= 30


def test_container_found_on_the_board(shot, made):
    x, y, yaw = made['report']['container']['pose']
    tx, ty, tyaw = shot['meta']['container']['pose']
    assert np.hypot(x - tx, y - ty) < 0.5
    assert abs((yaw - tyaw + 90.0) % 180.0 - 90.0) < 0.5
    assert made['report']['container']['residual_px'] < 3.0
    # Sharp, as stated: no rounding read into its outline (test_rounded_block.py).
    assert not made['report']['container']['edge_measured']


def test_uncertainty_and_coverage_reported(shot, made):
    """The solve's standard deviations bound the errors against the truth; the board covered
    the middle of the frame, where the fitted lens and the truth part (measured: 52 % of the
    frame, up to 7 px off in the corners, as the report says)."""
    truth, report = shot['meta'], made['report']
    camera = report['camera']
    K, K_est = np.array(truth['K']), np.array(camera['K_photo'])
    sd = camera['K_photo_std_px']
    assert 0 < sd['f'] < 2.0 and 0 < sd['cx'] < 1.0 and 0 < sd['cy'] < 1.0, sd
    # The truth within four standard deviations of the estimate.
    assert abs(K_est[0, 0] - K[0, 0]) < 4 * sd['f'] + 0.05, (K_est[0, 0], K[0, 0], sd)
    assert abs(K_est[0, 2] - K[0, 2]) < 4 * sd['cx'] and abs(K_est[1, 2] - K[1, 2]) < 4 * sd['cy'], (K_est, K, sd)
    for view in report['views']:
        assert 0 < view['rotation_std_deg'] < 0.2 and 0 < view['translation_std_mm'] < 1.0, view
    cover = camera['coverage']
    assert 0.3 < cover['share'] < 0.8
    # What the fitted lens gets wrong in the corners, against the truth, is of the size reported.
    from reneus_mi.capture.calibrate import _rays
    corners = np.array([[0.5, 0.5], [K[0, 2] * 2 - 0.5, 0.5], [0.5, K[1, 2] * 2 - 0.5], K[:2, 2] * 2 - 0.5])
    centre = K[:2, 2][None]
    dist = np.array(list(camera['distortion'].values()))

    def error(p):
        return K[0, 0] * (_rays(K, np.array(truth['distortion']), p) - _rays(K_est, dist, p))
    worst = np.linalg.norm(error(corners) - error(centre), axis=1).max()
    assert 0.5 * worst < cover['extrapolated_px'] < 2.0 * worst, (worst, cover['extrapolated_px'])


@pytest.fixture(scope='module')
def cropped(shot, tmp_path_factory):
    """The capture command with --crop-to-coverage."""
    out = tmp_path_factory.mktemp('capture_cropped') / 'dataset'
    assert capture_command.main([shot['photos'], '-o', str(out), '--quiet', '--crop-to-coverage']) == 0
    with open(out / 'report.json') as f:
        return {'out': out, 'report': json.load(f)}


def test_crop_to_coverage_keeps_what_the_board_covered(cropped):
    """Every pixel of the cropped images was seen, through the lens, where the board's corners
    were: the lens model is measured there, not extrapolated."""
    from reneus_mi.data.undistort import opencv_K
    camera = cropped['report']['camera']
    x0, y0, w, h = camera['coverage']['crop_px']
    assert camera['size'] == [w, h] and 0.3 * 640 < w < 640 and abs(w / h - 640 / 480) < 0.02
    K = np.array(camera['K'])
    edge = np.linspace(0.0, 1.0, 9)
    border = np.concatenate([np.c_[edge * w, np.zeros(9)], np.c_[edge * w, np.full(9, h)],
                             np.c_[np.zeros(9), edge * h], np.c_[np.full(9, w), edge * h]])
    rays = np.c_[(border - K[:2, 2]) / K[0, 0], np.ones(len(border))]
    seen, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                opencv_K(np.array(camera['K_photo'])), np.array(list(camera['distortion'].values())))
    hull = np.array(camera['coverage']['hull_px'], np.float32)
    inside = [cv2.pointPolygonTest(hull, (float(x) + 0.5, float(y) + 0.5), True) for x, y in seen.reshape(-1, 2)]
    assert min(inside) > -1.0, min(inside)
    windows = [view['window_px'] for view in cropped['report']['views']]
    for x0, y0, ww, hh in windows:
        assert 0 <= x0 and x0 + ww <= w and 0 <= y0 and y0 + hh <= h, (x0, y0, ww, hh, w, h)
    assert load_dataset(str(cropped['out'])).images.shape[1:3] == (hh, ww)


def test_views_are_windows_around_the_container(made):
    """The dataset keeps of each view a window of one size about the container's projection,
    with room around it, its intrinsics the frame's moved by the window's corner."""
    report, ds = made['report'], load_dataset(str(made['out']))
    w, h = report['camera']['size']
    K = np.array(report['camera']['K'])
    ww, hh = ds.width, ds.height
    assert ww * hh < 0.5 * w * h                      # the block is a small part of the frame
    for v, view in enumerate(report['views']):
        x0, y0, *size = view['window_px']
        assert size == [ww, hh]
        assert np.allclose(ds.K[v], K - np.array([[0, 0, x0], [0, 0, y0], [0, 0, 0]]))
        ys, xs = np.nonzero(ds.masks[v])
        # The container's projection inside, with at least half the margin on every side
        # where the frame allows it.
        room = 0.5 * CROP_MARGIN * max(np.ptp(xs), np.ptp(ys))
        assert xs.min() >= min(room, x0 + xs.min()) - 1 and ww - 1 - xs.max() >= min(room, w - x0 - 1 - xs.max()) - 1
        assert ys.min() >= min(room, y0 + ys.min()) - 1 and hh - 1 - ys.max() >= min(room, h - y0 - 1 - ys.max()) - 1


def test_windows_from_the_photographs_when_the_work_is_smaller(shot, made, tmp_path, monkeypatch):
    """Where the capture works on reduced copies, the windows are undistorted from the
    photographs decoded again: the same pixels as when it works at full size."""
    monkeypatch.setattr(pipeline, 'WORK_MAX_SIZE', 480)
    out = tmp_path / 'dataset'
    assert capture_command.main([shot['photos'], '-o', str(out), '--quiet']) == 0
    with open(out / 'report.json') as f:
        report = json.load(f)
    full, small = load_dataset(str(made['out'])), load_dataset(str(out))
    assert report['camera']['size'] == made['report']['camera']['size']
    assert (small.width, small.height) == pytest.approx((full.width, full.height), abs=6)
    for v in (0, 5, 11):
        (a, b), (c, d) = made['report']['views'][v]['window_px'][:2], report['views'][v]['window_px'][:2]
        x0, y0 = max(a, c), max(b, d)
        x1 = min(a + full.width, c + small.width)
        y1 = min(b + full.height, d + small.height)
        one = full.image(v)[y0 - b:y1 - b, x0 - a:x1 - a]
        other = small.image(v)[y0 - d:y1 - d, x0 - c:x1 - c]
        assert one.shape[0] > 0.8 * full.height
        # Exposure gains measured on the reduced copies differ by well under 1 %.
        assert np.abs(one - other).mean() < 0.004, np.abs(one - other).mean()


@pytest.mark.parametrize('which', ['made', 'cropped'])
def test_cameras_written_as_opencv_projects_them(which, shot, request):
    """transforms.json's pinhole cameras, in OpenCV's convention (cx, cy less half a pixel),
    moved back by their windows' corners, put the board's corners where the photographs
    undistorted to the report's camera show them (cropped to the coverage or not); the written
    images are those photographs' windows."""
    from reneus_mi.capture.charuco import Board
    from reneus_mi.data.cameras import OPENGL_FROM_OPENCV
    made = request.getfixturevalue(which)
    with open(made['out'] / 'transforms.json') as f:
        meta = json.load(f)
    camera = made['report']['camera']
    board = Board(12, 9, 20.0, 15.0)
    errors = []
    for frame, view in list(zip(meta['frames'], made['report']['views']))[:6]:
        x0, y0, ww, hh = view['window_px']
        photo = cv2.imread(os.path.join(shot['photos'], frame['photo']), cv2.IMREAD_GRAYSCALE)
        whole, _ = undistort(photo, np.array(camera['K_photo']), list(camera['distortion'].values()),
                             np.array(camera['K']), tuple(camera['size']))
        written = cv2.imread(str(made['out'] / frame['file_path']), cv2.IMREAD_GRAYSCALE)
        gain = view['exposure_gain'] ** (-1 / 2.2)
        inner = (slice(2, -2), slice(2, -2))
        assert np.abs(whole[y0:y0 + hh, x0:x0 + ww][inner] * gain - written[inner]).mean() < 2.0
        found = board.detect(whole)
        K = np.array([[frame['fl_x'], 0.0, frame['cx'] + x0 - 0.5], [0.0, frame['fl_y'], frame['cy'] + y0 - 0.5],
                      [0.0, 0.0, 1.0]])
        w2c = np.linalg.inv(np.array(frame['transform_matrix']) @ np.linalg.inv(OPENGL_FROM_OPENCV))
        rvec, _ = cv2.Rodrigues(w2c[:3, :3])
        px, _ = cv2.projectPoints(board.corners[found.ids], rvec, w2c[:3, 3], K, None)
        errors.append(np.linalg.norm(px.reshape(-1, 2) - (found.pixels - 0.5), axis=1))
    errors = np.concatenate(errors)
    # Half a pixel off would be the other convention.
    assert len(errors) > 100 and np.median(errors) < 0.15, (len(errors), np.median(errors))
    assert 'OpenCV puts it at (0, 0)' in made['report']['camera']['pixel_convention']


def test_exposure_and_light(shot, made):
    truth, report = shot['meta'], made['report']
    gains = np.array([{v['name']: v['gain'] for v in truth['views']}[w['photo']] for w in report['views']])
    measured = np.array([v['exposure_gain'] for v in report['views']])
    # Relative to the darkest photograph, as the command normalises.
    np.testing.assert_allclose(measured, gains / gains.min(), rtol=0.02)
    darkest = gains.min()
    np.testing.assert_allclose(report['light']['ambient'], truth['ambient'] * darkest, rtol=0.02)
    np.testing.assert_allclose(report['light']['board_white'], truth['board']['white'] * darkest, rtol=0.03)


def test_dataset_reads_back_in_millimetres(made, shot):
    ds = load_dataset(str(made['out']))
    assert len(ds) == len(shot['meta']['views'])
    np.testing.assert_allclose(ds.ambient, made['report']['light']['ambient'])
    # The container's projection is the mask; the block is 50x35x25 mm on the board.
    import trimesh
    from reneus_mi.capture.placement import pose_matrix
    block = trimesh.load(ds.container)
    block.apply_transform(np.linalg.inv(pose_matrix(made['report']['container']['pose'])))
    # The PLY holds float32: 1e-5 mm at 150 mm from the origin.
    np.testing.assert_allclose(block.extents, shot['meta']['container']['size_mm'], atol=1e-4)
    np.testing.assert_allclose(block.bounds[:, 2], [-25.0, 0.0], atol=1e-4)
    # A sharp block: no rounding measured (scene.block_settings: the margin of one too small to see).
    assert ds.edge == 0.0
    assert ds.masks.any(axis=(1, 2)).all()
    # Exposures normalised: the white print is equally bright in every image.
    assert len(os.listdir(made['out'] / 'overlays')) == len(ds)


def test_scene_board_is_the_photographed_one(made, tmp_path):
    """The board that ``python -m reneus_mi.scene`` puts under the container (from the dataset's
    pattern, geometry and measured print levels) is what the photographs show: around the
    block, and through its bottom. Measured (view 3): 0.031 around it, in the dataset's window
    (JPEG, noise, blur, the board within 15-40 px of the block; 0.017 over the whole frame), where
    the board taken as ambient light gives 0.40; in the glass a median of 0.047 (the insect, the
    path tracers' noise) against 0.24."""
    from reneus_mi import scene as scene_command
    ds = load_dataset(str(made['out']))
    view = 3
    around = cv2.dilate(ds.masks[view].astype(np.uint8), np.ones((31, 31), np.uint8)) > 0
    glass = ds.masks[view]
    error = {}
    for board in ('scene', 'ambient'):
        xml = tmp_path / f'{board}.xml'
        assert scene_command.main([str(made['out']), '-o', str(xml), '--board', board]) == 0
        assert os.path.isfile(tmp_path / f'{board}_board.exr') == (board == 'scene')
        d = np.abs(path_render(xml, ds, view) - ds.image(view)).mean(axis=-1)
        error[board] = d[~around].mean(), np.median(d[glass])
    print(error)
    assert error['scene'][0] < 0.04 and error['ambient'][0] > 5 * error['scene'][0]
    assert error['scene'][1] < 0.06 and error['ambient'][1] > 3 * error['scene'][1]


def test_the_scene_leaves_out_the_rays_by_a_rounding_too_small_to_see(made, tmp_path):
    """The capture found the block sharp, but a rounding of under UNSEEN_EDGE_PIXELS pixel
    footprints would not have shown in its outline (Blender's 0.5 mm one at 960 px did not): the
    scene leaves the rays within 1.6 such radii of the edges out of the loss."""
    from reneus_mi import scene
    from reneus_mi.render.loading import load_scene
    ds = load_dataset(str(made['out']))
    xml = str(tmp_path / 'scene.xml')
    assert scene.main([str(made['out']), '-o', xml]) == 0
    margin = load_scene(xml).integrator().model.render.edge_margin
    expected = scene.EDGE_MARGIN_RADII * scene.UNSEEN_EDGE_PIXELS * ds.pixel_footprint()
    assert margin == pytest.approx(expected, rel=1e-2)


def test_the_scene_models_a_blocks_faces_as_bulging_on_its_board(made, tmp_path):
    """A capture's solid block may bulge, and the board seen through it measures how much: the
    scene says so where the board is in it, unless --set says otherwise."""
    from reneus_mi import scene
    from reneus_mi.render.loading import load_scene
    written = {}
    for name, given in (('board', []), ('ambient', ['--board', 'ambient']),
                        ('off', ['--set', 'model.render.bow=false'])):
        xml = str(tmp_path / f'{name}.xml')
        assert scene.main([str(made['out']), '-o', xml, *given]) == 0
        written[name] = load_scene(xml).integrator().model.render.bow
    assert written == {'board': True, 'ambient': False, 'off': False}


def test_a_bulge_without_a_board_to_measure_it_is_refused(made, tmp_path):
    from reneus_mi import runs, scene
    from reneus_mi.utils.errors import ReneusError
    xml = str(tmp_path / 'scene.xml')
    assert scene.main([str(made['out']), '-o', xml, '--board', 'ambient', '--set', 'model.render.bow=true']) == 0
    trainer = runs.prepare(str(tmp_path / 'run'), xml, str(made['out'])).trainer()
    with pytest.raises(ReneusError, match=r"^model.render.bow: the scene has no board under the block, .*"
                                          r"--set model.render.bow=false$"):
        trainer.fit_media()


def test_a_flat_block_is_found_flat(made, tmp_path):
    """The search for bowed faces (test_bowed_block.py) finds the flat block flat."""
    from test_bowed_block import TOLERANCE_MM, found_bows
    bows, _ = found_bows(made['out'], tmp_path)
    print(bows)
    assert np.abs(bows).max() < TOLERANCE_MM, bows


#: The README's path from the capture's dataset to a mesh, trained to the end of its budget:
#: ``scene`` (the fast preset), ``optimize --iterations BUDGET_STEPS`` (the whole schedule laid
#: over that many steps, as ``--max-minutes`` lays it over minutes, but the same work on any
#: machine). The tests' capture is a large insect (26 mm) in a 50 mm block at 640x480, 16 views.
BUDGET_STEPS = 600
#: Largest Chamfer-L1 (mm) the run may end at: measured 1.17 mm in one piece (the old 150-step
#: run against the initial sphere: 2.52 against 3.54 mm).
CHAMFER_MM = 1.6


@pytest.fixture(scope='module')
def reconstructed(shot, made, tmp_path_factory):
    """The run's result and its mesh against the simulated specimen, in millimetres (Chamfer-L1:
    the mean of accuracy and completeness)."""
    from reneus_mi import optimize, scene
    from reneus_mi.geometry.chamfer import chamfer
    from reneus_mi.geometry.mesh import load_mesh
    from reneus_mi.geometry.surface import components
    folder = tmp_path_factory.mktemp('reconstruction')
    xml, run = str(folder / 'scene.xml'), str(folder / 'run')
    assert scene.main([str(made['out']), '-o', xml]) == 0
    assert optimize.main([xml, '-o', run, '--iterations', str(BUDGET_STEPS), '--quiet']) == 0
    with open(os.path.join(run, 'result.json')) as f:
        result = json.load(f)
    mesh = load_mesh(result['mesh'])
    truth = load_mesh(os.path.join(shot['truth'], 'specimen.ply'))
    with open(os.path.join(run, 'log.jsonl')) as f:
        psnr = np.array([json.loads(line)['psnr'] for line in f])
    return {'result': result, 'chamfer_mm': chamfer(mesh, truth)['chamfer'] / 100.0,
            'components': components(mesh), 'psnr': psnr}


@pytest.mark.slow
def test_reconstruction_from_the_photographs_in_millimetres(reconstructed):
    """From JPEGs with no poses to a mesh in millimetres, through the README's commands, trained
    until the budget is spent (CHAMFER_MM)."""
    r = reconstructed
    print(f"Chamfer-L1 {r['chamfer_mm']:.2f} mm, {r['components']} pieces, {r['result']['iterations']} steps")
    assert r['result']['iterations'] == BUDGET_STEPS
    assert r['chamfer_mm'] < CHAMFER_MM and r['components'] <= 5


@pytest.mark.slow
def test_training_does_not_get_worse(reconstructed):
    """The PSNR smoothed over 100 steps stays within 1 dB of its best so far for all but 10 %
    of the run (issue 27): a run that peaks and then decays fails."""
    psnr = reconstructed['psnr']
    smooth = np.convolve(psnr, np.ones(100) / 100, mode='valid')
    below = smooth < np.maximum.accumulate(smooth) - 1.0
    assert below.mean() <= 0.1, (below.mean(), smooth.max(), smooth[-1])


@pytest.mark.slow
def test_result_says_millimetres_and_a_coloured_glb_lies_beside(reconstructed):
    import trimesh
    result = reconstructed['result']
    assert result['units'] == 'mm' and result['frame'].startswith('board (OpenCV ChArUco')
    glb = result['glb']['path']
    assert glb == os.path.splitext(result['mesh'])[0] + '.glb'
    ply = trimesh.load(result['mesh'], process=False)
    web = trimesh.load(glb, force='mesh', process=False)
    # glTF's metres, y up: the board's x, -z and y.
    np.testing.assert_allclose(web.vertices, ply.vertices[:, [0, 2, 1]] * [1e-3, -1e-3, 1e-3], atol=1e-6)
    colors = web.visual.vertex_colors[:, :3]
    assert len(colors) == len(ply.vertices) and colors.std(axis=0).max() > 5


def test_board_corners_where_the_pattern_puts_them():
    """Corners of a blurred, upright and mirrored board image, at known places to 0.02 px
    (OpenCV 4.11's own ChArUco corners were half a pixel off)."""
    from reneus_mi.capture.charuco import Board
    board = Board(6, 5, 20.0, 15.0)
    ppm, pad = 4.0, 40
    image = cv2.GaussianBlur(np.pad(board.pattern(ppm), pad, constant_values=255), (0, 0), 1.2)
    h, w = image.shape
    expected = board.corners[:, :2] * ppm + pad
    for flipped in (False, True):
        found = board.detect(image[::-1, ::-1].copy() if flipped else image)
        assert len(found.ids) == len(board.corners)
        at = np.array([w, h]) - found.pixels if flipped else found.pixels
        err = at - expected[found.ids]
        assert np.abs(err).max() < 0.02, (flipped, np.abs(err).max())


def test_undistortion_inverts_a_known_lens():
    """A pinhole image through the simulator's lens (its own inverse mapping, iterative) and
    back through :func:`undistort` comes back; without undistortion it does not."""
    rig = Rig(width=320, height=240, focal_px=300.0, principal_offset_px=(7.0, -5.0),
              distortion=(-0.2, 0.08, 0.001, -0.0015, 0.01))
    K = rig.K()
    K_r = K.copy()
    ys, xs = np.mgrid[:240, :320] + 0.5
    # Smooth enough for bilinear resampling: periods of 12 pixels.
    pinhole = (0.5 + 0.25 * np.sin(2 * np.pi * xs / 12.0) * np.cos(2 * np.pi * ys / 15.0)).astype(np.float32)
    photo = distort_image(pinhole, K_r, rig)
    back, covered = undistort(photo, K, rig.distortion, K, (320, 240))
    inner = covered.copy()
    inner[:, :24] = inner[:, -24:] = False
    inner[:24] = inner[-24:] = False
    assert inner.mean() > 0.5
    assert np.abs(back - pinhole)[inner].mean() < 0.01
    assert np.abs(photo - pinhole)[inner].mean() > 0.05
    # To half the size (a smoother pattern): the pinhole image averaged 2x2.
    from reneus_mi.data.undistort import pinhole_K
    pinhole = (0.5 + 0.25 * np.sin(2 * np.pi * xs / 24.0) * np.cos(2 * np.pi * ys / 30.0)).astype(np.float32)
    photo = distort_image(pinhole, K_r, rig)
    half, covered = undistort(photo, K, rig.distortion, pinhole_K(K, 0.5), (160, 120))
    small = cv2.resize(pinhole, (160, 120), interpolation=cv2.INTER_AREA)
    inner = covered & np.pad(np.ones((96, 136), bool), 12)
    assert np.abs(half - small)[inner].mean() < 0.01


def distorted_photo():
    """A 160x120 pinhole image (a smooth pattern, one channel) and the photograph (RGB) a
    strongly distorting lens with an off-centre principal point makes of it."""
    rig = Rig(width=160, height=120, focal_px=150.0, principal_offset_px=(3.0, -2.5),
              distortion=(-0.25, 0.06, 0.002, -0.001, 0.0))
    ys, xs = np.mgrid[:120, :160] + 0.5
    pinhole = (0.5 + 0.3 * np.sin(2 * np.pi * xs / 16.0) * np.sin(2 * np.pi * ys / 19.0)).astype(np.float32)
    return rig, pinhole, distort_image(np.repeat(pinhole[..., None], 3, axis=-1), rig.K(), rig)


def test_nerfstudio_opencv_distortion_is_taken_out(tmp_path):
    """nerfstudio's camera_model OPENCV with k1..p2: the loader undistorts through the same path."""
    rig, pinhole, photo = distorted_photo()
    K = rig.K()
    os.makedirs(tmp_path / 'images')
    cv2.imwrite(str(tmp_path / 'images' / 'a.png'), np.round(photo[..., ::-1] * 255).astype(np.uint8))
    k1, k2, p1, p2, _ = rig.distortion
    meta = {'camera_model': 'OPENCV', 'fl_x': K[0, 0], 'fl_y': K[1, 1], 'cx': K[0, 2], 'cy': K[1, 2],
            'w': 160, 'h': 120, 'k1': k1, 'k2': k2, 'p1': p1, 'p2': p2,
            'frames': [{'file_path': 'images/a.png', 'transform_matrix': np.eye(4).tolist()}]}
    (tmp_path / 'transforms.json').write_text(json.dumps(meta))
    ds = load_dataset(str(tmp_path), need_container=False)
    inner = np.zeros((120, 160), bool)
    inner[16:-16, 16:-16] = True
    corrected = np.abs(ds.image(0)[..., 0] - pinhole)[inner].mean()
    assert corrected < 0.01
    # The same file read as a pinhole keeps the distortion.
    meta['camera_model'] = 'PINHOLE'
    for key in ('k1', 'k2', 'p1', 'p2'):
        del meta[key]
    (tmp_path / 'transforms.json').write_text(json.dumps(meta))
    raw = load_dataset(str(tmp_path), need_container=False)
    assert np.abs(raw.image(0)[..., 0] - pinhole)[inner].mean() > 4 * corrected


def test_settings_from_the_capture_file_or_the_flags(tmp_path):
    given = {'squares': '12x9', 'square_mm': 20, 'marker_mm': 15, 'size_mm': '50x35x25', 'ior': 1.5}
    (tmp_path / settings.CAPTURE_FILE).write_text(json.dumps(given))
    from_file = settings.resolve({}, str(tmp_path))
    from_flags = settings.resolve({k: str(v) for k, v in given.items()}, str(tmp_path / 'none'))
    assert from_file == from_flags
    assert from_file.squares == (12, 9) and from_file.size_mm == (50.0, 35.0, 25.0)
    # The same value twice is fine; a different one is refused.
    assert settings.resolve({'ior': '1.5'}, str(tmp_path)).ior == 1.5
    with pytest.raises(ValueError, match='contradicts'):
        settings.resolve({'ior': '1.45'}, str(tmp_path))


def test_colmap_model_read_and_undistorted(tmp_path):
    """A COLMAP model written here (OPENCV camera, two posed images) becomes a dataset whose
    cameras are the model's and whose images are undistorted."""
    pycolmap = pytest.importorskip('pycolmap')
    import trimesh
    from reneus_mi import colmap
    from reneus_mi.data.cameras import look_at
    rig, pinhole, photo = distorted_photo()
    K = rig.K()
    (tmp_path / 'images').mkdir()
    model = pycolmap.Reconstruction()
    camera = pycolmap.Camera.create_from_model_name(1, 'OPENCV', 150.0, 160, 120)
    camera.params = [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *rig.distortion[:4]]
    model.add_camera_with_trivial_rig(camera)
    c2ws = [look_at([4.0, 1.0, 2.0]), look_at([-3.0, 3.0, 1.5])]
    for i, c2w in enumerate(c2ws):
        name = f'v{i}.png'
        cv2.imwrite(str(tmp_path / 'images' / name), np.round(photo[..., ::-1] * 255).astype(np.uint8))
        w2c = np.linalg.inv(c2w)
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        model.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=i + 1), pose)
    (tmp_path / 'sparse').mkdir()
    model.write_text(str(tmp_path / 'sparse'))
    trimesh.creation.box(extents=(1.0, 0.8, 0.6)).export(tmp_path / 'box.ply')
    assert colmap.main([str(tmp_path / 'sparse'), '--images', str(tmp_path / 'images'), '--container',
                        str(tmp_path / 'box.ply'), '--ior', '1.5', '-o', str(tmp_path / 'ds')]) == 0
    ds = load_dataset(str(tmp_path / 'ds'))
    np.testing.assert_allclose(ds.c2w, np.stack(c2ws), atol=1e-6)
    # Each view a window around the container: the model's camera, moved by the window's corner.
    assert ds.width < 160 and ds.height < 120 and ds.masks.any(axis=(1, 2)).all()
    for v in range(2):
        corner = K[:2, 2] - ds.K[v][:2, 2]
        assert np.all(corner == np.round(corner)) and np.all(corner >= 0)
        np.testing.assert_allclose(ds.K[v], K - np.pad(corner[:, None], ((0, 1), (2, 0))), atol=1e-9)
    x0, y0 = (K[:2, 2] - ds.K[0][:2, 2]).astype(int)
    window = pinhole[y0:y0 + ds.height, x0:x0 + ds.width]
    inner = np.zeros((120, 160), bool)
    inner[16:-16, 16:-16] = True
    inner = inner[y0:y0 + ds.height, x0:x0 + ds.width]
    assert inner.mean() > 0.5
    assert np.abs(ds.image(0)[..., 0] - window)[inner].mean() < 0.01
    assert ds.ior == 1.5
