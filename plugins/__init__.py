"""Mitsuba plugins of reneus-mi, registered for the active variant."""
import mitsuba as mi

_registered: set[str] = set()


def register() -> None:
    """Register every plugin for the active variant (idempotent)."""
    if mi.variant() in _registered:
        return
    # The integrator class derives from the variant's ADIntegrator: a module
    # imported under another variant must be re-imported.
    import importlib
    from reneus_mi.plugins import reneus
    if reneus.VARIANT != mi.variant():
        reneus = importlib.reload(reneus)
    mi.register_integrator('reneus', lambda props: reneus.ReNeuSIntegrator(props))
    _registered.add(mi.variant())
