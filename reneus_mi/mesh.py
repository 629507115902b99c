"""Surface extraction from a field and clean-up of the extracted mesh.

The paper extracts the zero level set of the geometric MLP g_θ with Marching
Cubes and keeps the connected component with the most vertices. That rule
deletes real parts of multi-part objects (chair legs, a handle), so a second
rule is offered: crop the mesh to the container, which removes the "fake walls"
a field may grow on the glass without touching the object. Whoever reports
numbers says which rule was used (:func:`postprocess`).

The point-in-container test is a parity ray cast with Mitsuba, which needs no
optional trimesh dependency (rtree, embree) and works for any closed container.
"""
from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.errors import NoSurfaceError, ReneusError
from reneus_mi.fields.base import Field

#: Post-processing rules understood by :func:`postprocess`.
POSTPROCESS_MODES = ('clean', 'largest', 'crop', 'none')
#: :func:`clean` keeps components this many median edge lengths (about two marching-cubes
#: cells) from the kept surface ...
CLEAN_GAP = 4.0
#: ... and components with at least this share of the largest one's area.
CLEAN_SHARE = 0.1
#: Mesh files the package reads.
MESH_EXTENSIONS = ('.ply', '.obj', '.stl', '.off')

# Directions of the parity rays in :func:`inside`: three independent, generic
# directions, so that a ray grazing an edge or a vertex of the container (the
# only way a parity count goes wrong) is outvoted by the other two.
_RAY_DIRECTIONS = ((0.5366, 0.6104, 0.5826), (-0.7213, 0.2871, 0.6303), (0.1947, -0.8626, 0.4668))


def _triple(value, name: str) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    if not np.all(np.isfinite(arr)):
        raise ValueError(f'{name}={value!r}: expected finite numbers')
    return arr


def sdf_grid(field: Field, lo, hi, resolution, chunk: int = 2**18) -> np.ndarray:
    """Sample ``field.sdf`` on the regular grid spanning the box ``[lo, hi]``.

    ``lo``/``hi`` are scalars or 3-vectors, ``resolution`` an int or three ints
    (grid points per axis, both ends included). Returns a float32 array of shape
    ``(nx, ny, nz)`` indexed ``[i, j, k]`` ↔ ``(x, y, z)``. Points are built from
    a flat index inside the kernel, ``chunk`` at a time, so that no grid of
    coordinates is ever held in memory and every chunk reuses one compiled kernel.
    """
    lo, hi = _triple(lo, 'lo'), _triple(hi, 'hi')
    if np.any(hi <= lo):
        raise ValueError(f'box lo={lo.tolist()} hi={hi.tolist()}: expected lo < hi on every axis')
    res = np.broadcast_to(np.asarray(resolution), (3,))
    if res.dtype.kind not in 'iu' or np.any(res < 2):
        raise ValueError(f'resolution={resolution!r}: expected an int >= 2 or three of them')
    nx, ny, nz = (int(n) for n in res)
    if chunk < 1:
        raise ValueError(f'chunk={chunk}: expected a positive number of points')
    step = (hi - lo) / (res - 1)
    total = nx * ny * nz
    out = np.empty(total, dtype=np.float32)
    with dr.suspend_grad():
        for start in range(0, total, chunk):
            count = min(chunk, total - start)
            # Opaque, so that the offset is a kernel parameter, not a constant
            # baked into a new kernel per chunk.
            offset = dr.opaque(mi.UInt32, start)
            idx = offset + dr.arange(mi.UInt32, count)
            # C order: k (z) varies fastest, matching the (nx, ny, nz) reshape.
            k = idx % nz
            j = (idx // nz) % ny
            i = idx // (ny * nz)
            x = mi.Point3f(lo[0] + step[0] * mi.Float(i),
                           lo[1] + step[1] * mi.Float(j),
                           lo[2] + step[2] * mi.Float(k))
            out[start:start + count] = np.asarray(field.sdf(x), dtype=np.float32)
    return out.reshape(nx, ny, nz)


def extract_mesh(field: Field, lo, hi, resolution=256, *, to_world=None) -> trimesh.Trimesh:
    """Marching Cubes on the zero level set of ``field`` inside the box ``[lo, hi]``.

    The field lives in a normalised frame; ``to_world`` (a 4x4 matrix or a
    ``mi.ScalarTransform4f``) maps the vertices into the dataset's frame. Faces
    are wound so that normals point out of the object (where g > 0), also when
    ``to_world`` mirrors.
    """
    from skimage.measure import marching_cubes

    lo, hi = _triple(lo, 'lo'), _triple(hi, 'hi')
    grid = sdf_grid(field, lo, hi, resolution)
    if not np.all(np.isfinite(grid)):
        raise NoSurfaceError(f'{type(field).__name__}: the SDF is not finite at '
                         f'{int(np.sum(~np.isfinite(grid)))} grid points')
    g_min, g_max = float(grid.min()), float(grid.max())
    if not g_min < 0.0 < g_max:
        raise NoSurfaceError(f'{type(field).__name__} has no zero crossing in the box lo={lo.tolist()} '
                         f'hi={hi.tolist()}: the SDF ranges over [{g_min:.4g}, {g_max:.4g}]')
    step = (hi - lo) / (np.asarray(grid.shape) - 1)
    # skimage's 'descent' winding puts the normals on the side where the
    # values grow: outwards for an SDF (checked by the sign of the volume in tests).
    verts, faces, _, _ = marching_cubes(grid, level=0.0, spacing=tuple(step),
                                        gradient_direction='descent', allow_degenerate=False)
    verts = verts.astype(np.float64) + lo
    if to_world is not None:
        m = np.asarray(getattr(to_world, 'matrix', to_world), dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise ValueError(f'to_world: expected a finite 4x4 matrix, got shape {m.shape}')
        verts = verts @ m[:3, :3].T + m[:3, 3]
        if np.linalg.det(m[:3, :3]) < 0:
            faces = faces[:, ::-1]
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def component_labels(mesh: trimesh.Trimesh) -> np.ndarray:
    """The connected component (through shared edges, vertices welded by position) of each face."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    welded = mesh.copy()
    welded.merge_vertices(merge_tex=True, merge_norm=True)
    edges = welded.edges_unique
    n = len(welded.vertices)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    # Stray vertices are no component: number the faces' components 0..k-1.
    return np.unique(labels[welded.faces[:, 0]], return_inverse=True)[1].ravel()


def components(mesh: trimesh.Trimesh) -> int:
    """The number of connected pieces of ``mesh`` (0 for a mesh without faces)."""
    return int(component_labels(mesh).max()) + 1 if len(mesh.faces) else 0


def largest_component(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Keep the connected component with the most vertices (the paper's clean-up)."""
    if len(mesh.faces) == 0:
        return mesh.copy()
    labels = component_labels(mesh)
    vertices = np.zeros(labels.max() + 1)
    np.add.at(vertices, labels, 1.0)   # faces of a closed mesh: twice its vertices
    return _keep_faces(mesh, labels == np.argmax(vertices))


def clean(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Drop floating fragments, keep the object's parts: the largest component, every
    component within :data:`CLEAN_GAP` median edge lengths of what is kept (thin parts
    that noise cut off lie next to the body: kept link by link), and any component of
    at least :data:`CLEAN_SHARE` of the largest's area (a real second part)."""
    from scipy.spatial import cKDTree

    if len(mesh.faces) == 0:
        return mesh.copy()
    labels = component_labels(mesh)
    area = np.bincount(labels, weights=mesh.area_faces)
    keep = (area >= CLEAN_SHARE * area.max())
    keep[np.argmax(area)] = True
    gap = CLEAN_GAP * float(np.median(mesh.edges_unique_length))
    vertices = [np.unique(mesh.faces[labels == c]) for c in range(len(area))]
    grown = True
    while grown and not keep.all():
        tree = cKDTree(mesh.vertices[np.concatenate([vertices[c] for c in np.flatnonzero(keep)])])
        near = [c for c in np.flatnonzero(~keep)
                if tree.query(mesh.vertices[vertices[c]], distance_upper_bound=gap)[0].min() <= gap]
        keep[near] = True
        grown = bool(near)
    return _keep_faces(mesh, keep[labels])


def _keep_faces(mesh: trimesh.Trimesh, mask: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    out.update_faces(mask)
    out.remove_unreferenced_vertices()
    return out


def signed_volume(vertices, faces) -> float:
    """Volume enclosed by a closed triangle mesh, negative when its faces are wound inward.

    The divergence theorem over the faces (each face with the origin spans a
    tetrahedron): it needs no shared vertices, so flat-shaded meshes work.
    """
    v = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    return float(np.einsum('ij,ij->i', v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def check_container(container, name: str = 'container') -> None:
    """Raise naming ``name`` unless ``container`` is a closed, outward-facing triangle mesh.

    Inward normals would make the renderer take entering the glass for
    leaving it (the specimen vanishes from the renders), so they are refused
    rather than guessed at: the file itself must be fixed, because Mitsuba
    reads the file, not this copy.
    """
    if not isinstance(container, trimesh.Trimesh) or len(container.faces) == 0:
        raise ReneusError(f'{name}: expected a closed triangle mesh with faces, got {container!r}')
    # Meshes written per face (e.g. for flat shading) duplicate vertices; the
    # surface is still closed once they are merged.
    merged = container.copy()
    merged.merge_vertices()
    if not merged.is_watertight:
        raise ReneusError(f'{name}: container mesh is not closed (not watertight), so '
                          'inside/outside is undefined; expected a mesh enclosing a volume')
    volume = signed_volume(container.vertices, container.faces)
    if not volume > 0.0:
        raise ReneusError(f'{name}: container normals point inward (signed volume {volume:.4g}); '
                          'expected outward normals: reverse the winding of its faces '
                          '(trimesh: mesh.invert())')


def inside(points, container: trimesh.Trimesh) -> np.ndarray:
    """Boolean mask of the ``(N, 3)`` ``points`` that lie inside the closed ``container``.

    A point is inside when a ray from it crosses the surface an odd number of
    times; the answer is the majority over three ray directions.
    """
    check_container(container)
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f'points: expected an (N, 3) array, got shape {points.shape}')
    if len(points) == 0:
        return np.zeros(0, dtype=bool)

    scene = mi.load_dict({'type': 'scene', 'container': mitsuba_mesh(container)})

    # Every crossing is a distinct face, so a ray that has not left the
    # container after this many hits is stuck re-hitting one spot.
    max_hits = len(container.faces) + 1
    origin = mi.Point3f(*(points.T.astype(np.float32)))
    votes = mi.UInt32(0)
    for direction in _RAY_DIRECTIONS:
        votes += _parity(scene, origin, mi.Vector3f(*direction), max_hits)
    return np.asarray(votes) >= 2


def mitsuba_mesh(mesh: trimesh.Trimesh, name: str = 'container') -> mi.Mesh:
    """The triangles of ``mesh`` as a Mitsuba shape (for ray tests)."""
    shape = mi.Mesh(name, len(mesh.vertices), len(mesh.faces))
    params = mi.traverse(shape)
    params['vertex_positions'] = mi.Float(np.ravel(mesh.vertices).astype(np.float32))
    params['faces'] = mi.UInt32(np.ravel(mesh.faces).astype(np.uint32))
    params.update()
    return shape


@dr.syntax
def _parity(scene, origin, direction, max_hits):
    """1 where a ray from ``origin`` along ``direction`` crosses ``scene`` an odd number of times."""
    ray = mi.Ray3f(origin, dr.normalize(direction))
    hits = mi.UInt32(0)
    active = mi.Bool(True)
    while active:
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid() & (hits < max_hits)
        hits = dr.select(active, hits + 1, hits)
        # Lanes that stop here never read the ray again.
        ray = si.spawn_ray(ray.d)
    return hits & 1


def crop(mesh: trimesh.Trimesh, container: trimesh.Trimesh) -> trimesh.Trimesh:
    """Remove the faces that have a vertex outside the closed ``container``."""
    if len(mesh.faces) == 0:
        return mesh.copy()
    vertex_in = inside(mesh.vertices, container)
    return _keep_faces(mesh, np.all(vertex_in[mesh.faces], axis=1))


def postprocess(mesh: trimesh.Trimesh, mode: str, container: trimesh.Trimesh | None = None) -> trimesh.Trimesh:
    """Apply one rule of :data:`POSTPROCESS_MODES` to a copy of ``mesh``.

    ``'clean'`` drops floating fragments and keeps the object's parts (:func:`clean`),
    ``'largest'`` is the paper's (largest component by vertex count: a leg that noise
    cut off goes with the fragments), ``'crop'`` keeps what lies inside ``container``,
    ``'none'`` returns a copy.
    """
    if mode == 'clean':
        return clean(mesh)
    if mode == 'largest':
        return largest_component(mesh)
    if mode == 'crop':
        if container is None:
            raise ValueError("postprocess mode 'crop' needs a container mesh")
        return crop(mesh, container)
    if mode == 'none':
        return mesh.copy()
    raise ValueError(f'postprocess mode {mode!r}: expected one of {", ".join(POSTPROCESS_MODES)}')


def load_mesh(path: str | os.PathLike, what: str = 'mesh') -> trimesh.Trimesh:
    """Read a triangle mesh (.ply, .obj, .stl, .off); a clear error if that fails or it is empty.

    The one mesh reader of the package; vertices are kept as stored (no
    merging), so flat-shaded meshes keep their face normals.
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
    return mesh


def load_container(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a container mesh and check it (:func:`check_container`)."""
    mesh = load_mesh(path, 'container mesh')
    check_container(mesh, os.fspath(path))
    return mesh
