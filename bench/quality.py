"""Reconstruction quality on another renderer's photographs, through the README's commands.

    python bench/quality.py [--data /work/data/blender_set] [--scenes stool knot]
                            [--variants box nobox] [--configs fast:2,5,10 small:10]
                            [--runs runs/quality] [--doc docs] [--fresh | --remesh | --rewrite]
    python bench/quality.py --captures ant_small [beetle_large ...] [--capture-data /work/data/bcap]
                            [--configs ...] [--set PATH=VALUE ...] [--runs ...] [--doc ...]
                            [--fresh | --remesh | --rewrite]

The data are the Blender Cycles set of ``bench/blender_set.py`` (``DATA/SCENE/box/``,
``nobox/``, the ground truth ``DATA/SCENE/gt.ply`` outside both). For each scene, variant
and configuration (a preset and a time budget in minutes) it runs, as a user would, in
subprocesses::

    python -m reneus_mi.scene DATA/SCENE/VARIANT -o RUNS/SCENE/VARIANT/scene_PRESET.xml --preset PRESET
    python -m reneus_mi.optimize scene_PRESET.xml -o RUN --max-minutes M --quiet
    python -m reneus_mi.evaluate RUN/mesh.ply DATA/SCENE/gt.ply --json RUN/evaluate.json [--postprocess P]

and records Chamfer-L1 x100 of the run's mesh as the run cleaned it (``--postprocess none``;
another rule of evaluate's with ``--postprocess``) and the connected components of the run's ``mesh.ply`` as the run wrote it
(:func:`reneus_mi.geometry.surface.components`). Every budget is a separate run. It writes ``DOC/quality.md`` (one table per scene, the command, the date, the
share of the CPU other processes took during each row) and ``DOC/quality/SCENE_VARIANT_PRESET_Mmin.png``: the mesh beside the
ground truth, rendered by Mitsuba from the same camera. A run that fails or is skipped is
a row with its reason. Every row is also kept in ``DOC/quality.json`` with its date, commit and
machine: rows that an invocation does not run stay in the document as they were measured, so
that the whole table (hours on a CPU) can be filled over several sittings and machines.
Finished runs (an ``evaluate.json``) are read back, so a killed
benchmark continues where it stopped; ``--fresh`` runs everything again, ``--remesh`` meshes
and evaluates the finished runs again (a change of the clean-up, measured without training),
``--rewrite`` writes the document again from the record alone. A smoke run:
``--scenes stool --configs fast:0.3 --doc /tmp/quality``.

Capture rows (``--captures NAME ...``; then only they run) take the museum path from
photographs: the captures of ``bench/blender_capture.py`` (``CAPTURES/NAME/photos/``, the JPEGs
and ``capture.json``; ``CAPTURES/NAME/truth/``, ``truth.json`` and ``specimen.ply`` in the
board's frame, millimetres). Their variant is ``capture``, their scene the capture's name, and
each runs::

    python -m reneus_mi.capture CAPTURES/NAME/photos -o RUNS/NAME/capture/dataset --quiet
    python -m reneus_mi.scene RUNS/NAME/capture/dataset -o RUNS/NAME/capture/scene_PRESET.xml \\
        --preset PRESET --overwrite
    python -m reneus_mi.optimize scene_PRESET.xml -o RUN --max-minutes M --quiet
    python -m reneus_mi.evaluate RUN/mesh.ply CAPTURES/NAME/truth/specimen.ply --json RUN/evaluate.json \\
        --overwrite --threshold 0.1 [--postprocess P]

the first only where the dataset has no ``transforms.json`` (once per capture; ``--fresh``
makes it again; the first row's wall time includes it). They record Chamfer-L1 in millimetres
(evaluate's x100 over 100), the F-score at 0.1 mm, the size of the photographs (truth.json)
and the training PSNR's curve from ``RUN/log.jsonl``: its mean over 100 steps, that mean's best
(and step) and its end, and the share of the run's steps during which it lay more than 1 dB
below its best so far; ``DOC/quality/NAME_capture_PRESET_Mmin_psnr.png`` plots the PSNR per
step and its mean. Their pictures look down on the board (its z points into the table).

``--set PATH=VALUE`` (repeatable) passes a setting over the preset to the scene command (a
``train.`` setting to optimize): an ablation, a row of its own beside the preset's (its files
and its key carry the settings), e.g. the model before the capture fixes, ``--set
model.render.terminal=ambient --set model.render.board_texels=0``, or the batches before the
thin-part fixes, ``--set train.pixels.jitter=false --set train.pixels.error_share=0``.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import shlex
import shutil
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))

#: The benchmark: presets and their budgets in minutes.
CONFIGS = ('fast:2,5,10', 'small:10')
#: The acceptance rule of issue 15: fast with the block against fast without it, at 10 minutes.
CRITERION = {'preset': 'fast', 'minutes': 10.0, 'ratio': 1.5, 'components': 5}
#: Side of each half of a picture, pixels.
PICTURE = 160
#: Extra wall-clock time a run may take beyond its budget (kernel compilation, mesh
#: extraction) before it counts as hung.
GRACE_S = 900
#: Share of the machine's CPU taken by other processes above which a row is marked as run on
#: a loaded machine.
LOADED = 0.1
#: The variant of the capture rows.
CAPTURE = 'capture'
#: F-score distance of the capture rows, in their units (millimetres).
CAPTURE_THRESHOLD_MM = 0.1
#: Steps of the moving mean of a capture row's PSNR curve, and the drop below that mean's best
#: so far (dB) whose steps the row counts.
PSNR_WINDOW, PSNR_DROP = 100, 1.0
#: Size of the PSNR plot, inches at 100 dpi.
PLOT = (4.8, 2.4)
#: What a row keeps in DOC/quality.json (the run folder is this machine's, not kept).
RECORDED = ('scene', 'variant', 'preset', 'settings', 'minutes', 'chamfer', 'chamfer_mm', 'fscore', 'threshold',
            'at', 'extent_error', 'limbs', 'field_limbs', 'footprint_mm',
            'postprocess', 'components', 'steps', 'train_s', 'psnr', 'psnr_best', 'psnr_best_step', 'psnr_end',
            'psnr_below_1db', 'photos', 'wall_s', 'others', 'status', 'reused', 'remeshed', 'picture',
            'psnr_plot', 'date', 'commit', 'machine')


def parse_configs(items) -> list[tuple[str, float]]:
    """``['fast:2,5', 'small:10']`` -> ``[('fast', 2.0), ('fast', 5.0), ('small', 10.0)]``."""
    out = []
    for item in items:
        preset, sep, minutes = item.partition(':')
        try:
            values = [float(m) for m in minutes.split(',')] if sep else []
        except ValueError:
            values = []
        if not preset or not values or any(not m > 0 for m in values):
            raise SystemExit(f'error: --configs {item!r}: expected PRESET:MINUTES[,MINUTES...], '
                             'e.g. fast:2,5,10')
        out += [(preset, m) for m in values]
    return out


def _changed(settings: tuple[str, ...]) -> str:
    """``--set`` settings in a file name: ``('model.render.terminal=ambient',)`` -> ``_terminal-ambient``."""
    return ''.join(f"_{path.rpartition('.')[2]}-{value}" for path, _, value in (s.partition('=') for s in settings))


def _tag(preset: str, minutes: float, settings: tuple[str, ...] = ()) -> str:
    """A row's file name: ``fast_10min``, with settings ``fast_10min_terminal-ambient``."""
    return f'{preset}_{minutes:g}min{_changed(settings)}'


def _preset(row: dict) -> str:
    """A row's preset as the document shows it, with the settings it changed."""
    settings = row.get('settings') or ()
    return row['preset'] + ''.join(f' `{s}`' for s in settings)


def _run(cmd: list[str], log, timeout: float) -> str | None:
    """Run ``cmd``, appending its output to ``log``; None when it succeeded, else the reason
    (its last ``error:`` line, or its last line)."""
    log.write(f'$ {shlex.join(cmd)}\n')
    log.flush()
    try:
        proc = subprocess.run(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return f'{cmd[2]}: ran past {timeout / 60:.0f} min'
    log.write(proc.stdout)
    log.flush()
    if proc.returncode == 0:
        return None
    lines = [ln.strip() for ln in proc.stdout.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith('error:')]
    reason = (errors or lines or [f'exit status {proc.returncode}'])[-1]
    return f'{cmd[2]}: {reason}'


def busy_seconds() -> float | None:
    """CPU seconds the whole machine has spent busy since boot (Linux ``/proc/stat``; None
    elsewhere)."""
    try:
        with open('/proc/stat') as f:
            ticks = [int(v) for v in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle = ticks[3] + (ticks[4] if len(ticks) > 4 else 0)  # idle + iowait
    return (sum(ticks[:8]) - idle) / os.sysconf('SC_CLK_TCK')


def cpu_model() -> str:
    """The processor's name (/proc/cpuinfo), else its architecture: rows from different
    machines are not comparable at the same budget."""
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def children_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def count_components(mesh_path: str) -> int:
    """Connected pieces of the run's mesh as it wrote it (0 when it holds no surface)."""
    from reneus_mi.utils.errors import ReneusError
    from reneus_mi.geometry.mesh import load_mesh
    from reneus_mi.geometry.surface import components
    try:
        return components(load_mesh(mesh_path))
    except ReneusError:
        return 0


def run_one(data: str, gt: str, runs: str, scene: str, variant: str, preset: str, minutes: float,
            fresh: bool, postprocess: str | None, remesh: bool = False, make_data: list[str] | None = None,
            evaluate_args: tuple[str, ...] = (), settings: tuple[str, ...] = (),
            footprint_mm: float | None = None) -> dict:
    """One row: scene file, run, evaluation (or the reason there is none). ``make_data``: the
    command that writes the dataset ``data`` (a capture's), run first where ``data`` holds no
    ``transforms.json``; ``evaluate_args``: more options of evaluate's; ``settings``: the scene
    command's ``--set PATH=VALUE`` over the preset (an ablation)."""
    row = {'scene': scene, 'variant': variant, 'preset': preset, 'minutes': minutes, 'settings': list(settings)}
    if footprint_mm:
        row['footprint_mm'] = footprint_mm
    folder = os.path.join(runs, scene, variant)
    tag = _tag(preset, minutes, settings)
    run = os.path.join(folder, tag)
    evaluation = os.path.join(run, 'evaluate.json')
    row['run'] = run
    made = os.path.isfile(os.path.join(data, 'transforms.json'))
    if not made and make_data is None:
        return {**row, 'status': f'skipped: no dataset at {data}'}
    if not os.path.isfile(gt):
        return {**row, 'status': f'skipped: no ground truth at {gt}'}
    if os.path.isfile(evaluation) and not fresh:
        machine = os.path.join(folder, f'{tag}.machine.json')
        if os.path.isfile(machine):
            with open(machine) as f:
                row.update(json.load(f))
        if remesh:
            with open(os.path.join(run, 'config.json')) as f:
                resolution = json.load(f)['train']['mesh_resolution']
            with open(os.path.join(folder, f'{tag}.log'), 'a') as log:
                for cmd in ([sys.executable, '-m', 'reneus_mi.extract', os.path.join(run, 'checkpoint.npz'), '-o',
                             os.path.join(run, 'mesh.ply'), '--resolution', str(resolution), '--overwrite'],
                            _evaluate(run, gt, evaluation, postprocess, evaluate_args)):
                    failure = _run(cmd, log, GRACE_S)
                    if failure:
                        return {**row, 'status': f'failed: {failure}', **_read(run, None)}
            row['remeshed'] = True
        return {**row, **_read(run, evaluation), 'reused': True}
    if os.path.exists(run):
        # A run of this benchmark that did not finish (or --fresh): its folder is ours.
        shutil.rmtree(run)
    os.makedirs(folder, exist_ok=True)
    xml = os.path.join(folder, f'scene_{preset}{_changed(settings)}.xml')
    py = sys.executable
    with open(os.path.join(folder, f'{tag}.log'), 'w') as log:
        # Training settings are optimize's, the model's the scene's.
        steps = [[py, '-m', 'reneus_mi.scene', data, '-o', xml, '--preset', preset, '--overwrite',
                  *(a for s in settings if not s.startswith('train.') for a in ('--set', s))],
                 [py, '-m', 'reneus_mi.optimize', xml, '-o', run, '--max-minutes', f'{minutes:g}', '--quiet',
                  *(a for s in settings if s.startswith('train.') for a in ('--set', s))],
                 _evaluate(run, gt, evaluation, postprocess, evaluate_args)]
        timeouts = [GRACE_S, 60 * minutes + GRACE_S, GRACE_S]
        if not made:
            # A dataset this benchmark began and did not finish: its folder is ours too.
            shutil.rmtree(data, ignore_errors=True)
            steps.insert(0, make_data)
            timeouts.insert(0, GRACE_S)
        start, busy, own = time.perf_counter(), busy_seconds(), children_seconds()
        for cmd, timeout in zip(steps, timeouts):
            failure = _run(cmd, log, timeout)
            if failure:
                row['status'] = f'failed: {failure}'
                break
        row['wall_s'] = time.perf_counter() - start
        if busy is not None:
            # What other processes took of the machine while this row ran: a load average
            # cannot tell the benchmark's own runs from others'.
            others = busy_seconds() - busy - (children_seconds() - own)
            row['others'] = max(0.0, others / (row['wall_s'] * (os.cpu_count() or 1)))
    with open(os.path.join(folder, f'{tag}.machine.json'), 'w') as f:
        json.dump({k: row[k] for k in ('wall_s', 'others') if k in row}, f)
    if 'status' in row:
        return {**row, **_read(run, None)}
    return {**row, **_read(run, evaluation)}


def _evaluate(run: str, gt: str, evaluation: str, postprocess: str | None,
              evaluate_args: tuple[str, ...] = ()) -> list[str]:
    """evaluate's command; with limbs, the run's field is walked along them too (``--field``)
    where the run left its checkpoint."""
    checkpoint = os.path.join(run, 'checkpoint.npz')
    field = ('--field', checkpoint) if '--limbs' in evaluate_args and os.path.isfile(checkpoint) else ()
    return [sys.executable, '-m', 'reneus_mi.evaluate', os.path.join(run, 'mesh.ply'), gt, '--json', evaluation,
            '--overwrite', *evaluate_args, *field, *(['--postprocess', postprocess] if postprocess else [])]


def _read(run: str, evaluation: str | None) -> dict:
    """What a run folder tells: steps, PSNR, Chamfer and components."""
    out = {}
    result = os.path.join(run, 'result.json')
    if os.path.isfile(result):
        with open(result) as f:
            r = json.load(f)
        out.update(steps=r.get('iterations'), train_s=r.get('seconds'), psnr=r.get('psnr'))
    mesh = os.path.join(run, 'mesh.ply')
    if evaluation:
        with open(evaluation) as f:
            e = json.load(f)
        out.update(chamfer=e['chamfer'], fscore=e.get('fscore'), threshold=e.get('threshold'),
                   postprocess=e.get('postprocess'), status='ok', at=e.get('at'),
                   extent_error=(e.get('extents') or {}).get('error_pct'),
                   **{key: [{k: limb[k] for k in ('name', 'length', 'reach', 'error_pct', 'longest_gap')}
                             for limb in e.get(key, [])] or None for key in ('limbs', 'field_limbs')})
    if os.path.isfile(mesh):
        # Not evaluate's 'components': it counts after its clean-up (one, for 'largest').
        out['components'] = count_components(mesh)
    return out


# --- capture rows ---------------------------------------------------------------------------

def capture_job(captures: str, name: str, runs: str) -> dict:
    """What run_one needs for a capture's rows: its dataset (made by ``reneus_mi.capture``
    from the photographs), its truth and evaluate's distances in millimetres (the curator's
    0.1 and 0.2 mm, one and two pixels' footprint at the specimen) and its limbs."""
    data = os.path.join(runs, name, CAPTURE, 'dataset')
    truth = os.path.join(captures, name, 'truth', 'truth.json')
    footprint = pixel_footprint(truth)
    at = [0.1, 0.2] + ([footprint, 2 * footprint] if footprint else [])
    limbs = ('--limbs', truth) if _truth(truth).get('limbs') else ()
    return {'data': data, 'gt': os.path.join(captures, name, 'truth', 'specimen.ply'), 'scene': name,
            'variant': CAPTURE, 'footprint_mm': footprint,
            'evaluate_args': ('--threshold', f'{CAPTURE_THRESHOLD_MM:g}', '--at', *(f'{d:.4g}' for d in at), *limbs),
            'make_data': [sys.executable, '-m', 'reneus_mi.capture', os.path.join(captures, name, 'photos'),
                          '-o', data, '--quiet']}


def _truth(truth: str) -> dict:
    try:
        with open(truth) as f:
            return json.load(f)
    except (OSError, ValueError):
        return {}


def pixel_footprint(truth: str) -> float | None:
    """Millimetres a photograph's pixel covers at the specimen: the median over the views of
    the camera's distance to the specimen's centre over the focal length (truth.json)."""
    t = _truth(truth)
    try:
        centre = np.asarray(t['limbs'][0]['joints_mm'][0], float) if t.get('limbs') else \
            np.array([*t['container']['pose'][:2], -0.5 * t['container']['size_mm'][2]])
        eyes = np.array([np.asarray(v['c2w'], float)[:3, 3] for v in t['views']])
        return float(np.median(np.linalg.norm(eyes - centre, axis=1)) / t['K'][0][0])
    except (KeyError, IndexError, TypeError, ValueError):
        return None


def photo_size(truth: str) -> str | None:
    """``WIDTHxHEIGHT`` of a capture's photographs (its truth.json), None without it."""
    try:
        with open(truth) as f:
            t = json.load(f)
        return f"{t['width']}x{t['height']}"
    except (OSError, ValueError, KeyError):
        return None


def psnr_curve(entries: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Steps and PSNR of a run's log, the PSNR's mean over the last PSNR_WINDOW steps and where
    that mean counts: once a whole window has run (at the last step in a shorter run)."""
    # A resumed run logs the steps after its checkpoint again: the later entry counts.
    logged = {int(e['iteration']): float(e['psnr']) for e in entries
              if isinstance(e.get('psnr'), (int, float)) and e['psnr'] == e['psnr']}
    steps = np.array(sorted(logged), dtype=int)
    psnr = np.array([logged[k] for k in steps], dtype=float)
    if not len(steps):
        return steps, psnr, psnr, np.zeros(0, bool)
    cumulative = np.concatenate([[0.0], np.cumsum(psnr)])
    first = np.searchsorted(steps, steps - PSNR_WINDOW, side='right')
    smoothed = (cumulative[1:] - cumulative[first]) / (np.arange(1, len(steps) + 1) - first)
    full = steps >= steps[0] + PSNR_WINDOW - 1
    full[-1] = True
    return steps, psnr, smoothed, full


def psnr_figures(run: str) -> dict:
    """The row's PSNR curve (:func:`psnr_curve`): the mean's best and its step, its end, and the
    share of the run's steps during which it lay more than PSNR_DROP below its best so far."""
    from reneus_mi.train.run_folder import RunFolder
    steps, _, smoothed, full = psnr_curve(RunFolder(run).read_log())
    if not full.any():
        return {}
    # Each logged step stands for the steps since the one logged before it.
    weight = np.diff(steps, prepend=steps[0] - 1)[full]
    mean = smoothed[full]
    below = mean < np.maximum.accumulate(mean) - PSNR_DROP
    best = int(np.argmax(mean))
    return {'psnr_best': float(mean[best]), 'psnr_best_step': int(steps[full][best]), 'psnr_end': float(mean[-1]),
            'psnr_below_1db': float(weight[below].sum() / (steps[-1] - steps[0] + 1))}


def plot_psnr(run: str, out: str) -> bool:
    """Plot the PSNR of each logged step and its mean over PSNR_WINDOW steps; False when the
    run logged none."""
    from matplotlib.figure import Figure
    from reneus_mi.train.run_folder import RunFolder
    steps, psnr, smoothed, full = psnr_curve(RunFolder(run).read_log())
    if not len(steps):
        return False
    fig = Figure(figsize=PLOT, dpi=100, layout='tight')
    ax = fig.subplots()
    ax.plot(steps, psnr, color='0.75', linewidth=0.6, label='PSNR')
    ax.plot(steps[full], smoothed[full], color='C0', linewidth=1.4, label=f'mean of {PSNR_WINDOW} steps')
    ax.plot(steps[full], np.maximum.accumulate(smoothed[full]) - PSNR_DROP, color='C3', linewidth=0.8,
            linestyle='--', label=f'best so far - {PSNR_DROP:g} dB')
    best = np.argmax(smoothed[full])  # marked: a run shorter than the window has no line
    ax.plot(steps[full][best], smoothed[full][best], 'o', color='C0', markersize=4)
    ax.set_xlabel('step')
    ax.set_ylabel('PSNR (dB)')
    ax.legend(fontsize=7, loc='lower right')
    ax.grid(alpha=0.3)
    tmp = out + '.tmp.png'
    fig.savefig(tmp)
    os.replace(tmp, out)
    return True


# --- pictures -------------------------------------------------------------------------------

def _look_at(eye, target, up: float = 1.0) -> np.ndarray:
    import mitsuba as mi
    return mi.ScalarTransform4f().look_at(origin=list(map(float, eye)), target=list(map(float, target)),
                                         up=[0.0, 0.0, up])


def picture(mesh_path: str, gt_path: str, out: str, up: float = 1.0) -> None:
    """The mesh (left) beside the ground truth (right), grey, from one oblique camera that
    frames the ground truth, above it and lit from above. ``up``: the sign of z that points up
    (-1 in a capture's board frame, whose z points into the table)."""
    import mitsuba as mi
    from reneus_mi.utils.errors import ReneusError
    from reneus_mi.geometry.mesh import load_mesh
    if mi.variant() is None:
        mi.set_variant('scalar_rgb')
    gt = load_mesh(gt_path, 'ground-truth mesh')
    centre = gt.bounds.mean(axis=0)
    radius = float(np.linalg.norm(gt.vertices - centre, axis=1).max())
    direction = np.array([1.0, -1.4, 0.9 * up]) / np.linalg.norm([1.0, -1.4, 0.9])
    distance = 3.0 * radius
    fov = float(np.degrees(2 * np.arcsin(1.05 * radius / distance)))
    halves = []
    for path in (mesh_path, gt_path):
        try:
            mesh = load_mesh(path)
        except ReneusError:  # an empty mesh.ply: a run that found no surface
            mesh = None
        scene = {'type': 'scene', 'integrator': {'type': 'path', 'max_depth': 3},
                 'sensor': {'type': 'perspective', 'fov': fov,
                            'to_world': _look_at(centre + distance * direction, centre, up),
                            'film': {'type': 'hdrfilm', 'width': PICTURE, 'height': PICTURE,
                                     'rfilter': {'type': 'gaussian'}},
                            'sampler': {'type': 'independent', 'sample_count': 64}},
                 'sky': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.35}},
                 'sun': {'type': 'directional', 'direction': [-0.4, 0.7, -1.0 * up],
                         'irradiance': {'type': 'rgb', 'value': 2.2}}}
        if mesh is not None:
            m = mi.Mesh('mesh', len(mesh.vertices), len(mesh.faces))
            params = mi.traverse(m)
            params['vertex_positions'] = mesh.vertices.astype(np.float32).ravel()
            params['faces'] = mesh.faces.astype(np.uint32).ravel()
            params.update()
            m.set_bsdf(mi.load_dict({'type': 'twosided', 'bsdf': {
                'type': 'diffuse', 'reflectance': {'type': 'rgb', 'value': [0.62, 0.6, 0.55]}}}))
            scene['mesh'] = m
        img = np.asarray(mi.render(mi.load_dict(scene)))
        halves.append(img)
    both = np.concatenate(halves, axis=1)
    bmp = mi.Bitmap(both).convert(mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, srgb_gamma=True)
    tmp = out + '.tmp.png'
    bmp.write(tmp)
    os.replace(tmp, out)


# --- the record -----------------------------------------------------------------------------

def _key(row: dict) -> tuple:
    return row['scene'], row['variant'], row['preset'], float(row['minutes']), tuple(row.get('settings') or ())


def read_record(doc: str) -> list[dict]:
    """The rows of earlier invocations (DOC/quality.json), or none."""
    path = os.path.join(doc, 'quality.json')
    if not os.path.isfile(path):
        return []
    with open(path) as f:
        return json.load(f)['rows']


def merge(earlier: list[dict], rows: list[dict], scenes: list[str]) -> list[dict]:
    """This invocation's rows, and the earlier rows it did not run; ordered by scene (this
    invocation's order, then the others'), variant (box, nobox, then the rest), preset, budget."""
    ran = {_key(r) for r in rows}
    merged = [r for r in earlier if _key(r) not in ran] + rows
    order = {s: i for i, s in enumerate(dict.fromkeys(scenes + [r['scene'] for r in merged]))}
    variants = {'box': 0, 'nobox': 1}
    return sorted(merged, key=lambda r: (order[r['scene']], variants.get(r['variant'], 2), r['variant'],
                                         r['preset'], float(r['minutes']), tuple(r.get('settings') or ())))


def write_record(rows: list[dict], doc: str) -> None:
    from reneus_mi.utils.io import atomic_open
    with atomic_open(os.path.join(doc, 'quality.json'), 'w') as f:
        json.dump({'rows': [{k: r[k] for k in RECORDED if r.get(k) is not None} for r in rows]}, f, indent=1)


def commit(doc: str) -> str:
    """The commit the benchmark runs at, with ``+`` when the working tree differs from it
    outside ``doc`` (which the benchmark itself writes)."""
    def git(*args):
        return subprocess.run(['git', '-C', ROOT, *args], capture_output=True, text=True).stdout.strip()
    head = git('rev-parse', '--short', 'HEAD') or 'unknown'
    inside = os.path.relpath(os.path.abspath(doc), ROOT)
    # git refuses (and prints nothing) a pathspec outside the tree, e.g. --doc /tmp/quality.
    changed = git('status', '--porcelain', '--untracked-files=no', '--', '.',
                  *([] if inside == '..' or inside.startswith('..' + os.sep) else [f':(exclude){inside}']))
    return head + ('+' if changed else '')


# --- the document ---------------------------------------------------------------------------

def _fmt(value, spec: str) -> str:
    return '' if value is None or value != value else format(value, spec)


def _status(r: dict) -> str:
    """A row's status, with whether it was an earlier run and ran on a loaded machine."""
    return (r['status'] + (' (earlier run' + (', meshed again' if r.get('remeshed') else '') + ')'
                           if r.get('reused') else '')
            + (', **loaded machine**' if r.get('others', 0) > LOADED else ''))


def _link(r: dict, key: str) -> str:
    return f"[png]({r[key]})" if r.get(key) else ''


def _joined(rows: list[dict], key: str) -> str:
    """The values of ``key`` among ``rows``, e.g. their evaluate clean-up; '-' for none."""
    return ', '.join(sorted({format(r[key], 'g') if isinstance(r[key], float) else r[key]
                             for r in rows if r.get(key)})) or '-'


def write_doc(rows: list[dict], doc: str, command: str, started: dict, minutes: float) -> str:
    smoke = any(float(r['minutes']) < 2 for r in rows)
    def machine_of(r):
        return r.get('machine') or started['machine']

    machines = list(dict.fromkeys(machine_of(r) for r in rows))
    # Rows from several machines are told apart by a letter in the column "ran".
    letter = {m: chr(ord('A') + i) for i, m in enumerate(machines)} if len(machines) > 1 else {}
    named = (f"Machines (column \"ran\"): {'; '.join(f'{letter[m]}: {m}' for m in machines)}" if letter
             else f'Machine: {machines[0]}')

    def ran(r):
        return f"{r.get('date', '')} {r.get('commit', '')} {letter.get(machine_of(r), '')}"

    lines = ['# Reconstruction quality on a second renderer\'s photographs', '',
             f'Written by `{command}` on {started["date"]} ({minutes:.0f} min). Rows it did not run are '
             'kept from earlier invocations (`quality.json`); column "ran" says when and at which commit '
             'each row ran.', '',
             f'{named}. Column "others": the share of the machine\'s CPU that '
             f'other processes took while the row ran; a row above {LOADED:.0%} ran on a **loaded '
             'machine** and is marked so (blank: not measured).', '']
    if smoke:
        lines += ['**Smoke rows**: budgets under 2 minutes say nothing about quality.', '']
    set_rows = [r for r in rows if r['variant'] != CAPTURE]
    if set_rows:
        lines += _set_lines(set_rows, ran)
    captures = [r for r in rows if r['variant'] == CAPTURE]
    if captures:
        lines += _capture_lines(captures, ran)
    os.makedirs(doc, exist_ok=True)
    from reneus_mi.utils.io import atomic_open
    path = os.path.join(doc, 'quality.md')
    with atomic_open(path, 'w') as f:
        f.write('\n'.join(lines))
    return path


def _set_lines(rows: list[dict], ran) -> list[str]:
    """The document's part on the rows of the Blender set: a table per scene, issue 15's test."""
    lines = ['Data: `bench/blender_set.py` (Blender Cycles, a glass block IOR 1.45 exported by '
             "Blender itself, constant world 0.8, 48 views at 128 px; each scene's `scene.json` "
             'says how its block file was written). Each row is the README\'s path, in subprocesses: '
             '`python -m reneus_mi.scene DATA -o scene.xml --preset P` (without the block it writes a plain '
             'NeuS scene), '
             '`python -m reneus_mi.optimize scene.xml -o RUN --max-minutes M --quiet`, '
             '`python -m reneus_mi.evaluate RUN/mesh.ply GT --json ...`. Chamfer-L1 x100 is '
             f"evaluate's, of the run's mesh (`--postprocess {_joined(rows, 'postprocess')}`); "
             "components are those of the run's `mesh.ply` as the run wrote it. "
             'Pictures: the mesh (left) beside the ground truth (right).', '']
    for scene in dict.fromkeys(r['scene'] for r in rows):
        lines += [f'## {scene}', '', '| variant | preset | budget | Chamfer x100 | components | steps | '
                  'PSNR | others | status | ran | picture |',
                  '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
        for r in (r for r in rows if r['scene'] == scene):
            lines.append(f"| {r['variant']} | {_preset(r)} | {r['minutes']:g} min | "
                         f"{_fmt(r.get('chamfer'), '.3f')} | {_fmt(r.get('components'), 'd')} | "
                         f"{_fmt(r.get('steps'), 'd')} | {_fmt(r.get('psnr'), '.2f')} | "
                         f"{_fmt(r.get('others'), '.0%')} | {_status(r)} | {ran(r)} | {_link(r, 'picture')} |")
        lines.append('')
    verdicts = criterion(rows)
    if verdicts:
        c = CRITERION
        lines += [f"## {c['preset']} at {c['minutes']:g} min: with the block against without", '',
                  f"Issue 15 asks for at most {c['ratio']}x the Chamfer without the block and at most "
                  f"{c['components']} components.", '',
                  '| scene | box | nobox | ratio | components | met |', '| --- | --- | --- | --- | --- | --- |']
        for v in verdicts:
            lines.append(f"| {v['scene']} | {v['box']:.3f} | {v['nobox']:.3f} | {v['ratio']:.2f} | "
                         f"{v['components']} | {v['met']} |")
        lines.append('')
    return lines


def _capture_lines(rows: list[dict], ran) -> list[str]:
    """The document's part on the capture rows: one table."""
    threshold = _joined(rows, 'threshold')
    lines = ['## Captures: the museum path from photographs', '',
             'Data: `bench/blender_capture.py` (Blender Cycles photographs, JPEG with lens distortion, of '
             'a specimen in a glass block on a printed ChArUco board; the truth in the board\'s frame, '
             'millimetres). Each row, in subprocesses: `python -m reneus_mi.capture PHOTOS -o DATASET --quiet` '
             "(once per capture, into the benchmark's runs folder), "
             '`python -m reneus_mi.scene DATASET -o scene.xml --preset P --overwrite`, '
             '`python -m reneus_mi.optimize scene.xml -o RUN --max-minutes M --quiet`, '
             f'`python -m reneus_mi.evaluate RUN/mesh.ply TRUTH/specimen.ply --json ... --threshold {threshold} '
             f"--postprocess {_joined(rows, 'postprocess')}`. Chamfer-L1 in mm (evaluate's x100 / 100), "
             f'F-score at {threshold} mm; precision / recall (the share of the mesh near the truth / of the '
             "truth near the mesh) at 0.1 and 0.2 mm and at one and two pixels' footprint at the specimen "
             "(from truth.json's cameras); extent error in % along the truth's principal axes, longest "
             "first; reach: how far the mesh follows each leg, then each antenna, in % of its length "
             "(`evaluate --limbs truth.json`), and after a semicolon how far the run's field itself does "
             "(`--field RUN/checkpoint.npz`: a limb the field reaches and the mesh misses was lost in "
             "meshing); pieces: the components of the run's `mesh.ply`. PSNR: the "
             f"training PSNR's mean over {PSNR_WINDOW} steps: its best (at step), its end, and the share of "
             f'the run\'s steps during which it lay more than {PSNR_DROP:g} dB below its best so far. '
             'Pictures: the mesh (left) beside the truth (right), seen from above the board.', '',
             f'| capture | photographs | preset | budget | Chamfer-L1 mm | F@{threshold} mm | '
             'precision / recall 0.1 mm | 0.2 mm | 1 px | 2 px | extent error % | legs, antennae reach % '
             '(mesh; field) | '
             f'pieces | steps | '
             f'PSNR best (step) | PSNR end | below best - {PSNR_DROP:g} dB | others | status | ran | picture | '
             'PSNR plot |',
             '|' + ' --- |' * 22]
    for r in rows:
        best = (f"{r['psnr_best']:.2f} ({r['psnr_best_step']})" if r.get('psnr_best') is not None else '')
        lines.append(f"| {r['scene']} | {r.get('photos', '')} | {_preset(r)} | {r['minutes']:g} min | "
                     f"{_fmt(r.get('chamfer_mm'), '.3f')} | {_fmt(r.get('fscore'), '.3f')} | "
                     f"{' | '.join(_precision_recall(r, k) for k in range(4))} | "
                     f"{' '.join(f'{e:+.0f}' for e in r.get('extent_error') or [])} | {_limbs(r)} | "
                     f"{_fmt(r.get('components'), 'd')} | {_fmt(r.get('steps'), 'd')} | {best} | "
                     f"{_fmt(r.get('psnr_end'), '.2f')} | {_fmt(r.get('psnr_below_1db'), '.0%')} | "
                     f"{_fmt(r.get('others'), '.0%')} | {_status(r)} | {ran(r)} | {_link(r, 'picture')} | "
                     f"{_link(r, 'psnr_plot')} |")
    return lines + ['']


def _precision_recall(row: dict, k: int) -> str:
    """The k-th distance of a capture row's ``at`` (0.1 mm, 0.2 mm, 1 px, 2 px) as P / R."""
    at = list((row.get('at') or {}).values())
    return f"{at[k]['precision']:.2f} / {at[k]['recall']:.2f}" if k < len(at) else ''


def _limbs(row: dict) -> str:
    """Each limb's reach error in %, legs then antennae, as evaluate names them: the mesh's, and
    after a semicolon the field's where it was measured."""
    def errors(limbs):
        return ' '.join(f"{limb['error_pct']:+.0f}" for limb in sorted(limbs, key=lambda x: 'antenna' in x['name']))
    mesh, field = errors(row.get('limbs') or []), errors(row.get('field_limbs') or [])
    return f'{mesh}; {field}' if field else mesh


def criterion(rows: list[dict]) -> list[dict]:
    """Issue 15's test per scene where both variants of its configuration finished."""
    c = CRITERION
    out = []
    for scene in dict.fromkeys(r['scene'] for r in rows):
        got = {r['variant']: r for r in rows if r['scene'] == scene and r['preset'] == c['preset']
               and not r.get('settings')
               and r['minutes'] == c['minutes'] and r.get('chamfer') is not None}
        if 'box' in got and 'nobox' in got:
            box, nobox = got['box'], got['nobox']
            ratio = box['chamfer'] / nobox['chamfer']
            comps = box.get('components')
            met = ratio <= c['ratio'] and comps is not None and comps <= c['components']
            # A budget buys different training on different machines: no verdict across them.
            same = box.get('machine') == nobox.get('machine')
            out.append({'scene': scene, 'box': box['chamfer'], 'nobox': nobox['chamfer'], 'ratio': ratio,
                        'components': comps, 'met': ('yes' if met else 'no') if same else
                        'not comparable: the two rows ran on different machines'})
    return out


def set_jobs(args) -> list[dict]:
    """run_one's arguments for each scene and variant of the Blender set."""
    if not os.path.isdir(args.data):
        raise SystemExit(f'error: {args.data}: no such folder; make the set with bench/blender_set.py')
    scenes = args.scenes or sorted(s for s in os.listdir(args.data)
                                   if os.path.isfile(os.path.join(args.data, s, 'gt.ply')))
    if not scenes:
        raise SystemExit(f'error: {args.data}: no scenes (folders with a gt.ply)')
    return [{'data': os.path.join(args.data, scene, variant), 'gt': os.path.join(args.data, scene, 'gt.ply'),
             'scene': scene, 'variant': variant} for scene in scenes for variant in args.variants]


def capture_jobs(args) -> list[dict]:
    """run_one's arguments for each capture (:func:`capture_job`); with ``--fresh`` their
    datasets are removed here, so that the first row of each makes it again."""
    if args.scenes:
        raise SystemExit('error: --captures runs capture rows only; run --scenes in another invocation')
    jobs = []
    for name in args.captures:
        if not os.path.isdir(os.path.join(args.capture_data, name, 'photos')):
            raise SystemExit(f'error: {os.path.join(args.capture_data, name)}: no photos/ folder; make the '
                             'capture with bench/blender_capture.py')
        jobs.append(capture_job(args.capture_data, name, args.runs))
        if args.fresh:
            shutil.rmtree(jobs[-1]['data'], ignore_errors=True)
    return jobs


def figures(row: dict, gt: str, pictures: str, doc: str) -> dict:
    """What a row adds to its run's numbers: its picture and, a capture row, its millimetres,
    the size of its photographs and its PSNR curve with its plot."""
    out = {}
    stem = os.path.join(pictures, f"{row['scene']}_{row['variant']}_{_tag(row['preset'], row['minutes'], tuple(row.get('settings') or ()))}")
    capture = row['variant'] == CAPTURE
    mesh = os.path.join(row['run'], 'mesh.ply')
    if os.path.isfile(mesh):
        picture(mesh, gt, stem + '.png', up=-1.0 if capture else 1.0)
        out['picture'] = os.path.relpath(stem + '.png', doc)
    if not capture:
        return out
    out['photos'] = photo_size(os.path.join(os.path.dirname(gt), 'truth.json'))
    if row.get('chamfer') is not None:
        out['chamfer_mm'] = row['chamfer'] / 100
    if os.path.isdir(row['run']):
        out.update(psnr_figures(row['run']))
        if plot_psnr(row['run'], stem + '_psnr.png'):
            out['psnr_plot'] = os.path.relpath(stem + '_psnr.png', doc)
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog='bench/quality.py', description=__doc__.split('\n\n')[0])
    parser.add_argument('--data', default='/work/data/blender_set', help='the set (default: %(default)s)')
    parser.add_argument('--scenes', nargs='+', help='scenes of the set (default: all)')
    parser.add_argument('--variants', nargs='+', default=['box', 'nobox'],
                        help='dataset folders of each scene (default: %(default)s)')
    parser.add_argument('--captures', nargs='+', metavar='NAME',
                        help='captures of bench/blender_capture.py to run instead of the set: the museum path '
                             'from their photographs')
    parser.add_argument('--capture-data', default='/work/data/bcap',
                        help='folder of the captures, NAME/photos and NAME/truth (default: %(default)s)')
    parser.add_argument('--configs', nargs='+', default=list(CONFIGS),
                        help='PRESET:MINUTES[,MINUTES...] (default: %(default)s)')
    parser.add_argument('--set', dest='settings', action='append', default=[], metavar='PATH=VALUE',
                        help="a setting over every preset, passed to the scene command's --set (a train. "
                             "setting: to optimize's; repeatable): ablation rows, kept apart from the preset's "
                             'own, e.g. model.render.terminal=ambient, train.pixels.error_share=0')
    parser.add_argument('--runs', default=os.path.join(ROOT, 'runs', 'quality'),
                        help='folder of the runs (default: runs/quality)')
    parser.add_argument('--doc', default=os.path.join(ROOT, 'docs'),
                        help='folder of quality.md and quality/ (default: docs)')
    parser.add_argument('--postprocess', default='none',
                        help="evaluate's --postprocess (default: %(default)s: the run's mesh.ply as the run "
                             "cleaned it)")
    parser.add_argument('--fresh', action='store_true', help='run again what an earlier run finished')
    parser.add_argument('--remesh', action='store_true',
                        help="mesh the finished runs' checkpoints again with the current code (as the run "
                             'would: its resolution, the default clean-up) and evaluate them, without training')
    parser.add_argument('--rewrite', action='store_true',
                        help='write DOC/quality.md again from the rows kept in DOC/quality.json, running '
                             "nothing (after a change of the document's form)")
    args = parser.parse_args(argv)
    command = 'python bench/quality.py ' + shlex.join(sys.argv[1:] if argv is None else argv)
    started = {'date': datetime.date.today().isoformat(),
               'machine': f'{cpu_model()}, {os.cpu_count()} cores'}
    if args.rewrite:
        rows = read_record(args.doc)
        if not rows:
            raise SystemExit(f'error: {args.doc}: no rows in quality.json to write')
        print(f'wrote {write_doc(rows, args.doc, command, started, 0.0)}')
        return
    configs = parse_configs(args.configs)
    jobs = capture_jobs(args) if args.captures else set_jobs(args)
    scenes = list(dict.fromkeys(job['scene'] for job in jobs))
    t0 = time.time()
    pictures = os.path.join(args.doc, 'quality')
    os.makedirs(pictures, exist_ok=True)
    earlier, rows = read_record(args.doc), []
    stamp = {'date': started['date'], 'commit': commit(args.doc), 'machine': started['machine']}
    for job in jobs:
        for preset, minutes in configs:
            row = run_one(job['data'], job['gt'], args.runs, job['scene'], job['variant'], preset, minutes,
                          args.fresh, args.postprocess, args.remesh, job.get('make_data'),
                          job.get('evaluate_args', ()), tuple(args.settings), job.get('footprint_mm'))
            row.update(figures(row, job['gt'], pictures, args.doc))
            rows.append({**row, **stamp})
            chamfer = (f"Chamfer-L1 {_fmt(row.get('chamfer_mm'), '.3f') or '-'} mm" if row['variant'] == CAPTURE
                       else f"Chamfer {_fmt(row.get('chamfer'), '.3f') or '-'}")
            print(f"{row['scene']} {row['variant']} {_preset(row)} {minutes:g} min: {row['status']}, {chamfer}, "
                  f"components {_fmt(row.get('components'), 'd') or '-'}", flush=True)
            merged = merge(earlier, rows, scenes)
            write_record(merged, args.doc)
            path = write_doc(merged, args.doc, command, started, (time.time() - t0) / 60)
    print(f'wrote {path}')


if __name__ == '__main__':
    main()
