"""The container: the closed glass mesh the rays pass through, its checks, shading normals and medium.

The paper's method needs the container as a closed, outward-facing triangle
mesh in world coordinates (:func:`check_container`; as a scene holds it:
:func:`check_scene_containers`); its silhouette in each view is the mask
``M_in`` (:mod:`reneus_mi.data.masks`).

The point-in-container test (:func:`inside`) is a parity ray cast with
Mitsuba, which needs no optional trimesh dependency (rtree, embree) and works
for any closed container.

**Which normal bends light** (:func:`corner_normals`, the one rule of the package).
A mesh file does not say which of its edges are creases: a box written with 8
shared vertices and no normals (trimesh, Blender's cube, most CAD exports) gets
smooth vertex normals from Mitsuba and would refract like a rounded lens. So the
shading normal of every triangle corner follows the geometry:

- faces meeting at a vertex at more than the crease angle (30 degrees, like
  Blender's auto-smooth) are not smoothed together: a box's faces keep their own
  normals whatever the file looks like;
- where the faces around a vertex all lie within the crease angle of each other the
  surface is smooth there: the file's stored normal is used (rounded blocks, jars),
  or, when the file has none, the angle-weighted mean of those faces' normals.

Vertices are welded by position first, so a mesh written with one vertex per
triangle corner is read like the same mesh with shared vertices.
"""
from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np
import trimesh

from reneus_mi.geometry.mesh import MESH_EXTENSIONS, load_mesh, mitsuba_mesh, signed_volume
from reneus_mi.utils.errors import ReneusError

#: Mitsuba's shape plugin of each mesh format it reads; a container in another format of
#: :data:`~reneus_mi.geometry.mesh.MESH_EXTENSIONS` (STL, OFF: CAD exports) is handed to
#: Mitsuba as a triangle PLY (:func:`container_shape`, :func:`~reneus_mi.data.scene_xml.write_scene`).
MITSUBA_READERS = {'.ply': 'ply', '.obj': 'obj'}
#: Faces meeting at more than this angle (degrees) form a crease: light sees them flat.
CREASE_ANGLE = 30.0
#: Vertices closer than this fraction of the mesh's size are one vertex (welding).
_WELD = 1e-6
#: Rounding of a cosine between face normals computed from float32 vertices.
_ANGLE_ROUNDING = 1e-5
#: A stored normal is the vertex's own when its copies agree this closely (1 - cos).
_SAME_NORMAL = 1e-4

# Directions of the parity rays in :func:`inside`: three independent, generic
# directions, so that a ray grazing an edge or a vertex of the container (the
# only way a parity count goes wrong) is outvoted by the other two.
_RAY_DIRECTIONS = ((0.5366, 0.6104, 0.5826), (-0.7213, 0.2871, 0.6303), (0.1947, -0.8626, 0.4668))


def mesh_type(path: str) -> str | None:
    """Mitsuba's shape plugin (``ply``/``obj``) for a mesh file, None for a mesh format
    Mitsuba does not read (STL, OFF); raise for a file that is no mesh the package reads."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_EXTENSIONS:
        raise ReneusError(f"{path}: expected a mesh file ending in {', '.join(MESH_EXTENSIONS[:-1])} "
                          f"or {MESH_EXTENSIONS[-1]}")
    return MITSUBA_READERS.get(ext)


def bounding_sphere(path: str) -> tuple[np.ndarray, float]:
    """Centre of the mesh's bounding box and the radius that reaches every vertex."""
    vertices = np.asarray(load_container(path).vertices)
    centre = 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    return centre, float(np.linalg.norm(vertices - centre, axis=1).max())


def corner_normals(vertices, faces, normals=None, crease_angle: float = CREASE_ANGLE) -> np.ndarray:
    """The shading normal of every triangle corner (F,3,3) by the rule of this module.

    ``vertices`` (V,3) and ``faces`` (F,3) are the mesh as stored; ``normals`` (V,3)
    the vertex normals it was read with, if any (a copy of a vertex whose copies
    disagree is not taken as stored: Mitsuba computed it from its own faces).
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    corners = v[f]                                              # (F, 3 corners, xyz)
    n_face, area = face_normals(v, f)
    # Slivers have no reliable normal: they neither make creases nor weigh in means.
    solid = area > 1e-12 * max(float(np.median(area)), 1e-30)
    e_next = np.roll(corners, -1, axis=1) - corners
    e_prev = np.roll(corners, 1, axis=1) - corners
    cos_corner = np.einsum('fci,fci->fc', e_next, e_prev) / np.maximum(
        np.linalg.norm(e_next, axis=2) * np.linalg.norm(e_prev, axis=2), 1e-30)
    weight = np.arccos(np.clip(cos_corner, -1.0, 1.0)) * solid[:, None]

    welded = weld(v)
    # Every ordered pair (a, b) of corners at one welded vertex, a and b included.
    w = welded[f].ravel()
    order = np.argsort(w, kind='stable')
    count = np.bincount(w)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    degree = count[w[order]]
    a = np.repeat(order, degree)
    offset = np.arange(len(a)) - np.repeat(np.cumsum(degree) - degree, degree)
    b = order[np.repeat(start[w[order]], degree) + offset]
    fa, fb = a // 3, b // 3
    # Faces exactly at the crease angle (a 12-sided jar at 30 degrees) are smooth, as in
    # Blender, whichever way rounding falls at each vertex.
    cos_crease = np.cos(np.radians(crease_angle)) - _ANGLE_ROUNDING
    smooth = (np.einsum('pi,pi->p', n_face[fa], n_face[fb]) >= cos_crease) | ~solid[fb]
    mean = np.zeros((3 * len(f), 3))
    np.add.at(mean, a[smooth], weight.ravel()[b[smooth], None] * n_face[fb[smooth]])
    length = np.linalg.norm(mean, axis=1, keepdims=True)
    n_corner = np.where(length > 1e-12, mean / np.maximum(length, 1e-30), n_face[np.arange(3 * len(f)) // 3])

    if normals is not None:
        n = np.asarray(normals, np.float64)
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        # A vertex's copies (one per face in a flat-written mesh) must carry one normal.
        ref = np.zeros((welded.max() + 1, 3))
        ref[welded] = n
        agree = np.ones(len(ref), bool)
        np.logical_and.at(agree, welded, np.einsum('vi,vi->v', n, ref[welded]) >= 1.0 - _SAME_NORMAL)
        creased = np.zeros(3 * len(f), bool)
        np.logical_or.at(creased, a, ~smooth)
        stored = n[f.ravel()]
        use = (~creased & agree[w]
               & (np.einsum('ci,ci->c', stored, n_face[np.arange(3 * len(f)) // 3])
                  >= cos_crease))
        n_corner[use] = stored[use]
    return n_corner.reshape(-1, 3, 3).astype(np.float32)


def container_edges(shape: mi.Mesh, crease_angle: float = CREASE_ANGLE,
                    margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Where a Mitsuba mesh as loaded has edges, its vertices welded as :func:`corner_normals`
    welds them: the segments (M,2,3) within ``margin`` of which a point is near an edge, and
    per face whether it lies on a rounding (then every point of it is).

    An edge is a crease (faces meeting at more than ``crease_angle`` degrees: a box's twelve
    edges, a jar's sharp rims) or a rounding: where the surface turns by more than
    ``crease_angle`` within ``margin`` (a polished block's rounded edges and corners, a jar's
    rounded rims; not a jar's side or a sphere, whose radius is large against the margin).
    Between two faces the turn is their angle over the distance across the edge between
    their centroids; a rounding's segments are its borders with the faces around it."""
    params = mi.traverse(shape)
    v = np.array(params['vertex_positions'], np.float64).reshape(-1, 3)
    index = weld(v)
    welded = np.zeros((index.max() + 1, 3))
    welded[index] = v
    mesh = trimesh.Trimesh(welded, index[np.array(params['faces']).reshape(-1, 3)], process=False)
    angle, edges, pairs = np.degrees(mesh.face_adjacency_angles), mesh.face_adjacency_edges, mesh.face_adjacency
    crease = angle > crease_angle
    rounded = np.zeros(len(mesh.faces), bool)
    if margin > 0.0:
        a, b = mesh.vertices[edges[:, 0]], mesh.vertices[edges[:, 1]]
        along = (b - a) / np.maximum(np.linalg.norm(b - a, axis=1), 1e-30)[:, None]

        def across(c):
            w = c - a
            return np.linalg.norm(w - np.einsum('ij,ij->i', w, along)[:, None] * along, axis=1)
        centres = mesh.triangles_center
        width = across(centres[pairs[:, 0]]) + across(centres[pairs[:, 1]])
        bend = ~crease & (angle * margin > crease_angle * np.maximum(width, 1e-30))
        rounded[pairs[bend].ravel()] = True
    border = crease | (rounded[pairs[:, 0]] != rounded[pairs[:, 1]])
    return mesh.vertices[edges[border]], rounded


def weld(v: np.ndarray) -> np.ndarray:
    """Each vertex's index among the vertices welded by position, to :data:`_WELD` of the
    mesh's size (a mesh written with one vertex per face corner is then connected)."""
    size = float(np.ptp(v, axis=0).max()) if len(v) else 1.0
    _, index = np.unique(np.round(v / (_WELD * max(size, 1e-30))).astype(np.int64), axis=0,
                         return_inverse=True)
    return index.ravel()


def face_normals(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each triangle's unit normal (by its winding) and area."""
    c = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(c, axis=1)
    return c / np.maximum(length, 1e-30)[:, None], 0.5 * length


def offset_directions(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Per vertex the direction D that moves every face around it (welded by position) one
    unit along its normal: the least-norm solution of n_i · D = 1 over its surfaces, a surface
    being the faces within :data:`CREASE_ANGLE` of each other
    (their area-weighted mean normal). A box's corner is mitred; a smooth wall, or a rim
    rounded by small facets a few degrees apart, moves along its normal (mitred between such
    facets, a vertex would move 30 times the change)."""
    n, area = face_normals(v, f)
    welded = weld(v)
    # The faces at each welded vertex: the corners sorted by it.
    corner = welded[f].ravel()
    order = np.argsort(corner, kind='stable')
    ends = np.cumsum(np.bincount(corner, minlength=welded.max() + 1))
    cos_crease = np.cos(np.radians(CREASE_ANGLE))
    D = np.zeros((len(ends), 3))
    for k, faces in enumerate(np.split(order // 3, ends[:-1])):
        first, sums = [], []
        for normal, a in zip(n[faces], area[faces]):
            near = [i for i, p in enumerate(first) if normal @ p >= cos_crease]
            if near:
                sums[near[0]] += a * normal
            else:
                first.append(normal)
                sums.append(a * normal)
        if sums:      # a vertex of no face stays
            N = np.array(sums)
            N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)
            D[k] = np.linalg.lstsq(N, np.ones(len(N)), rcond=None)[0]
    return D[welded]


def shading_normals(shape: mi.Mesh, crease_angle: float = CREASE_ANGLE) -> mi.Float:
    """:func:`corner_normals` of a Mitsuba mesh as it was loaded: 9 floats per face, the
    normals of its corners in order (what the ``reneus`` integrator interpolates)."""
    params = mi.traverse(shape)
    vertices = np.array(params['vertex_positions']).reshape(-1, 3)
    normals = np.array(params['vertex_normals']).reshape(-1, 3) if shape.has_vertex_normals() else None
    return mi.Float(corner_normals(vertices, np.array(params['faces']).reshape(-1, 3), normals,
                                   crease_angle).ravel())


def interpolated_normal(normals: dict, si: mi.SurfaceInteraction3f, p: mi.Point3f, vertex=None) -> mi.Vector3f:
    """The shading normal at ``p`` on the triangle ``si`` hit: its corners' normals
    (``normals[shape]``, the container's rule: :func:`shading_normals`) interpolated at the barycentrics of ``p``. Unlike ``si.sh_frame.n`` it follows ``p`` when
    the ray moves (the pose's derivative on curved glass), and the corners where ``vertex``
    (shape, index, active) -> position puts them (default: the mesh's own; the refined walls'
    derivative). Shapes that are not meshes (Mitsuba's analytic sphere) keep their own."""
    n_s = mi.Vector3f(si.sh_frame.n)
    for shape, table in normals.items():
        on = si.is_valid() & (si.shape == mi.ShapePtr(shape))
        f = shape.face_indices(si.prim_index, on)
        p0, p1, p2 = ((vertex or _vertex)(shape, f[i], on) for i in range(3))
        e1, e2, e = p1 - p0, p2 - p0, p - p0
        d11, d12, d22 = dr.dot(e1, e1), dr.dot(e1, e2), dr.dot(e2, e2)
        inv = dr.rcp(dr.maximum(d11 * d22 - d12 * d12, 1e-20))
        b1 = (d22 * dr.dot(e, e1) - d12 * dr.dot(e, e2)) * inv
        b2 = (d11 * dr.dot(e, e2) - d12 * dr.dot(e, e1)) * inv
        corner = 3 * si.prim_index
        n = ((1.0 - b1 - b2) * dr.gather(mi.Vector3f, table, corner, on)
             + b1 * dr.gather(mi.Vector3f, table, corner + 1, on)
             + b2 * dr.gather(mi.Vector3f, table, corner + 2, on))
        n_s = dr.select(on, dr.normalize(n), n_s)
    return n_s


def _vertex(shape: mi.Mesh, index: mi.UInt32, active: mi.Bool) -> mi.Point3f:
    return shape.vertex_position(index, active)


def container_shape(path: str, bsdf: dict | None = None) -> mi.Mesh:
    """The container file as a Mitsuba mesh: as Mitsuba's own reader loads it (stored
    normals included) where it can; a PLY of polygons, which that reader refuses
    (Blender's default export), or an STL or OFF file read by trimesh instead (without its
    normals: :func:`corner_normals` computes them)."""
    if mitsuba_reads(path):
        props = {'type': mesh_type(path), 'filename': os.path.abspath(path)}
        if bsdf is not None:
            props['bsdf'] = bsdf
        return mi.load_dict(props)
    mesh = load_container(path)
    return mitsuba_mesh(mesh.vertices, mesh.faces, props=_props(bsdf, None))


def mitsuba_reads(path: str) -> bool:
    """Whether Mitsuba's own reader loads the mesh file (OBJ, and PLY of triangles only)."""
    plugin = mesh_type(path)
    if plugin is None:
        return False
    try:
        mi.load_dict({'type': plugin, 'filename': os.path.abspath(path)})
    except RuntimeError:
        return False
    return True


def shading_mesh(path: str, crease_angle: float = CREASE_ANGLE, bsdf: dict | None = None,
                 interior: dict | None = None) -> mi.Mesh:
    """The container file as a Mitsuba mesh whose own vertex normals are the rule's: one
    vertex per triangle corner. Mitsuba's ``path`` integrator renders it as ``reneus``
    sees the file (references, synthetic photographs); ``bsdf`` and ``interior`` (a medium)
    are ``load_dict`` dicts."""
    loaded = container_shape(path)
    params = mi.traverse(loaded)
    corners = np.array(params['vertex_positions']).reshape(-1, 3)[np.array(params['faces']).reshape(-1, 3)]
    normals = np.array(shading_normals(loaded, crease_angle)).reshape(-1, 3)
    return mitsuba_mesh(corners.reshape(-1, 3), np.arange(corners.size // 3).reshape(-1, 3),
                        props=_props(bsdf, interior), normals=normals)


def _props(bsdf: dict | None, interior: dict | None) -> mi.Properties:
    props = mi.Properties()
    for name, value in (('bsdf', bsdf), ('interior', interior)):
        if value is not None:
            props[name] = mi.load_dict(value)
    return props


def scene_of(shapes: list) -> mi.Scene:
    """A Mitsuba scene of already loaded ``shapes`` (for ray queries of its own). Each keeps its
    id: a scene names the shapes it holds by their keys, so other keys would rename them in
    the scene they came from too (and in its ``mi.traverse``)."""
    return mi.load_dict({'type': 'scene', **{shape.id() or f'shape_{i}': shape for i, shape in enumerate(shapes)}})


def load_container(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a container mesh and check it (:func:`check_container`)."""
    mesh = load_mesh(path, 'container mesh')
    check_container(mesh, os.fspath(path))
    return mesh


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
        raise ReneusError(f'points: expected an (N, 3) array, got shape {points.shape}')
    if len(points) == 0:
        return np.zeros(0, dtype=bool)

    return scene_inside(mi.load_dict({'type': 'scene', 'container': mitsuba_mesh(container.vertices,
                                                                             container.faces)}), points)


def scene_inside(scene: mi.Scene, points: np.ndarray) -> np.ndarray:
    """Boolean mask of the ``(N, 3)`` ``points`` inside the closed surfaces of a Mitsuba
    ``scene``: an odd number of crossings along a ray, the majority over three directions."""
    # Every crossing is a distinct face (an analytic shape has two), so a ray that has not
    # left the container after this many hits is stuck re-hitting one spot.
    max_hits = sum(shape.face_count() if isinstance(shape, mi.Mesh) else 2 for shape in scene.shapes()) + 1
    origin = mi.Point3f(*(np.asarray(points, np.float64).T.astype(np.float32)))
    votes = mi.UInt32(0)
    for direction in _RAY_DIRECTIONS:
        votes += _parity(scene, origin, mi.Vector3f(*direction), max_hits)
    return np.asarray(votes) >= 2


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


def is_container(shape: mi.Shape) -> bool:
    """Whether a scene's shape is (part of) the container: one with Mitsuba's ``dielectric``."""
    bsdf = shape.bsdf()
    return bsdf is not None and bsdf.class_name() == 'SmoothDielectric'


def check_scene_containers(scene: mi.Scene, where: str) -> None:
    """Every dielectric mesh of ``scene`` (the container) must be closed, face outward,
    and be made of parts that do not overlap, or lie one inside the other as interfaces of
    their own (a case's inner faces, a jar's liquid: another dielectric).

    This is the geometry Mitsuba traces, after the scene's transforms and
    ``flip_normals`` (and after Mitsuba merged shapes that share a BSDF): the
    check catches what the XML points to, whatever file the dataset names.
    """
    parts, etas, names = [], [], []
    for shape in scene.shapes():
        if not isinstance(shape, mi.Mesh) or not is_container(shape):
            continue
        vertices = np.array(shape.vertex_positions_buffer()).reshape(-1, 3)
        faces = np.array(shape.faces_buffer()).reshape(-1, 3)
        if shape.has_flipped_normals():
            faces = faces[:, ::-1]
        mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
        check_container(mesh, f"{where}: shape '{shape.id() or 'container'}'")
        merged = mesh.copy()
        merged.merge_vertices()
        split = merged.split(only_watertight=False)
        parts += split
        etas += [round(float(mi.traverse(shape.bsdf())['eta']), 6)] * len(split)
        name = f"shape '{shape.id() or 'container'}'"
        names += [name + (f' (its surface {k + 1} of {len(split)})' if len(split) > 1 else '') for k in range(len(split))]
    _check_disjoint(parts, where, etas, names)


def check_container_files(files: list[tuple[str, float]], where: str) -> None:
    """A dataset's container as its files state it, outermost first, as (mesh file, IOR
    inside): each closed, its surfaces and the files' apart or nested as interfaces of their
    own, never cut through each other; a hollow vessel in one file (an outer surface around a
    cavity) refused with the advice to state the two as entries of their own, which is what
    the integrator reads. What the scene command can see before it writes a scene."""
    parts, etas, names = [], [], []
    for path, ior in files:
        mesh = load_container(path)
        merged = mesh.copy()
        merged.merge_vertices()
        split = merged.split(only_watertight=False)
        if len(split) > 1 and any(signed_volume(p.vertices, p.faces) < 0 for p in split):
            raise ReneusError(f'{where}: {path}: a hollow vessel in one mesh (an outer surface around a '
                              f'cavity, {len(split)} surfaces); expected its outer surface and its cavity as '
                              "entries of their own in 'containers', each facing out of the space it holds, "
                              'the cavity with the IOR of what fills it (docs/containers.md)')
        parts += split
        etas += [round(float(ior), 6)] * len(split)
        names += [path + (f' (its surface {k + 1} of {len(split)})' if len(split) > 1 else '')
                  for k in range(len(split))]
    _check_disjoint(parts, where, etas, names)


def _check_disjoint(parts, where: str, etas=None, names=None) -> None:
    """Container parts may sit apart or one inside another as its cavity (inward normals:
    a hollow vessel) or as an interface of its own (another dielectric, outward normals),
    never cut through each other or nest glass in the same glass, where a ray would enter
    glass it is already in."""
    etas = etas or [None] * len(parts)
    names = names or [f'part {k + 1}' for k in range(len(parts))]
    for i, a in enumerate(parts):
        for j, b in enumerate(parts[i + 1:], i + 1):
            if not (np.all(a.bounds[0] <= b.bounds[1]) and np.all(b.bounds[0] <= a.bounds[1])):
                continue
            for (inner, name_in), (outer, name_out) in (((a, names[i]), (b, names[j])), ((b, names[j]), (a, names[i]))):
                if signed_volume(outer.vertices, outer.faces) < 0:
                    outer = outer.copy()   # parity is blind to orientation; inside() is not
                    outer.invert()
                within = inside(_probes(inner), outer)
                cavity = signed_volume(inner.vertices, inner.faces) < 0
                nested = etas[i] != etas[j] and not cavity
                if within.any() and not (within.all() and (cavity or nested)):
                    c = np.round(0.5 * (inner.bounds[0] + inner.bounds[1]), 3).tolist()
                    same = ' (the same file twice?)' if np.allclose(inner.bounds, outer.bounds) else ''
                    raise ReneusError(f'{where}: container parts overlap: {name_in} (centred at {c}) reaches '
                                      f'into {name_out}{same}; expected disjoint parts, or a cavity with '
                                      'inward normals inside its part')


def _probes(mesh) -> np.ndarray:
    """Points of a mesh's surface that tell whether it reaches into another: vertices and face centres."""
    return np.concatenate([mesh.vertices, mesh.triangles_center])


def medium_absorption(shape, side: str = 'interior') -> tuple[float, float, float] | None:
    """The absorption coefficient (RGB, per scene unit) of a shape's ``side`` medium, Mitsuba's
    ``homogeneous`` with albedo 0 (pure absorption, what ``volpath`` renders): sigma_t times its
    scale; None where it has none."""
    medium = shape.interior_medium() if side == 'interior' else shape.exterior_medium()
    if medium is None:
        return None
    params = mi.traverse(medium)
    if medium.class_name() != 'HomogeneousMedium' or 'sigma_t.value.value' not in params:
        raise ReneusError(f"reneus integrator: shape '{shape.id()}' has a {medium.class_name()} {side}; "
                          'expected a homogeneous medium with a constant sigma_t')
    albedo = np.array(params['albedo.value.value'], np.float64).ravel()
    if albedo.max() > 1e-6:
        raise ReneusError(f"reneus integrator: shape '{shape.id()}': medium albedo {albedo.round(4).tolist()}; "
                          'expected 0 (the medium absorbs, it does not scatter)')
    sigma = np.array(params['sigma_t.value.value'], np.float64).ravel() * float(params['scale'])
    return tuple(np.broadcast_to(sigma, 3).round(9).tolist())


def absorbing_medium(sigma_a) -> dict:
    """Mitsuba's ``homogeneous`` medium that absorbs ``sigma_a`` (RGB per scene unit) and
    scatters nothing, as a ``load_dict`` dict: what :func:`medium_absorption` reads back. An
    RGB sigma_t is a reflectance (at most 1 per channel), so the largest channel is the scale."""
    sigma_a = np.broadcast_to(np.asarray(sigma_a, np.float64), (3,))
    scale = float(sigma_a.max()) if sigma_a.max() > 0 else 1.0
    return {'type': 'homogeneous', 'albedo': 0.0, 'scale': scale,
            'sigma_t': {'type': 'rgb', 'value': (sigma_a / scale).tolist()}}
