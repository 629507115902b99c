"""From a museum's photographs to a dataset: the paper's ChArUco capture (Sec. 4, "Real Dataset").

The specimen in its glass container stands on a printed ChArUco board; photographs are taken
from a hemisphere. The board gives the camera's intrinsics and distortion and every view's
pose (:mod:`~reneus_mi.capture.calibrate`); the container of measured size is found standing
on it (:mod:`~reneus_mi.capture.register`); the photographs are undistorted to pinhole
cameras (:mod:`~reneus_mi.data.undistort`), their exposures normalised and the ambient
light measured (:mod:`~reneus_mi.capture.exposure`). Everything is in the board's frame, in
millimetres. ``python -m reneus_mi.capture PHOTOS -o DATASET`` (:mod:`reneus_mi.capture.__main__`);
:mod:`~reneus_mi.capture.simulation` renders captures to test it; :mod:`~reneus_mi.capture.colmap_model`
reads poses from a COLMAP model instead.
"""
