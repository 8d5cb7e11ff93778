"""The stereo front end of the VIO: a rig that cannot make a pair is one line naming --stereo;
on a rendered stereo sequence (EuRoC's rig) the left corners are found in the right image where
the VIO's own (monocular) landmarks say they are; a right frame missing, late or first is
handled, the left frame then used as mono and counted."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest

from quadnav.errors import VioError
from quadnav.geometry.multiview import triangulate
from quadnav.io.datasets import VisualInertialDataset
from quadnav.messages import ImageFrame, ImuSample
from quadnav.odometry import TRACKING_EVENTS, FrameFeatures, OdometryState
from quadnav.rig import rig_named
from quadnav.vio import VioConfig, VioEstimator
from quadnav.vio.stereo import partner_camera
from tests.vio.rendered import rendered

Sample = ImuSample | ImageFrame


@pytest.fixture(scope="module")
def stereo_ds(tmp_path_factory: pytest.TempPathFactory) -> VisualInertialDataset:
    return rendered(tmp_path_factory, "room_easy", duration_s=5.0, still_s=1.0, rig="euroc", seed=5)


@dataclass
class _Out:
    vio: VioEstimator
    states: list[OdometryState]
    stereo_share: list[float]  # at keyframes (the only frames matched in the right image)
    last_keyframe: tuple[OdometryState, FrameFeatures] | None = None


def _run(stream: Iterator[Sample], ds: VisualInertialDataset) -> _Out:
    vio = VioEstimator(ds.rig, VioConfig(stereo=True))
    out = _Out(vio=vio, states=[], stereo_share=[])
    for s in stream:
        st = vio.push(s)
        if st is not None and st.status == "tracking":
            out.states.append(st)
            f = vio.last_features
            if st.keyframe and f is not None and len(f.ids):
                out.stereo_share.append(len(f.stereo_ids) / len(f.ids))
                out.last_keyframe = (st, f)
    return out


def test_a_rig_that_cannot_pair_is_one_line_naming_stereo() -> None:
    with pytest.raises(VioError, match="--stereo: rig 'euroc_mono' has one camera"):
        VioEstimator(rig_named("euroc_mono"), VioConfig(stereo=True))
    rig = rig_named("euroc")
    same = dataclasses.replace(rig.cameras[1], T_B_C=rig.cameras[0].T_B_C)
    with pytest.raises(VioError, match=r"--stereo: cam0 and cam1.*no baseline"):
        partner_camera(dataclasses.replace(rig, cameras=(rig.cameras[0], same)), "cam0")


def test_the_right_cameras_points_agree_with_the_mono_landmarks(
    stereo_ds: VisualInertialDataset,
) -> None:
    out = _run(stereo_ds.stream(), stereo_ds)
    assert out.vio.rejected.get("stereo_unpaired", 0) == 0
    assert out.vio.cameras == ("cam0", "cam1")
    assert np.median(out.stereo_share) > 0.6, "most corners are found in the right image"
    # the stereo depth of a keyframe's corners against the window's landmarks (made from
    # the left camera's views over time): the same points
    rig = stereo_ds.rig
    T_B_L, T_B_R = rig.camera("cam0").T_B_C, rig.camera("cam1").T_B_C
    ratios = []
    assert out.last_keyframe is not None
    st, f = out.last_keyframe
    T_W_B = st.T_W_B
    P = np.array([(T_W_B @ T).inverse().matrix()[:3] for T in (T_B_L, T_B_R)])
    at = {int(j): k for k, j in enumerate(f.ids)}
    for j, xy_r in zip(f.stereo_ids.tolist(), f.stereo_xy, strict=True):
        p_lm = out.vio.window.landmark_position(int(j))
        if p_lm is None:
            continue
        _, z = triangulate(np.array([[f.xy[at[j]], xy_r]]), P)
        z_lm = ((T_W_B @ T_B_L).inverse() @ p_lm[None])[0, 2]
        ratios.append(z[0, 0] / z_lm)
    assert len(ratios) >= 20
    assert abs(float(np.median(ratios)) - 1.0) < 0.05


def test_missing_late_and_early_partners(stereo_ds: VisualInertialDataset) -> None:
    items = list(stereo_ds.stream())
    rights = [k for k, s in enumerate(items) if isinstance(s, ImageFrame) and s.camera == "cam1"]
    dropped = set(rights[5::4])
    # a missing right frame: its left goes on as mono, counted once
    missing = _run(iter([s for k, s in enumerate(items) if k not in dropped]), stereo_ds)
    assert missing.vio.rejected.get("stereo_unpaired") == len(dropped)
    # every right frame before its left (the other order of a stream): all paired
    swapped = list(items)
    for k in rights:
        if isinstance(swapped[k - 1], ImageFrame):
            swapped[k - 1], swapped[k] = swapped[k], swapped[k - 1]
    early = _run(iter(swapped), stereo_ds)
    assert early.vio.rejected.get("stereo_unpaired", 0) == 0
    full = _run(stereo_ds.stream(), stereo_ds)
    # every left frame gives its state either way (a late one when the stream moves past it)
    assert len(missing.states) == len(full.states) == len(early.states)


@pytest.fixture(scope="module")
def moving_ds(tmp_path_factory: pytest.TempPathFactory) -> VisualInertialDataset:
    """A start in motion (no still period): the monocular start waits for a window of parallax."""
    return rendered(
        tmp_path_factory, "room_medium", duration_s=4.0, still_s=0.0, rig="euroc", seed=4
    )


def _track(
    ds: VisualInertialDataset, *, stereo: bool, early_ns: int = 0
) -> tuple[VioEstimator, float, float]:
    """The VIO over ``ds`` (cam1 too when ``stereo``): itself, when its first estimate came (s
    after the first image) and its ATE after the 4-DoF alignment. ``early_ns``: the cameras
    stamp their images that much early, and their calibration says so (``time_offset_ns``)."""
    from quadnav.eval.align import align
    from quadnav.eval.associate import associate
    from quadnav.geometry.trajectory import Trajectory

    rig = ds.rig
    if early_ns:
        cams = tuple(dataclasses.replace(c, time_offset_ns=early_ns) for c in rig.cameras)
        rig = dataclasses.replace(rig, cameras=cams)
    vio = VioEstimator(rig, VioConfig(stereo=stereo))
    states = []
    stream = ds.stream()
    if early_ns:  # in the order of the stamps, as a recording keeps them
        moved = (
            dataclasses.replace(s, t_ns=s.t_ns - early_ns) if isinstance(s, ImageFrame) else s
            for s in stream
        )
        stream = iter(sorted(moved, key=lambda s: s.t_ns))
    for s in stream:
        if isinstance(s, ImageFrame) and s.camera == "cam1" and not stereo:
            continue
        st = vio.push(s)
        if st is not None and st.status == "tracking":
            states.append(st)
    assert [e.kind for e in vio.events if e.kind in TRACKING_EVENTS] == ["initialized"], vio.events
    est = Trajectory(
        t_ns=np.array([s.t_ns for s in states]),
        p_W_B=np.array([s.T_W_B.p_A_B for s in states]),
        q_W_B_xyzw=np.array([s.T_W_B.R_A_B.as_quat() for s in states]),
    )
    assert ds.groundtruth is not None
    ref, e = associate(ds.groundtruth.trajectory, est, t_max_diff_s=0.01)
    aligned, _ = align(ref, e, "4dof")
    ate = float(np.sqrt(np.mean(np.linalg.norm(aligned.p_W_B - ref.p_W_B, axis=1) ** 2)))
    return vio, (states[0].t_ns - ds.frames_of("cam0")[0].t_ns) * 1e-9, ate


@pytest.mark.parametrize("stereo", [pytest.param(False, marks=pytest.mark.slow), True])
def test_a_camera_stamped_early_by_more_than_an_imu_period_still_starts_in_motion(
    moving_ds: VisualInertialDataset, stereo: bool
) -> None:
    """A camera whose images are stamped 12 ms before the IMU's clock says they were taken,
    as its calibration states (Kalibr's timeshift_cam_imu): its frames, moved to the IMU's
    clock, lie past the newest IMU sample when they arrive. The start in motion
    preintegrated without letting the last sample hold, so such a rig never started (found on
    realistic corridor1 with an offset of 6 ms)."""
    vio, after_s, ate = _track(moving_ds, stereo=stereo, early_ns=12_000_000)
    start = next(e for e in vio.events if e.kind in TRACKING_EVENTS)
    assert start.detail.startswith("visual"), vio.events
    assert after_s < 2.0 and ate < 0.05, (after_s, ate)


def test_a_stereo_start_in_motion_is_metric_and_early(moving_ds: VisualInertialDataset) -> None:
    _, mono_after_s, _ = _track(moving_ds, stereo=False)
    vio, after_s, ate = _track(moving_ds, stereo=True)
    started = [e for e in vio.events if e.kind == "initialized"]
    assert started[0].detail == "visual, stereo"
    assert ate < 0.05  # metric from the start: no scale error
    assert after_s < 0.8 and after_s < mono_after_s, (after_s, mono_after_s)


@pytest.mark.slow  # 3 renders and 6 runs: about 2 minutes of one core
def test_stereo_factors_beat_mono_over_seeds(tmp_path_factory: pytest.TempPathFactory) -> None:
    """The right camera's observations in the window: over three seeds of a moving start in the
    room (8 s), the stereo VIO's ATE is well under the monocular one's (measured 0.009 against
    0.017 m on a 15 s sequence)."""
    mono, stereo = [], []
    for seed in (11, 12, 13):
        ds = rendered(
            tmp_path_factory, "room_medium", duration_s=8.0, still_s=0.0, rig="euroc", seed=seed
        )
        mono.append(_track(ds, stereo=False)[2])
        stereo.append(_track(ds, stereo=True)[2])
    assert np.mean(stereo) < 0.8 * np.mean(mono), (mono, stereo)
    assert max(stereo) < 0.05
