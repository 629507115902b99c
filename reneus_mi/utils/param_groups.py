"""Named groups of parameters, each with its learning rate and the step it starts moving at.

What is fitted declares its own groups, as nerfstudio's models do with
``get_param_groups``: the field (:meth:`reneus_mi.fields.Field.param_groups`:
its networks, a hash grid's table at its own rate) and the surroundings a run
refines (:meth:`reneus_mi.render.surroundings.Surroundings.param_groups`: the
IOR, the container's pose, the light). The trainer builds one Adam over every
group's keys, selected by name in ``mi.traverse(scene)``, gives each group its
rate on the run's schedule, holds it until its start step and keeps it within
its bounds.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ParamGroup:
    name: str
    """What the group is: ``field``, ``field.grid``, ``ior``, ``pose``, ``light``."""
    keys: tuple[str, ...]
    """The integrator's names of its arrays (``sdf.weights``, ``container.eta``, ...)."""
    learning_rate: float
    """Peak learning rate; it follows the run's schedule (warm-up, cosine decay)."""
    start: int = 0
    """Step of the run's schedule (the step, or under a time budget the share of it spent laid
    over the iterations) from which the group moves; before it, its learning rate is 0."""
    bounds: tuple[float, float] | None = None
    """Interval the values are clipped to after every step (None: unbounded)."""
