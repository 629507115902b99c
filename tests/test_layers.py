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
    ('utils', 'reneus_mi', 'paper'),  # the package's __init__ (version, variant); the paper's values
    ('fields',),
    ('geometry',),
    ('data',),
    ('render',),
    ('train',),
    ('config',),
    ('presets',),
    ('plugins',),
    ('capture',),
    ('export',),
    ('batch',),
    # The commands, and each room's __main__.py.
    ('optimize', 'scene', 'extract', 'evaluate', 'synth', 'simulate', 'board', 'colmap', '__main__'),
]

#: Each layer's height in LAYERS.
RANK = {name: i for i, row in enumerate(LAYERS) for name in row}

#: Upward imports still in the house, each with what removes it (#42). The test fails on any
#: other, and on an entry here that no longer happens: the list only shrinks.
KNOWN = {
    ('reneus_mi/train/trainer.py', 'config'): 'TrainConfig moves into train/, config.py aggregates it',
    ('reneus_mi/train/runs.py', 'config'): 'the same: ReconstructionConfig built above train',
    ('reneus_mi/train/runs.py', 'presets'): 'the same: a run built from a preset above train',
    ('reneus_mi/render/properties.py', 'config'): 'the XML properties to configs: above config',
    ('reneus_mi/render/properties.py', 'presets'): 'the same',
    ('reneus_mi/data/scene_xml.py', 'config'): 'RenderConfig beside the renderer, below data',
    ('reneus_mi/utils/cli.py', 'config'): "text_value's field kinds: the CLI generator above config",
    ('reneus_mi/utils/variant.py', 'plugins'): "the integrator's registration from the package's entry",
}


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
            for name in names:
                target = _imported(name)
                if target is not None and target != layer:
                    assert target in RANK, f'{path}: imports {name}, whose layer {target!r} is in no row'
                    found.add((str(path.relative_to(ROOT)), layer, target))
    return found


def test_no_module_imports_a_layer_above_its_own():
    upward = {(f, target) for f, layer, target in imports() if RANK[target] > RANK[layer]}
    new = sorted(upward - KNOWN.keys())
    gone = sorted(KNOWN.keys() - upward)
    assert not new, ('imports of a layer above their own (docs/architecture.md): '
                     + '; '.join(f'{f} imports {t}' for f, t in new))
    assert not gone, f'no longer imported, strike them from KNOWN: {gone}'
