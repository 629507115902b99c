"""Shared by every test: the CPU variant, the ``slow`` marker and the fixtures.

Helpers that are not fixtures live beside this file: ``reference.py`` (reference
scenes and shapes), ``tiny.py`` (the tiny dataset and trainers on it) and
``capture_data.py`` (the simulated ChArUco capture).
"""
import os
import sys

import pytest

# Tests run on the CPU variant, whatever the machine has.
os.environ.setdefault('RENEUS_VARIANT', 'llvm_ad_rgb')
sys.path.insert(0, os.path.dirname(__file__))

import drjit as dr  # noqa: E402
import reneus_mi  # noqa: E402,F401  (sets the variant, registers the plugins)


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: long-running, still run by CI')


@pytest.fixture(scope='session')
def scene_xml(tmp_path_factory):
    """The scene XML of the tiny statuette dataset (``tiny.py``), rendered once per session."""
    from tiny import tiny_dataset
    return tiny_dataset(tmp_path_factory.getbasetemp() / 'tiny_statuette')


@pytest.fixture(scope='session')
def simulated_capture(tmp_path_factory):
    """The simulated capture (``capture_data.py``): ``{'photos', 'truth', 'meta'}``, rendered
    once per session."""
    from capture_data import capture
    return capture(tmp_path_factory.getbasetemp() / 'capture')


@pytest.fixture
def one_thread():
    """Dr.Jit on one thread: float sums in a fixed order, runs bitwise equal."""
    old = dr.thread_count()
    dr.set_thread_count(1)
    yield
    dr.set_thread_count(old)
