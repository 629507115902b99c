"""The Mitsuba 3 scene of a dataset: the container, the lighting and one camera.

:func:`write_scene` writes an XML file (format version 3.0.0) that
``mi.load_file`` reads: the container mesh (if the dataset has one) as a smooth ``dielectric``
(``int_ior`` from the dataset, else 1.45 like the paper's synthetic data), the
paper's homogeneous ambient light (a ``constant`` emitter: the dataset's measured
``ambient`` if it has one, else the paper's 0.8), a
``perspective`` sensor reproducing the first view's pixel rays, and the
integrator. For the ``reneus`` integrator it also names the dataset and the
sphere the field lives in (``field_center``, ``field_scale``, see
:meth:`reneus_mi.data.Dataset.normalization`).

A dataset whose capture measured the printed board the container stands on
(:class:`~reneus_mi.data.dataset.PrintedBoard`) gets it as a backdrop:
a ``rectangle`` over the print, :data:`~reneus_mi.data.dataset.CONTACT_GAP` under the
container, facing the cameras, with an ``area`` emitter whose radiance is the print's
measured linear radiance (a bitmap written beside the scene, ``<scene>_board.exr``) and a
black ``diffuse`` BSDF: Mitsuba's ``path`` and the ``reneus`` integrator (which takes a
backdrop's emission where a ray leaving the container meets it) see the same board.

``python -m reneus_mi.scene DATA_DIR -o scene.xml`` writes one (:mod:`reneus_mi.scene`).
"""
from __future__ import annotations

import os
import warnings
import xml.etree.ElementTree as ET

import mitsuba as mi
import numpy as np

from reneus_mi.data.cameras import MITSUBA_FROM_OPENCV, has_skew
from reneus_mi.data.dataset import CONTACT_GAP, Dataset
from reneus_mi.data.images import write_image
from reneus_mi.geometry.container import load_container, mesh_type, mitsuba_reads
from reneus_mi.paper import AMBIENT, D_RE, IOR
from reneus_mi.geometry.container import absorbing_medium
from reneus_mi.utils import guards
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_export, atomic_open

#: Samples per pixel of the written sampler.
SAMPLE_COUNT = 16
#: Relative focal-length difference above which fx != fy is reported.
_SQUARE_PIXEL_TOL = 1e-4
#: Integrator properties that write_scene sets itself for the reneus integrator.
_RESERVED = ('dataset', 'field_center', 'field_scale')
#: Most texels of the board's radiance along its longer side: 2048 keeps the default A4 board
#: (240 mm) at 8.5 texels per millimetre, finer than a 24-megapixel photograph sees it, in
#: 38 MB as Mitsuba holds it.
BOARD_TEXELS = 2048


def sensor_params(K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> dict:
    """Properties of a Mitsuba ``perspective`` sensor equal to an OpenCV camera.

    Returns ``to_world`` (4x4 numpy), ``fov`` (degrees, along x) and
    ``principal_point_offset_x/y`` (fractions of the film size). Mitsuba
    models square pixels without skew; others are approximated with ``fx``
    and a warning.
    """
    fx, fy = K[0, 0], K[1, 1]
    if abs(fx - fy) > _SQUARE_PIXEL_TOL * fx or has_skew(K):
        warnings.warn(f"camera with fx={fx}, fy={fy}, skew={K[0, 1]}: a Mitsuba perspective "
                      "sensor has square pixels and no skew; using fx for both axes")
    return {'to_world': c2w @ MITSUBA_FROM_OPENCV,
            'fov': float(np.degrees(2.0 * np.arctan(0.5 * width / fx))),
            # Mitsuba's offset moves the image, not the principal point: hence centre - c.
            'principal_point_offset_x': float((0.5 * width - K[0, 2]) / width),
            'principal_point_offset_y': float((0.5 * height - K[1, 2]) / height)}


def sensor_dict(K: np.ndarray, c2w: np.ndarray, width: int, height: int) -> dict:
    """``mi.load_dict`` description of the sensor of one view (box-filtered film)."""
    params = sensor_params(K, c2w, width, height)
    return {'type': 'perspective', 'fov_axis': 'x', **params,
            'to_world': mi.ScalarTransform4f(params['to_world']),
            'sampler': {'type': 'independent', 'sample_count': SAMPLE_COUNT},
            'film': {'type': 'hdrfilm', 'width': width, 'height': height,
                     'pixel_format': 'rgb', 'rfilter': {'type': 'box'}}}


def _num(x: float) -> str:
    return repr(float(x))


def _prop(parent: ET.Element, name: str, value) -> None:
    """Append ``value`` as the XML property its Python type calls for."""
    if isinstance(value, (bool, np.bool_)):
        ET.SubElement(parent, 'boolean', name=name, value='true' if value else 'false')
    elif isinstance(value, (int, np.integer)):
        ET.SubElement(parent, 'integer', name=name, value=str(int(value)))
    elif isinstance(value, (float, np.floating)):
        ET.SubElement(parent, 'float', name=name, value=_num(value))
    elif isinstance(value, str):
        ET.SubElement(parent, 'string', name=name, value=value)
    else:
        raise ReneusError(f"integrator setting {name}={value!r}: expected a bool, int, float "
                         f"or str, got {type(value).__name__}")


def _interface(scene: ET.Element, name: str, shape_type: str, filename: str, int_ior: float, ext_ior: float,
               absorption) -> None:
    """One of the container's interfaces: its mesh, a dielectric of its two IORs, and its interior
    medium where it absorbs."""
    shape = ET.SubElement(scene, 'shape', type=shape_type, id=name)
    ET.SubElement(shape, 'string', name='filename', value=filename)
    bsdf = ET.SubElement(shape, 'bsdf', type='dielectric')
    ET.SubElement(bsdf, 'float', name='int_ior', value=_num(int_ior))
    ET.SubElement(bsdf, 'float', name='ext_ior', value=_num(ext_ior))
    if absorption is not None:
        medium = absorbing_medium(absorption)
        element = ET.SubElement(shape, 'medium', type=medium['type'], name='interior')
        for key in ('albedo', 'scale'):
            ET.SubElement(element, 'float', name=key, value=_num(medium[key]))
        ET.SubElement(element, 'rgb', name='sigma_t', value=', '.join(map(_num, medium['sigma_t']['value'])))


def _relative(path: str, xml_dir: str) -> str:
    try:
        return os.path.relpath(path, xml_dir)
    except ValueError:  # another drive on Windows: no relative path exists
        return os.path.abspath(path)


def board_to_world(board) -> np.ndarray:
    """4x4 world transform of Mitsuba's ``rectangle`` ([-1, 1]^2, uv = (x, y) / 2 + 1/2) onto the
    print of ``board`` (a :class:`~reneus_mi.data.dataset.PrintedBoard`), ``CONTACT_GAP`` into the
    table: u along the board's x, v along its y, as the pattern's columns and rows."""
    w, h = board.size_mm
    local = np.diag([0.5 * w, 0.5 * h, 1.0, 1.0])
    local[:3, 3] = [0.5 * w, 0.5 * h, CONTACT_GAP]
    return board.to_world @ local


def hollow_depth(ds: Dataset) -> int:
    """D_re for the dataset's container: the paper's for a solid block, one more for each
    interface inside it (a case's or a jar's inside: 3). A ray reaches the specimen one
    interface later than in a block, and the specimen's reflection in the far inner wall, which
    the photographs show, is then in the tree: on a simulated capture of a case (``fast``, 10
    minutes) D_re 2 ended in fog (Chamfer-L1 6.8 mm), 3 at 0.86 mm in one piece."""
    return D_RE + len(ds.inner)


def scene_xml(ds: Dataset, xml_dir: str, *, integrator: str = 'reneus', ambient: float | None = None,
              container: str | None = None, board: str | None = None,
              **integrator_settings) -> ET.ElementTree:
    """Build the scene of :func:`write_scene`; file paths relative to ``xml_dir``.

    ``container`` names the mesh file the scene gives Mitsuba (default: the dataset's);
    ``board`` the radiance image of the dataset's printed board (None: no board)."""
    ds.validate()
    container = container or ds.container
    clash = [k for k in integrator_settings if integrator == 'reneus' and k in _RESERVED]
    if clash:
        raise ReneusError(f"integrator settings {clash}: set by write_scene from the dataset")
    shape_type = None if container is None else mesh_type(container)
    ior = ds.ior
    if ior is None and ds.container is not None:
        warnings.warn(f"{ds.root}: dataset states no container IOR; using {IOR}")
        ior = IOR

    scene = ET.Element('scene', version='3.0.0')
    integ = ET.SubElement(scene, 'integrator', type=integrator, id='field')
    if integrator == 'reneus':
        centre, radius = ds.normalization()
        ET.SubElement(integ, 'string', name='dataset', value=os.path.abspath(ds.root))
        ET.SubElement(integ, 'point', name='field_center',
                      **{axis: _num(c) for axis, c in zip('xyz', centre)})
        ET.SubElement(integ, 'float', name='field_scale', value=_num(radius))
        if ds.inner and 'max_depth' not in integrator_settings:
            integrator_settings = {**integrator_settings, 'max_depth': hollow_depth(ds)}
    for name, value in integrator_settings.items():
        _prop(integ, name, value)

    params = sensor_params(ds.K[0], ds.c2w[0], ds.width, ds.height)
    sensor = ET.SubElement(scene, 'sensor', type='perspective', id='view_0')
    ET.SubElement(sensor, 'string', name='fov_axis', value='x')
    for name in ('fov', 'principal_point_offset_x', 'principal_point_offset_y'):
        ET.SubElement(sensor, 'float', name=name, value=_num(params[name]))
    to_world = ET.SubElement(sensor, 'transform', name='to_world')
    ET.SubElement(to_world, 'matrix', value=' '.join(map(_num, params['to_world'].ravel())))
    sampler = ET.SubElement(sensor, 'sampler', type='independent')
    ET.SubElement(sampler, 'integer', name='sample_count', value=str(SAMPLE_COUNT))
    film = ET.SubElement(sensor, 'film', type='hdrfilm')
    ET.SubElement(film, 'integer', name='width', value=str(ds.width))
    ET.SubElement(film, 'integer', name='height', value=str(ds.height))
    ET.SubElement(film, 'string', name='pixel_format', value='rgb')
    ET.SubElement(film, 'rfilter', type='box')

    if ambient is None:
        ambient = ds.ambient if ds.ambient is not None else AMBIENT
    emitter = ET.SubElement(scene, 'emitter', type='constant')
    ET.SubElement(emitter, 'rgb', name='radiance', value=', '.join(map(_num, np.broadcast_to(ambient, (3,)))))

    if container is not None:
        # The paper's outside medium is air with an index of exactly 1.
        _interface(scene, 'container', shape_type, _relative(container, xml_dir), ior, 1.0, ds.absorption)
        outside = ior
        for i, inner in enumerate(ds.inner):
            _interface(scene, f'container_inner_{i + 1}', mesh_type(inner.mesh), _relative(inner.mesh, xml_dir),
                       inner.ior, outside, inner.absorption)
            outside = inner.ior

    if board is not None:
        shape = ET.SubElement(scene, 'shape', type='rectangle', id='board')
        # The rectangle faces +z, the board's z points into the table: turned to the cameras.
        ET.SubElement(shape, 'boolean', name='flip_normals', value='true')
        to_world = ET.SubElement(shape, 'transform', name='to_world')
        ET.SubElement(to_world, 'matrix', value=' '.join(map(_num, board_to_world(ds.board).ravel())))
        bsdf = ET.SubElement(shape, 'bsdf', type='diffuse')
        ET.SubElement(bsdf, 'rgb', name='reflectance', value='0.0')
        emitter = ET.SubElement(shape, 'emitter', type='area')
        texture = ET.SubElement(emitter, 'texture', type='bitmap', name='radiance')
        ET.SubElement(texture, 'string', name='filename', value=_relative(board, xml_dir))
        ET.SubElement(texture, 'boolean', name='raw', value='true')

    tree = ET.ElementTree(scene)
    ET.indent(tree)
    return tree


def write_scene(ds: Dataset, path: str, *, integrator: str = 'reneus', ambient: float | None = None,
                board: bool = True, overwrite: bool = False, **integrator_settings) -> None:
    """Write the Mitsuba 3 scene XML of ``ds`` to ``path``, lit by a constant ``ambient``
    (default: the dataset's measured one, else :data:`AMBIENT`).

    A dataset with a printed board gets it in the scene, its radiance in
    ``<scene>_board.exr`` beside it (``board=False``: the paper's model, the board
    taken as ambient light like the rest of the surroundings).

    ``integrator_settings`` become properties of the integrator, typed by
    their Python type (bool, int, float, str). A dataset without a container
    (the paper's "w/o box" data) gives a scene without one. A container file that
    Mitsuba cannot read (a PLY of quads, Blender's default; STL or OFF) is written triangulated
    beside the scene (``<scene>_container.ply``; ``overwrite`` replaces an earlier
    one). Nothing is written when anything is wrong.
    """
    xml_dir = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(xml_dir):
        raise ReneusError(f"{path}: folder {xml_dir} does not exist")
    container = ds.container
    if container is not None and not mitsuba_reads(container):
        # Mitsuba reads OBJ and triangle PLYs only: the scene names a triangle PLY of its own.
        container = guards.check_output_file(os.path.splitext(path)[0] + '_container.ply',
                                             inputs=[ds.root, ds.container], overwrite=overwrite,
                                             what='triangulated container')
    board_file = None
    if board and ds.board is not None:
        board_file = guards.check_output_file(os.path.splitext(path)[0] + '_board.exr', inputs=[ds.root],
                                              overwrite=overwrite, what="board's radiance")
    tree = scene_xml(ds, xml_dir, integrator=integrator, ambient=ambient, container=container,
                     board=board_file, **integrator_settings)
    if container != ds.container:
        atomic_export(load_container(ds.container), container)
    if board_file is not None:
        write_image(board_file, ds.board.radiance(BOARD_TEXELS))
    with atomic_open(path, 'wb') as f:
        tree.write(f, encoding='utf-8', xml_declaration=True)
