"""The containers' meshes: closed, outward, and shaded with the normals of the shape they stand for."""
import numpy as np
import pytest
import trimesh

from reneus_mi.geometry.shapes import SHARP_RIM, container_mesh


def _shading_normals(mesh: trimesh.Trimesh, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Random points of the surface and the vertex normals interpolated there, as a renderer
    shades them (barycentric, normalised)."""
    points, faces = trimesh.sample.sample_surface(mesh, count, seed=seed)
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[faces], points)
    normals = np.einsum('ij,ijk->ik', bary, mesh.vertex_normals[mesh.faces[faces]])
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


@pytest.mark.parametrize('grow', [0.0, -2.0])
def test_a_sharp_jar_is_a_cylinder_with_its_normals_to_the_rims(grow):
    """A jar with sharp rims (a drinking glass's, Blender's cylinder): closed, wound outwards,
    its volume the cylinder's, and its shading normals the cylinder's wherever a ray can land,
    up to the rim itself. The marching-cubes jar (96 cells across) cut such a rim by a cell: its
    normals were up to 84 degrees wrong within 0.15 mm of the rims, 1.6 % of the surface more
    than a degree; it failed this test (and its volume, 0.03 % short)."""
    half = np.array([10.0, 10.0, 15.0])
    mesh = container_mesh('cylinder', half, grow=grow, edge=0.0)
    radius, half_height = np.hypot(*half[:2]) + grow, half[2] + grow
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(np.pi * radius ** 2 * 2 * half_height, rel=1e-4)
    points, normals = _shading_normals(mesh, 200000)
    r = np.linalg.norm(points[:, :2], axis=1)
    on_lid = np.abs(np.abs(points[:, 2]) - half_height) < 1e-9 * half_height + 1e-6
    on_side = np.abs(r - radius) < 1e-3 * radius
    band = 2.0 * SHARP_RIM * radius
    away = (radius - r > band) | (half_height - np.abs(points[:, 2]) > band)
    assert np.all(on_lid | on_side)
    exact = np.where(on_lid[:, None], [[0.0, 0.0, 1.0]] * np.sign(points[:, 2:3]),
                     np.c_[points[:, :2] / r[:, None], np.zeros(len(r))])
    angle = np.degrees(np.arccos(np.clip(np.sum(normals * exact, axis=1), -1.0, 1.0)))
    assert np.max(angle[away]) < 0.01
    # Within a hundredth of a millimetre of the rims: both faces reach them.
    near = ~on_lid & (half_height - np.abs(points[:, 2]) < 0.01)
    assert near.sum() > 10 and np.max(angle[near & away]) < 0.01


@pytest.mark.parametrize('edge, grow', [(3.0, 0.0), (0.0, 2.0)])
def test_a_rounded_rim_is_a_quarter_circle(edge, grow):
    """Rims of radius 3, or the outside of a wall 2 thick around sharp ones: the normal turns
    with the quarter circle, each point's shading normal that of the torus it lies on."""
    half = np.array([10.0, 10.0, 12.0])
    mesh = container_mesh('cylinder', half, grow=grow, edge=edge)
    radius, half_height = np.hypot(*half[:2]) + grow, half[2] + edge + grow
    edge += grow
    points, normals = _shading_normals(mesh, 200000, seed=1)
    r = np.linalg.norm(points[:, :2], axis=1)
    rim = (r > radius - edge) & (np.abs(points[:, 2]) > half_height - edge)
    centre = np.c_[points[:, :2] / r[:, None] * (radius - edge), np.sign(points[:, 2]) * (half_height - edge)]
    exact = points - centre
    distance = np.linalg.norm(exact, axis=1)
    assert np.allclose(distance[rim], edge, rtol=0.01)
    angle = np.degrees(np.arccos(np.clip(np.sum(normals * exact / distance[:, None], axis=1), -1.0, 1.0)))
    assert rim.sum() > 1000 and np.max(angle[rim]) < 0.2
