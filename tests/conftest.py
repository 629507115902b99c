import os
import sys


# Tests run on the CPU variant, whatever the machine has.
os.environ.setdefault('RENEUS_VARIANT', 'llvm_ad_rgb')
sys.path.insert(0, os.path.dirname(__file__))

import reneus_mi  # noqa: E402,F401  (sets the variant, registers the plugins)


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: long-running, still run by CI')
