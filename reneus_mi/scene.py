"""Write the Mitsuba 3 scene of a dataset: ``python -m reneus_mi.scene DATA_DIR -o scene.xml``.

The scene (container, ambient light, first camera, integrator) is
:func:`reneus_mi.data.scene_xml.write_scene`'s.
"""
from __future__ import annotations

import argparse
import warnings

from reneus_mi import guards
from reneus_mi.data import load_dataset
from reneus_mi.data.scene_xml import RESERVED, write_scene
from reneus_mi.errors import ReneusError, exit_on_error


def _setting(text: str) -> tuple[str, str]:
    key, sep, value = text.partition('=')
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE")
    return key, value


def _literal(text: str) -> bool | int | float | str:
    if text.lower() in ('true', 'false'):
        return text.lower() == 'true'
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def typed_settings(settings: list[tuple[str, str]], preset: str) -> dict:
    """``--set`` values typed as the integrator's settings are (``reneus_mi.config``)."""
    from reneus_mi.plugins.reneus import property_types
    kinds = dict(settings)
    types = property_types(preset, kinds.get('field'))
    out = {}
    for key, text in settings:
        if key not in types or key in RESERVED or key == 'preset':
            raise ReneusError(f"--set {key}: not a setting of the reneus integrator; expected one of "
                              f"{', '.join(k for k in types if k not in (*RESERVED, 'preset'))}")
        kind = types[key]
        try:
            if kind is bool:
                if text.lower() not in ('true', 'false'):
                    raise ValueError
                out[key] = text.lower() == 'true'
            else:
                out[key] = kind(text) if kind in (int, float, str) else text
        except ValueError:
            raise ReneusError(f"--set {key}={text}: expected {'true or false' if kind is bool else kind.__name__}") from None
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog='python -m reneus_mi.scene',
        description='Write a Mitsuba 3 scene (container, ambient light, first camera, '
                    'integrator) for a ReNeuS dataset.')
    parser.add_argument('data_dir', metavar='DATA_DIR',
                        help='dataset folder (transforms.json or cameras_sphere.npz)')
    parser.add_argument('-o', '--output', required=True, help='scene XML file to write')
    parser.add_argument('--integrator', default='reneus',
                        help='integrator plugin name (default: %(default)s)')
    parser.add_argument('--preset', default='fast',
                        help="the reneus integrator's preset (reneus_mi.presets: fast, cpu, paper, "
                             "demo, tiny; default: %(default)s)")
    parser.add_argument('--set', dest='settings', metavar='KEY=VALUE', type=_setting,
                        action='append', default=[],
                        help='an integrator setting over the preset, e.g. max_depth=3 or field_hidden=64, '
                             'typed as reneus_mi.config declares it (repeatable)')
    parser.add_argument('--overwrite', action='store_true', help='replace an existing scene file')
    args = parser.parse_args(argv)
    with exit_on_error():
        guards.check_output_file(args.output, inputs=[args.data_dir], overwrite=args.overwrite,
                                 extensions=('.xml',))
        ds = load_dataset(args.data_dir, need_container=False)
        if ds.container is None:
            warnings.warn(f"{args.data_dir}: dataset names no container mesh; "
                          "the scene has none")
        if args.integrator == 'reneus':
            from reneus_mi.presets import preset
            preset(args.preset)
            settings = {'preset': args.preset, **typed_settings(args.settings, args.preset)}
        else:  # another plugin's settings: typed by their look
            settings = {key: _literal(text) for key, text in args.settings}
        write_scene(ds, args.output, integrator=args.integrator, overwrite=args.overwrite, **settings)


if __name__ == '__main__':
    main()
