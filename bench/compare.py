"""The paper's synthetic comparison (Table 1 and the ablation), reproduced.

    python bench/compare.py [--config small|full] [--objects insect statuette vase]
                            [--iterations N] [--out runs/compare_small] [--doc docs]

For each object it renders (or reuses) the synthetic dataset with both subsets
(:func:`reneus_mi.data.synthetic.make_dataset`, Mitsuba's path tracer), then fits

==================  ========  ==========  ====================
method              subset    mode        λ1 (``trans_weight``)
==================  ========  ==========  ====================
NeuS (w/o box)      nobox     neus        0
NeuS                box       neus        0
NeuS+               box       neus_plus   0
ReNeuS w/o L_trans  box       reneus      0
ReNeuS              box       reneus      0.1
==================  ========  ==========  ====================

extracts each mesh raw (marching cubes, no post-processing) and measures the
Chamfer-L1 x100 to the ground truth twice: after the paper's post-processing
(largest connected component, Table 1) and without it, dropping predicted
points outside the glass box (``chamfer(..., container=box)``, as in the
ablation, where fake walls on the glass count). It writes
``DOC/comparison.md`` (the table, the configuration and the device) and
``DOC/comparison.png`` (every mesh rendered with Mitsuba from one viewpoint).

Runs live in ``OUT/<object>/<method>/`` (the trainer's folder: checkpoint,
log, ``mesh.ply`` raw, plus ``mesh_largest.ply`` and ``evaluation.json``). It is
resumable: a method whose ``mesh.ply`` exists is not trained again, and one
killed mid-way continues from its checkpoint.

``--config small`` is sized for a 2-core CPU (the small preset's field and sampling,
16 views at 32x32); ``--config full`` is the paper's (60 views at 800x800,
NeuS-sized networks, 64+64 samples, 1024 rays, 200k iterations: a GPU job).
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import time

import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))

#: (key, label, subset, model settings, trans_weight)
METHODS = (
    ('neus_nobox', 'NeuS (w/o box)', 'nobox', {'render.mode': 'neus'}, 0.0),
    ('neus', 'NeuS', 'box', {'render.mode': 'neus'}, 0.0),
    ('neus_plus', 'NeuS+', 'box', {'render.mode': 'neus_plus'}, 0.0),
    ('reneus_notrans', 'ReNeuS w/o L_trans', 'box', {'render.mode': 'reneus', 'render.max_depth': 2}, 0.0),
    ('reneus', 'ReNeuS', 'box', {'render.mode': 'reneus', 'render.max_depth': 2}, 0.1),
)
METHOD_KEYS = tuple(m[0] for m in METHODS)
OBJECTS = ('insect', 'statuette', 'vase')

#: The paper's Table 1 (its own Blender objects, 60 views at 800x800, 200k iterations):
#: NeuS w/o box, NeuS w/ box, ReNeuS w/ box. Not the same meshes as ours.
PAPER = {'insect': (5.89, 21.71, 1.10), 'statuette': (0.79, 25.44, 2.26), 'vase': (1.35, 24.68, 3.68)}


def configs() -> dict:
    """Preset, dataset and training changes of each configuration."""
    return {
        'small': {'preset': 'small', 'data': {'views': 16, 'res': 32, 'spp': 256},
                  'train': {'iterations': 200, 'validate_every': 0, 'checkpoint_every': 50,
                            'mesh_resolution': 128, 'postprocess': 'none'}},
        # The paper preset: NeuS's 256x8 SDF MLP, 256x4 colour MLP, 64 coarse + 64 fine samples.
        'full': {'preset': 'paper', 'data': {'views': 60, 'res': 800, 'spp': 256},
                 'train': {'iterations': 200000, 'batch_rays': 1024, 'learning_rate': 5e-4,
                           'warm_up': 5000, 'anneal_end': 50000, 'validate_every': 10000,
                           'checkpoint_every': 1000, 'mesh_resolution': 512, 'postprocess': 'none'}},
    }


def resolve(config: str, iterations: int | None = None, preset: str | None = None, **overrides) -> dict:
    """The settings of ``config`` with ``--iterations`` and test-size overrides applied.

    ``preset`` replaces the configuration's; ``overrides`` may hold ``data`` / ``train`` dicts
    merged into the configuration's.
    """
    all_cfgs = configs()
    if config not in all_cfgs:
        raise ValueError(f'config {config!r}: expected one of {", ".join(all_cfgs)}')
    cfg = {k: (dict(v) if isinstance(v, dict) else v) for k, v in all_cfgs[config].items()}
    for part, values in overrides.items():
        cfg[part].update(values or {})
    if iterations is not None:
        cfg['train']['iterations'] = int(iterations)
    if preset is not None:
        cfg['preset'] = preset
    cfg['name'] = config
    return cfg


def reconstruction_config(cfg: dict, model: dict | None = None, **train):
    """The ReconstructionConfig of ``cfg``'s preset with its training changes, ``model`` and ``train``."""
    from reneus_mi.config import replace
    from reneus_mi.presets import preset
    changes = {f'train.{k}': v for k, v in {**cfg['train'], **train}.items()}
    changes.update({f'model.{k}': v for k, v in (model or {}).items()})
    return replace(preset(cfg['preset']), **changes)


# ------------------------------------------------------------------ running
def dataset(obj: str, out: str, cfg: dict) -> str:
    """The folder of ``obj``'s dataset (both subsets), rendered once."""
    from reneus_mi.data.synthetic import make_dataset
    folder = os.path.join(out, obj, 'data')
    meta = os.path.join(folder, 'synth.json')
    want = cfg['data']
    if os.path.isfile(meta):
        with open(meta) as f:
            have = json.load(f)
        if all(have.get(k) == v for k, v in want.items()) and \
                all(os.path.isfile(os.path.join(folder, s, 'transforms.json')) for s in ('box', 'nobox')):
            return folder
        raise ValueError(f'{folder}: holds a dataset rendered with other settings '
                         f'({ {k: have.get(k) for k in want} } != {want}); choose another --out')
    print(f'[{obj}] rendering the dataset {want} into {folder}', flush=True)
    make_dataset(obj, folder, subsets=('box', 'nobox'), **want)
    return folder


def run_method(obj: str, key: str, out: str, cfg: dict, *, model_extra: dict | None = None,
               run_name: str | None = None, progress: bool = False) -> dict:
    """Fit one method on one object (or reuse its run) and evaluate it; returns result.json's dict."""
    import reneus_mi  # noqa: F401  (variant, plugins)
    from reneus_mi import runs
    from reneus_mi.config import to_dict
    from reneus_mi.data import load_dataset
    from reneus_mi.geometry.container import load_container
    from reneus_mi.geometry.chamfer import chamfer
    from reneus_mi.geometry.mesh import load_mesh, write_mesh
    from reneus_mi.utils.io import atomic_write_text
    from reneus_mi.geometry.surface import postprocess
    from reneus_mi.data.scene_xml import write_scene

    _, label, subset, settings, trans_weight = METHODS[METHOD_KEYS.index(key)]
    out = os.path.abspath(out)
    data = dataset(obj, out, cfg)
    config = reconstruction_config(cfg, {**settings, **(model_extra or {})}, trans_weight=trans_weight)
    subset_dir = os.path.join(data, subset)
    scene_path = os.path.join(out, obj, f'scene_{subset}.xml')
    if not os.path.isfile(scene_path):
        write_scene(load_dataset(subset_dir, need_container=False), scene_path, preset=cfg['preset'])
    # Every method is meshed in the glass box's bounds, box-free data too, so that the
    # Chamfer distances compare.
    box = load_container(os.path.join(data, 'box.ply'))
    spec = runs.RunSpec(scene_path, subset_dir, config, cfg['preset'],
                        mesh_bounds=tuple(map(tuple, box.bounds.tolist())))
    name = run_name or key
    run_dir = os.path.join(out, obj, name)
    evaluation = os.path.join(run_dir, 'evaluation.json')
    if os.path.isfile(evaluation) and runs.read_spec(run_dir).same_run(spec):
        with open(evaluation) as f:
            return json.load(f)
    print(f'[{obj}] {label}: training {config.train.iterations} iterations in {run_dir}', flush=True)
    start = time.perf_counter()
    result = runs.run_many({name: spec}, os.path.join(out, obj), progress=progress)[name]
    record = {'object': obj, 'method': key, 'label': label, 'subset': subset,
              'integrator': to_dict(config.model.render), 'train': to_dict(config.train),
              'data': cfg['data'], 'seconds': time.perf_counter() - start,
              's_per_it': _median_step_seconds(os.path.join(run_dir, 'log.jsonl'), config.train.batch_rays),
              'failure': result.get('failure'), 'chamfer': float('nan'), 'chamfer_raw_in_box': float('nan')}
    if record['failure'] is None:
        try:
            raw = load_mesh(result['mesh'])
            largest = postprocess(raw, 'largest')
            write_mesh(largest, os.path.join(run_dir, 'mesh_largest.ply'))
            gt = load_mesh(os.path.join(data, 'gt.ply'))
            record['chamfer'] = chamfer(largest, gt)['chamfer']
            record['chamfer_raw_in_box'] = chamfer(raw, gt, container=box)['chamfer']
            record['faces'] = int(len(raw.faces))
        except ValueError as e:  # empty mesh, nothing inside the box
            record['failure'] = str(e).splitlines()[0]
    atomic_write_text(evaluation, json.dumps(record, indent=2))
    print(f"[{obj}] {label}: Chamfer x100 {record['chamfer']:.3f} (largest), "
          f"{record['chamfer_raw_in_box']:.3f} (raw, in box); "
          f"{record['s_per_it'] or float('nan'):.2f} s/it", flush=True)
    return record


def _median_step_seconds(log_path: str, batch: int) -> float | None:
    if not os.path.isfile(log_path):
        return None
    with open(log_path) as f:
        rates = [json.loads(line)['rays_per_s'] for line in f if line.strip()]
    # Skip the first steps: they include the kernels' compilation.
    rates = rates[5:] if len(rates) > 10 else rates
    return float(np.median(batch / np.asarray(rates))) if rates else None


# ------------------------------------------------------------------- figure
def render_meshes(paths: list[str | None], res: int = 160, spp: int = 64) -> list[np.ndarray]:
    """Each mesh rendered with Mitsuba from one fixed viewpoint (grey diffuse, env + sun)."""
    import mitsuba as mi
    import reneus_mi  # noqa: F401
    sensor = mi.load_dict({
        'type': 'perspective', 'fov': 2.0 * np.degrees(np.arcsin(1.0 / 3.2)) * 0.8,
        'to_world': mi.ScalarTransform4f().look_at(origin=[2.0, -2.0, 1.6], target=[0, 0, 0], up=[0, 0, 1]),
        'sampler': {'type': 'independent', 'sample_count': spp},
        'film': {'type': 'hdrfilm', 'width': res, 'height': res, 'pixel_format': 'rgb'}})
    images = []
    for path in paths:
        if path is None or not os.path.isfile(path):
            images.append(np.full((res, res, 3), 0.25, np.float32))
            continue
        scene = mi.load_dict({
            'type': 'scene', 'integrator': {'type': 'direct'},
            'env': {'type': 'constant', 'radiance': {'type': 'rgb', 'value': 0.35}},
            'sun': {'type': 'directional', 'direction': [-1.0, 1.5, -2.0],
                    'irradiance': {'type': 'rgb', 'value': 2.5}},
            'mesh': {'type': 'ply', 'filename': os.path.abspath(path), 'face_normals': True,
                     'bsdf': {'type': 'twosided', 'bsdf': {'type': 'diffuse',
                              'reflectance': {'type': 'rgb', 'value': 0.7}}}}})
        img = np.asarray(mi.render(scene, sensor=sensor, spp=spp), np.float32)
        images.append(np.clip(img, 0, 1) ** (1 / 2.2))
    return images


def write_figure(results: dict, objects: list[str], path: str, out: str) -> None:
    """Grid: rows = objects, columns = ground truth + methods (largest component), labelled."""
    from PIL import Image, ImageDraw
    cols = ['GT'] + [m[1] for m in METHODS]
    res, label_h, row_w = 160, 18, 70
    canvas = Image.new('RGB', (row_w + res * len(cols), label_h + (res + label_h) * len(objects)), 'white')
    draw = ImageDraw.Draw(canvas)
    for c, name in enumerate(cols):
        draw.text((row_w + c * res + 4, 3), name, fill='black')
    for r, obj in enumerate(objects):
        paths = [os.path.join(out, obj, 'data', 'gt.ply')]
        for key in METHOD_KEYS:
            p = os.path.join(out, obj, key, 'mesh_largest.ply')
            paths.append(p if os.path.isfile(p) else None)
        y = label_h + r * (res + label_h)
        draw.text((4, y + res // 2), obj, fill='black')
        for c, img in enumerate(render_meshes(paths, res)):
            canvas.paste(Image.fromarray((img * 255 + 0.5).astype(np.uint8)), (row_w + c * res, y))
            if c > 0:
                value = results.get((obj, METHOD_KEYS[c - 1]), {}).get('chamfer', float('nan'))
                text = 'failed' if not np.isfinite(value) else f'CD {value:.2f}'
                draw.text((row_w + c * res + 4, y + res + 3), text, fill='black')
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    canvas.save(path)


# -------------------------------------------------------------------- table
def device() -> str:
    import mitsuba as mi
    import drjit as dr
    import reneus_mi  # noqa: F401
    cpu = platform.processor() or platform.machine()
    return (f'Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}, variant `{mi.variant()}`, '
            f'{os.cpu_count()} CPU cores ({cpu}), Python {platform.python_version()}')


def _num(x, fmt='.2f') -> str:
    return '—' if x is None or not np.isfinite(x) else format(x, fmt)


def table(results: dict, objects: list[str], cfg: dict, *, elapsed: float | None = None) -> str:
    from reneus_mi.config import to_dict
    config = reconstruction_config(cfg)
    d, t = cfg['data'], to_dict(config.train)
    field_cfg = to_dict(config.model.field)
    field = f"{field_cfg.pop('kind')} (" + ', '.join(f'{k}={v}' for k, v in field_cfg.items()) + ')'
    samples = ', '.join(f'{k}={v}' for k, v in to_dict(config.model.sampler).items())
    lines = [
        f"# Synthetic comparison (`--config {cfg['name']}`)", '',
        f"Generated by `python bench/compare.py --config {cfg['name']} --objects {' '.join(objects)} "
        f"--iterations {t['iterations']}` on {datetime.date.today().isoformat()}.", '',
        f"- Data: {d['views']} views at {d['res']}x{d['res']} px, {d['spp']} spp (Mitsuba `path`, "
        'glass box IOR 1.45, ambient 0.8), both subsets rendered with the same cameras.',
        f"- Training: {t['iterations']} iterations of {t['batch_rays']} rays, lr {t['learning_rate']} "
        f"(warm-up {t['warm_up']}, cosine decay), λ2 (Eikonal) {t['eikonal_weight']}, seed {t['seed']}.",
        f"- Preset `{cfg['preset']}`. Field: {field}; samples per segment: {samples}; ReNeuS D_re = 2.",
        f"- Mesh: marching cubes at {t['mesh_resolution']}^3 in the box's bounding box.",
        f'- Device: {device()}.',
        '', 'Chamfer-L1 x100 (lower is better). **CD** = after the paper\'s post-processing (largest '
        'connected component), as in Table 1. **CD raw∩box** = no post-processing, predicted points '
        'outside the glass box dropped, as in the ablation. Time = wall time of the training run '
        '(first method of a process includes kernel compilation); s/it = median step time.', '',
        '| object | method | subset | λ1 | CD | CD raw∩box | time (s) | s/it |',
        '| --- | --- | --- | --- | --- | --- | --- | --- |']
    for obj in objects:
        for key, label, subset, _, lam in METHODS:
            r = results.get((obj, key))
            if r is None:
                lines.append(f'| {obj} | {label} | {subset} | {lam:g} | not run | | | |')
                continue
            cd = 'failed' if r.get('failure') else _num(r['chamfer'])
            lines.append(f"| {obj} | {label} | {subset} | {lam:g} | {cd} | {_num(r['chamfer_raw_in_box'])} "
                         f"| {_num(r.get('seconds'), '.0f')} | {_num(r.get('s_per_it'))} |")
    failures = [(o, k, r['failure']) for (o, k), r in results.items() if r.get('failure')]
    if failures:
        lines += ['', 'Failures: ' + '; '.join(f'{o} / {k}: {f}' for o, k, f in failures)]
    lines += ['', '## Who wins on the box subset', '']
    for obj in objects:
        box = {k: results[(obj, k)]['chamfer'] for k in METHOD_KEYS[1:] if (obj, k) in results}
        box = {k: v for k, v in box.items() if np.isfinite(v)}
        if not box:
            lines.append(f'- {obj}: no finite result.')
            continue
        best = min(box, key=box.get)
        re, ne = box.get('reneus', np.nan), box.get('neus', np.nan)
        verdict = ('ReNeuS is ahead of NeuS' if re < ne else
                   '**ReNeuS is NOT ahead of NeuS**' if np.isfinite(re) and np.isfinite(ne) else
                   'ReNeuS vs NeuS: incomplete')
        lines.append(f"- {obj}: best on the box subset is {dict((m[0], m[1]) for m in METHODS)[best]} "
                     f"({box[best]:.2f}); {verdict} ({_num(re)} vs {_num(ne)}).")
    lines += ['', "The paper's Table 1 for reference (its own objects, 60 views at 800x800, 200k "
              'iterations on a GPU; not the same meshes as these procedural ones):', '',
              '| object | NeuS w/o box | NeuS w/ box | ReNeuS w/ box |', '| --- | --- | --- | --- |']
    lines += [f'| {o} | {a} | {b} | {c} |' for o, (a, b, c) in PAPER.items()]
    if elapsed is not None:
        lines += ['', f'Whole command: {elapsed / 60:.1f} min (including dataset rendering and '
                  'evaluation; reused runs cost nothing).']
    lines += ['', '![meshes](comparison.png)', '']
    return '\n'.join(lines)


def compare(objects, cfg: dict, out: str, doc_dir: str, *, progress: bool = False,
            methods=METHOD_KEYS, note: str | None = None) -> dict:
    """Run every method on every object, write the table and the figure; return the results."""
    start = time.perf_counter()
    out = os.path.abspath(out)
    results = {}
    for obj in objects:
        for key in methods:
            results[(obj, key)] = run_method(obj, key, out, cfg, progress=progress)
    os.makedirs(doc_dir, exist_ok=True)
    md = table(results, list(objects), cfg, elapsed=time.perf_counter() - start)
    if note:
        md = md.replace('## Who wins', note + '\n\n## Who wins', 1)
    from reneus_mi.utils.io import write_section
    write_figure(results, list(objects), os.path.join(doc_dir, 'comparison.png'), out)
    # bench/refine.py writes its own section of the same document.
    write_section(os.path.join(doc_dir, 'comparison.md'), 'compare', md)
    return results


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('--config', choices=('small', 'full'), default='small')
    p.add_argument('--objects', nargs='+', default=list(OBJECTS), choices=OBJECTS)
    p.add_argument('--iterations', type=int, help="iterations per method (default: the config's)")
    p.add_argument('--out', help='runs folder (default: runs/compare_<config>)')
    p.add_argument('--doc', default=os.path.join(ROOT, 'docs'), help='where comparison.md/.png go')
    p.add_argument('--progress', action='store_true', help='progress bars')
    args = p.parse_args(argv)
    cfg = resolve(args.config, args.iterations)
    out = args.out or os.path.join('runs', f'compare_{args.config}')
    from reneus_mi.utils.errors import exit_on_error
    with exit_on_error():
        compare(args.objects, cfg, out, args.doc, progress=args.progress)
    print(f"wrote {os.path.join(args.doc, 'comparison.md')} and comparison.png")
    return 0


if __name__ == '__main__':
    sys.exit(main())
