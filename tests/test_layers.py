"""The house's layers, kept: no module imports one of a layer above its own.

The order, bottom to top (``docs/architecture.md`` draws it in words). A module's layer is its
package under ``reneus_mi`` (``reneus_mi/train/trainer.py``: ``train``), or its own name at the
top (``reneus_mi/config.py``: ``config``); the integrator's ``plugins/`` has a layer of its own,
and a package's ``__main__.py`` is a command.
Every ``import`` counts, at the top of a file or inside a function.
"""
import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]

#: Bottom to top; names on one row are one layer (they may import each other's layers below).
LAYERS = [
    ('utils', 'paper'),  # the plumbing; the paper's values
    ('fields',),
    ('geometry',),
    ('data',),
    ('render',),
    ('train',),
    ('config',),
    ('presets',),
    ('runs',),
    ('plugins',),
    ('capture',),
    ('export',),
    ('batch',),
    # The commands, each room's __main__.py, and the package's entry (its __init__: the variant
    # and the integrator's registration).
    ('optimize', 'scene', 'extract', 'evaluate', 'synth', 'simulate', 'board', 'colmap', '__main__', 'reneus_mi'),
]

#: Each layer's height in LAYERS.
RANK = {name: i for i, row in enumerate(LAYERS) for name in row}


def _layer_of(path: pathlib.Path) -> str:
    parts = path.relative_to(ROOT).with_suffix('').parts
    if parts[0] == 'plugins':
        return 'plugins'
    if parts[-1] == '__main__':
        return '__main__'
    return parts[1] if len(parts) > 2 or parts[1] != '__init__' else 'reneus_mi'


def _imported(module: str) -> str | None:
    """The layer of an imported module's name, or None outside the project."""
    parts = module.split('.')
    if parts[0] == 'plugins':
        return 'plugins'
    if parts[0] != 'reneus_mi':
        return None
    if len(parts) == 1:
        return 'reneus_mi'
    return 'plugins' if parts[1] == 'plugins' else parts[1]


def imports() -> set[tuple[str, str, str]]:
    """(file, its layer, an imported layer) of every import in the project's modules."""
    found = set()
    for path in sorted([*ROOT.glob('reneus_mi/**/*.py'), *ROOT.glob('plugins/*.py')]):
        if 'vendor' in path.parts:
            continue
        layer = _layer_of(path)
        assert layer in RANK, f'{path}: layer {layer!r} is in no row of LAYERS'
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = ([node.module] if isinstance(node, ast.ImportFrom) and node.module and not node.level
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            if names == ['reneus_mi'] and isinstance(node, ast.ImportFrom):
                # ``from reneus_mi import runs``: the module imported, not the package's entry.
                names = [f'reneus_mi.{a.name}' for a in node.names]
            for name in names:
                target = _imported(name)
                if target is not None and target != layer:
                    assert target in RANK, f'{path}: imports {name}, whose layer {target!r} is in no row'
                    found.add((str(path.relative_to(ROOT)), layer, target))
    return found


def test_no_module_imports_a_layer_above_its_own():
    upward = sorted({(f, target) for f, layer, target in imports() if RANK[target] > RANK[layer]})
    assert not upward, ('imports of a layer above their own (docs/architecture.md): '
                        + '; '.join(f'{f} imports {t}' for f, t in upward))
