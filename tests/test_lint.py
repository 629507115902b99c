"""The linter of the hooks before each commit (.pre-commit-config.yaml), in CI as well:
pyflakes' checks (names undefined or unused, imports unused) over the code, the tests, the
benchmarks and the notebooks, as ``pyproject.toml``'s ``[tool.ruff]`` selects them."""
import pathlib
import shutil
import subprocess

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_the_linter_finds_nothing():
    ruff = shutil.which('ruff')
    assert ruff, "no ruff: pip install -e '.[test]' (bash setup.sh test) installs it"
    found = subprocess.run([ruff, 'check', '--no-cache', '--output-format', 'concise', str(ROOT)],
                           capture_output=True, text=True, cwd=ROOT)
    assert found.returncode == 0, found.stdout + found.stderr
