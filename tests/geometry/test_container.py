"""The container: the parity test of what lies inside, and parts that must not overlap."""
import numpy as np
import pytest
import trimesh

from reneus_mi.geometry.container import _check_disjoint, inside


def test_inside_against_analytic_shapes():
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (20000, 3))
    # A rotated box: inside when the rotated-back point is in the box.
    rotation = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])
    box = trimesh.creation.box(extents=(1.2, 0.8, 1.0), transform=rotation)
    local = points @ rotation[:3, :3]
    expected = np.all(np.abs(local) < [0.6, 0.4, 0.5], axis=1)
    assert np.array_equal(inside(points, box), expected)
    # An icosphere, away from its faceted surface.
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    r = np.linalg.norm(points, axis=1)
    clear = np.abs(r - 0.7) > 0.01
    assert np.array_equal(inside(points, ball)[clear], (r < 0.7)[clear])


def test_inside_rejects_an_open_container():
    open_box = trimesh.creation.box()
    open_box.update_faces(np.arange(len(open_box.faces)) > 0)
    with pytest.raises(ValueError, match='not closed'):
        inside(np.zeros((1, 3)), open_box)


def test_container_parts_apart_or_hollow_pass_overlapping_fail():
    outer = trimesh.creation.box(extents=(2, 2, 2))
    apart = trimesh.creation.box().apply_translation((5, 0, 0))
    cavity = trimesh.creation.box()
    cavity.invert()
    _check_disjoint([outer, apart], 'scene.xml')
    _check_disjoint([outer, cavity], 'scene.xml')      # a hollow vessel
    with pytest.raises(ValueError, match='scene.xml: container parts overlap'):
        _check_disjoint([outer, trimesh.creation.box()], 'scene.xml')    # glass in glass
    with pytest.raises(ValueError, match='container parts overlap'):
        _check_disjoint([outer, trimesh.creation.box().apply_translation((0.8, 0.8, 0.8))], 's')
    # Named by the scene's shapes, not by a centre that two parts share; the same file twice said.
    with pytest.raises(ValueError, match=r"shape 'case' \(centred at \[0.0, 0.0, 0.0\]\) reaches into shape "
                                         r"'case_copy' \(the same file twice\?\)"):
        _check_disjoint([outer, outer.copy()], 's', names=["shape 'case'", "shape 'case_copy'"])
    # An interface of its own inside the glass (a case's air, a jar's liquid: another dielectric).
    _check_disjoint([outer, trimesh.creation.box()], 'scene.xml', etas=[1.5, 1 / 1.5])
    with pytest.raises(ValueError, match='container parts overlap'):
        _check_disjoint([outer, trimesh.creation.box().apply_translation((0.8, 0.8, 0.8))], 's', etas=[1.5, 0.9])
