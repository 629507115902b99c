"""The field's surface as a mesh: marching cubes and clean-up.

The paper extracts the zero level set of the geometric MLP g_θ with Marching
Cubes and keeps the connected component with the most vertices. That rule
deletes real parts of multi-part objects (chair legs, a handle), so a second
rule is offered: crop the mesh to the container, which removes the "fake walls"
a field may grow on the glass without touching the object. Whoever reports
numbers says which rule was used (:func:`postprocess`). :func:`field_mesh`
does both in the world of a reconstruction, and first joins the pieces that the field
itself nearly joins (:func:`bridge`): thin parts a pixel wide, whose SDF stops a
fraction of a cell short of zero, otherwise come out as gaps with the parts beyond
them floating free.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes
import trimesh

from reneus_mi.fields.base import Field
from reneus_mi.geometry.container import inside, load_container
from reneus_mi.geometry.frame import FieldFrame
from reneus_mi.utils import limits
from reneus_mi.utils.errors import NoSurfaceError, ReneusError

#: Post-processing rules understood by :func:`postprocess`.
POSTPROCESS_MODES = ('clean', 'largest', 'crop', 'none')
#: :func:`clean` keeps components this many median edge lengths (about two marching-cubes
#: cells) from the kept surface ...
CLEAN_GAP = 4.0
#: ... and components with at least this share of the largest one's area, wherever they lie
#: (a part whose thin stalk was lost, not a floater: docs/constants.md); specks under
#: CLEAN_SPECK of it go even next to the body (a few dozen faces of noise, no part).
CLEAN_SHARE, CLEAN_SPECK = 0.01, 1e-3
#: :func:`bridge` joins pieces whose connection stays below the field's own blur 1/s (there
#: NeuS's density already renders a quarter of opacity and more) but never further than this
#: many grid cells (a blurry field early in training), no further than :func:`clean` keeps
#: pieces anyway.
BRIDGE_CELLS = 2.0
#: A region below the gap larger than this share of the grid is fog (a field early in training,
#: its SDF near zero everywhere), not a surface's shell (about 1 % at 512^3): not bridged, which
#: also bounds the search graph's memory.
BRIDGE_MAX_SHARE = 0.05
#: Bytes per grid point of marching cubes: the float32 SDF grid, skimage's working copies,
#: the vertices and faces, and :func:`bridge`'s label grids and its copy of the SDF
#: (docs/constants.md).
BYTES_PER_GRID_POINT = 24


def _triple(value, name: str) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=np.float64), (3,))
    if not np.all(np.isfinite(arr)):
        raise ReneusError(f'{name}={value!r}: expected finite numbers')
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
        raise ReneusError(f'box lo={lo.tolist()} hi={hi.tolist()}: expected lo < hi on every axis')
    res = np.broadcast_to(np.asarray(resolution), (3,))
    if res.dtype.kind not in 'iu' or np.any(res < 2):
        raise ReneusError(f'resolution={resolution!r}: expected an int >= 2 or three of them')
    nx, ny, nz = (int(n) for n in res)
    if chunk < 1:
        raise ReneusError(f'chunk={chunk}: expected a positive number of points')
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


def extract_mesh(field: Field, lo, hi, resolution=256, *, to_world=None, gap: float = 0.0) -> trimesh.Trimesh:
    """Marching Cubes on the zero level set of ``field`` inside the box ``[lo, hi]``.

    The field lives in a normalised frame; ``to_world`` (a 4x4 matrix or a
    ``mi.ScalarTransform4f``) maps the vertices into the dataset's frame. Faces
    are wound so that normals point out of the object (where g > 0), also when
    ``to_world`` mirrors. With ``gap`` > 0 (SDF units) the pieces that the field
    joins below ``gap`` are joined first (:func:`bridge`).
    """

    lo, hi = _triple(lo, 'lo'), _triple(hi, 'hi')
    grid = sdf_grid(field, lo, hi, resolution)
    if not np.all(np.isfinite(grid)):
        raise NoSurfaceError(f'{type(field).__name__}: the SDF is not finite at '
                         f'{int(np.sum(~np.isfinite(grid)))} grid points')
    g_min, g_max = float(grid.min()), float(grid.max())
    if not g_min < 0.0 < g_max:
        raise NoSurfaceError(f'{type(field).__name__} has no zero crossing in the box lo={lo.tolist()} '
                         f'hi={hi.tolist()}: the SDF ranges over [{g_min:.4g}, {g_max:.4g}]')
    if gap > 0:
        grid = bridge(grid, gap)
    step = (hi - lo) / (np.asarray(grid.shape) - 1)
    # skimage's 'descent' winding puts the normals on the side where the
    # values grow: outwards for an SDF (checked by the sign of the volume in tests).
    verts, faces, _, _ = marching_cubes(grid, level=0.0, spacing=tuple(step),
                                        gradient_direction='descent', allow_degenerate=False)
    verts = verts.astype(np.float64) + lo
    if to_world is not None:
        m = np.asarray(getattr(to_world, 'matrix', to_world), dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise ReneusError(f'to_world: expected a finite 4x4 matrix, got shape {m.shape}')
        verts = verts @ m[:3, :3].T + m[:3, 3]
        if np.linalg.det(m[:3, :3]) < 0:
            faces = faces[:, ::-1]
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def bridge(grid: np.ndarray, gap: float) -> np.ndarray:
    """``grid`` (an SDF on a grid) with the pieces of its zero set that it joins below ``gap`` joined.

    A part a pixel thin that the field renders, but whose SDF stops short of zero along
    it, leaves marching cubes a gap, and whatever lies beyond floats free (a bud on its
    stalk, an insect's foot). Where the grid joins two pieces of {g < 0} through
    {g < ``gap``}, the shortest such connection (in grid steps) is carved below zero, one
    voxel wide: marching cubes then draws a stalk about a cell thick along it. Pieces
    joined only through values above ``gap`` stay apart. Returns ``grid`` itself when
    nothing is joined, else a copy.
    """

    solid = grid < 0
    pieces, n_pieces = ndimage.label(solid)
    if n_pieces < 2:
        return grid
    near, _ = ndimage.label(grid < gap)
    # The near regions that hold two pieces or more: only there is anything to join.
    regions = np.unique(near[solid].astype(np.int64) * (n_pieces + 1) + pieces[solid]) // (n_pieces + 1)
    shared = np.unique(regions[np.bincount(regions)[regions] > 1])
    if len(shared) == 0:
        return grid
    out = grid.copy()
    # The pieces' inner voxels cannot be on a shortest connection: the graph is the
    # near region less them (its surface shell, the necks and the pieces' outer layer).
    inner = ndimage.binary_erosion(solid, border_value=1)
    boxes = ndimage.find_objects(near)
    for region in shared:
        box = boxes[region - 1]
        nodes = (near[box] == region) & ~inner[box]
        count = int(nodes.sum())
        if count > BRIDGE_MAX_SHARE * grid.size:
            continue
        index = np.full(nodes.shape, -1, np.int64)
        index[nodes] = np.arange(count)
        edges = []
        for axis in range(3):
            a = index[tuple(slice(None, -1) if d == axis else slice(None) for d in range(3))]
            b = index[tuple(slice(1, None) if d == axis else slice(None) for d in range(3))]
            both = (a >= 0) & (b >= 0)
            edges.append(np.stack([a[both], b[both]]))
        edges = np.concatenate(edges, axis=1)
        graph = coo_matrix((np.ones(edges.shape[1]), (edges[0], edges[1])), shape=(count, count)).tocsr()
        piece = pieces[box][nodes]
        sources = np.flatnonzero(piece > 0)
        # One search from every piece at once: each voxel's nearest piece and the way to it.
        dist, pred, origin = dijkstra(graph, directed=False, indices=sources, min_only=True,
                                      return_predecessors=True)
        owner = np.where(origin >= 0, piece[origin], 0)   # 0: a voxel no piece reaches
        # Where two pieces' territories touch lies the shortest connection between them;
        # join the pieces along a minimum spanning tree of these connections (Kruskal).
        cross = (owner[edges[0]] != owner[edges[1]]) & (owner[edges[0]] > 0) & (owner[edges[1]] > 0)
        u, v = edges[0][cross], edges[1][cross]
        order = np.argsort(dist[u] + dist[v], kind='stable')
        parent = {int(p): int(p) for p in np.unique(piece[sources])}
        joins = len(parent) - 1

        def root(p):
            while parent[p] != p:
                parent[p] = parent[parent[p]]
                p = parent[p]
            return p

        coords = np.argwhere(nodes)
        for e in order:
            if joins == 0:
                break
            ru, rv = root(int(owner[u[e]])), root(int(owner[v[e]]))
            if ru == rv:
                continue
            parent[ru] = rv
            joins -= 1
            for end in (u[e], v[e]):
                while end >= 0:
                    i, j, k = coords[end] + [b.start for b in box]
                    out[i, j, k] = min(out[i, j, k], -gap)
                    end = pred[end]
    return out


def component_labels(mesh: trimesh.Trimesh) -> np.ndarray:
    """The connected component (through shared edges, vertices welded by position) of each face."""

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


def clean(mesh: trimesh.Trimesh, container: trimesh.Trimesh | None = None) -> trimesh.Trimesh:
    """Drop floating fragments, keep the object's parts: the largest component, every
    component within :data:`CLEAN_GAP` median edge lengths of what is kept (thin parts
    that noise cut off lie next to the body: kept link by link) unless it is a speck, and
    any component of at least :data:`CLEAN_SHARE` of the largest's area (a real second part)
    that does not touch ``container``'s surface within that gap: one that does is a fake wall
    (the paper's term), a sheet the field painted on the glass where the photographs and the
    model of the container part (measured: sheets 0.007-0.2 mm from a rounded block's faces,
    12-18 mm from its ant; docs/containers.md)."""

    if len(mesh.faces) == 0:
        return mesh.copy()
    labels = component_labels(mesh)
    area = np.bincount(labels, weights=mesh.area_faces)
    gap = CLEAN_GAP * float(np.median(mesh.edges_unique_length))
    vertices = [np.unique(mesh.faces[labels == c]) for c in range(len(area))]
    keep = (area >= CLEAN_SHARE * area.max())
    if container is not None:
        parts = np.flatnonzero(keep)
        keep[parts] = ~_touching(mesh.vertices, [vertices[c] for c in parts], container, gap)
    keep[np.argmax(area)] = True
    grown = True
    while grown and not keep.all():
        tree = cKDTree(mesh.vertices[np.concatenate([vertices[c] for c in np.flatnonzero(keep)])])
        near = [c for c in np.flatnonzero(~keep & (area >= CLEAN_SPECK * area.max()))
                if tree.query(mesh.vertices[vertices[c]], distance_upper_bound=gap)[0].min() <= gap]
        keep[near] = True
        grown = bool(near)
    return _keep_faces(mesh, keep[labels])


def _touching(points: np.ndarray, groups: list[np.ndarray], surface: trimesh.Trimesh, gap: float) -> np.ndarray:
    """Per group of ``points`` (indices), whether one of them lies within ``gap`` of
    ``surface``: measured to the surface's points spaced at most ``gap`` / 2 apart (so up to a
    quarter of the gap more than the true distance)."""
    spacing = 0.5 * gap
    count = int(min(np.ceil(surface.area / spacing ** 2), 4_000_000))
    samples = trimesh.sample.sample_surface_even(surface, count, seed=0)[0]
    tree = cKDTree(np.concatenate([samples, surface.vertices]))
    return np.array([tree.query(points[g], distance_upper_bound=gap + spacing)[0].min() <= gap + 0.5 * spacing
                     for g in groups])


def _keep_faces(mesh: trimesh.Trimesh, mask: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    out.update_faces(mask)
    out.remove_unreferenced_vertices()
    return out


def crop(mesh: trimesh.Trimesh, container: trimesh.Trimesh) -> trimesh.Trimesh:
    """Remove the faces that have a vertex outside the closed ``container``."""
    if len(mesh.faces) == 0:
        return mesh.copy()
    vertex_in = inside(mesh.vertices, container)
    return _keep_faces(mesh, np.all(vertex_in[mesh.faces], axis=1))


def postprocess(mesh: trimesh.Trimesh, mode: str, container: trimesh.Trimesh | None = None) -> trimesh.Trimesh:
    """Apply one rule of :data:`POSTPROCESS_MODES` to a copy of ``mesh``.

    ``'clean'`` drops floating fragments and keeps the object's parts (:func:`clean`; with
    ``container``, not the sheets that touch it),
    ``'largest'`` is the paper's (largest component by vertex count: a leg that noise
    cut off goes with the fragments), ``'crop'`` keeps what lies inside ``container``,
    ``'none'`` returns a copy.
    """
    if mode == 'clean':
        return clean(mesh, container)
    if mode == 'largest':
        return largest_component(mesh)
    if mode == 'crop':
        if container is None:
            raise ReneusError("postprocess mode 'crop' needs a container mesh")
        return crop(mesh, container)
    if mode == 'none':
        return mesh.copy()
    raise ReneusError(f'postprocess mode {mode!r}: expected one of {", ".join(POSTPROCESS_MODES)}')


#: Grid points per axis of the coarse look at the field that finds where its surface lies
#: (:func:`surface_box`) before the mesh's grid is laid over it.
SURFACE_BOX_RESOLUTION = 96


def surface_box(field: Field, lo, hi, resolution: int = SURFACE_BOX_RESOLUTION) -> tuple[np.ndarray, np.ndarray]:
    """The part of the box ``[lo, hi]`` that holds ``field``'s surface: where a coarse grid's
    SDF is below two of its cells (inside, or near enough for a part thinner than a cell),
    grown by two cells, within the box; the whole box where the grid finds nothing.

    A specimen is a small part of its container (an ant of 12 mm in a 40 mm block: 3 % of its
    volume): a grid over that part alone has the same cells for a thirtieth of the points."""
    lo, hi = _triple(lo, 'lo'), _triple(hi, 'hi')
    with dr.suspend_grad():
        grid = sdf_grid(field, lo, hi, resolution)
    step = (hi - lo) / (resolution - 1)
    near = np.argwhere(np.nan_to_num(grid, nan=np.inf) < 2.0 * np.linalg.norm(step))
    if len(near) == 0:
        return lo, hi
    return (np.maximum(lo + (near.min(axis=0) - 2) * step, lo),
            np.minimum(lo + (near.max(axis=0) + 2) * step, hi))


def mesh_grid(lo, hi, resolution: int, inner=None) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """The grid of ``resolution`` points per axis over the box ``[lo, hi]``, or only its cells
    that cover the box ``inner`` (lo, hi) within it: that part's corners and points per axis."""
    lo, hi = _triple(lo, 'lo'), _triple(hi, 'hi')
    if inner is None:
        return lo, hi, (resolution,) * 3
    step = (hi - lo) / (resolution - 1)
    first = np.clip(np.floor((np.asarray(inner[0]) - lo) / step + 1e-9), 0, resolution - 2).astype(int)
    last = np.clip(np.ceil((np.asarray(inner[1]) - lo) / step - 1e-9), first + 1, resolution - 1).astype(int)
    return lo + first * step, lo + last * step, tuple(int(n) for n in last - first + 1)


def field_mesh(field: Field, frame: FieldFrame, resolution: int, mode: str, container: str | None = None):
    """The post-processed mesh of ``field`` in world coordinates.

    Marching cubes runs on the grid of ``resolution`` points per axis over the container's
    box in the field's frame (:meth:`FieldFrame.field_box`), over the part of it that holds
    the surface only (:func:`surface_box`); ``container`` is the container mesh file, needed by
    ``mode='crop'`` and used by ``'clean'`` (in the world's coordinates, as the mesh).
    """
    box = frame.field_box()
    lo, hi, counts = mesh_grid(*box, resolution, surface_box(field, *box))
    gap = 0.0
    if mode == 'clean':
        cell = float(np.max((hi - lo) / (np.asarray(counts) - 1)))
        gap = min(1.0 / float(np.asarray(field.inv_s()).ravel()[0]), BRIDGE_CELLS * cell)
    with dr.suspend_grad():
        mesh = extract_mesh(field, lo, hi, counts, to_world=frame.to_world_matrix(), gap=gap)
    if mode == 'crop' and not container:
        raise ReneusError("postprocess 'crop' needs the container mesh, and none is recorded")
    return postprocess(mesh, mode, load_container(container) if container and mode in ('clean', 'crop') else None)


def field_colors(field: Field, frame: FieldFrame, vertices: np.ndarray, gamma: float,
                 chunk: int = 2**18) -> np.ndarray:
    """(V, 3) colours of the field at world ``vertices`` (on its surface), as the photographs
    show colour: the radiance leaving each vertex along the field's normal (seen head-on from
    outside), gamma-encoded (c^(1/γ)) and clipped to [0, 1]."""
    vertices = np.asarray(vertices, np.float64)
    out = np.zeros((len(vertices), 3), np.float32)
    with dr.suspend_grad():
        for start in range(0, len(vertices), chunk):
            v = vertices[start:start + chunk].astype(np.float32)
            x = frame.to_field(mi.Point3f(*(mi.Float(v[:, i]) for i in range(3))))
            _, grad, feature = field.gradient(x)
            n = dr.normalize(grad)
            c = field.radiance(x, -n, n, feature)
            out[start:start + len(v)] = np.array(c, np.float32).T
    return np.clip(np.maximum(np.nan_to_num(out), 0.0) ** (1.0 / gamma), 0.0, 1.0)


def check_resolution(resolution: int, what: str = '--resolution') -> None:
    """Refuse a grid below 8 per axis, past 32-bit indices or the machine's memory."""
    if resolution < 8:
        raise ReneusError(f'{what} {resolution}: expected >= 8')
    points = resolution ** 3
    limits.check_index_range(points, f'{what} {resolution}')
    limits.check_memory(points * BYTES_PER_GRID_POINT, f'{what} {resolution}')
