"""The thickness of a hollow container's walls, refined (``train.refine.wall``): the stated
thickness measured from the meshes, the inner surface rebuilt where the refined thickness puts
it (against the container made at that thickness), the render's derivative against central
differences, and the thickness found from renders of the truth with the field known."""
import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
import trimesh

from reference import derivatives_agree, pixel_rays, render_derivatives, reneus_pixels, reneus_scene
from reneus_mi.config import RefineConfig
from reneus_mi.geometry.mesh import mitsuba_mesh
from reneus_mi.render.interfaces import dielectric, display_case
from reneus_mi.render.walls import ContainerWalls
from reneus_mi.utils.errors import ReneusError
from test_interfaces import BLOCK_HALF, BLOCK_ROTATION, GLASS, LIQUID, RES, WALL

#: Sides of the meshed jar: its faces move in along their normals, the polygon's apothem.
SIDES = 48
#: The jar's outer radius (to its vertices) and height.
JAR_RADIUS, JAR_HEIGHT = 0.58, 1.0


def case(wall=WALL):
    return display_case(BLOCK_HALF, wall, GLASS, BLOCK_ROTATION)


def jar(wall=WALL):
    """A jar as triangle meshes (a capture writes them so): the liquid's faces ``wall`` in from the glass's."""
    def cylinder(name, radius, height, bsdf):
        mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=SIDES)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
        props = mi.Properties()
        props['bsdf'] = mi.load_dict(bsdf)
        return {name: mitsuba_mesh(mesh.vertices, mesh.faces, name, props)}
    inner = JAR_RADIUS - wall / np.cos(np.pi / SIDES)
    return {**cylinder('glass', JAR_RADIUS, JAR_HEIGHT, dielectric(GLASS)),
            **cylinder('liquid', inner, JAR_HEIGHT - 2 * wall, dielectric(LIQUID, GLASS))}


CONTAINERS = {'case': case, 'jar': jar}


def _scene(kind, wall=WALL, refine=True, **settings):
    scene = reneus_scene(RES, shapes=CONTAINERS[kind](wall), max_depth=2, **settings)
    if refine:
        scene.integrator().configure(refine=RefineConfig(wall=True))
    scene.integrator().bind(scene)
    return scene


@pytest.mark.parametrize('kind', CONTAINERS)
def test_stated_thickness_is_measured_from_the_meshes(kind):
    walls = _scene(kind).integrator().bind(_scene(kind)).walls
    assert walls.stated == pytest.approx([WALL], abs=1e-5)
    assert np.array(walls.thickness) == pytest.approx([WALL], abs=1e-5)


@pytest.mark.parametrize('kind', CONTAINERS)
def test_refined_thickness_renders_as_the_container_made_so(kind):
    # Stated 50 % too thick, set to the truth: the inner surface rebuilt (each face moved along
    # its normal, the vertices mitred) is the container made at the true thickness: the case's
    # exactly; the jar's sides, one smooth surface, move by the change at their vertices, their
    # faces cos(pi / 48) of it (0.2 %: 6e-5 here, a pixel or two along the rims).
    scene = _scene(kind, wall=1.5 * WALL)
    mi.set_property(scene.integrator().params()[ContainerWalls.NAME], mi.Float([WALL]))
    moved = reneus_pixels(scene)
    truth = reneus_pixels(_scene(kind, refine=False))
    stated = reneus_pixels(_scene(kind, wall=1.5 * WALL, refine=False))
    error = np.abs(moved - truth)
    assert (error.max() if kind == 'case' else error.mean()) < 1e-4, (error.max(), error.mean())
    assert np.abs(stated - truth).mean() > 30 * error.mean()


@pytest.mark.parametrize('kind', CONTAINERS)
def test_render_gradient_of_the_wall_matches_finite_differences(kind):
    # As the surroundings' (test_surroundings): a soft field, coarse samples only, pixel by pixel.
    scene = _scene(kind, n_fine=0, field_inv_s=60.0)
    ad, fd = render_derivatives(scene, ContainerWalls.NAME, 0)
    agree = derivatives_agree(ad, fd)
    assert agree.mean() > 0.98, agree.mean()
    assert np.abs(ad - fd)[agree].sum() < 0.03 * np.abs(fd)[agree].sum()
    assert np.abs(fd).max() > 0.3, np.abs(fd).max()


@pytest.mark.parametrize('kind', CONTAINERS)
@pytest.mark.parametrize('start', [0.5, 1.5])
def test_wall_is_found_from_the_truths_renders(kind, start):
    # The field known (the sphere, soft: a sharp one's image moves only at its edges, where a
    # pixel's derivative is none), the thickness alone fitted to the renders of the truth from
    # half or one and a half of it: Adam on the pixels' L1, its rate decaying.
    target = mi.Color3f(reneus_pixels(_scene(kind, field_inv_s=60.0)).T)
    scene = _scene(kind, wall=start * WALL, field_inv_s=60.0)
    integrator, ray = scene.integrator(), pixel_rays(scene)
    array = integrator.params()[ContainerWalls.NAME]
    opt = mi.ad.Adam(lr=0.05 * WALL)
    opt['wall'] = mi.Float(array)
    steps = 60
    for k in range(steps):
        mi.set_property(array, opt['wall'])
        loss = dr.mean(dr.abs(integrator.render_rays(scene, ray).L - target), axis=None)
        dr.backward(loss)
        opt.set_learning_rate(0.05 * WALL * (1.0 - k / steps))
        opt.step()
    assert float(opt['wall'][0]) == pytest.approx(WALL, rel=0.02), float(opt['wall'][0])


def test_refining_the_wall_of_a_solid_block_is_refused():
    scene = reneus_scene(RES)
    scene.integrator().configure(refine=RefineConfig(wall=True))
    with pytest.raises(ReneusError, match=r"^train.refine.wall \(--refine-wall\): the container has no inner "):
        scene.integrator().bind(scene)


def test_refining_the_wall_of_an_analytic_shape_is_refused():
    from reneus_mi.render.interfaces import jar as analytic_jar
    scene = reneus_scene(RES, shapes=analytic_jar(JAR_RADIUS, 0.5, WALL, GLASS, LIQUID))
    scene.integrator().configure(refine=RefineConfig(wall=True))
    with pytest.raises(ReneusError, match=r"inner interface 'jar_liquid_\w+' is a \w+; expected a triangle mesh"):
        scene.integrator().bind(scene)
