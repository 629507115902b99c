"""Finding the container on the board from the photographs (the paper labelled its edges by hand).

The board and the cameras are known once calibrated, so each photograph can be predicted
as the bare board would look: the printed pattern warped into the view (:func:`predict_board`).
Where the photograph disagrees with that prediction, something stands between the camera
and the board: the glass, which displaces the pattern behind it, and the specimen
(:func:`changed_region`). Every container here is convex, so its silhouette in a view is
the convex hull of its projected vertices, and the disagreeing region of each view, closed
and filled, is a measurement of that silhouette.

The container's size is measured and it stands on the board, so three numbers remain: its
place ``(x, y, yaw)`` (:mod:`reneus_mi.capture.placement`). :func:`register` finds them by
fitting the projected silhouettes to the measured ones over all views at once, through each
view's signed distance map to the measured silhouette's outline (as
:mod:`reneus_mi.train.silhouette` does for the trainer): a start from the rays through the
measured silhouettes' centroids, a coarse search over yaw, then a robust least-squares
refinement of all three. The residual is the RMS distance in pixels between the projected
and the measured outlines. A solid block stated as a box, once found as stated, is fitted
again with its edges rounded (:func:`_measure_edge`): polished blocks are.
"""
from __future__ import annotations

import copy
import dataclasses

import cv2
import numpy as np
from scipy import ndimage, optimize

from reneus_mi.capture.charuco import Board
from reneus_mi.capture.placement import local_mesh, pose_matrix, symmetry
from reneus_mi.capture.settings import AUTO
from reneus_mi.render.config import RenderConfig
from reneus_mi.utils.errors import ReneusError

#: A pixel disagrees with the bare board when it differs by this share of the board's contrast.
CHANGE_THRESHOLD = 0.35
#: Points sampled along each view's projected outline.
OUTLINE_POINTS = 256
#: Yaw steps (degrees) of the coarse search.
YAW_STEP = 3.0
#: Distances beyond this share of the container's apparent size count as this much (outliers:
#: a view whose measured silhouette is wrong must not drag the fit).
TRUNCATION = 0.25
#: A view measures the container's place when at least this share of its outline lies on
#: the board in the photograph.
MIN_KNOWN = 0.5
#: The stated outer size is refused when the size that fits the photographs best differs by
#: more than this along an axis (mm; docs/constants.md).
SIZE_TOLERANCE_MM = 1.0
#: Rounds of place and size when the size is measured (--size-mm auto): the first from a
#: cube of the silhouettes' width, the second from the first's size.
SIZE_ROUNDS = 2
#: Edge radii tried for a block stated as a box (mm, up to this share of its smallest size),
#: and how much closer a rounded block's outline must lie to the silhouettes to be taken for
#: it: polished blocks are rounded, and a box stated for one bends light at its edges
#: otherwise than the photographs show (docs/containers.md).
EDGE_STEP_MM = 0.25
EDGE_MAX_SHARE = 0.2
EDGE_GAIN = 0.1
#: The container is not found when the median view's residual exceeds this share of its
#: apparent size (and 2 pixels).
FOUND_LIMIT = 0.05


@dataclasses.dataclass
class Registration:
    """The container's place on the board and how well the photographs agree with it."""
    pose: tuple[float, float, float]
    #: RMS outline distance (pixels of the dataset's images) over all views, and per view.
    residual: float
    view_residuals: np.ndarray
    #: The measured silhouettes (N,h,w) bool, for the overlays.
    measured: np.ndarray
    #: The outer size (mm) whose outline fits the silhouettes best, with the place, and the
    #: residual of each: (stated size's, best size's), pixels.
    best_size: tuple[float, float, float] | None = None
    size_residuals: tuple[float, float] | None = None
    #: The best size's standard deviations (mm), from the fit's Jacobian.
    size_std: tuple[float, float, float] | None = None
    #: Whether the size was measured (--size-mm auto) rather than stated.
    size_measured: bool = False
    #: The radius of the edges of a block stated as a box (mm) where the photographs show them
    #: rounded, else None; and the mean outline distance (pixels) of the sharp box and of the
    #: best radius, each at its own best place.
    edge_mm: float | None = None
    edge_residuals: tuple[float, float] | None = None


def predict_board(board: Board, K: np.ndarray, c2w: np.ndarray, size: tuple[int, int]):
    """The bare board as a pinhole camera sees it: (h,w) share of white in each pixel and
    (h,w) bool of pixels wholly on the printed pattern. Pixels in reneus-mi's convention."""
    width, height = size
    w2c = np.linalg.inv(c2w)
    H_board = K @ w2c[:3][:, [0, 1, 3]]                                      # board mm -> pixels
    # Supersampled twice, then averaged: a pixel's share of white, not a point sample.
    depth = (w2c[:3, :3] @ np.c_[board.corners.T] + w2c[:3, 3:]).T[:, 2]
    px_per_mm = K[0, 0] / max(depth.min(), 1e-6)
    ppm = float(np.clip(np.ceil(4.0 * px_per_mm), 2.0, 40.0))
    pattern = board.pattern(ppm).astype(np.float32) / 255.0
    from_pattern = np.diag([1.0 / ppm, 1.0 / ppm, 1.0])
    from_pattern[:2, 2] = 0.5 / ppm                                      # pattern pixel centres
    to_cv = np.array([[2.0, 0.0, -0.5], [0.0, 2.0, -0.5], [0.0, 0.0, 1.0]])  # 2x, OpenCV pixels
    H = to_cv @ H_board @ from_pattern
    big = (2 * width, 2 * height)
    white = cv2.warpPerspective(pattern, H, big, flags=cv2.INTER_LINEAR, borderValue=0.0)
    cover = cv2.warpPerspective(np.ones_like(pattern), H, big, flags=cv2.INTER_LINEAR, borderValue=0.0)
    white = cv2.resize(white, size, interpolation=cv2.INTER_AREA)
    cover = cv2.resize(cover, size, interpolation=cv2.INTER_AREA)
    on_board = cv2.erode((cover > 0.999).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return white, on_board


def linear(image: np.ndarray) -> np.ndarray:
    """Linear values of display values (the camera response the trainer assumes)."""
    return np.clip(image, 0.0, 1.0) ** RenderConfig.gamma


def board_levels(lin: np.ndarray, white: np.ndarray, on_board: np.ndarray, keep=None):
    """Median linear value of the black and of the white print (channels kept if ``lin`` has
    them), or (None, None) when too little of either is seen.

    From the pixels wholly of one print, and of those the half farthest from the other (the
    lens blurs edges; the white ring around a corner may be two pixels wide); ``keep`` limits
    the pixels.
    """
    pick = on_board if keep is None else on_board & keep
    share = cv2.GaussianBlur(white, (0, 0), 1.0)
    levels = []
    for wholly, sign in ((pick & (white < 0.02), -1.0), (pick & (white > 0.98), 1.0)):
        if wholly.sum() < 32:
            return None, None
        inner = wholly & (sign * share >= np.median(sign * share[wholly]))
        levels.append(np.median(lin[inner], axis=0))
    return tuple(levels)


def changed_region(image: np.ndarray, white: np.ndarray, on_board: np.ndarray, square_px: float):
    """Where a photograph (display values, (h,w,3)) disagrees with the bare board: closed,
    filled, the largest part, its convex hull. (h,w) bool; all False if nothing disagrees."""
    lin = linear(image).mean(axis=-1)
    black, bright = board_levels(lin, white, on_board)
    if black is None or not bright > black:
        return np.zeros(lin.shape, bool)
    residual = np.abs(lin - (black + (bright - black) * white)) / (bright - black)
    residual = cv2.GaussianBlur(residual.astype(np.float32), (0, 0), 0.7)
    changed = ((residual > CHANGE_THRESHOLD) & on_board).astype(np.uint8)
    changed = cv2.morphologyEx(changed, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    radius = max(2, int(round(0.5 * square_px)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    changed = cv2.morphologyEx(changed, cv2.MORPH_CLOSE, disc)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(changed)
    if n <= 1:
        return np.zeros(lin.shape, bool)
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    points = np.argwhere(labels == largest)[:, ::-1].astype(np.int32)
    hull = cv2.convexHull(points)
    out = np.zeros(lin.shape, np.uint8)
    cv2.fillConvexPoly(out, hull, 1)
    return out > 0


class Outline:
    """The projected outline of the container at a place on the board, in every view."""

    def __init__(self, shape: str, size, K: np.ndarray, c2w: np.ndarray, edge: float | None = None):
        mesh = local_mesh(shape, size, edge=edge)
        hull = np.asarray(mesh.convex_hull.vertices)
        # A smooth container's hull has thousands of vertices: its outline needs far fewer.
        if len(hull) > 512:
            hull = hull[np.random.default_rng(0).choice(len(hull), 512, replace=False)]
        self.points = hull
        self.stated = np.asarray(size, np.float64)
        self.K = K
        self.w2c = np.linalg.inv(c2w)

    def polygon(self, pose, view: int, size=None) -> np.ndarray:
        """(M,2) outline polygon (pixels) of the container at ``pose`` in ``view``; ``size``:
        of another outer size (the shapes scale with it along each axis)."""
        M = pose_matrix(pose)
        points = self.points if size is None else self.points * (np.asarray(size) / self.stated)
        world = points @ M[:3, :3].T + M[:3, 3]
        cam = world @ self.w2c[view, :3, :3].T + self.w2c[view, :3, 3]
        uv = cam @ self.K.T
        px = uv[:, :2] / np.maximum(uv[:, 2:], 1e-9)
        return cv2.convexHull(px.astype(np.float32)).reshape(-1, 2).astype(np.float64)

    def samples(self, pose, view: int, n: int = OUTLINE_POINTS, size=None) -> np.ndarray:
        """``n`` points spread evenly along the outline."""
        poly = self.polygon(pose, view, size)
        edges = np.roll(poly, -1, axis=0) - poly
        length = np.linalg.norm(edges, axis=1)
        at = (np.arange(n) + 0.5) * length.sum() / n
        cum = np.concatenate([[0.0], np.cumsum(length)])
        k = np.clip(np.searchsorted(cum, at, side='right') - 1, 0, len(poly) - 1)
        t = (at - cum[k]) / np.maximum(length[k], 1e-12)
        return poly[k] + t[:, None] * edges[k]

    def size(self, pose, view: int) -> float:
        poly = self.polygon(pose, view)
        return float(np.sqrt(max(cv2.contourArea(poly.astype(np.float32)), 1.0)))


def _distance_maps(measured: np.ndarray) -> np.ndarray:
    """Signed distance (pixels) to each measured silhouette's outline, > 0 outside."""
    return np.stack([ndimage.distance_transform_edt(~m) - ndimage.distance_transform_edt(m)
                     for m in measured]).astype(np.float32)


def _lookup(D: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinear values of a map at pixel positions (reneus-mi convention)."""
    return ndimage.map_coordinates(D, [points[:, 1] - 0.5, points[:, 0] - 0.5], order=1, mode='nearest')


class _Fit:
    """The outline distances of a pose over all views whose silhouette was measured."""

    def __init__(self, outline: Outline, measured: np.ndarray, trusted: np.ndarray, views):
        self.outline, self.views = outline, list(views)
        self.D = _distance_maps(measured)
        self.trusted = trusted.astype(np.float32)

    def with_outline(self, outline: Outline) -> '_Fit':
        """The same silhouettes fitted by another outline (the distance maps are kept)."""
        other = copy.copy(self)
        other.outline = outline
        return other

    def distances(self, pose, clip=None, unknown: float | str | None = 0.0, size=None) -> np.ndarray:
        """(views, OUTLINE_POINTS) distances, clipped to ``clip`` (per view); where a point lies
        off the board or the photograph, nothing is known: ``unknown`` there (0: no say in a
        fit; the clip: as bad as it gets; None: NaN)."""
        out = np.zeros((len(self.views), OUTLINE_POINTS))
        for j, v in enumerate(self.views):
            p = self.outline.samples(pose, v, size=size)
            d = _lookup(self.D[v], p)
            if clip is not None:
                d = np.clip(d, -clip[j], clip[j])
            known = _lookup(self.trusted[v], p) > 0.5
            fill = np.nan if unknown is None else (clip[j] if unknown == 'clip' else unknown)
            out[j] = np.where(known, d, fill)
        return out


def _wrap(yaw: float, period: float) -> float:
    return 0.0 if period == 0 else float((yaw + 0.5 * period) % period - 0.5 * period)


def register(images: np.ndarray, valid: np.ndarray, K: np.ndarray, c2w: np.ndarray, board: Board,
             shape: str, size, *, pose=None, start=None, measured: np.ndarray | None = None,
             edge: float | None = None, rounding: bool = False) -> Registration:
    """Find the container (``shape``, outer ``size`` in mm, ``edge`` the radius of its rounded
    edges, see :func:`~reneus_mi.capture.placement.local_mesh`) standing on ``board``; with
    ``rounding``, a block stated as a box whose edges the photographs show rounded is found as
    the rounded block it is (:func:`_measure_edge`).

    ``images`` (N,h,w,3) are the undistorted photographs (display values), ``valid`` where
    they hold photograph, ``K`` their pinhole intrinsics and ``c2w`` (N,4,4) their cameras in
    the board's frame. ``pose`` skips the search (a manual place) but still measures the
    residual; ``start`` (a place found before) skips the coarse search; ``measured`` reuses
    silhouettes measured before. Raises when the container is
    not found (the result's silhouettes are on the exception, ``err.measured``).
    """
    n, h, w = images.shape[:3]
    pose_given = pose is not None
    trusted = np.zeros((n, h, w), bool)
    squares = np.zeros(n)
    need = measured is None
    if need:
        measured = np.zeros((n, h, w), bool)
    for v in range(n):
        white, on_board = predict_board(board, K, c2w[v], (w, h))
        trusted[v] = on_board & valid[v]
        # A square's size in pixels at the board's centre: the scale of the disagreement's gaps.
        depth = np.linalg.norm(c2w[v, :3, 3] - [*np.multiply(board.size_mm, 0.5), 0.0])
        squares[v] = K[0, 0] * board.square_mm / depth
        if need:
            measured[v] = changed_region(images[v], white, trusted[v], squares[v])
    seen = [v for v in range(n) if measured[v].any()]
    if len(seen) < max(2, n // 3):
        err = ReneusError(f'container not found: {len(seen)} of {n} photographs show something on '
                          'the board that the bare board does not explain; expected the container '
                          'in most of them (see the overlays; or give --container-pose x,y,yaw)')
        err.measured = measured
        raise err
    measured_size = size == AUTO
    if measured_size:
        size, start = _measure_size(measured, trusted, K, c2w, seen, shape, start, edge)
    outline = Outline(shape, size, K, c2w, edge)
    fit = _Fit(outline, measured, trusted, seen)
    if pose is None:
        pose = _search(fit, measured, K, c2w, seen, shape, size, start)
    pose = tuple(float(x) for x in pose)
    per_view, residual, apparent = _residuals(fit, pose, n)
    result = Registration(pose=pose, residual=residual, view_residuals=per_view, measured=measured,
                          size_measured=measured_size)
    _check_place(board, pose, per_view, measured, result)
    if rounding and shape == 'box' and not pose_given:
        # Only a box found as stated: a wrong statement is refused as such, not fitted round.
        _check_found(result, apparent)
        radius, result.edge_residuals, rounded_pose = _measure_edge(fit, pose, size, K, c2w)
        if radius is not None:
            shape, fit = 'rounded', fit.with_outline(Outline('rounded', size, K, c2w, radius))
            pose = tuple(float(x) for x in rounded_pose)
            per_view, residual, apparent = _residuals(fit, pose, n)
            result = dataclasses.replace(result, pose=pose, residual=residual, view_residuals=per_view,
                                         edge_mm=radius)
    if not pose_given:
        _check_size(fit, pose, size, shape, TRUNCATION * apparent, result, measured_size)
    _check_found(result, apparent)
    return result


def _check_found(result: Registration, apparent: np.ndarray) -> None:
    """Refuse a place whose outline lies further from the silhouettes than :data:`FOUND_LIMIT`
    of the container's apparent size (median view)."""
    median = float(np.nanmedian(result.view_residuals))
    limit = max(2.0, FOUND_LIMIT * float(np.median(apparent)))
    if not median <= limit:
        x, y, yaw = result.pose
        err = ReneusError(f'container not found: at the best place x={x:.1f} mm, y={y:.1f} mm, '
                          f'yaw={yaw:.1f} deg its outline lies {median:.1f} px '
                          f'(median view) from what the photographs show; expected at most {limit:.1f} px '
                          '(check --size-mm and --container; see the overlays; or give --container-pose x,y,yaw)')
        err.measured, err.registration = result.measured, result
        raise err


def _residuals(fit: _Fit, pose, n: int) -> tuple[np.ndarray, float, np.ndarray]:
    """Per view (of ``n``; NaN where too little of the outline lies on the board) and over all
    views, the RMS outline distance at ``pose`` (outliers beyond :data:`TRUNCATION` of the
    apparent size left out), and each measured view's apparent size (pixels)."""
    d = fit.distances(pose, unknown=None)
    apparent = np.array([fit.outline.size(pose, v) for v in fit.views])
    known = np.isfinite(d)
    inlier = known & (np.abs(np.nan_to_num(d)) < TRUNCATION * apparent[:, None])
    per_view = np.full(n, np.nan)
    for j, v in enumerate(fit.views):
        if known[j].mean() >= MIN_KNOWN:
            per_view[v] = float(np.sqrt(np.mean(d[j][inlier[j]] ** 2))) if inlier[j].any() else np.inf
    residual = float(np.sqrt(np.mean(d[inlier] ** 2))) if inlier.any() else float('inf')
    return per_view, residual, apparent


def _best_size(fit: _Fit, pose, size, shape: str, clip) -> tuple[tuple, float, float]:
    """The outer size whose outline, at its own best place, fits the silhouettes best, its
    standard deviations (mm), and the mean clipped outline distance of the stated size and of
    that one (pixels)."""
    cylinder = shape == 'cylinder'

    def unpack(q):
        p = np.array([q[0], q[1], pose[2] if cylinder else q[2]])
        dims = q[2:] if cylinder else q[3:]
        return p, ((dims[0], dims[0], dims[1]) if cylinder else tuple(dims))
    q0 = np.array([*pose[:2], *(() if cylinder else (pose[2],)), *((size[0], size[2]) if cylinder else size)])

    def residuals(q):
        p, dims = unpack(q)
        return fit.distances(p, clip, size=dims).ravel()
    sol = optimize.least_squares(residuals, q0, loss='soft_l1', f_scale=1.0, diff_step=1e-3)
    _, dims = unpack(sol.x)
    # The deviations from the solve's Jacobian (robustly weighted): the residuals' variance
    # times (JᵀJ)⁻¹.
    dof = max(1, sol.jac.shape[0] - sol.jac.shape[1])
    cov = np.linalg.pinv(sol.jac.T @ sol.jac) * (2.0 * sol.cost / dof)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))[-(2 if cylinder else 3):]
    sd = (sd[0], sd[0], sd[1]) if cylinder else tuple(sd)

    def cost(q): return float(np.mean(np.abs(residuals(q))))
    return tuple(float(x) for x in dims), tuple(float(x) for x in sd), cost(q0), cost(sol.x)


def _check_size(fit: _Fit, pose, size, shape: str, clip, result: Registration, measured: bool) -> None:
    """Refuse a stated size that the photographs contradict: the size whose outline fits the
    silhouettes best lies more than :data:`SIZE_TOLERANCE_MM` from it along some axis (a
    ``measured`` size is that one: only its deviations are recorded)."""
    best, sd, stated_cost, best_cost = _best_size(fit, pose, size, shape, clip)
    result.best_size, result.size_std, result.size_residuals = best, sd, (stated_cost, best_cost)
    if not measured and np.abs(np.subtract(best, size)).max() > SIZE_TOLERANCE_MM:
        err = ReneusError(
            f"size_mm={'x'.join(f'{v:g}' for v in size)} and the photographs disagree: the outline fits them "
            f"best at {'x'.join(f'{v:.1f}' for v in best)} mm (mean outline distance {best_cost:.2f} px, "
            f"{stated_cost:.2f} px at the stated size); expected them within {SIZE_TOLERANCE_MM:g} mm: measure "
            'the container again (--size-mm; see the overlays)')
        err.measured, err.registration = result.measured, result
        raise err


def _search(fit: _Fit, measured, K, c2w, seen, shape: str, size, start) -> tuple:
    """The place of the outline of ``size`` that fits the silhouettes: from ``start`` (a place
    found before), or from the silhouettes' centroids and a coarse search over yaw."""
    outline, period = fit.outline, symmetry(shape, size)
    centre = _start(measured, K, c2w, seen, size) if start is None else start[:2]
    clip = TRUNCATION * np.array([outline.size((*centre, 0.0), v) for v in seen])
    if start is None:
        # Every point of the outline counts: a place where nothing is known is no better
        # than one where the outline misses.
        def cost(p): return float(np.mean(np.abs(fit.distances(p, clip, unknown='clip'))))
        yaws = np.arange(0.0, period, YAW_STEP) if period else np.array([0.0])
        starts = [(*centre, y) for _, y in sorted((cost((*centre, y)), y) for y in yaws)[:3]]
    else:
        starts = [tuple(start)]
    return min((_refine(fit, p0, clip, period) for p0 in starts), key=lambda r: r[0])[1]


def _measure_edge(fit: _Fit, pose, size, K, c2w) -> tuple[float | None, tuple[float, float], tuple]:
    """The radius of a block's edges that its silhouettes show (None: sharp, as stated), the
    mean outline distance of the sharp box and of the best radius, and the place that fits:
    each radius of :data:`EDGE_STEP_MM` steps at its own best place; rounded only where that
    brings the outline :data:`EDGE_GAIN` closer."""
    clip = TRUNCATION * np.array([fit.outline.size(pose, v) for v in fit.views])
    period = symmetry('box', size)
    sharp = float(np.mean(np.abs(fit.distances(pose, clip))))
    best = (sharp, None, pose)
    for radius in np.arange(EDGE_STEP_MM, EDGE_MAX_SHARE * min(size) + 1e-9, EDGE_STEP_MM):
        cost, place = _refine(fit.with_outline(Outline('rounded', size, K, c2w, float(radius))), pose, clip, period)
        best = min(best, (cost, float(radius), place), key=lambda b: b[0])
    if best[1] is None or not best[0] < (1.0 - EDGE_GAIN) * sharp:
        return None, (sharp, best[0]), pose
    return best[1], (sharp, best[0]), best[2]


def _measure_size(measured, trusted, K, c2w, seen, shape: str, start, edge) -> tuple[tuple, tuple]:
    """The outer size the silhouettes suggest (``--size-mm auto``), and the place it fits at:
    from a cube as wide as the silhouettes' median apparent width, :data:`SIZE_ROUNDS` rounds of
    a place for the size, then the size and the place together."""
    centre = _start(measured, K, c2w, seen, (1.0, 1.0, 1.0)) if start is None else start[:2]
    widths = [np.sqrt(measured[v].sum()) * np.linalg.norm(c2w[v, :3, 3] - [*centre, 0.0]) / K[0, 0] for v in seen]
    side = 0.8 * float(np.median(widths))
    size, pose = (side, side, 0.8 * side), start
    for _ in range(SIZE_ROUNDS):
        fit = _Fit(Outline(shape, size, K, c2w, edge), measured, trusted, seen)
        pose = _search(fit, measured, K, c2w, seen, shape, size, pose)
        clip = TRUNCATION * np.array([fit.outline.size(pose, v) for v in seen])
        size = _best_size(fit, pose, size, shape, clip)[0]
    return size, pose


def _check_place(board: Board, pose, per_view: np.ndarray, measured: np.ndarray, result: Registration) -> None:
    """Refuse a place off the board, or one that no photograph shows (a wrong size can fit
    best where nothing is known)."""
    width, depth = board.size_mm
    problem = None
    if not (0.0 <= pose[0] <= width and 0.0 <= pose[1] <= depth):
        problem = (f'placed at x={pose[0]:.1f} mm, y={pose[1]:.1f} mm, off the {width:g}x{depth:g} mm board; '
                   'expected it standing on the board')
    elif np.isnan(per_view).all():
        problem = (f'placed at x={pose[0]:.1f} mm, y={pose[1]:.1f} mm, where no photograph shows '
                   f'{MIN_KNOWN:.0%} of its outline on the board')
    if problem:
        err = ReneusError(f'container not found: {problem} (check --size-mm and --container; see the overlays; '
                          'or give --container-pose x,y,yaw)')
        err.measured, err.registration = measured, result
        raise err


def _refine(fit: _Fit, p0, clip, period: float):
    """Robust least squares of the outline distances from the place ``p0``: (cost, place)."""
    p0 = np.asarray(p0, np.float64)
    free = slice(0, 3 if period else 2)

    def place(q):
        p = p0.copy()
        p[free] = q
        return p

    sol = optimize.least_squares(lambda q: fit.distances(place(q), clip).ravel(), p0[free],
                                 loss='soft_l1', f_scale=1.0, diff_step=1e-3)
    p = place(sol.x)
    p[2] = _wrap(p[2], period)
    return float(np.mean(np.abs(fit.distances(p, clip)))), tuple(float(x) for x in p)


def _start(measured, K, c2w, views, size) -> tuple[float, float]:
    """The point nearest to the rays through the measured silhouettes' centroids, at half the
    container's height: a start for x, y."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for v in views:
        ys, xs = np.nonzero(measured[v])
        d = c2w[v, :3, :3] @ np.linalg.solve(K, [xs.mean() + 0.5, ys.mean() + 0.5, 1.0])
        d /= np.linalg.norm(d)
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c2w[v, :3, 3]
    # The point is constrained to the container's mid-height plane (z = -H/2).
    A2, b2 = A[:2, :2], b[:2] - A[:2, 2] * (-0.5 * size[2])
    x, y = np.linalg.solve(A2, b2)
    return float(x), float(y)
