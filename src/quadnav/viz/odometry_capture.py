"""What a visual odometry run's camera showed, captured as it runs for its recording: an
observer of the odometry runner (:class:`~quadnav.experiments.odometry_run.OdometryObserver`,
which it satisfies without importing it) that writes ``viz.npz`` into the run folder
(:mod:`quadnav.io.odometry_run_files`).

Bounded whatever the run's length: at most ``MAX_IMAGES`` images (every n-th frame, n from the
frames to come), each downsampled by a whole factor to at most ``MAX_IMAGE_WIDTH`` pixels wide
and JPEG-encoded; at most ``MAX_LANDMARKS`` landmarks (those past it are counted, not kept). The
per-state counts and covariances (88 bytes a state) are what grows with the run.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav.io.odometry_run_files import VIZ_CAPTURE, VizCapture, write_viz_capture
from quadnav.odometry import FrameFeatures, KeyframeRecord, OdometryState
from quadnav.rig import Rig
from quadnav.viz.recording import JPEG_QUALITY, MAX_IMAGE_WIDTH, MAX_IMAGES, jpeg_of, small_size

__all__ = ["JPEG_QUALITY", "MAX_IMAGES", "MAX_IMAGE_WIDTH", "MAX_LANDMARKS", "OdometryCapture"]

#: Landmarks kept (the first this many seen).
MAX_LANDMARKS = 100_000


class OdometryCapture:
    """Collects a run's images, features, covariances and landmarks (see the module); writes
    them to ``RUN_DIR/viz.npz`` when the run finishes."""

    def __init__(self, *, max_images: int = MAX_IMAGES, max_width: int = MAX_IMAGE_WIDTH) -> None:
        self.max_images, self.max_width = max_images, max_width
        self.camera = ""
        self.every, self.scale, self.size = 1, 1, (0, 0)
        self.K = np.zeros(4)
        self.T_B_C = np.eye(4)
        self._k = 0
        self._lengths: dict[int, int] = {}
        self._images: list[bytes] = []
        self._image_t: list[int] = []
        self._features: list[tuple[int, NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]]
        self._features = []
        self._frame_t: list[int] = []
        self._state_t: list[int] = []
        self._tracked: list[int] = []
        self._cov: list[NDArray[np.float64]] = []
        self._landmarks: dict[int, tuple[int, NDArray[np.float64]]] = {}
        self.landmarks_dropped = 0
        self.path: Path | None = None

    def begin(self, rig: Rig, camera: str, n_frames: int) -> None:
        cam = rig.camera(camera)
        self.camera = camera
        self.every = max(1, math.ceil(n_frames / max(self.max_images, 1)))
        m = cam.camera
        self.scale, self.size = small_size(m.width, m.height, self.max_width)
        self.K = np.array([m.fx, m.fy, m.K[0, 2], m.K[1, 2]], dtype=np.float64) / self.scale
        self.T_B_C = cam.T_B_C.matrix()

    def frame(self, t_ns: int, image: NDArray[np.uint8], features: FrameFeatures | None) -> None:
        k, self._k = self._k, self._k + 1
        ids = np.zeros(0, np.int64) if features is None else np.asarray(features.ids, np.int64)
        lengths = np.array([self._lengths.get(int(i), 0) + 1 for i in ids], dtype=np.int64)
        self._lengths = dict(zip(ids.tolist(), lengths.tolist(), strict=True))
        self._frame_t.append(int(t_ns))
        if k % self.every:
            return
        if features is not None:
            uv = np.asarray(features.uv_px, np.float64) / self.scale
            self._features.append((len(self._images), ids, uv, lengths))
        self._images.append(jpeg_of(image, self.size))
        self._image_t.append(int(t_ns))

    def state(self, state: OdometryState) -> None:
        self._state_t.append(int(state.t_ns))
        self._tracked.append(int(state.tracked))
        self._cov.append(_position_cov_W(state))

    def keyframes(self, records: Sequence[KeyframeRecord]) -> None:
        for r in records:
            for i, X in zip(r.landmark_ids.tolist(), r.landmarks_W, strict=True):
                seen = self._landmarks.get(i)
                if seen is not None:
                    self._landmarks[i] = (seen[0], X)
                elif len(self._landmarks) < MAX_LANDMARKS:
                    self._landmarks[i] = (r.t_ns, X)
                else:
                    self.landmarks_dropped += 1

    def capture(self) -> VizCapture:
        """What was captured so far."""
        f = self._features
        lm = sorted(self._landmarks.items(), key=lambda kv: (kv[1][0], kv[0]))
        offsets = np.cumsum([0, *[len(b) for b in self._images]], dtype=np.int64)
        return VizCapture(
            camera=self.camera, image_every=self.every, image_scale=self.scale,
            width=self.size[0], height=self.size[1], K=self.K, T_B_C=self.T_B_C,
            image_t_ns=np.array(self._image_t, np.int64),
            jpeg=np.frombuffer(b"".join(self._images), np.uint8), jpeg_offsets=offsets,
            feature_image=_join([np.full(len(x[1]), x[0], np.int64) for x in f], (0,), np.int64),
            feature_ids=_join([x[1] for x in f], (0,), np.int64),
            feature_uv=_join([x[2] for x in f], (0, 2), np.float64),
            feature_length=_join([x[3] for x in f], (0,), np.int64),
            frame_t_ns=np.array(self._frame_t, np.int64),
            state_t_ns=np.array(self._state_t, np.int64),
            state_tracked=np.array(self._tracked, np.int64),
            state_cov_p_W=np.array(self._cov).reshape(-1, 3, 3),
            landmark_ids=np.array([i for i, _ in lm], np.int64),
            landmark_t_ns=np.array([v[0] for _, v in lm], np.int64),
            landmark_W=np.array([v[1] for _, v in lm], np.float64).reshape(-1, 3),
            landmarks_dropped=self.landmarks_dropped,
        )  # fmt: skip

    def finish(self, run_dir: Path) -> None:
        self.path = Path(run_dir) / VIZ_CAPTURE
        write_viz_capture(self.path, self.capture())


def _join(parts: list[NDArray[Any]], empty: tuple[int, ...], dtype: type) -> NDArray[Any]:
    return np.concatenate(parts).astype(dtype) if parts else np.zeros(empty, dtype)


def _position_cov_W(state: OdometryState) -> NDArray[np.float64]:
    """The state's position covariance in the world (its pose covariance is the body's, rotation
    first)."""
    R = state.T_W_B.R_A_B.as_matrix()
    C = np.asarray(state.cov_pose, np.float64)[3:, 3:]
    return np.asarray(R @ C @ R.T, dtype=np.float64)


def capture_if(rerun: bool) -> OdometryCapture | None:
    """An observer capturing what a run's camera shows when it is recorded, else None."""
    return OdometryCapture() if rerun else None
