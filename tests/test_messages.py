from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quadnav.errors import SampleError
from quadnav.messages import HeightSample, ImuSample, PoseSample, PositionSample, VehicleState


def test_imu_sample_is_validated_and_immutable() -> None:
    s = ImuSample(t_ns=10, gyro_rad_s=[0.0, 0.1, 0.0], accel_m_s2=[0.0, 0.0, 9.8])
    assert s.gyro_rad_s.dtype == np.float64
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.t_ns = 11  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        s.accel_m_s2[0] = 1.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"t_ns": 1.5}, "integer"),
        ({"t_ns": True}, "integer"),
        ({"t_ns": "5"}, "integer"),
        ({"gyro_rad_s": [0.0, np.nan, 0.0]}, "non-finite"),
        ({"accel_m_s2": [0.0, 0.0]}, "shape"),
        ({"accel_m_s2": ["a", 0, 0]}, "numeric"),
    ],
)
def test_bad_imu_samples_are_refused(kwargs: dict[str, object], message: str) -> None:
    args: dict[str, object] = {"t_ns": 0, "gyro_rad_s": [0, 0, 0], "accel_m_s2": [0, 0, 0]}
    args.update(kwargs)
    with pytest.raises(SampleError, match=message):
        ImuSample(**args)  # type: ignore[arg-type]


def test_numpy_integer_timestamps_become_int() -> None:
    s = PositionSample(t_ns=np.int64(7), p_W_B=[1, 2, 3], sigma_m=0.1)
    assert type(s.t_ns) is int and s.t_ns == 7


@pytest.mark.parametrize("sigma", [0.0, -1.0, float("nan"), float("inf")])
def test_position_sample_needs_a_positive_sigma(sigma: float) -> None:
    with pytest.raises(SampleError, match="sigma_m"):
        PositionSample(t_ns=0, p_W_B=[0, 0, 0], sigma_m=sigma)


def test_vehicle_state_needs_a_unit_quaternion() -> None:
    with pytest.raises(SampleError, match="unit quaternion"):
        VehicleState(
            t_ns=0,
            p_W_B=[0, 0, 0],
            v_W_B=[0, 0, 0],
            a_W_B=[0, 0, 0],
            q_W_B_xyzw=[0, 0, 0, 2],
            w_B=[0, 0, 0],
        )


def test_an_image_frame_loads_lazily_and_says_which_file_is_bad() -> None:
    import numpy as np
    import pytest

    from quadnav.errors import SampleError
    from quadnav.messages import ImageFrame

    calls: list[int] = []

    def load() -> np.ndarray:
        calls.append(1)
        return np.zeros((4, 5), np.uint8)

    f = ImageFrame(t_ns=10, camera="cam0", load=load, origin="cam0/data/10.png")
    assert calls == []  # nothing read until asked
    assert f.image().shape == (4, 5)
    assert calls == [1]

    def broken() -> np.ndarray:
        raise OSError("truncated PNG")

    bad = ImageFrame(t_ns=10, camera="cam0", load=broken, origin="cam0/data/10.png")
    with pytest.raises(SampleError, match=r"cam0/data/10.png cannot be read: truncated PNG"):
        bad.image()
    none = ImageFrame(t_ns=10, camera="cam0", load=lambda: None, origin="x.png")  # type: ignore[arg-type,return-value]
    with pytest.raises(SampleError, match="not an 8-bit picture"):
        none.image()
    with pytest.raises(SampleError, match="exposure_s"):
        ImageFrame(t_ns=10, camera="cam0", load=load, exposure_s=float("nan"))


def test_the_simulators_unchecked_samples_are_the_checked_ones() -> None:
    """A simulated vision pose and barometer height made without the checks are the samples
    the constructor makes of the same values (read-only arrays, the defaults)."""
    p, q = np.array([0.1, -2.0, 1.5]), np.array([0.0, 0.0, 0.6, 0.8])
    fast = PoseSample.from_checked(5, p.copy(), q.copy(), 0.02, 0.05)
    slow = PoseSample(t_ns=5, p_W_B=p, q_W_B_xyzw=q, sigma_pos_m=0.02, sigma_yaw_rad=0.05)
    for name in ("t_ns", "sigma_pos_m", "sigma_yaw_rad", "reset_counter", "source", "cov_p_m2"):
        assert getattr(fast, name) == getattr(slow, name), name
    for arr, want in ((fast.p_W_B, p), (fast.q_W_B_xyzw, q)):
        np.testing.assert_array_equal(arr, want)
        assert not arr.flags.writeable
    assert HeightSample.from_checked(7, 1.25, 0.1) == HeightSample(t_ns=7, z_m=1.25, sigma_m=0.1)
