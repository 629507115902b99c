"""What a batch reports: a row per specimen read from disk, as CSV and HTML, and a progress line.

Every figure comes from the folders (the run's ``result.json`` and ``log.jsonl``,
the batch's ``metrics.json`` and ``attempts.jsonl``), so any process can write
the summary at any time and it says what the disk holds.

=============  ==================================================================
column         what
=============  ==================================================================
state, reason  the run's state (new, running, resumable, finished, failed) and why
wall_s         seconds of all its attempts (start, training, mesh, preview)
iterations     steps done
psnr           dB, mean of the last 100 steps
chamfer        Chamfer-L1 x 100 to the dataset's ground truth mesh (where it has one)
ior            the refined IOR (train.refine.ior)
translation,   the refined pose of the container (train.refine.pose): shift,
rotation,      rotation (the integrator's parameters), per-axis scale
scale
light          the refined light (its mean colour)
mesh, preview  the mesh file and the rendered preview, relative to RUNS_DIR
page           the report page of its package (reneus_mi.export), relative to RUNS_DIR
=============  ==================================================================
"""
from __future__ import annotations

import csv
import html
import io
import math
import os
import time

from reneus_mi.train.run_folder import recent_psnr
from reneus_mi.utils.io import atomic_write_text

COLUMNS = ('name', 'state', 'reason', 'wall_s', 'iterations', 'psnr', 'chamfer', 'ior', 'translation',
           'rotation', 'scale', 'light', 'mesh', 'container', 'preview', 'page', 'data')
#: Result keys of the refined quantities, by column.
_REFINED = {'ior': 'container.eta', 'translation': 'container.translation', 'rotation': 'container.rotation',
            'scale': 'container.scale', 'light': 'light.mean'}


def row(batch, specimen) -> dict:
    """The summary of one specimen, read from disk."""
    folder, files = batch.run(specimen.name), batch.specimen(specimen.name)
    state = folder.state()
    result = folder.read_result() or {}
    log = folder.read_log() if os.path.isfile(folder.log) else []
    psnr = result.get('psnr')
    if not isinstance(psnr, (int, float)) or psnr != psnr:
        psnr = recent_psnr(log)
    attempts = [a['seconds'] for a in files.read_attempts() if isinstance(a.get('seconds'), (int, float))]
    out = {'name': specimen.name, 'state': state.name, 'reason': state.reason,
           'wall_s': round(sum(attempts), 1) if attempts else None,
           'iterations': result.get('iterations', log[-1]['iteration'] if log else None),
           'psnr': None if psnr is None else round(psnr, 2),
           'chamfer': _rounded(files.read_metrics().get('chamfer'), 4), 'data': specimen.data}
    refined = result.get('refined') or (log[-1] if log else {})
    for column, key in _REFINED.items():
        out[column] = _numbers(refined.get(key))
    for column, path in (('mesh', folder.mesh), ('container', folder.container), ('preview', files.preview)):
        out[column] = os.path.relpath(path, batch.path) if _nonempty(path) else None
    page = files.page()
    out['page'] = os.path.relpath(page, batch.path) if page else None
    return out


def write(batch, specimens) -> list[dict]:
    """Rewrite ``summary.csv`` and ``summary.html``; return the rows."""
    rows = [row(batch, s) for s in specimens]
    text = io.StringIO()
    writer = csv.DictWriter(text, COLUMNS, lineterminator='\n')
    writer.writeheader()
    writer.writerows({k: '' if v is None else v for k, v in r.items()} for r in rows)
    atomic_write_text(batch.summary_csv, text.getvalue())
    atomic_write_text(batch.summary_html, _html(rows))
    return rows


def progress_line(counts: dict, started: float, ended: int, now: float | None = None) -> str:
    """``batch: 3 finished, 2 running, 1 failed, 4 left (ETA 12 min)``: ``counts`` by state
    of this batch's specimens; the ETA from the pace of the ``ended`` runs since ``started``."""
    now = time.monotonic() if now is None else now
    parts = [f"{counts.get('finished', 0)} finished", f"{counts.get('running', 0)} running",
             f"{counts.get('failed', 0)} failed", f"{counts.get('left', 0)} left"]
    if counts.get('busy'):
        parts.append(f"{counts['busy']} in use by another process")
    todo = counts.get('left', 0) + counts.get('running', 0)
    eta = ''
    if todo and ended:
        eta = f' (ETA {_duration((now - started) / ended * todo)})'
    elif not todo:
        eta = f' (done in {_duration(now - started)})'
    return 'batch: ' + ', '.join(parts) + eta


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f'{seconds:.0f} s'
    if seconds < 90 * 60:
        return f'{seconds / 60:.0f} min'
    return f'{seconds / 3600:.1f} h'


def _rounded(value, digits: int):
    return round(value, digits) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _numbers(value) -> str | None:
    if value is None:
        return None
    values = value if isinstance(value, (list, tuple)) else [value]
    return ' '.join(f'{v:.6g}' for v in values)


def _nonempty(path: str) -> bool:
    return os.path.isfile(path) and os.path.getsize(path) > 0


_STATE_COLOURS = {'finished': '#d9f2d9', 'failed': '#f8d7d7', 'running': '#fff3c4', 'resumable': '#e6e6f5',
                  'new': '#ffffff'}


def _html(rows: list[dict]) -> str:
    e = html.escape
    head = ''.join(f'<th>{e(c)}</th>' for c in ('preview', 'name', 'state', 'wall', 'iterations', 'PSNR',
                                                 'Chamfer x100', 'refined', 'files'))
    body = []
    for r in rows:
        preview = (f'<img src="{e(r["preview"])}" width="120" height="120" alt="{e(r["name"])}">'
                   if r['preview'] else '<span class="none">no mesh</span>')
        if r['page']:    # the thumbnail opens the specimen's report page
            preview = f'<a href="{e(r["page"])}">{preview}</a>'
        name = f'<a href="{e(r["page"])}">{e(r["name"])}</a>' if r['page'] else e(r['name'])
        state = e(r['state']) + (f'<div class="reason">{e(r["reason"])}</div>' if r['reason'] else '')
        refined = '<br>'.join(f'{e(c)} {e(r[c])}' for c in _REFINED if r[c])
        links = ' '.join(f'<a href="{e(r[c])}">{c}</a>' for c in ('page', 'mesh', 'container') if r[c])
        cells = [preview, name, state, _cell(r['wall_s'], 's'), _cell(r['iterations']),
                 _cell(r['psnr'], 'dB'), _cell(r['chamfer']), refined, links]
        body.append(f'<tr style="background:{_STATE_COLOURS.get(r["state"], "#fff")}">'
                    + ''.join(f'<td>{c}</td>' for c in cells) + '</tr>')
    counts = {}
    for r in rows:
        counts[r['state']] = counts.get(r['state'], 0) + 1
    said = ', '.join(f'{n} {s}' for s, n in sorted(counts.items()))
    return f'''<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>reneus-mi batch</title>
<style>
body {{ font-family: sans-serif; margin: 1.5em; }}
table {{ border-collapse: collapse; }}
td, th {{ border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: middle; }}
.reason {{ font-size: small; color: #722; max-width: 28em; }}
.none {{ color: #999; font-size: small; }}
</style></head><body>
<h1>reneus-mi batch</h1>
<p>{len(rows)} specimens: {e(said)}. Written {e(time.strftime('%Y-%m-%d %H:%M:%S'))}; the same in
<a href="summary.csv">summary.csv</a>.</p>
<table><tr>{head}</tr>
{chr(10).join(body)}
</table></body></html>
'''


def _cell(value, unit: str = '') -> str:
    if value is None:
        return ''
    return html.escape(f'{value:g} {unit}'.strip() if isinstance(value, float) else f'{value} {unit}'.strip())
