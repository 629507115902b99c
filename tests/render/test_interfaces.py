"""Containers of nested interfaces (beyond the paper's solid block): a display case (glass
walls around air) and a jar of tinted liquid (a glass wall around an absorbing liquid, each
closed surface a cylinder and two disks), each with an opaque probe inside, against Mitsuba's
``path`` and ``volpath`` on the same scene; each part shown to matter; the derivatives with
respect to the IORs against central differences; how the interfaces are found."""
import functools

import mitsuba as mi
import numpy as np
import pytest

from reference import (BLOCK_HALF, BLOCK_ROTATION, derivatives_agree, path_reference, path_scene, render_derivatives,
                       reneus_pixels, reneus_scene)
from reneus_mi.config import RefineConfig
from reneus_mi.render import interfaces
from reneus_mi.render.interfaces import AIR, dielectric, display_case, interfaces_of
from reneus_mi.render.surroundings import Surroundings
from reneus_mi.utils.errors import ReneusError

RES = 24
SPP = 8192
#: The glass, the liquid (ethanol).
GLASS, LIQUID = 1.5, 1.36
#: The case's walls, and the jar's glass, in scene units (the block is about 1 across).
WALL = 0.06
#: The jar's liquid absorbs (a tinted preserving fluid), per unit.
LIQUID_SIGMA = (0.1, 0.3, 0.9)
#: Mean |reneus - path| over the pixels, linear radiance, as for the solid block: measured
#: 0.0005 / 0.0006 (case, D_re 2 / 3) and 0.0010 / 0.0011 (jar); either seen as one solid block
#: of glass (the paper's model) is 0.06-0.07 off.
MEAN_TOL = 0.003
#: 99th percentile of the per-pixel error: measured 0.005 (case) and 0.009 (jar).
P99_TOL = 0.02


def case():
    """A glass case: the block's outer faces, and inner faces WALL in from them around air."""
    return display_case(BLOCK_HALF, WALL, GLASS, BLOCK_ROTATION)


def jar():
    """A glass jar full of a tinted liquid: glass outside, the liquid's surface WALL in from it."""
    return interfaces.jar(0.58, 0.5, WALL, GLASS, LIQUID, LIQUID_SIGMA)


#: Each container, the IOR around its probe, whether it holds a medium, the depth it needs.
CONTAINERS = {'case': (case, AIR, False, 2), 'jar': (jar, LIQUID, True, 2)}


@functools.cache
def reference(kind: str, depth: int) -> np.ndarray:
    shapes, probe_ior, volume, _ = CONTAINERS[kind]
    return path_reference(path_scene(RES, max_depth=depth + 1, shapes=shapes(), probe_ior=probe_ior,
                                     volume=volume), SPP)[0]


def errors(kind: str, depth: int) -> tuple[float, float]:
    image = reneus_pixels(reneus_scene(RES, shapes=CONTAINERS[kind][0](), max_depth=depth, terminal='black'))
    d = np.abs(image - reference(kind, depth))
    return d.mean(), np.percentile(d, 99)


@pytest.mark.parametrize('kind', CONTAINERS)
@pytest.mark.parametrize('extra', [0, 1], ids=['needed', 'one_more'])
def test_nested_container_matches_path_tracer(kind, extra):
    depth = CONTAINERS[kind][3] + extra
    mean_err, p99 = errors(kind, depth)
    assert mean_err < MEAN_TOL and p99 < P99_TOL, (kind, mean_err, p99)


def _absolute_ior(self, group, lanes=None):
    """An inner interface given the IOR inside it, not the ratio of its two sides."""
    return self.ior(group + 1, lanes)


@pytest.mark.parametrize('kind', CONTAINERS)
@pytest.mark.parametrize('broken', ['absolute_ior', 'one_solid_block'])
def test_nested_comparison_has_teeth(kind, broken, monkeypatch):
    depth = CONTAINERS[kind][3]
    if broken == 'absolute_ior':
        monkeypatch.setattr(Surroundings, 'eta', _absolute_ior)
    if broken == 'one_solid_block':
        # The paper's one solid block: the outer glass alone, the field inside it.
        shapes = CONTAINERS[kind][0]()
        outer = {k: v for k, v in shapes.items() if k.startswith(('case_outer', 'jar_glass'))}
        image = reneus_pixels(reneus_scene(RES, shapes=outer, max_depth=depth, terminal='black'))
        d = np.abs(image - reference(kind, depth))
        mean_err, p99 = d.mean(), np.percentile(d, 99)
    else:
        mean_err, p99 = errors(kind, depth)
    assert mean_err > 2 * MEAN_TOL or p99 > 2 * P99_TOL, (kind, broken, mean_err, p99)


def test_interfaces_are_found_nested_whatever_their_order():
    scene = reneus_scene(RES, shapes={**dict(reversed(list(jar().items())))})
    shapes = [s for s in scene.shapes()]
    found = interfaces_of(shapes)
    names = [{shapes[k].id() for k in group} for group in found.shapes]
    assert names == [{'jar_glass_wall', 'jar_glass_top', 'jar_glass_bottom'},
                     {'jar_liquid_wall', 'jar_liquid_top', 'jar_liquid_bottom'}]
    assert found.outer == (0, 1) and found.field == 2
    assert found.ior == pytest.approx((GLASS / AIR, LIQUID / AIR), rel=1e-6)
    assert found.sigma_a[0] is None and found.sigma_a[1] == pytest.approx(LIQUID_SIGMA)


def test_side_by_side_blocks_are_refused():
    apart = {'left': {'type': 'cube', 'to_world': mi.ScalarTransform4f().translate([-1.5, 0, 0]),
                      'bsdf': dielectric(GLASS)},
             'right': {'type': 'cube', 'to_world': mi.ScalarTransform4f().translate([1.5, 0, 0]),
                       'bsdf': dielectric(1.6)}}
    scene = reneus_scene(RES, shapes=apart)
    with pytest.raises(ReneusError, match=r"interfaces \('(left|right)'; '(left|right)'\) do not nest one inside the other"):
        scene.integrator().bind(scene)


@pytest.mark.parametrize('key', ['container.eta', 'container.inner_ior', 'container.sigma_a'])
def test_render_gradients_through_the_jar_match_finite_differences(key):
    # As for the solid block (test_surroundings): a soft field, coarse samples only, pixel by pixel.
    scene = reneus_scene(RES, shapes=jar(), max_depth=2, n_fine=0, field_inv_s=60.0)
    integrator = scene.integrator()
    integrator.configure(refine=RefineConfig(inner_ior=True))
    integrator.bind(scene)
    ad, fd = render_derivatives(scene, key, len(np.array(integrator.params()[key])) - 1)
    agree = derivatives_agree(ad, fd)
    assert agree.mean() > 0.98, (key, agree.mean())
    assert np.abs(ad - fd)[agree].sum() < 0.03 * np.abs(fd)[agree].sum(), key
    assert np.abs(fd).max() > 0.05, (key, np.abs(fd).max())


def test_tinted_jar_in_uniform_light_follows_the_empty_container():
    # Against volpath's full transport (max_depth 16) at D_re 2: 'trace' follows the rays left
    # inside through the glass and the tinted liquid (measured 0.0058: what it drops is the
    # field beyond the tree), 'ambient' sees the light outside straight on (0.0166).
    shapes, probe_ior, volume, depth = CONTAINERS['jar']
    mean, _ = path_reference(path_scene(RES, max_depth=16, shapes=shapes(), probe_ior=probe_ior, volume=volume),
                             SPP)
    error = {terminal: np.abs(reneus_pixels(reneus_scene(RES, shapes=shapes(), max_depth=depth,
                                                         terminal=terminal)) - mean).mean()
             for terminal in ('trace', 'ambient')}
    assert error['trace'] < 0.01 and error['ambient'] > 2 * error['trace'], error


def _flipped(shape: dict) -> dict:
    return {**shape, 'flip_normals': True}


@pytest.mark.parametrize('change, expected', [
    (lambda shapes: {**shapes, 'case_inner': _flipped(shapes['case_inner'])},
     ("interface 'case_inner'", 'normals that point into the space it holds', 'flip its faces')),
    (lambda shapes: {k: v for k, v in shapes.items() if k != 'jar_liquid_top'},
     ("'jar_liquid_wall', 'jar_liquid_bottom'", 'is not closed')),
    (lambda shapes: {**shapes, 'case_inner': {**shapes['case_inner'],
                                              'to_world': mi.ScalarTransform4f().translate([0.3, 0, 0]).scale(0.5)}},
     ("'case_outer'", "'case_inner'", 'intersect', 'expected one inside the other')),
], ids=['inner_normals_inward', 'open_liquid', 'walls_cut'])
def test_containers_the_integrator_refuses(change, expected):
    base = jar() if 'jar' in expected[0] else case()
    scene = reneus_scene(RES, shapes=change(base))
    with pytest.raises(ReneusError) as e:
        scene.integrator().bind(scene)
    assert all(part in str(e.value) for part in expected), str(e.value)
