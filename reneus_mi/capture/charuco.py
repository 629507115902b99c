"""The printed ChArUco board: its layout, its pattern, and finding it in a photograph.

The board's frame is OpenCV's (``cv2.aruco.CharucoBoard``): the origin at the outer corner
of the first square (the top-left corner of the pattern image), x along the columns, y
along the rows, z = x × y pointing into the table, in millimetres. The container standing
on the board therefore occupies z in [-height, 0], and the cameras have z < 0.

Pixel coordinates here follow reneus-mi (:mod:`reneus_mi.data.cameras`): the centre of the
top-left pixel is at (0.5, 0.5); OpenCV puts it at (0, 0), hence the half-pixel shifts.
"""
from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np
from PIL import Image

from reneus_mi.capture.settings import CaptureSettings
from reneus_mi.utils.errors import ReneusError
from reneus_mi.utils.io import atomic_path

#: OpenCV's predefined ArUco dictionaries, by name.
DICTIONARIES = {name: getattr(cv2.aruco, name) for name in dir(cv2.aruco)
                if name.startswith('DICT_') and name.upper() == name}
#: Fewest ChArUco corners a photograph needs to enter the calibration.
MIN_CORNERS = 8
#: A marker is where the board puts it if its corners lie within this fraction of a
#: marker's side from the homography fitted to all markers of the photograph.
LAYOUT_TOLERANCE = 0.25
#: Half-size of the corner refinement's window, as a share of a square's side in the image
#: (docs/constants.md).
REFINE_WINDOW = 0.15
#: Share of a photograph's markers that must fit the board's layout.
LAYOUT_INLIERS = 0.6
#: Longest side of the copy the markers are looked for in: a 24-megapixel photograph's
#: markers are hundreds of pixels wide, and finding them costs in proportion to the pixels.
#: The corners are refined in the photograph itself.
FIND_SIZE = 2000


@dataclasses.dataclass
class Detection:
    """What one photograph shows of the board."""
    #: (M,) ids of the ChArUco (chessboard) corners found.
    ids: np.ndarray
    #: (M,2) their positions, pixels (reneus-mi convention).
    pixels: np.ndarray
    #: (K,) ids of the ArUco markers found, (K,4,2) their corners (pixels, reneus-mi convention).
    marker_ids: np.ndarray
    marker_corners: np.ndarray


@dataclasses.dataclass(frozen=True)
class Board:
    """A ChArUco board: ``columns`` x ``rows`` squares of ``square_mm``, markers of ``marker_mm``."""
    columns: int
    rows: int
    square_mm: float
    marker_mm: float
    dictionary: str = 'DICT_4X4_100'
    #: OpenCV before 4.6 laid out boards with an even number of rows differently.
    legacy: bool = False

    @classmethod
    def from_settings(cls, s: CaptureSettings) -> 'Board':
        board = cls(*s.squares, s.square_mm, s.marker_mm, s.dictionary)
        board.check()
        return board

    def check(self) -> None:
        if self.dictionary not in DICTIONARIES:
            raise ReneusError(f"dictionary={self.dictionary!r}: expected an OpenCV ArUco dictionary "
                              f"such as DICT_4X4_100, DICT_5X5_250 (one of {len(DICTIONARIES)})")
        size = self.aruco_dictionary().bytesList.shape[0]
        if self.n_markers > size:
            raise ReneusError(f"squares={self.columns}x{self.rows} needs {self.n_markers} markers, but "
                              f"{self.dictionary} has {size}; expected a larger dictionary or fewer squares")

    @property
    def n_markers(self) -> int:
        return (self.columns * self.rows) // 2

    @property
    def size_mm(self) -> tuple[float, float]:
        """Extent of the pattern along x (columns) and y (rows)."""
        return self.columns * self.square_mm, self.rows * self.square_mm

    def describe(self) -> str:
        return (f"{self.columns}x{self.rows} squares of {self.square_mm:g} mm, markers of "
                f"{self.marker_mm:g} mm, {self.dictionary}")

    def aruco_dictionary(self):
        return cv2.aruco.getPredefinedDictionary(DICTIONARIES[self.dictionary])

    @functools.cached_property
    def cv(self) -> cv2.aruco.CharucoBoard:
        board = cv2.aruco.CharucoBoard((self.columns, self.rows), self.square_mm, self.marker_mm,
                                       self.aruco_dictionary())
        board.setLegacyPattern(self.legacy)
        return board

    @functools.cached_property
    def corners(self) -> np.ndarray:
        """(N,3) positions of the chessboard corners by id, millimetres (z = 0)."""
        return np.asarray(self.cv.getChessboardCorners(), np.float64).reshape(-1, 3)

    @functools.cached_property
    def marker_points(self) -> np.ndarray:
        """(n_markers,4,2) board positions of each marker's corners, by marker id."""
        points = np.asarray(self.cv.getObjPoints(), np.float64)[..., :2]
        order = np.argsort(np.asarray(self.cv.getIds()).ravel())
        return points[order]

    def pattern(self, px_per_mm: float) -> np.ndarray:
        """The printed pattern, uint8 (rows x columns of squares at ``px_per_mm``), 0 black.

        Pixel (i, j) covers the board's x in [j, j+1] / px_per_mm, y in [i, i+1] / px_per_mm.
        """
        width, height = (int(round(s * px_per_mm)) for s in self.size_mm)
        return self.cv.generateImage((width, height), marginSize=0, borderBits=1)

    def detect(self, gray: np.ndarray) -> Detection:
        """The markers and ChArUco corners in an 8-bit grey photograph: the markers in a copy
        of at most :data:`FIND_SIZE` pixels, the corners at full size."""
        scale = min(1.0, FIND_SIZE / max(gray.shape))
        find = gray if scale == 1.0 else cv2.resize(gray, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        markers = cv2.aruco.ArucoDetector(self.aruco_dictionary(), params)
        marker_corners, marker_ids, _ = markers.detectMarkers(find)
        empty = Detection(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0, int), np.zeros((0, 4, 2)))
        if marker_ids is None or len(marker_ids) == 0:
            return empty
        marker_ids = np.asarray(marker_ids).ravel()
        corners_m = (np.asarray(marker_corners, np.float64).reshape(-1, 4, 2) + 0.5) / scale
        marker_corners = (corners_m - 0.5).astype(np.float32)
        on_board = marker_ids < self.n_markers
        result = Detection(empty.ids, empty.pixels, marker_ids, corners_m)
        if not on_board.any():
            return result
        detector = cv2.aruco.CharucoDetector(self.cv)
        kept = tuple(np.asarray(marker_corners)[on_board].astype(np.float32).reshape(-1, 1, 4, 2))
        corners, ids, _, _ = detector.detectBoard(gray, markerCorners=kept,
                                                  markerIds=marker_ids[on_board].reshape(-1, 1).astype(np.int32))
        if ids is not None and len(ids):
            result.ids = np.asarray(ids).ravel().astype(int)
            result.pixels = self._refine(gray, np.asarray(corners, np.float64).reshape(-1, 2), corners_m)
        return result

    def _refine(self, gray: np.ndarray, corners: np.ndarray, markers: np.ndarray) -> np.ndarray:
        """The corners refined to the saddle of their four squares (reneus-mi convention).

        OpenCV 4.11's ChArUco corners lie half a pixel off (measured on a blurred pattern and
        its mirror image); ``cv2.cornerSubPix`` itself is unbiased. Its window spans
        :data:`REFINE_WINDOW` of a square as the photograph shows it.
        """
        side = np.median(np.linalg.norm(np.diff(markers, axis=1, append=markers[:, :1]), axis=-1))
        half = int(max(2, round(REFINE_WINDOW * side * self.square_mm / self.marker_mm)))
        criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
        refined = cv2.cornerSubPix(gray, corners.astype(np.float32).reshape(-1, 1, 2), (half, half),
                                   (-1, -1), criteria)
        return refined.reshape(-1, 2).astype(np.float64) + 0.5

    def layout_fit(self, det: Detection) -> float:
        """Share of the photograph's markers that lie where this board's layout puts them
        (one homography from the board to the image, RANSAC); 1 with fewer than 4 markers."""
        keep = det.marker_ids < self.n_markers
        if keep.sum() < 4:
            return 1.0
        board = self.marker_points[det.marker_ids[keep]].reshape(-1, 2)
        image = det.marker_corners[keep].reshape(-1, 2)
        side = np.median(np.linalg.norm(np.diff(det.marker_corners[keep], axis=1), axis=-1))
        H, inliers = cv2.findHomography(board, image, cv2.RANSAC, LAYOUT_TOLERANCE * side)
        if H is None:
            return 0.0
        # A marker fits when its four corners do.
        return float(np.mean(inliers.reshape(-1, 4).all(axis=1)))


def other_dictionary(gray: np.ndarray, board: Board) -> str | None:
    """The predefined dictionary whose markers a photograph shows most of (None if none):
    what to suggest when the stated one finds nothing."""
    best, found = None, 0
    detector_params = cv2.aruco.DetectorParameters()
    for name, code in DICTIONARIES.items():
        if name == board.dictionary:
            continue
        detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(code), detector_params)
        _, ids, _ = detector.detectMarkers(gray)
        n = 0 if ids is None else len(ids)
        if n > found:
            best, found = name, n
    return best if found >= 4 else None


def write_print(board: Board, path: str, dpi: float = 600.0) -> tuple[int, int]:
    """The board as a file to print at 100 % (a white margin of up to 10 mm, the density in
    the PNG so that printers keep the size); returns its size in pixels."""
    px_per_mm = dpi / 25.4
    pattern = board.pattern(px_per_mm)
    margin = int(round(min(board.square_mm, 10.0) * px_per_mm))
    sheet = np.pad(pattern, margin, constant_values=255)
    with atomic_path(path) as tmp:
        Image.fromarray(sheet).save(tmp, format='PNG', dpi=(dpi, dpi))
    return sheet.shape[1], sheet.shape[0]
