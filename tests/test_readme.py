"""The README's layout table names every module of the tree, and nothing that is not there."""
import glob
import os
import re

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))


def layout() -> set[str]:
    """The paths the layout table names (a row's later files are relative to its first's folder,
    a folder's modules are the .py files its description names)."""
    text = open(os.path.join(ROOT, 'README.md')).read().split('## Layout', 1)[1]
    named = set()
    for line in text.splitlines():
        cells = line.strip().strip('|').split('|')
        if len(cells) != 2 or cells[0].strip() in ('path', '---'):
            continue
        first, *rest = re.findall(r'`([^`]+)`', cells[0])
        paths = [first] + [os.path.join(os.path.dirname(first.rstrip('/')), p) for p in rest]
        named.update(paths)
        for folder in (p for p in paths if p.endswith('/')):
            named |= {os.path.join(folder, f) for f in re.findall(r'`(\w+\.py)`', cells[1])}
    return named


def test_layout_table_matches_the_tree():
    named = layout()
    missing = sorted(p for p in named if not os.path.exists(os.path.join(ROOT, p)))
    assert not missing, f'the README names what is not in the tree: {missing}'
    modules = [os.path.relpath(p, ROOT) for p in glob.glob(os.path.join(ROOT, 'reneus_mi', '**', '*.py'),
                                                            recursive=True) + [os.path.join(ROOT, 'plugins', 'reneus.py')]]
    unnamed = sorted(m for m in modules if not m.endswith('__init__.py') and m not in named)
    assert not unnamed, f'the README\'s layout table does not name {unnamed}'
