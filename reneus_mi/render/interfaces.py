"""The container as nested closed interfaces and the media between them (beyond the paper,
whose container is one solid block).

A display case is a box of glass walls with air inside: two interfaces, the outer faces
(glass inside, air outside) and the inner ones (air inside, glass outside). A jar of alcohol
is a glass wall around the liquid: the outer surface, and the liquid's (liquid inside, glass
outside). The scene states each as Mitsuba does: shapes with a smooth ``dielectric`` BSDF
whose η is the ratio of the IORs on its two sides (``int_ior`` / ``ext_ior``), and an
``interior`` medium where the space inside absorbs (``homogeneous``, albedo 0: amber, a
tinted liquid). Shapes with the same η and medium form one interface (a jar may be a
``cylinder`` and two ``disk`` shapes); :func:`interfaces_of` finds how the interfaces nest,
from where rays cross them.

Regions are numbered from the world outward in: 0 is the world (air, IOR 1, clear), the
inside of interface g is region g + 1, and interfaces are sorted outermost first, so region 1
is inside the outermost glass. The field lives in the innermost region (the block itself,
the case's air, the jar's liquid).
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from reneus_mi.geometry.container import absorbing_medium, medium_absorption, scene_inside, scene_of
from reneus_mi.utils.errors import ReneusError


def _spokes() -> np.ndarray:
    """14 directions around the sphere (the axes and the diagonals), turned off the axes: a ray
    along an axis meets a box's face on the diagonal between its two triangles, where a ray
    tracer may let it through."""
    d = np.concatenate([np.eye(3), -np.eye(3), np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
                        / np.sqrt(3.0)])
    a, b = 0.1234, 0.2345
    turn = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]) @ \
        np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    return d @ turn.T


#: Directions from an interface's centre to points on it, for the nesting and closedness tests.
_SPOKES = _spokes()


@dataclass(frozen=True)
class Interfaces:
    """The container's interfaces, outermost first, and what lies inside each."""
    shapes: tuple[tuple[int, ...], ...]
    """The scene's container shapes (indices) that make up each interface."""
    outer: tuple[int, ...]
    """The region outside each interface (0: the world); its inside is region g + 1."""
    ior: tuple[float, ...]
    """The absolute IOR inside each interface (region g + 1), the world's being 1."""
    sigma_a: tuple[tuple[float, float, float] | None, ...]
    """The absorption inside each interface (RGB per scene unit; None: clear)."""

    @property
    def count(self) -> int:
        return len(self.shapes)

    @property
    def field(self) -> int:
        """The region the field lives in: inside the innermost interface."""
        return self.count

    def group_of_shape(self) -> list[int]:
        """The interface each container shape belongs to, by the shape's index."""
        out = {}
        for g, members in enumerate(self.shapes):
            out.update({k: g for k in members})
        return [out[k] for k in range(len(out))]


def interfaces_of(shapes: list) -> Interfaces:
    """The interfaces the container ``shapes`` (smooth dielectrics) make, checked: they nest
    one inside the other, each closed; the IORs follow from their ratios, from the world in."""
    keys, members = [], []
    for k, shape in enumerate(shapes):
        key = (round(float(mi.traverse(shape.bsdf())['eta']), 6), medium_absorption(shape))
        if key not in keys:
            keys.append(key)
            members.append([])
        members[keys.index(key)].append(k)
    scenes = [scene_of([shapes[k] for k in m]) for m in members]
    names = [', '.join(f"'{shapes[k].id()}'" for k in m) for m in members]
    # Interface b lies inside interface a when points on b are inside a; some but not all: they cut.
    points = [_points_on(scene, name) for scene, name in zip(scenes, names)]
    inside = [[a != b and scene_inside(scenes[a], points[b]) for a in range(len(scenes))] for b in range(len(scenes))]
    for b, row in enumerate(inside):
        for a, within in enumerate(row):
            if a != b and within.any() and not within.all():
                raise ReneusError(f'reneus integrator: the interfaces {names[a]} and {names[b]} intersect; '
                                  'expected one inside the other (a wall thinner than zero?)')
    inside = [[bool(a != b and within.all()) for a, within in enumerate(row)] for b, row in enumerate(inside)]
    depth = [sum(row) for row in inside]
    order = sorted(range(len(scenes)), key=lambda g: depth[g])
    if [depth[g] for g in order] != list(range(len(order))):
        raise ReneusError(f"reneus integrator: the container's interfaces ({'; '.join(names)}) do not nest "
                          'one inside the other; expected a solid block, or walls around air or a liquid '
                          '(each interface a closed surface, with its own IOR ratio)')
    outer, ior, sigma_a = [], [], []
    for i, g in enumerate(order):
        eta, sigma = keys[g]
        outside = 0 if i == 0 else i      # the region of the interface just outside, order[i - 1]
        outer.append(outside)
        ior.append(eta * (1.0 if outside == 0 else ior[outside - 1]))
        sigma_a.append(sigma)
        for k in members[g]:
            if shapes[k].exterior_medium() is not None and (i == 0 or medium_absorption(shapes[k], 'exterior')
                                                             != sigma_a[outside - 1]):
                raise ReneusError(f"reneus integrator: shape '{shapes[k].id()}' has an exterior medium that is "
                                  "not the one around it; expected none (the medium is the interior of the "
                                  "shape around it)")
    return Interfaces(shapes=tuple(tuple(members[g]) for g in order), outer=tuple(outer), ior=tuple(ior),
                      sigma_a=tuple(sigma_a))


def _points_on(scene: mi.Scene, name: str) -> np.ndarray:
    """Points on an interface, seen from its centre along :data:`_SPOKES`, moved a hair inward;
    checked: every spoke meets it (it is closed around its centre) from inside (its normals
    point out of the space it encloses, as Mitsuba's ``dielectric`` takes its interior)."""
    bbox = scene.bbox()
    c = np.array(bbox.center(), np.float64)
    size = float(np.max(np.array(bbox.extents())))
    d = _SPOKES
    rays = mi.Vector3f(*(mi.Float(d[:, i].astype(np.float32)) for i in range(3)))
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*(mi.Float(np.full(len(d), c[i], np.float32)) for i in range(3))),
                                      rays))
    if not np.all(np.array(si.is_valid())):
        raise ReneusError(f'reneus integrator: interface {name} is not closed: a ray from its centre leaves '
                          'without crossing it; expected a closed surface around the space it holds')
    if not np.all(np.array(dr.dot(rays, si.n)) > 0.0):
        raise ReneusError(f'reneus integrator: interface {name} has normals that point into the space it '
                          'holds; expected them out of it (flip its faces), as dielectric reads int_ior inside; '
                          'a hollow vessel (glass around a cavity) in one mesh is two interfaces: state its outer '
                          'surface and its cavity as two entries, each facing out of the space it holds '
                          '(docs/containers.md)')
    t = np.array(si.t, np.float64)
    return c + d * (t - 1e-4 * size)[:, None]


# ------------------------------------------------------------ common containers
#: Mitsuba's air, which its ``dielectric`` takes as the outside by default.
AIR = 1.000277


def dielectric(int_ior: float, ext_ior: float = AIR) -> dict:
    return {'type': 'dielectric', 'int_ior': int_ior, 'ext_ior': ext_ior}


def display_case(half, wall: float, ior: float = 1.5, to_world=None) -> dict:
    """A glass case as Mitsuba shapes: a box of half-extents ``half`` (``cube`` placed by
    ``to_world``), its inner faces ``wall`` in from the outer ones around air."""
    to_world = to_world or mi.ScalarTransform4f()
    inner = [h - wall for h in half]
    return {'case_outer': {'type': 'cube', 'to_world': to_world.scale(list(half)), 'bsdf': dielectric(ior)},
            'case_inner': {'type': 'cube', 'to_world': to_world.scale(inner), 'bsdf': dielectric(AIR, ior)}}


def jar(radius: float, half_height: float, wall: float, ior: float = 1.5, liquid_ior: float = 1.36,
        sigma_a=None) -> dict:
    """A closed glass jar about the y axis full of a liquid, as Mitsuba shapes: each surface a
    ``cylinder`` and a ``disk`` at either end (normals out), the liquid's ``wall`` in from the
    glass's, absorbing ``sigma_a`` (RGB per unit; None: clear)."""
    liquid = None if sigma_a is None else absorbing_medium(sigma_a)
    return {**_closed_cylinder('jar_glass', radius, half_height, dielectric(ior), None),
            **_closed_cylinder('jar_liquid', radius - wall, half_height - wall, dielectric(liquid_ior, ior), liquid)}


def _closed_cylinder(name: str, radius: float, half: float, bsdf: dict, interior: dict | None) -> dict:
    up = mi.ScalarTransform4f().rotate([1, 0, 0], -90)      # a disk's +z to +y
    size = mi.ScalarTransform4f().scale([radius, radius, 1.0])
    extra = {'bsdf': bsdf, **({} if interior is None else {'interior': interior})}
    return {f'{name}_wall': {'type': 'cylinder', 'p0': [0, -half, 0], 'p1': [0, half, 0], 'radius': radius, **extra},
            f'{name}_top': {'type': 'disk', 'to_world': mi.ScalarTransform4f().translate([0, half, 0]) @ up @ size,
                            **extra},
            f'{name}_bottom': {'type': 'disk', 'to_world': mi.ScalarTransform4f().translate([0, -half, 0]) @ up
                               @ mi.ScalarTransform4f().rotate([1, 0, 0], 180) @ size, **extra}}
