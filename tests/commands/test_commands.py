"""The commands: one thin main() each, run by ``python -m reneus_mi.<command>`` and by the
console scripts of pyproject.toml; the library never imports a command."""
import ast
import importlib
import os
import tomllib

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..'))
COMMANDS = {'optimize': 'reneus_mi.optimize', 'render': 'reneus_mi.render.__main__',
            'extract': 'reneus_mi.extract', 'evaluate': 'reneus_mi.evaluate', 'scene': 'reneus_mi.scene',
            'synth': 'reneus_mi.synth', 'capture': 'reneus_mi.capture.__main__',
            'batch': 'reneus_mi.batch.__main__', 'board': 'reneus_mi.board', 'colmap': 'reneus_mi.colmap',
            'simulate': 'reneus_mi.simulate', 'export': 'reneus_mi.export.__main__'}
#: The package's top level: the commands that are modules, the configuration, its presets, the
#: runs built from them, and the paper's values that it and the data start from.
TOP_LEVEL = {'optimize', 'extract', 'evaluate', 'scene', 'synth', 'board', 'colmap', 'simulate', 'config',
             'presets', 'runs', 'paper'}


def test_console_scripts_are_the_commands_mains():
    with open(os.path.join(ROOT, 'pyproject.toml'), 'rb') as f:
        scripts = tomllib.load(f)['project']['scripts']
    assert scripts == {f'reneus-{name}': f'{module}:main' for name, module in COMMANDS.items()}
    for target in scripts.values():
        module, _, name = target.partition(':')
        assert callable(getattr(importlib.import_module(module), name))


def test_no_library_module_imports_a_command():
    for module, path in _library_modules():
        for node in ast.walk(ast.parse(open(path).read())):
            names = ([node.module] + [f'{node.module}.{a.name}' for a in node.names]
                     if isinstance(node, ast.ImportFrom) and node.module else
                     [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            hit = [n for n in names if n in COMMANDS.values()]
            assert not hit, f'{module} imports the command {hit[0]}'


def _library_modules():
    for folder in ('reneus_mi', 'plugins'):
        for dirpath, _, names in os.walk(os.path.join(ROOT, folder)):
            for n in names:
                if n.endswith('.py'):
                    path = os.path.join(dirpath, n)
                    module = os.path.relpath(path, ROOT)[:-3].replace(os.sep, '.')
                    if module not in COMMANDS.values():
                        yield module, path


def test_only_commands_have_a_main():
    for module, path in _library_modules():
        defined = [node.name for node in ast.parse(open(path).read()).body
                   if isinstance(node, ast.FunctionDef) and node.name == 'main']
        assert not defined, f'{module} defines main(): a command belongs in python -m reneus_mi.<command>'


def test_the_top_level_shows_the_commands_and_the_configuration():
    package = os.path.join(ROOT, 'reneus_mi')
    modules = {n[:-3] for n in os.listdir(package) if n.endswith('.py') and n != '__init__.py'}
    assert modules == TOP_LEVEL
