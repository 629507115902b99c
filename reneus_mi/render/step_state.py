"""What a training step hands the renderer: its place in the schedules and its seed."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi


@dataclass
class StepState:
    """Per-step schedule values of training, handed to the renderer in one place
    (``integrator.begin_step``); the default is a render's: stratum midpoints, full sharpness."""
    step: int = 0
    """The optimisation step (the occupancy grid's refreshes count these)."""
    schedule: int | None = None
    """Where the schedules stand, in steps (the field's coarse-to-fine levels follow it):
    the step itself, or under a time budget the share of the budget spent times the
    planned iterations (None: ``step``)."""
    cos_anneal_ratio: float = 1.0
    """NeuS's cosine annealing ratio in [0, 1]."""
    seed: int | None = None
    """Seed of the step's random numbers: the stratified jitter of every segment's samples and
    the Russian roulette of low-weight branches (None: stratum midpoints, roulette stream 0)."""
    refining: mi.Bool | None = None
    """Which camera rays' gradients reach the refined quantities (the container's IOR, pose and
    absorption, the light): the uniformly drawn ones of an error-drawn batch (None: every ray's).
    The error-drawn rays over-represent what the field still fits badly, and a quantity of the
    whole scene fitted to them drifts (an ambient light started at 0.7 for the true 0.8: 0.797
    at 200 steps, then 0.782 at 400 as the field sharpened; 0.797 with the uniform rays only);
    the field learns from all of them (the thin parts' gain)."""
    field: bool = True
    """Whether the field is rendered (False: the container empty, its media only absorbing: what
    the photographs show where no specimen is, to which the media are fitted first)."""


def refined(value, lanes: mi.Bool | None):
    """A refined quantity as the rays read it, its gradient taken from the ``lanes`` alone
    (:attr:`StepState.refining`, gathered per ray; None: from every ray)."""
    return value if lanes is None else dr.select(lanes, value, dr.detach(value))
