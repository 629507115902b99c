"""Geometry: meshes from fields, the container, and the Chamfer distance."""
