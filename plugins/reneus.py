import mitsuba as mi

VARIANT = mi.variant()


class ReNeuSIntegrator(mi.ad.integrators.common.ADIntegrator):
    pass
