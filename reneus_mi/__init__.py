"""reneus-mi: ReNeuS (CVPR 2023) on Mitsuba 3.

Importing the package selects a variant (see :mod:`reneus_mi.variant`) unless
one is already set, and registers the ``reneus`` integrator with Mitsuba.
"""
from reneus_mi.variant import ensure_variant, set_variant

ensure_variant()

__all__ = ['set_variant']
__version__ = '0.1.0'
