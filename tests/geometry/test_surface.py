"""SDF grids, Marching Cubes extraction and the post-processing rules."""
import numpy as np
import pytest
import trimesh

import reneus_mi  # noqa: F401  (sets the variant)
from reneus_mi.fields.analytic import SphereField, TorusField
from reneus_mi.geometry.chamfer import chamfer
from reneus_mi.geometry.surface import extract_mesh, postprocess, sdf_grid
from reneus_mi.geometry.frame import FieldFrame


def sphere(radius, center, subdivisions):
    out = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    out.apply_translation(center)
    return out


def test_sdf_grid_index_order_and_chunking():
    # A non-cubic grid with an off-centre torus: [i, j, k] must be (x, y, z),
    # whatever the chunk size.
    field = TorusField(major=0.4, minor=0.15, center=(0.1, -0.2, 0.05))
    lo, hi, res = np.array([-1.0, -0.8, -0.5]), np.array([1.0, 0.6, 0.7]), (9, 6, 5)
    grid = sdf_grid(field, lo, hi, res, chunk=7)
    axes = [np.linspace(lo[a], hi[a], res[a]) for a in range(3)]
    x, y, z = np.meshgrid(*axes, indexing='ij')
    x, y, z = x - 0.1, y + 0.2, z - 0.05
    expected = np.sqrt((np.sqrt(x**2 + y**2) - 0.4) ** 2 + z**2) - 0.15
    assert grid.shape == res
    np.testing.assert_allclose(grid, expected, atol=1e-6)
    np.testing.assert_array_equal(sdf_grid(field, lo, hi, res), grid)


def test_sphere_extraction_matches_an_icosphere():
    mesh = extract_mesh(SphereField(radius=0.5), -0.6, 0.6, 64)
    # Vertices sit on the sphere to well under the voxel size (0.019), and
    # outward normals give a positive volume.
    assert np.abs(np.linalg.norm(mesh.vertices, axis=1) - 0.5).max() < 2e-4
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * 0.5**3, rel=2e-3)
    # Independent triangulations: Chamfer x100 sits at the sampling floor
    # 100 * 0.5 sqrt(pi / N) = 0.28 for N = 1e5, plus the faceting.
    n = 100000
    r = chamfer(mesh, sphere(0.5, (0, 0, 0), 5), n_points=n)
    assert r['chamfer'] < 1.1 * 100 * 0.5 * np.sqrt(np.pi / n)


def test_to_world_is_honoured():
    field = SphereField(radius=0.5)
    local = extract_mesh(field, -0.6, 0.6, 32)
    to_world = np.array([[0, -2, 0, 1], [2, 0, 0, 2], [0, 0, 2, 3], [0, 0, 0, 1.0]])
    world = extract_mesh(field, -0.6, 0.6, 32, to_world=to_world)
    np.testing.assert_allclose(world.vertices, local.vertices @ to_world[:3, :3].T + [1, 2, 3], atol=1e-12)
    assert world.volume == pytest.approx(8 * local.volume, rel=1e-9)
    # A mirror keeps the normals outwards.
    mirrored = extract_mesh(field, -0.6, 0.6, 32, to_world=np.diag([-1.0, 1.0, 1.0, 1.0]))
    assert mirrored.volume == pytest.approx(local.volume, rel=1e-9)


def test_no_zero_crossing_is_an_error():
    with pytest.raises(ValueError, match='no zero crossing'):
        extract_mesh(SphereField(radius=0.5), 0.6, 0.9, 8)
    with pytest.raises(ValueError, match='resolution'):
        sdf_grid(SphereField(radius=0.5), -1, 1, 1)


def test_largest_keeps_the_component_with_most_vertices():
    # The big sphere has fewer vertices: the rule counts vertices, not area.
    big = sphere(1.0, (3, 0, 0), 1)
    dense = sphere(0.1, (0, 0, 0), 3)
    for parts in ([big, dense], [dense, big]):
        kept = postprocess(trimesh.util.concatenate(parts), 'largest')
        assert len(kept.vertices) == len(dense.vertices) == 642
        assert len(kept.faces) == len(dense.faces)
        np.testing.assert_allclose(kept.vertices.mean(axis=0), 0.0, atol=1e-9)


def test_crop_removes_what_lies_outside_the_container():
    container = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    inner, outer = sphere(0.2, (0, 0, 0), 3), sphere(0.2, (2, 0, 0), 3)
    straddling = sphere(0.2, (0.5, 0, 0), 3)
    cropped = postprocess(trimesh.util.concatenate([inner, outer, straddling]), 'crop', container)
    assert np.all(np.abs(cropped.vertices) < 0.5)
    # The inner sphere and the half of the straddling one with x < 0.5.
    n_half = np.sum(np.all(straddling.vertices[straddling.faces][..., 0] < 0.5, axis=1))
    assert len(cropped.faces) == len(inner.faces) + n_half
    assert postprocess(inner, 'none').vertices.tolist() == inner.vertices.tolist()
    with pytest.raises(ValueError, match='container'):
        postprocess(inner, 'crop')
    with pytest.raises(ValueError, match='largest, crop, none'):
        postprocess(inner, 'biggest')


def _body_with_fragments():
    """A body, a leg that noise cut into two pieces beside it, a second real part, a bud whose
    stalk was lost, a floater and a speck of noise on the body's skin."""
    body = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    upper = trimesh.creation.cylinder(radius=0.03, height=0.3, sections=16)
    upper.apply_translation((0.0, 0.0, -0.665))           # 0.01 below the body
    lower = upper.copy()
    lower.apply_translation((0.0, 0.0, -0.31))            # 0.01 below the upper piece
    second = trimesh.creation.icosphere(subdivisions=3, radius=0.25)
    second.apply_translation((0.0, 1.2, 0.0))             # far, but a real part
    bud = trimesh.creation.icosphere(subdivisions=2, radius=0.08)
    bud.apply_translation((-0.9, 0.0, 0.0))               # 0.32 from the body, 2.6 % of its area
    floater = trimesh.creation.icosphere(subdivisions=1, radius=0.02)
    floater.apply_translation((0.7, 0.7, 0.0))            # 0.49 from the body
    speck = trimesh.creation.icosphere(subdivisions=1, radius=0.005)
    speck.apply_translation((0.51, 0.0, 0.0))             # on the body, 1e-4 of its area
    return trimesh.util.concatenate([body, upper, lower, second, bud, floater, speck])


def test_clean_drops_floaters_and_keeps_cut_off_parts():
    from reneus_mi.geometry.surface import components
    mesh = _body_with_fragments()
    assert components(mesh) == 7
    kept = postprocess(mesh, 'clean')
    assert components(kept) == 5
    assert kept.bounds[0][2] < -0.97                           # the leg's lower piece is there
    assert kept.bounds[0][0] < -0.97                           # and the bud
    assert not np.any(np.linalg.norm(kept.vertices - (0.7, 0.7, 0.0), axis=1) < 0.05)
    assert not np.any(np.linalg.norm(kept.vertices - (0.51, 0.0, 0.0), axis=1) < 0.01)
    # The paper's rule keeps the body alone.
    assert components(postprocess(mesh, 'largest')) == 1


def test_clean_drops_the_sheets_that_touch_the_container():
    """A fake wall (a sheet the field paints on the glass, as on a rounded block's faces) goes
    however large; the real parts stay, the second part 0.25 from the container included. Without
    the container rule the sheet is kept (5 + 1 components): this test fails then."""
    from reneus_mi.geometry.surface import components
    container = trimesh.creation.box(extents=(3.0, 3.4, 2.4))       # faces at x = ±1.5, y = ±1.7
    sheet = trimesh.creation.box(extents=(0.8, 0.02, 0.6))
    sheet.apply_translation((0.6, -1.69, 0.3))                        # against the face y = -1.7
    mesh = trimesh.util.concatenate([_body_with_fragments(), sheet])
    assert components(postprocess(mesh, 'clean')) == 6
    kept = postprocess(mesh, 'clean', container)
    assert components(kept) == 5
    assert kept.bounds[0][1] > -1.5 and kept.bounds[1][1] > 1.4        # the sheet gone, the part kept


#: The bridge tests' gap: 0.6 cells of their 97-point grid over [-1, 1] (a sharp field's 1/s is
#: under a cell).
_GAP = 0.6 * 2.0 / 96


def _bud_on_a_stalk(x, y, z, shortfall, m=np):
    """SDF (``m``: numpy or drjit) of a body (sphere at the origin), a bud (sphere at x = 0.7) and
    a stalk between them whose SDF stops ``shortfall`` above zero all along its axis (a capsule
    of negative radius, on the x axis: grid points of the tests' grid); a floater (a sphere
    near a corner) far from both."""
    body = m.sqrt(x * x + y * y + z * z) - 0.3
    bud = m.sqrt((x - 0.7) * (x - 0.7) + y * y + z * z) - 0.1
    stalk = m.sqrt(y * y + z * z) + m.maximum(m.maximum(-x, x - 0.7), 0.0) + shortfall
    floater = m.sqrt((x + 0.7) * (x + 0.7) + (y - 0.7) * (y - 0.7) + z * z) - 0.08
    return m.minimum(m.minimum(body, bud), m.minimum(stalk, floater))


def _pieces(grid) -> int:
    from skimage.measure import marching_cubes
    from reneus_mi.geometry.surface import components
    verts, faces, _, _ = marching_cubes(grid, level=0.0)
    return components(trimesh.Trimesh(verts, faces, process=False))


@pytest.mark.parametrize('shortfall, pieces', [(0.5, 2), (1.5, 3)])
def test_bridge_joins_what_the_field_nearly_joins(shortfall, pieces):
    # The stalk's SDF stops half a gap short of zero: marching cubes alone loses it and the
    # bud floats free; bridged, body and bud are one piece and the floater stays apart. A
    # stalk 1.5 gaps short is not the field's: nothing is joined.
    from reneus_mi.geometry.surface import bridge
    t = np.linspace(-1.0, 1.0, 97)
    grid = _bud_on_a_stalk(*np.meshgrid(t, t, t, indexing='ij'), shortfall * _GAP).astype(np.float32)
    assert _pieces(grid) == 3
    joined = bridge(grid, _GAP)
    assert _pieces(joined) == pieces
    if pieces == 3:
        assert joined is grid
    else:
        # One voxel-wide line along the stalk's axis between the spheres, nothing else.
        carved = np.argwhere(joined < grid)
        assert 0 < len(carved) < 20
        assert np.all((t[carved[:, 1]] == 0.0) & (t[carved[:, 2]] == 0.0))
        assert np.all((t[carved[:, 0]] > 0.25) & (t[carved[:, 0]] < 0.65))


def test_bridge_leaves_fog_alone():
    # A field early in training: its SDF within the gap of zero nearly everywhere, in many
    # pieces. That is no surface's shell; nothing is carved (and no graph of the grid is built).
    from reneus_mi.geometry.surface import bridge
    rng = np.random.default_rng(0)
    fog = rng.uniform(-0.2 * _GAP, 0.9 * _GAP, (48, 48, 48)).astype(np.float32)
    assert _pieces(fog) > 10
    assert np.array_equal(bridge(fog, _GAP), fog)


class _BudField(SphereField):
    def _distance(self, p):
        import drjit as dr
        return _bud_on_a_stalk(p.x, p.y, p.z, 0.5 * _GAP, dr)


def test_the_clean_mesh_bridges_at_the_fields_own_blur():
    # field_mesh's clean rule bridges below 1/s: here 1/s is the gap, and the stalk's SDF
    # stops half of it short of zero.
    from reneus_mi.geometry.surface import components, field_mesh
    field = _BudField(inv_s=1.0 / _GAP)
    assert components(field_mesh(field, FieldFrame(), 97, 'none')) == 3
    clean = field_mesh(field, FieldFrame(), 97, 'clean')
    assert components(clean) == 2            # body and bud joined; the floater (a real part) kept
    assert clean.bounds[1][0] > 0.75         # the bud is there


def test_components_counts_pieces_of_a_per_face_mesh():
    from reneus_mi.geometry.surface import components
    soup = _body_with_fragments()
    soup.unmerge_vertices()
    assert components(soup) == 7 and components(trimesh.Trimesh()) == 0


class _FacingField(SphereField):
    """A sphere whose radiance tells where it is seen from: 0.25 (1 - v_x) along direction v."""

    def radiance(self, x, v, n, feature):
        import mitsuba as mi
        return mi.Color3f(0.25 * (1.0 - v.x), 0.1 + 0.0 * x.x, 0.5 + 0.0 * x.x)


def test_vertex_colours_are_the_radiance_seen_head_on():
    from reneus_mi.geometry.surface import field_colors
    frame = FieldFrame(center=(10.0, -5.0, 2.0), scale=30.0)
    mesh = sphere(0.4, (0.0, 0.0, 0.0), 3)
    world = mesh.vertices * 30.0 + [10.0, -5.0, 2.0]
    colors = field_colors(_FacingField(radius=0.4), frame, world, gamma=2.2, chunk=100)
    # Seen along the outward normal n the ray runs along -n: red 0.25 (1 + n_x), gamma-encoded.
    n = mesh.vertices / 0.4
    expected = np.stack([0.25 * (1 + n[:, 0]), np.full(len(n), 0.1), np.full(len(n), 0.5)], axis=1) ** (1 / 2.2)
    np.testing.assert_allclose(colors, expected, atol=2e-3)


def test_glb_in_metres_with_the_tables_up(tmp_path):
    from reneus_mi.geometry.mesh import gltf_from_world, write_glb
    # A capture's board frame: millimetres, z into the table; glTF: metres, y up.
    M = gltf_from_world('mm', up=(0.0, 0.0, -1.0), right=(1.0, 0.0, 0.0))
    np.testing.assert_allclose(M[:3, :3] @ [10.0, 20.0, -30.0], [0.01, 0.03, 0.02])
    assert np.linalg.det(M[:3, :3]) > 0
    np.testing.assert_allclose(gltf_from_world(None), np.eye(4))
    mesh = sphere(5.0, (100.0, 50.0, -5.0), 2)
    colors = np.random.default_rng(0).random((len(mesh.vertices), 3))
    write_glb(mesh, colors, tmp_path / 'm.glb', M)
    back = trimesh.load(tmp_path / 'm.glb', force='mesh', process=False)
    np.testing.assert_allclose(back.bounds.mean(axis=0), [0.1, 0.005, 0.05], atol=1e-4)
    assert len(back.vertices) == len(mesh.vertices)
    np.testing.assert_array_equal(back.visual.vertex_colors[:, :3], np.round(colors * 255).astype(np.uint8))


class _SmallSphere(SphereField):
    """A sphere of radius 0.1 off the centre of the [-1, 1] box: a specimen in its container."""
    def _distance(self, p):
        import drjit as dr
        import mitsuba as mi
        return dr.norm(p - mi.Vector3f(0.3, -0.2, 0.1)) - 0.1


def test_the_mesh_grid_covers_the_surface_only_with_the_same_cells():
    """field_mesh lays the container's grid over the part of it that holds the surface: the
    same vertices as the whole grid, for a sixtieth of the points."""
    from reneus_mi.geometry.surface import field_mesh, mesh_grid, surface_box
    field = _SmallSphere()
    lo, hi = surface_box(field, -1.0, 1.0)
    assert np.all(lo <= [0.2, -0.3, 0.0]) and np.all(hi >= [0.4, -0.1, 0.2])
    assert np.all(hi - lo < 0.5)
    sub_lo, sub_hi, counts = mesh_grid(-1.0, 1.0, 129, (lo, hi))
    assert np.prod(counts) < 129 ** 3 / 60
    part = field_mesh(field, FieldFrame(), 129, 'none')
    whole = extract_mesh(field, -1.0, 1.0, 129)
    assert len(part.vertices) == len(whole.vertices)
    np.testing.assert_allclose(np.sort(part.vertices, axis=0), np.sort(whole.vertices, axis=0), atol=1e-6)
    # Inside everywhere: the whole box.
    assert np.allclose(surface_box(SphereField(radius=5.0), -1.0, 1.0)[0], -1.0)
