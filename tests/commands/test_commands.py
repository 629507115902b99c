"""The commands: one thin main() each, run by ``python -m reneus_mi.<command>`` and by the
console scripts of pyproject.toml; the library never imports a command."""
import ast
import importlib
import os
import tomllib

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..'))
COMMANDS = {'optimize': 'reneus_mi.optimize', 'render': 'reneus_mi.render.__main__',
            'extract': 'reneus_mi.extract', 'evaluate': 'reneus_mi.evaluate', 'scene': 'reneus_mi.scene',
            'synth': 'reneus_mi.synth', 'capture': 'reneus_mi.capture.command',
            'batch': 'reneus_mi.batch.__main__'}


def test_console_scripts_are_the_commands_mains():
    with open(os.path.join(ROOT, 'pyproject.toml'), 'rb') as f:
        scripts = tomllib.load(f)['project']['scripts']
    assert scripts == {f'reneus-{name}': f'{module}:main' for name, module in COMMANDS.items()}
    for target in scripts.values():
        module, _, name = target.partition(':')
        assert callable(getattr(importlib.import_module(module), name))


def test_no_library_module_imports_a_command():
    library = []
    for folder in ('reneus_mi', 'plugins'):
        for dirpath, _, names in os.walk(os.path.join(ROOT, folder)):
            library += [os.path.join(dirpath, n) for n in names if n.endswith('.py')]
    for path in library:
        module = os.path.relpath(path, ROOT)[:-3].replace(os.sep, '.')
        if module in COMMANDS.values() or module in ('reneus_mi.cli', 'reneus_mi.capture.__main__'):
            continue
        for node in ast.walk(ast.parse(open(path).read())):
            names = ([node.module] + [f'{node.module}.{a.name}' for a in node.names]
                     if isinstance(node, ast.ImportFrom) and node.module else
                     [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            hit = [n for n in names if n in COMMANDS.values() or n == 'reneus_mi.render.__main__']
            assert not hit, f'{module} imports the command {hit[0]}'
