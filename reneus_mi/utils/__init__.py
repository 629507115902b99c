"""The plumbing every room uses.

- :mod:`~reneus_mi.utils.errors`: :class:`ReneusError`, one line per bad input.
- :mod:`~reneus_mi.utils.validate`: the configuration dataclasses' range checks.
- :mod:`~reneus_mi.utils.io`: atomic files and folders, ``.npz`` checks.
- :mod:`~reneus_mi.utils.guards`: what a folder holds before a command writes into it.
- :mod:`~reneus_mi.utils.limits`: memory and size limits checked before a kernel runs.
- :mod:`~reneus_mi.utils.interrupt`: Ctrl-C in a command ends in one line.
- :mod:`~reneus_mi.utils.cli`: command-line settings over the configuration dataclasses.
- :mod:`~reneus_mi.utils.variant`: the Mitsuba variant, and the plugins registered for it.
- :mod:`~reneus_mi.utils.param_groups`: named parameter groups, each with its learning rate.
"""
