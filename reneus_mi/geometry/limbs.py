"""How far a reconstruction reaches along a specimen's legs and antennae: the lengths a
taxonomist measures, which Chamfer averages away.

A limb of the truth is its axis, a polyline of joints from the body out, with a radius at
each joint (``truth.json``'s ``limbs`` of ``bench/blender_capture.py``). Along the axis,
every ``step``, the reconstruction *covers* the limb where its surface comes within the
limb's radius plus ``tolerance`` of the axis, or holds the axis inside it (a leg come out
thick). The limb's reach is the farthest covered point, as arclength from the body; its
error is the reach against the limb's length, in %; the longest run of uncovered axis
before the reach says whether the limb is attached or a piece lies beyond a gap.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.spatial import cKDTree
import trimesh

from reneus_mi.geometry.container import inside
from reneus_mi.utils.errors import ReneusError

#: Surface points per mesh from which distances to the axes are taken.
SURFACE_POINTS = 200_000


def axis_samples(joints: np.ndarray, radii: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points every ``step`` along the polyline ``joints`` (both ends included), their
    arclength from the first joint and the radius there (linear between joints)."""
    seg = np.linalg.norm(np.diff(joints, axis=0), axis=1)
    at = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, at[-1], max(2, int(np.ceil(at[-1] / step)) + 1))
    points = np.stack([np.interp(s, at, joints[:, k]) for k in range(3)], axis=1)
    return points, s, np.interp(s, at, radii)


def limb_reach(mesh: trimesh.Trimesh, limbs: list[dict], tolerance: float, step: float | None = None,
               seed: int = 0) -> list[dict]:
    """Per limb (``{'name', 'joints_mm', 'radii_mm'}``): its ``length``, the ``reach`` of
    ``mesh`` along it, ``error_pct`` and ``longest_gap`` (same units as the mesh)."""
    if len(mesh.faces) == 0:
        raise ReneusError('the mesh has no surface to measure limbs on')
    surface, _ = trimesh.sample.sample_surface(mesh, SURFACE_POINTS, seed=seed)
    tree = cKDTree(surface)
    out = []
    for name, points, s, r in _axes(limbs, step or 0.5 * tolerance):
        covered = tree.query(points, workers=-1)[0] <= r + tolerance
        try:
            covered |= inside(points, mesh)
        except ReneusError:
            pass        # a mesh that is not closed holds nothing inside: its surface alone counts
        out.append(_reach(name, s, covered))
    return out


def field_reach(field, frame, limbs: list[dict], tolerance: float, step: float | None = None) -> list[dict]:
    """:func:`limb_reach` of a trained field itself, before marching cubes and the clean-up: an
    axis point is covered where the field's SDF there, in the world's units (``frame``), is at
    most the limb's radius plus ``tolerance`` (inside counts). A limb the mesh misses and the
    field reaches was lost in meshing; one the field misses too was never grown."""
    out = []
    for name, points, s, r in _axes(limbs, step or 0.5 * tolerance):
        x = frame.to_field(mi.Point3f(*(mi.Float(points[:, k].astype(np.float32)) for k in range(3))))
        with dr.suspend_grad():
            sdf = np.asarray(field.sdf(x), np.float64) * frame.scale
        out.append(_reach(name, s, sdf <= r + tolerance))
    return out


def _axes(limbs: list[dict], step: float):
    """Per limb: its name and :func:`axis_samples` (checked: a clear error for a malformed limb)."""
    for limb in limbs:
        try:
            joints = np.asarray(limb['joints_mm'], float).reshape(-1, 3)
            radii = np.asarray(limb['radii_mm'], float).reshape(-1)
            name = str(limb['name'])
        except (KeyError, TypeError, ValueError) as e:
            raise ReneusError(f'limb {limb!r}: {e!r}; expected name, joints_mm (N x 3) and radii_mm (N)') from None
        if len(joints) < 2 or len(radii) != len(joints):
            raise ReneusError(f'limb {name!r}: {len(joints)} joints and {len(radii)} radii; expected at least '
                              'two joints, a radius each')
        yield (name, *axis_samples(joints, radii, step))


def _reach(name: str, s: np.ndarray, covered: np.ndarray) -> dict:
    """A limb's reach from which of its axis samples (arclength ``s``) are covered."""
    reached = np.flatnonzero(covered)
    reach = float(s[reached[-1]]) if len(reached) else 0.0
    # Uncovered axis between covered samples, and before the first one.
    bounds = np.concatenate([[-(s[1] - s[0])], s[reached]])
    gap = float(np.diff(bounds).max() - (s[1] - s[0])) if len(reached) else float(s[-1])
    return {'name': name, 'length': float(s[-1]), 'reach': reach,
            'error_pct': 100.0 * (reach - s[-1]) / s[-1], 'longest_gap': gap}
