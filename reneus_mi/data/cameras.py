"""Pinhole camera conventions and conversions.

Inside reneus-mi a camera is an OpenCV intrinsic matrix ``K`` (pixels, the
centre of the top-left pixel at (0.5, 0.5)) and a camera-to-world matrix
``c2w`` with OpenCV axes: x right, y down, z forward. This module converts from
and to the conventions of the file formats:

- NeRF/Blender ``transform_matrix``: camera-to-world with OpenGL axes
  (x right, y up, z backward), i.e. OpenCV with y and z flipped;
- NeuS/IDR ``world_mat``: the projection ``K [R | t]`` padded to 4x4, split
  again here by an RQ decomposition;
- Mitsuba's ``perspective`` sensor: looks down +z with +y up, i.e. OpenCV with
  x and y flipped.
"""
from __future__ import annotations

import numpy as np

from reneus_mi.utils.errors import ReneusError

#: Right-multiplying a c2w matrix by this swaps OpenCV and OpenGL camera axes.
OPENGL_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
#: Right-multiplying a c2w matrix by this swaps OpenCV and Mitsuba camera axes.
MITSUBA_FROM_OPENCV = np.diag([-1.0, -1.0, 1.0, 1.0])

# A rotation must satisfy R^T R = I to this tolerance; NeRF-style files store
# float32-rounded matrices, so exact orthonormality cannot be asked for.
_ROTATION_TOL = 1e-4
# Matrices worse conditioned than this are treated as singular.
_MAX_COND = 1e10


def intrinsics(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Return the 3x3 OpenCV intrinsic matrix of a pinhole camera."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def has_skew(K: np.ndarray) -> np.ndarray:
    """Whether intrinsics (..., 3, 3) have a skew term beyond round-off."""
    return np.abs(K[..., 0, 1]) > 1e-9 * K[..., 0, 0]


def focal_from_fov(fov: float, size: int) -> float:
    """Focal length in pixels of a field of view ``fov`` (radians) across ``size`` pixels."""
    return 0.5 * size / np.tan(0.5 * fov)


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera-to-world of a camera at ``eye`` looking at ``target``.

    ``up`` points up in the image (so the camera's y axis, which points down,
    is as close to ``-up`` as the viewing direction allows).
    """
    eye = np.asarray(eye, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    right = np.cross(forward, up)
    if np.linalg.norm(forward) == 0 or np.linalg.norm(right) < 1e-12 * np.linalg.norm(forward):
        raise ReneusError(f"look_at: eye {eye.tolist()} must differ from target {target} and the "
                         f"viewing direction must not be parallel to up {up}")
    forward /= np.linalg.norm(forward)
    right /= np.linalg.norm(right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, np.cross(forward, right), forward, eye
    return c2w


def _check_finite(m: np.ndarray, where: str) -> None:
    bad = np.argwhere(~np.isfinite(m))
    if len(bad):
        i, j = bad[0]
        raise ReneusError(f"{where}: entry [{i}][{j}] is {m[i, j]}; expected finite numbers")


def check_c2w(c2w: np.ndarray, where: str) -> np.ndarray:
    """Return ``c2w`` as a float64 4x4 rigid transform, or raise naming what is wrong.

    A 3x4 matrix is padded with ``[0, 0, 0, 1]``. ``where`` names the file and
    field in the message.
    """
    m = np.asarray(c2w, dtype=np.float64)
    if m.shape not in ((3, 4), (4, 4)):
        raise ReneusError(f"{where}: expected a 4x4 (or 3x4) camera matrix, got shape {m.shape}")
    _check_finite(m, where)
    if m.shape == (3, 4):
        m = np.vstack([m, [0.0, 0.0, 0.0, 1.0]])
    rot = m[:3, :3]
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ReneusError(f"{where}: last row is {m[3].tolist()}; expected [0, 0, 0, 1]")
    if np.linalg.cond(m) > _MAX_COND:
        raise ReneusError(f"{where}: camera matrix is not invertible (rotation part has "
                          f"determinant {np.linalg.det(rot):.3g}): {m.tolist()}")
    det = np.linalg.det(rot)
    if det < 0:
        raise ReneusError(f"{where}: rotation part has determinant {det:.4g}, a mirror; expected "
                          "a rotation (determinant +1): is one axis flipped?")
    if not np.allclose(rot.T @ rot, np.eye(3), atol=_ROTATION_TOL):
        raise ReneusError(f"{where}: camera matrix is not a rotation plus translation "
                          f"(scaled or sheared: determinant {det:.4g}, expected 1): {m.tolist()}")
    return m


def check_K(K: np.ndarray, where: str) -> np.ndarray:
    """Return ``K`` as float64 if it is an invertible 3x3 intrinsic matrix, else raise."""
    k = np.asarray(K, dtype=np.float64)
    if (k.shape != (3, 3) or not np.all(np.isfinite(k)) or not np.allclose(k[2], [0, 0, 1])
            or k[0, 0] <= 0 or k[1, 1] <= 0):
        raise ReneusError(f"{where}: expected an intrinsic matrix [[fx,s,cx],[0,fy,cy],[0,0,1]] "
                         f"with fx, fy > 0, got {k.tolist()}")
    return k


def rq(m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """RQ decomposition ``m = U @ Q`` of a 3x3 matrix, U upper triangular, Q orthogonal.

    Obtained from numpy's QR of the row-reversed transpose; the signs are fixed
    so that U has a positive diagonal.
    """
    flip = np.eye(3)[::-1]
    q, r = np.linalg.qr((flip @ m).T)
    upper = flip @ r.T @ flip
    ortho = flip @ q.T
    signs = np.diag(np.sign(np.diag(upper)))
    return upper @ signs, signs @ ortho


def decompose_projection(P: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Split a 3x4 (or 4x4) projection ``K [R | t]`` into ``K`` and an OpenCV c2w."""
    p = np.asarray(P, dtype=np.float64)
    if p.shape not in ((3, 4), (4, 4)):
        raise ReneusError(f"{where}: expected a 4x4 projection matrix, got shape {p.shape}")
    _check_finite(p, where)
    p = p[:3]
    m = p[:, :3]
    if np.linalg.cond(m) > _MAX_COND:
        raise ReneusError(f"{where}: camera matrix is not invertible: {p.tolist()}")
    # A projection is defined up to scale: pick the sign that makes R proper.
    if np.linalg.det(m) < 0:
        p = -p
        m = p[:, :3]
    K, R = rq(m)
    centre = -np.linalg.solve(m, p[:, 3])
    K = K / K[2, 2]
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = centre
    return K, c2w


def compose_projection(K: np.ndarray, c2w: np.ndarray) -> np.ndarray:
    """Return NeuS's ``world_mat``: ``K [R | t]`` as a 4x4 matrix (last row 0 0 0 1)."""
    k4 = np.eye(4)
    k4[:3, :3] = K
    return k4 @ np.linalg.inv(c2w)


def pixel_rays(K: np.ndarray, c2w: np.ndarray, view: np.ndarray,
               px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World origins and unit directions of the rays through pixel centres.

    ``K`` (N,3,3) and ``c2w`` (N,4,4) are the cameras; ``view`` (M,) picks one
    per ray (a scalar broadcasts); ``px`` (M,2) holds integer pixel
    coordinates x, y. Returns two (M,3) float64 arrays.
    """
    px = np.asarray(px)
    if px.ndim != 2 or px.shape[1] != 2:
        raise ReneusError(f"pixel coordinates: expected shape (M, 2), got {px.shape}")
    view = np.broadcast_to(np.asarray(view, dtype=np.int64), (px.shape[0],))
    if view.size and (view.min() < 0 or view.max() >= len(K)):
        raise ReneusError(f"view indices: expected values in [0, {len(K)}), got "
                         f"[{view.min()}, {view.max()}]")
    uv1 = np.concatenate([px + 0.5, np.ones((px.shape[0], 1))], axis=1)
    d_cam = np.einsum('mij,mj->mi', np.linalg.inv(K)[view], uv1)
    d = np.einsum('mij,mj->mi', c2w[view, :3, :3], d_cam)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.array(c2w[view, :3, 3]), d
