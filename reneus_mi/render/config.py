"""What the ``reneus`` integrator renders, as settings: the field, its sampling, the ray tree.

:class:`ModelConfig` is the ``model`` half of a run's configuration (:mod:`reneus_mi.config`)
and what a scene's ``<integrator type="reneus">`` properties set (:mod:`reneus_mi.plugins.properties`).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from reneus_mi.fields import FieldConfig, NeuSFieldConfig
from reneus_mi.geometry.container import CREASE_ANGLE
from reneus_mi.paper import D_RE, GAMMA
from reneus_mi.render.ray_samplers import SamplerConfig
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.validate import check_choice, check_numbers

MODES = ('reneus', 'neus', 'neus_plus')
TERMINALS = ('trace', 'ambient', 'black')


@dataclass
class RenderConfig:
    """How the ray tree through the container is rendered (Sec. 3.3)."""

    mode: str = 'reneus'
    """'reneus' (the paper), 'neus' (ignores the container: plain NeuS in the field's bounding
    sphere) or 'neus_plus' (refracts once on entry, no reflection, no Fresnel weights)."""
    max_depth: int = D_RE
    """D_re, the number of interface events followed (the paper: 2; scenes written for a case or
    a jar get one more per inner interface, reneus_mi.data.scene_xml.hollow_depth)."""
    terminal: str = 'trace'
    """What a ray left at the depth limit sees beyond its last segment: 'trace' (the container
    without the field: its further reflections and refractions, to the backdrop or the ambient;
    the same as 'ambient' in uniform light), 'ambient' (straight on: the backdrop or C_out; wrong
    where the glass reflects totally toward a board) or 'black' (what Mitsuba's path tracer
    computes with max_depth = D_re + 1)."""
    gamma: float = GAMMA
    """Output is C^(1/gamma), the paper's camera response; 1 gives linear radiance."""
    rr_threshold: float = 0.0
    """Russian roulette on ray-tree branches whose weight β is below this: such a branch is
    followed with probability β/rr_threshold and then weighs rr_threshold, an unbiased and
    cheaper estimate of the paper's deterministic tree (0: the paper's tree, every branch)."""
    aovs: bool = False
    """Append the AOV channels mask, sparsity, nx, ny, nz to rendered images."""
    board_texels: int = 256
    """Texels along the longer side of the grid of gains fitted on the backdrop's emission
    (:class:`~reneus_mi.render.board_shading.BoardShading`: the light the container and the
    specimen let reach the printed board; 256 on a 240 mm board: about 1 mm; 0: the board
    as the scene gives it, lit evenly)."""
    crease_angle: float = CREASE_ANGLE
    """Container faces meeting at more than this angle (degrees) are not smoothed together:
    each side bends light by its own faces (a box stays a box however its file was written);
    smoother surfaces use the file's stored normals, or the mean of their faces' normals."""
    edge_margin: float = 0.0
    """Camera rays that enter or leave the container within this distance (scene units) of
    one of its edges are flagged, and training leaves them out of its colour loss: a crease,
    or a rounding (where the surface turns by more than `crease_angle` within the margin; a ray
    through the rounding itself is flagged too). A block polished round bends them otherwise
    than any model of it the photographs give (0: every ray counts; the scene writer sets it
    for a capture's solid block, rounded or found sharp, ``reneus_mi.scene.block_settings``)."""
    bow: bool = False
    """Model each face of a solid block as bulging by its own amount at its centre
    (container.bow: the six faces of its bounding box, scene units; :mod:`~reneus_mi.render.bow`),
    found before training from the photographs rendered with the block empty, the board seen
    through it: a polished block's faces bulge by tenths of a millimetre, which its outline does
    not show (False: the block's file as it is; the scene writer sets it for a capture's solid
    block on its board, ``reneus_mi.scene.block_settings``)."""

    def __post_init__(self):
        check_choice(self, 'mode', MODES)
        check_choice(self, 'terminal', TERMINALS)
        check_numbers(self, at_least_zero=('max_depth', 'rr_threshold', 'board_texels', 'edge_margin'),
                      positive=('gamma',))
        if not 0.0 <= self.crease_angle <= 180.0:
            raise ReneusError(f'crease_angle={self.crease_angle}: expected degrees in [0, 180]')


@dataclass
class ModelConfig:
    """What the ``reneus`` integrator renders: the field, its sampling and the ray tree."""

    field: FieldConfig = dataclasses.field(default_factory=NeuSFieldConfig)
    """The field inside the container (its kind and architecture)."""
    sampler: SamplerConfig = dataclasses.field(default_factory=SamplerConfig)
    """Samples per inside segment."""
    render: RenderConfig = dataclasses.field(default_factory=RenderConfig)
    """The ray tree through the container."""
