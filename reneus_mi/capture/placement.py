"""The container standing on the board: its mesh from the stated shape and size, and its place.

A container's own frame has the centre of its footprint at the origin, its W side along x,
its D side along y and its height along -z (the board's z points into the table), so that
it stands on z = 0. Its place on the board is ``(x, y, yaw)``: the footprint's centre in
millimetres and the angle in degrees from the board's x axis to the container's W side,
about the board's z. The shapes are those :func:`reneus_mi.geometry.shapes.container_mesh` makes
(box, rounded block, cylinder jar), scaled so that their outer size is the measured one.
"""
from __future__ import annotations

import numpy as np
import trimesh

from reneus_mi.data.dataset import Interface
from reneus_mi.geometry.shapes import ROUNDING, container_mesh


def _inner_half(shape: str, size, edge: float | None = None) -> np.ndarray:
    """Half-extents to give :func:`container_mesh` for an outer size ``size`` (W, D, H) and an
    edge radius ``edge`` (mm; None: the generator's share, ROUNDING)."""
    outer = 0.5 * np.asarray(size, np.float64)
    if shape == 'box':
        return outer
    if shape == 'rounded':
        # container_mesh grows each half-extent by r (1 - 1/sqrt 3), r = ROUNDING x the smallest.
        c = 1.0 - 1.0 / np.sqrt(3.0)
        if edge is not None:
            return outer - c * edge
        return outer - ROUNDING * c * outer.min() / (1.0 + ROUNDING * c)
    # The jar's radius reaches the inner box's corners and its height adds a rounding r.
    side = outer[0] / np.sqrt(2.0)
    if edge is not None:
        return np.array([side, side, outer[2] - edge])
    hz = outer[2] / (1.0 + ROUNDING)
    if hz > side:
        hz = outer[2] - ROUNDING * side
    return np.array([side, side, hz])


def local_mesh(shape: str, size, inset: float = 0.0, edge: float | None = None) -> trimesh.Trimesh:
    """The container in its own frame (see the module docstring), outer size ``size`` in mm;
    with ``inset``, the surface that many millimetres inside it everywhere (the inside of a
    hollow container's walls); ``edge`` the radius of a rounded block's edges or a jar's rims
    (mm; 0: sharp; None: the generator's, ROUNDING of the smallest half-size).

    Smooth shapes keep their vertex normals (the renderers shade with them)."""
    mesh = container_mesh(shape, _inner_half(shape, size, edge), grow=-inset, edge=edge)
    normals = None if shape == 'box' else np.asarray(mesh.vertex_normals).copy()
    # The shapes are centred on the origin: standing on z = 0, upwards being -z; a mirror in z
    # keeps a closed mesh closed once the faces are turned over.
    vertices = np.asarray(mesh.vertices) + [0.0, 0.0, 0.5 * size[2]]
    vertices[:, 2] *= -1.0
    out = trimesh.Trimesh(vertices, np.asarray(mesh.faces)[:, ::-1], process=False)
    if normals is not None:
        normals[:, 2] *= -1.0
        out.vertex_normals = normals
    return out


def pose_matrix(pose) -> np.ndarray:
    """4x4 board-from-container transform of a place ``(x, y, yaw)``."""
    x, y, yaw = pose
    c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    M = np.eye(4)
    M[:2, :2] = [[c, -s], [s, c]]
    M[:3, 3] = [x, y, 0.0]
    return M


def board_mesh(shape: str, size, pose, inset: float = 0.0, edge: float | None = None) -> trimesh.Trimesh:
    """The container (or with ``inset`` its inside, see :func:`local_mesh`) placed on the board
    (board frame, millimetres), normals carried along."""
    mesh = local_mesh(shape, size, inset, edge)
    normals = None if shape == 'box' else np.asarray(mesh.vertex_normals).copy()
    M = pose_matrix(pose)
    mesh.apply_transform(M)
    if normals is not None:
        mesh.vertex_normals = normals @ M[:3, :3].T
    return mesh


def symmetry(shape: str, size) -> float:
    """The yaw period (degrees) of a container: 180 for a block, 90 for a square one, 0 when
    every yaw is the same (a cylinder)."""
    if shape == 'cylinder':
        return 0.0
    return 90.0 if np.isclose(size[0], size[1], rtol=1e-3) else 180.0


def interfaces(container: str, size, ior: float, wall_mm: float | None, liquid_ior: float | None,
               pose, edge: float | None = None) -> list[tuple[Interface, trimesh.Trimesh]]:
    """The container's interfaces on the board, outermost first, each with its mesh (file names
    as a dataset holds them): the container, then a hollow one's inside ``wall_mm`` in (its air,
    or a liquid of ``liquid_ior``)."""
    out = [(Interface('container.ply', ior), board_mesh(container, size, pose, edge=edge))]
    if wall_mm is not None:
        out.append((Interface('container_inner.ply', liquid_ior or 1.0),
                    board_mesh(container, size, pose, wall_mm, edge)))
    return out
