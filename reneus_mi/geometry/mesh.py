"""Triangle meshes in and out, and the few properties the package measures on them.

:func:`load_mesh` is the package's one mesh reader, :func:`write_mesh` its one
writer (atomic), :func:`write_glb` the web viewers' copy (vertex colours, glTF's metres
and axes); :func:`mitsuba_mesh` hands a mesh to Mitsuba for ray tests.
"""
from __future__ import annotations

import os

import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_export

#: Mesh files the package reads.
MESH_EXTENSIONS = ('.ply', '.obj', '.stl', '.off')


def load_mesh(path: str | os.PathLike, what: str = 'mesh') -> trimesh.Trimesh:
    """Read a triangle mesh (.ply, .obj, .stl, .off); a clear error if that fails or it is empty.

    Vertices are kept as stored (no merging), so flat-shaded meshes keep their
    face normals.
    """
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_EXTENSIONS:
        raise ReneusError(f"{path}: {what} file of unknown type {ext or '(none)'}; expected "
                          f"{', '.join(MESH_EXTENSIONS)}")
    if not os.path.isfile(path):
        raise ReneusError(f'{path}: {what} file does not exist')
    try:
        mesh = trimesh.load(path, force='mesh', process=False)
    except Exception as e:  # trimesh raises many kinds for unreadable files
        raise ReneusError(f'{path}: cannot read the {what} ({type(e).__name__}: {e})') from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ReneusError(f'{path}: the {what} file holds no triangles')
    bad = ~np.all(np.isfinite(mesh.vertices), axis=1)
    if bad.any():
        v = int(np.argmax(bad))
        raise ReneusError(f'{path}: the {what} has {int(bad.sum())} vertex(es) with non-finite coordinates '
                          f'(first: vertex {v} at {mesh.vertices[v].tolist()}); expected finite numbers')
    return mesh


def write_mesh(mesh: trimesh.Trimesh, path: str | os.PathLike) -> None:
    """Export atomically (the format follows the extension)."""
    atomic_export(mesh, path)


#: Metres per unit of the coordinates that datasets state (glTF's unit is the metre).
METRES = {'mm': 1e-3, 'cm': 1e-2, 'm': 1.0}


def gltf_from_world(units: str | None = None, up=None, right=None) -> np.ndarray:
    """4x4 from world coordinates to glTF's convention (metres, +y up, right-handed): scaled
    by the ``units`` (unchanged when unknown) and turned so that ``up`` (a world direction)
    becomes +y and ``right`` +x (the world unturned without them)."""
    M = np.eye(4)
    if up is not None:
        u = np.asarray(up, np.float64) / np.linalg.norm(up)
        r = np.asarray(right, np.float64) - np.dot(right, u) * u
        r /= np.linalg.norm(r)
        M[:3, :3] = np.stack([r, u, np.cross(r, u)])
    return np.diag([METRES.get(units, 1.0)] * 3 + [1.0]) @ M


def write_glb(mesh: trimesh.Trimesh, colors: np.ndarray, path: str | os.PathLike,
              to_gltf: np.ndarray | None = None) -> None:
    """Write ``mesh`` as binary glTF with per-vertex ``colors`` ((V, 3) in [0, 1], display
    values), its vertices moved by ``to_gltf`` (:func:`gltf_from_world`), atomically."""
    out = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
    if to_gltf is not None:
        out.apply_transform(to_gltf)
    rgba = np.concatenate([np.round(np.clip(colors, 0.0, 1.0) * 255.0), np.full((len(colors), 1), 255.0)], axis=1)
    out.visual = trimesh.visual.ColorVisuals(out, vertex_colors=rgba.astype(np.uint8))
    atomic_export(out, path)


def decimated_glb(source: str | os.PathLike, path: str | os.PathLike, max_bytes: int) -> int:
    """Write a copy of the binary glTF ``source`` under ``max_bytes``: its surface simplified by
    quadric edge collapse (``fast-simplification``, through trimesh), each vertex taking the
    colour of the source's nearest; return its face count."""
    from scipy.spatial import cKDTree
    mesh = trimesh.load(source, file_type='glb', force='mesh', process=False)
    colors = np.asarray(mesh.visual.vertex_colors, np.float64)[:, :3] / 255.0
    size = os.path.getsize(source)
    faces = len(mesh.faces)
    while size > max_bytes:
        # The file grows with the faces; a tenth spare for the vertices' share.
        faces = max(4, int(faces * 0.9 * max_bytes / size))
        small = mesh.simplify_quadric_decimation(face_count=faces)
        _, nearest = cKDTree(mesh.vertices).query(small.vertices)
        write_glb(small, colors[nearest], path)
        size, faces = os.path.getsize(path), len(small.faces)
    return faces


def signed_volume(vertices, faces) -> float:
    """Volume enclosed by a closed triangle mesh, negative when its faces are wound inward.

    The divergence theorem over the faces (each face with the origin spans a
    tetrahedron): it needs no shared vertices, so flat-shaded meshes work.
    """
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return float(np.einsum('ij,ij->i', v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def mitsuba_mesh(vertices, faces, name: str = 'container', props: mi.Properties | None = None,
                 normals=None, texcoords=None) -> mi.Mesh:
    """Triangles (an (n, 3) array of vertices, one of faces) as a Mitsuba mesh: ``props`` its
    BSDF and media; ``normals`` None (none), an (n, 3) array, or 'recompute' (Mitsuba's own);
    ``texcoords`` None or an (n, 2) array of uv."""
    has_normals = normals is not None
    shape = mi.Mesh(name, len(vertices), len(faces), has_vertex_normals=has_normals,
                    has_vertex_texcoords=texcoords is not None, **({} if props is None else {'props': props}))
    params = mi.traverse(shape)
    params['vertex_positions'] = mi.Float(np.ravel(vertices).astype(np.float32))
    params['faces'] = mi.UInt32(np.ravel(faces).astype(np.uint32))
    if has_normals and not isinstance(normals, str):
        params['vertex_normals'] = mi.Float(np.ravel(normals).astype(np.float32))
    if texcoords is not None:
        params['vertex_texcoords'] = mi.Float(np.ravel(texcoords).astype(np.float32))
    params.update()
    if isinstance(normals, str):
        shape.recompute_vertex_normals()
    return shape
