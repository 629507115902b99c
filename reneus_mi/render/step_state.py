"""What a training step hands the renderer: its place in the schedules and its seed."""
from __future__ import annotations

from dataclasses import dataclass


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
    field: bool = True
    """Whether the field is rendered (False: the container empty, its media only absorbing: what
    the photographs show where no specimen is, to which the media are fitted first)."""
