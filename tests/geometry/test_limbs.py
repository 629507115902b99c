"""How far a reconstruction reaches along a limb: the mesh's reach and the field's own, on
shapes whose reach is known."""
import numpy as np
import pytest
import trimesh

import reneus_mi  # noqa: F401  (variant)
from reneus_mi.evaluate import main as evaluate
from reneus_mi.fields import SphereField
from reneus_mi.geometry.frame import FieldFrame
from reneus_mi.geometry.limbs import field_reach, limb_reach

#: A limb along +x from the origin, 3 long, 0.1 thick all along.
LIMB = {'name': 'leg', 'joints_mm': [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]], 'radii_mm': [0.1, 0.1]}
TOLERANCE = 0.05


def test_a_mesh_reaches_as_far_as_it_covers_the_axis():
    """A rod of length 1 along the limb's first third: its end cap covers the axis as far as the
    limb's radius and the tolerance beyond it (within a step)."""
    rod = trimesh.creation.cylinder(radius=0.1, height=1.0)
    rod.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    rod.apply_translation([0.5, 0.0, 0.0])
    (leg,) = limb_reach(rod, [LIMB], tolerance=TOLERANCE)
    assert leg['length'] == pytest.approx(3.0)
    # Within a step of the axis' samples and one of the surface's (sampled, not exact).
    assert leg['reach'] == pytest.approx(1.0 + 0.1 + TOLERANCE, abs=TOLERANCE)
    assert leg['error_pct'] == pytest.approx(-62.0, abs=1.0)
    assert leg['longest_gap'] == pytest.approx(0.0, abs=1e-9)


def test_a_field_reaches_where_its_sdf_at_the_axis_is_within_the_radius():
    """A sphere of radius 0.5 in a field frame of scale 2 (1 in the world): the axis is covered
    while the world distance to the sphere, |p| - 1, is at most the radius and the tolerance."""
    field = SphereField(radius=0.5)
    frame = FieldFrame(center=(0.0, 0.0, 0.0), scale=2.0)
    (leg,) = field_reach(field, frame, [LIMB], tolerance=TOLERANCE)
    assert leg['reach'] == pytest.approx(1.0 + 0.1 + TOLERANCE, abs=0.5 * TOLERANCE)
    # The same sphere in a frame of scale 1 (radius 0.5 in the world) reaches half as far.
    (leg,) = field_reach(field, FieldFrame(scale=1.0), [LIMB], tolerance=TOLERANCE)
    assert leg['reach'] == pytest.approx(0.5 + 0.1 + TOLERANCE, abs=0.5 * TOLERANCE)


def test_the_field_needs_the_limbs(tmp_path):
    mesh = tmp_path / 'mesh.ply'
    trimesh.creation.icosphere().export(mesh)
    with pytest.raises(SystemExit, match='--field needs --limbs'):
        evaluate([str(mesh), str(mesh), '--field', str(tmp_path / 'checkpoint.npz')])
