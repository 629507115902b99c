"""Mitsuba plugins of reneus-mi, registered for the active variant."""
import importlib

import mitsuba as mi

_registered: set[str] = set()


def register() -> None:
    """Register every plugin for the active variant (idempotent)."""
    if mi.variant() in _registered:
        return
    # A plugin module registers itself as it is imported. Its class derives from the variant's
    # ADIntegrator: imported here, once a variant is active, and again under another variant.
    from reneus_mi.plugins import reneus
    if reneus.VARIANT != mi.variant():
        importlib.reload(reneus)
    _registered.add(mi.variant())
