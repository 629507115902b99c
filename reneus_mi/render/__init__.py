"""Rendering through the container: what the ``reneus`` integrator (plugins/reneus.py) uses."""
