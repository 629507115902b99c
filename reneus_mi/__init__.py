"""reneus-mi: ReNeuS (CVPR 2023) on Mitsuba 3.

Importing the package selects a variant (see :mod:`reneus_mi.utils.variant`) unless
one is already set, and registers the ``reneus`` integrator with Mitsuba. In a
command's process it first takes Ctrl-C (:mod:`reneus_mi.utils.interrupt`), so that an
interrupt during the imports already ends in one line.
"""
from reneus_mi.utils import interrupt

if interrupt.is_command():
    interrupt.install()

from reneus_mi.utils.variant import ensure_variant, on_set, set_variant  # noqa: E402  (after the interrupt)
from reneus_mi.plugins import register  # noqa: E402

ensure_variant()
on_set(register)

__all__ = ['set_variant']
__version__ = '0.1.0'
