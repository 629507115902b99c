"""Write the Mitsuba 3 scene of a dataset: ``python -m reneus_mi.scene DATA_DIR -o scene.xml``.

The scene (container, ambient light, first camera, integrator, and the printed board
of a capture with its radiance beside the XML) is
:func:`reneus_mi.data.scene_xml.write_scene`'s. The ``reneus`` integrator's
settings start from ``--preset``; a hash grid's finest level follows the photographs'
pixel footprint at the specimen where that is finer, and a capture's solid block has the rays
through its edges, rounded or maybe so, left out and its faces' bulge measured (:func:`block_settings`); ``--set model.render.max_depth=3`` changes one,
by its dotted path in :class:`reneus_mi.config.ReconstructionConfig`, typed and
checked as the configuration declares it, and written under its XML name.
"""
from __future__ import annotations

import argparse
import sys
import warnings

from reneus_mi.config import with_settings
from reneus_mi.data import load_dataset
from reneus_mi.data.scene_xml import write_scene
from reneus_mi.fields.hashgrid import HashGridFieldConfig
from reneus_mi.geometry.container import check_container_files
from reneus_mi.presets import preset
from reneus_mi.plugins.properties import xml_properties
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError, exit_on_error


def _literal(text: str) -> bool | int | float | str:
    """A value typed by its look: another plugin's settings have no configuration here."""
    if text.lower() in ('true', 'false'):
        return text.lower() == 'true'
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def footprint_settings(field, ds, changes: dict) -> dict:
    """The field's settings that follow the photographs: a hash grid's finest level at least
    the pixel footprint at the specimen (:meth:`HashGridFieldConfig.for_footprint`), unless
    ``--set`` gave it; as integrator properties."""
    if not isinstance(field, HashGridFieldConfig) or 'model.field.finest_resolution' in changes \
            or ds.container is None:
        return {}
    _, radius = ds.normalization()
    finest = field.for_footprint(ds.pixel_footprint() / radius).finest_resolution
    return {'field_finest_resolution': finest} if finest != field.finest_resolution else {}


#: A capture's solid block: the camera rays through its rounding and this many radii of it are
#: left out of the loss (``model.render.edge_margin``), at least :data:`EDGE_MARGIN_PIXELS` pixel
#: footprints. Blender's block rounded 1.5 mm, measured 1.25 by the capture, modelled sharp with
#: 2 mm left out: Chamfer-L1 0.104 mm against the sharp block's 0.103 (docs/containers.md); the
#: field paints walls where the model's rounding and the photographs part.
EDGE_MARGIN_RADII, EDGE_MARGIN_PIXELS = 1.6, 2.0
#: The radius, in pixel footprints, below which a block's outline does not tell its rounding
#: from sharp: a block the capture found sharp is given the margin of this rounding. Blender's
#: 0.5 mm rounding at 960 px (1.9 footprints) was found sharp, and left in the loss it grew walls
#: (1.091 mm against the sharp block's 0.103); 1.5 mm (5.7) was measured 1.25.
UNSEEN_EDGE_PIXELS = 3.0


def block_settings(ds, changes: dict, board: bool) -> dict:
    """A capture's solid block as the photographs may show it, as integrator properties, each
    unless ``--set`` gave it: the margin of its edges, EDGE_MARGIN_RADII of its radius as stated
    or measured, or, where the capture found it sharp, of the largest rounding its outline could
    have missed (:data:`UNSEEN_EDGE_PIXELS`); and, standing on its ``board``, its faces' bulge
    measured (``model.render.bow``: Blender's block bowed 0.3 mm, stated flat, 5.2 mm Chamfer-L1,
    measured 0.096; the sharp block 0.104 -> 0.099). Blocks not from a capture (their files exact)
    and hollow containers get neither."""
    if ds.edge is None or ds.inner:
        return {}
    out = {}
    if 'model.render.edge_margin' not in changes:
        footprint = ds.pixel_footprint()
        radius = ds.edge or UNSEEN_EDGE_PIXELS * footprint
        out['edge_margin'] = float(f'{max(EDGE_MARGIN_RADII * radius, EDGE_MARGIN_PIXELS * footprint):.3g}')
    if board and 'model.render.bow' not in changes:
        out['bow'] = True
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog='python -m reneus_mi.scene',
        description='Write a Mitsuba 3 scene (container, ambient light, first camera, '
                    "integrator, a capture's printed board) for a ReNeuS dataset.")
    parser.add_argument('data_dir', metavar='DATA_DIR',
                        help='dataset folder (transforms.json or cameras_sphere.npz)')
    parser.add_argument('-o', '--output', required=True, help='scene XML file to write')
    parser.add_argument('--integrator', default='reneus',
                        help='integrator plugin name (default: %(default)s)')
    parser.add_argument('--preset', default='fast',
                        help="the reneus integrator's preset (reneus_mi.presets: fast, cpu, paper, "
                             "demo, tiny; default: %(default)s)")
    parser.add_argument('--set', dest='settings', metavar='PATH=VALUE', action='append', default=[],
                        help='a model setting over the preset by its dotted path, e.g. '
                             'model.render.max_depth=3, model.field.hidden=64 or model.field=hashgrid, '
                             'typed as reneus_mi.config declares it (repeatable; for another '
                             "--integrator: NAME=VALUE, that plugin's property)")
    parser.add_argument('--board', choices=('scene', 'ambient'), default='scene',
                        help="a capture's printed board: 'scene' puts it under the container, so that "
                             "rays leaving through the bottom see the print (its radiance in "
                             "<scene>_board.exr); 'ambient' leaves it out, the paper's model: they see "
                             "C_out (default: %(default)s)")
    parser.add_argument('--max-image-size', type=int, default=0, metavar='N',
                        help='read the photographs reduced to at most N pixels on a side (they are '
                             'read to check the cameras and masks; lowers the memory they take; the '
                             "scene's camera takes that size; default: as they are)")
    parser.add_argument('--overwrite', action='store_true', help='replace an existing scene file '
                        '(and its <scene>_container.ply, <scene>_board.exr)')
    args = parser.parse_args(argv)
    with exit_on_error():
        guards.check_output_file(args.output, inputs=[args.data_dir], overwrite=args.overwrite,
                                 extensions=('.xml',))
        if args.integrator == 'reneus':
            cfg, changes = with_settings(preset(args.preset), args.settings)
            settings = {'preset': args.preset, **xml_properties(changes)}
        else:
            settings = {}
            for text in args.settings:
                name, sep, value = text.partition('=')
                if not sep or not name:
                    parser.error(f'--set {text!r}: expected NAME=VALUE')
                settings[name] = _literal(value)
        if args.max_image_size < 0:
            raise ReneusError(f'--max-image-size {args.max_image_size}: expected >= 0')
        ds = load_dataset(args.data_dir, need_container=False, max_size=args.max_image_size)
        if ds.container is None and args.integrator == 'reneus' and settings.get('mode', 'neus') != 'neus':
            raise ReneusError(f"{args.data_dir}: dataset names no container mesh (no 'mesh_outside'), "
                              f"but --set model.render.mode={settings['mode']} traces one; expected a "
                              'dataset with its container, or mode neus')
        if ds.container is None:
            warnings.warn(f"{args.data_dir}: dataset names no container mesh; the scene has none"
                          + (' and renders plain NeuS (mode neus)' if args.integrator == 'reneus' else ''))
            if args.integrator == 'reneus':
                settings['mode'] = 'neus'
        if ds.container is not None:
            check_container_files([(ds.container, ds.ior)] + [(i.mesh, i.ior) for i in ds.inner], args.data_dir)
        if args.integrator == 'reneus':
            settings.update(footprint_settings(cfg.model.field, ds, changes))
            settings.update(block_settings(ds, changes, board=args.board == 'scene'))
        write_scene(ds, args.output, integrator=args.integrator, board=args.board == 'scene',
                    overwrite=args.overwrite, **settings)
    return 0


if __name__ == '__main__':
    sys.exit(main())
