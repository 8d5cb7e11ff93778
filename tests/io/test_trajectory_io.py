from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from quadnav.errors import IoError
from quadnav.geometry import Trajectory
from quadnav.io import guess_format, read_trajectory, write_euroc, write_kitti, write_tum


def random_traj(
    rng: np.random.Generator, n: int = 50, *, t0_ns: int = 1_403_636_579_763_555_527
) -> Trajectory:
    t = t0_ns + np.cumsum(rng.integers(1, 50_000_000, n))
    return Trajectory(
        t_ns=t,
        p_W_B=rng.normal(0, 10, (n, 3)),
        q_W_B_xyzw=Rotation.random(n, random_state=1).as_quat(),
        name="r",
    )


def same(a: Trajectory, b: Trajectory, *, times: bool = True) -> None:
    if times:
        np.testing.assert_array_equal(a.t_ns, b.t_ns)
    np.testing.assert_allclose(a.p_W_B, b.p_W_B, rtol=1e-8, atol=1e-8)
    # q and -q are the same rotation
    dots = np.abs(np.sum(a.q_W_B_xyzw * b.q_W_B_xyzw, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-8)


@pytest.mark.parametrize(("writer", "fmt"), [(write_tum, "tum"), (write_euroc, "euroc")])
def test_timed_formats_round_trip_with_exact_nanoseconds(tmp_path: Path, writer, fmt: str) -> None:
    tr = random_traj(np.random.default_rng(0))
    path = tmp_path / f"t.{'csv' if fmt == 'euroc' else 'txt'}"
    writer(path, tr)
    assert guess_format(path) == fmt
    same(read_trajectory(path), tr)


def test_kitti_round_trip(tmp_path: Path) -> None:
    tr = random_traj(np.random.default_rng(1))
    write_kitti(tmp_path / "k.txt", tr)
    back = read_trajectory(tmp_path / "k.txt")
    assert not back.timed and list(back.t_ns) == list(range(len(tr)))
    same(back, tr, times=False)


def test_euroc_ground_truth_with_extra_columns(tmp_path: Path) -> None:
    f = tmp_path / "data.csv"
    f.write_text(
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1]\n"
        "1403636579758555392,4.688319,-1.786938,0.783338,0.534108,-0.153029,-0.827383,-0.082152,-0.027876\n"
        "1403636579763555584,4.688177,-1.786770,0.787350,0.534640,-0.152990,-0.826976,-0.082863,-0.029044\n"
    )
    tr = read_trajectory(f)
    assert tr.t_ns[0] == 1403636579758555392
    # w-first in the file, x-y-z-w inside
    np.testing.assert_allclose(
        tr.q_W_B_xyzw[0] * np.sign(tr.q_W_B_xyzw[0, 3]),
        np.array([-0.153029, -0.827383, -0.082152, 0.534108]) / 1.0,
        atol=1e-5,
    )


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0\n", ":2: expected 8 values, got 6"),  # truncated
        ("1.0 0 0 0 0 0 0 1\n2.0 nan 0 0 0 0 0 1\n", ":2: non-finite"),
        ("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 x 0 0 0 0 1\n", ":3: not a number: 'x'"),
        ("2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", "increase"),
        ("", "no poses"),
        ("1 2 3\n", "cannot tell the trajectory format"),
    ],
)
def test_malformed_files_are_one_line_errors_with_line_numbers(
    tmp_path: Path, content: str, message: str
) -> None:
    f = tmp_path / "bad.txt"
    f.write_text(content)
    with pytest.raises(IoError) as info:
        read_trajectory(f, None if "format" in message else "tum")
    assert message in str(info.value)
    assert str(f) in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_and_binary_files(tmp_path: Path) -> None:
    with pytest.raises(IoError, match="not found"):
        read_trajectory(tmp_path / "nope.txt")
    b = tmp_path / "b.txt"
    b.write_bytes(bytes(range(256)))
    with pytest.raises(IoError, match="not a text file"):
        read_trajectory(b, "tum")
    with pytest.raises(IoError, match="unknown trajectory format"):
        read_trajectory(b, "xyz")


def test_quadnav_planar_csv(tmp_path: Path) -> None:
    f = tmp_path / "delayed.csv"
    f.write_text(
        "t_ns,t_now_ns,x_m,z_m,vx_m_s,vz_m_s,theta_rad,var_x,var_z\n10,20,1.0,2.0,0,0,0.5,0.01,0.04\n20,30,1.5,2.5,0,0,0.5,0.01,0.04\n"
    )
    assert guess_format(f) == "quadnav"
    tr = read_trajectory(f)
    np.testing.assert_allclose(tr.p_W_B[0], [1.0, 0.0, 2.0])
    np.testing.assert_allclose(tr.R_W_B[0].as_rotvec(), [0.0, 0.5, 0.0], atol=1e-12)
    np.testing.assert_allclose(np.diagonal(tr.cov_p[1]), [0.01, 0.0, 0.04])


@given(st.text(max_size=300))
@settings(max_examples=150, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_garbage_never_crashes_a_reader(tmp_path: Path, text: str) -> None:
    f = tmp_path / "g.txt"
    f.write_text(text, encoding="utf-8")
    for fmt in (None, "tum", "euroc", "kitti", "quadnav"):
        try:
            tr = read_trajectory(f, fmt)
        except IoError as exc:
            assert "\n" not in str(exc)
        else:
            assert np.isfinite(tr.p_W_B).all() and len(tr) > 0


def test_tum_lines_carry_exact_seconds(tmp_path: Path) -> None:
    tr = Trajectory(
        t_ns=np.array([1_500_000_001, 2_000_000_000]),
        p_W_B=np.ones((2, 3)),
        q_W_B_xyzw=np.tile([0, 0, 0, 1.0], (2, 1)),
    )
    write_tum(tmp_path / "t.tum", tr)
    lines = (tmp_path / "t.tum").read_text().splitlines()
    assert lines[0] == "1.500000001 1 1 1 0 0 0 1"
    assert len(lines[1].split()) == 8


@given(st.integers(0, 10**11), st.text(alphabet="0123456789", max_size=14))
def test_timestamp_parsing_is_exact_decimal_rounding(whole: int, frac: str) -> None:
    from decimal import Decimal

    from quadnav.io.trajectory_io import _seconds_to_ns

    token = f"{whole}.{frac}" if frac else str(whole)
    assert _seconds_to_ns(token, "t") == int((Decimal(token) * 1_000_000_000).to_integral_value())


def test_tum_repeated_timestamps_keep_the_first_pose(tmp_path: Path) -> None:
    f = tmp_path / "dup.txt"
    f.write_text(
        "# t x y z qx qy qz qw\n1.0 0 0 0 0 0 0 1\n1.0 5 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n"
        "2.0 9 0 0 0 0 0 1\n2.0 9 9 0 0 0 0 1\n3.0 2 0 0 0 0 0 1\n"
    )
    tr = read_trajectory(f)
    assert list(tr.t_ns) == [1_000_000_000, 2_000_000_000, 3_000_000_000]
    np.testing.assert_array_equal(tr.p_W_B[:, 0], [0.0, 1.0, 2.0])  # the first of each
    assert tr.meta["repeated_timestamps"] == "3"
    assert "dup.txt: 3 pose(s) repeat" in tr.meta["note"] and "line 3" in tr.meta["note"]


@pytest.mark.slow  # 180,000 rows under tracemalloc
def test_a_long_tum_is_written_a_block_at_a_time(tmp_path: Path) -> None:
    """180,000 rows (30 minutes at 200 Hz): the writing's peak traced memory stays under 10 MB
    above the trajectory's arrays (it was 98 MB as one string), and the file is every row,
    identical to the short file's rows where they overlap."""
    import tracemalloc

    n = 180_000
    rng = np.random.default_rng(1)
    q = rng.normal(size=(n, 4))
    traj = Trajectory(
        t_ns=np.arange(n, dtype=np.int64) * 5_000_000 + 1_403_715_273_262_142_976,
        p_W_B=rng.normal(size=(n, 3)),
        q_W_B_xyzw=q / np.linalg.norm(q, axis=1, keepdims=True),
    )
    tracemalloc.start()
    try:
        write_tum(tmp_path / "long.tum", traj)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 10e6, peak
    short = Trajectory(
        t_ns=traj.t_ns[:100], p_W_B=traj.p_W_B[:100], q_W_B_xyzw=traj.q_W_B_xyzw[:100]
    )
    write_tum(tmp_path / "short.tum", short)
    lines = (tmp_path / "long.tum").read_text().splitlines()
    assert len(lines) == n and lines[:100] == (tmp_path / "short.tum").read_text().splitlines()
    back = read_trajectory(tmp_path / "long.tum")
    assert np.array_equal(back.t_ns, traj.t_ns)
