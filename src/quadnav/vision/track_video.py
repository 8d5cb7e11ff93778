"""Tracked features drawn on their frame, coloured by track length as VINS-Mono's viewer does
(blue when new, turning red as a track reaches ``saturate_length`` frames), with a line back to
where each was in the previous frame. Images only: writing a video is :mod:`quadnav.io`'s job.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from quadnav.vision.tracking import TrackedFrame, as_grey

__all__ = ["draw_tracks", "length_colour"]

#: VINS' viewer: a track of this many frames is drawn fully red.
SATURATE_LENGTH = 20


def length_colour(length: int, saturate_length: int = SATURATE_LENGTH) -> tuple[int, int, int]:
    """BGR of a track ``length`` frames long: (255, 0, 0) blue at 1, (0, 0, 255) red from
    ``saturate_length`` on."""
    s = min(max(length - 1, 0) / max(saturate_length - 1, 1), 1.0)
    return (round(255 * (1.0 - s)), 0, round(255 * s))


def draw_tracks(
    image: object,
    frame: TrackedFrame,
    previous: TrackedFrame | None = None,
    *,
    saturate_length: int = SATURATE_LENGTH,
    radius_px: int = 2,
) -> NDArray[np.uint8]:
    """A BGR copy of ``image`` with ``frame``'s features as dots coloured by length and, when
    ``previous`` is given, a line from each tracked feature's position there."""
    out = cv2.cvtColor(as_grey(image), cv2.COLOR_GRAY2BGR)
    before: dict[int, tuple[int, int]] = {}
    if previous is not None:
        xy = np.rint(previous.pixels).astype(int).tolist()
        before = {int(i): (p[0], p[1]) for i, p in zip(previous.ids.tolist(), xy, strict=True)}
    xy = np.rint(frame.pixels).astype(int).tolist()
    for i, (x, y), n in zip(frame.ids.tolist(), xy, frame.track_lengths.tolist(), strict=True):
        colour = length_colour(int(n), saturate_length)
        if int(i) in before:
            cv2.line(out, before[int(i)], (x, y), (0, 255, 0), 1, cv2.LINE_AA)
        cv2.circle(out, (x, y), radius_px, colour, -1, cv2.LINE_AA)
    return np.asarray(out, np.uint8)
