"""The simulated capture the capture tests share: rendered once per session.

Mitsuba's path tracer renders a glass block (50x35x25 mm) with an insect inside standing on a
12x9 ChArUco board, 16 views at 640x480 on three elevations with four portrait shots, lens
distortion, an off-centre principal point, exposure jitter, noise and JPEG
(:mod:`reneus_mi.capture.simulate`). About 40 s on two cores.
"""
from __future__ import annotations

import json
import os

from reneus_mi.capture.simulate import Rig, simulate

#: The capture of the tests: the generator's defaults, fewer samples (the noise is the sensor's).
RIG = Rig(spp=16)


def capture(root) -> dict:
    """``{'photos', 'truth', 'meta'}`` of the capture under ``root`` (rendered if missing)."""
    photos, truth = os.path.join(root, 'photos'), os.path.join(root, 'truth')
    if not os.path.isfile(os.path.join(truth, 'truth.json')):
        simulate(RIG, photos, truth)
    with open(os.path.join(truth, 'truth.json')) as f:
        return {'photos': photos, 'truth': truth, 'meta': json.load(f)}
