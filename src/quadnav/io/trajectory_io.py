"""Trajectory files: TUM, EuRoC ASL, KITTI and quadnav run-folder CSVs (read and write),
plus ROS bags and PX4 ULogs (read, in ``io.rosbag`` and ``io.ulog``).

:func:`read_trajectory` guesses the format from the file, or takes ``fmt``. A malformed line
is an :class:`~quadnav.errors.IoError` naming the file and line number.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Literal, get_args

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import GeometryError, IoError
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.run_folder import require_complete, write_text, write_text_chunks
from quadnav.units import NS_PER_S

__all__ = [
    "TrajectoryFormat",
    "guess_format",
    "read_euroc",
    "read_kitti",
    "read_quadnav_csv",
    "read_trajectory",
    "read_tum",
    "write_euroc",
    "write_kitti",
    "write_trajectory",
    "write_tum",
]

FloatArray = NDArray[np.float64]
TrajectoryFormat = Literal["tum", "euroc", "kitti", "quadnav", "rosbag", "ulog"]
FORMATS: tuple[str, ...] = get_args(TrajectoryFormat)


def _read_lines(path: Path, *, head_bytes: int | None = None) -> list[str]:
    """The lines of a text file, or only those in its first ``head_bytes`` (whole lines)."""
    if not path.exists():
        raise IoError(f"trajectory file not found: {path}")
    if path.is_dir():
        raise IoError(
            f"{path} is a folder, not a trajectory file (a ROS 2 bag? use --format rosbag)"
        )
    try:
        if head_bytes is None:
            return path.read_text(encoding="utf-8").splitlines()
        with path.open("rb") as f:
            data = f.read(head_bytes)
        if len(data) == head_bytes and b"\n" in data:
            data = data[: data.rindex(b"\n")]  # no cut line (or cut character)
        return data.decode("utf-8").splitlines()
    except UnicodeDecodeError:
        raise IoError(f"{path}: not a text file (wrong --format?)") from None
    except OSError as exc:
        raise IoError(f"cannot read {path}: {exc.strerror}") from None


_PLAIN_SECONDS = re.compile(r"([0-9]+)(?:\.([0-9]*))?")


def _seconds_to_ns(token: str, where: str) -> int:
    """Exact decimal seconds to integer nanoseconds (no float rounding of long stamps)."""
    m = _PLAIN_SECONDS.fullmatch(token)
    if m is not None:  # the common case, without Decimal: "1403636579.763555527"
        frac = (m.group(2) or "").ljust(10, "0")
        ns = int(m.group(1)) * NS_PER_S + int(frac[:9])
        if frac[9] >= "5" and (frac[9] > "5" or frac[10:].strip("0") or int(frac[8]) % 2):
            ns += 1  # round half to even, as Decimal does
        return ns
    try:
        value = Decimal(token)
    except InvalidOperation:
        raise IoError(f"{where}: not a timestamp: {token!r}") from None
    if not value.is_finite():
        raise IoError(f"{where}: non-finite timestamp {token!r}")
    return int((value * NS_PER_S).to_integral_value())


def _rows(
    path: Path, lines: list[str], n_cols: int, *, sep: str | None, skip_header: bool = False
) -> tuple[list[int], list[list[str]]]:
    """Non-comment rows split into ``n_cols`` tokens, with their 1-based line numbers."""
    numbers, rows = [], []
    first = True
    for k, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("#") or line.startswith("%"):
            continue
        if first and skip_header:
            first = False
            continue
        first = False
        tokens = (
            [t for t in (line.split(sep) if sep else line.split()) if t != ""]
            if sep
            else line.split()
        )
        tokens = [t.strip() for t in tokens]
        if len(tokens) != n_cols:
            raise IoError(f"{path}:{k}: expected {n_cols} values, got {len(tokens)}")
        numbers.append(k)
        rows.append(tokens)
    if not rows:
        raise IoError(f"{path}: no poses in the file")
    return numbers, rows


def _floats(path: Path, numbers: list[int], rows: list[list[str]], cols: slice) -> FloatArray:
    try:
        arr = np.array([r[cols] for r in rows], dtype=np.float64)
    except ValueError:
        for k, r in zip(numbers, rows, strict=True):
            for tok in r[cols]:
                try:
                    float(tok)
                except ValueError:
                    raise IoError(f"{path}:{k}: not a number: {tok!r}") from None
        raise
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        k = numbers[int(np.argmax(bad))]
        raise IoError(f"{path}:{k}: non-finite value (NaN or inf)")
    return arr


def _build(path: Path, **kwargs: object) -> Trajectory:
    try:
        return Trajectory(**kwargs)  # type: ignore[arg-type]
    except GeometryError as exc:
        raise IoError(f"{path}: {exc}") from None


def _first_of_repeats(
    path: Path, numbers: list[int], t: NDArray[np.int64], v: FloatArray
) -> tuple[NDArray[np.int64], FloatArray, dict[str, str]]:
    """Keep the first pose of each run of equal timestamps (evo reads such files); the count
    and the first repeated line go into the trajectory's ``meta``."""
    repeat = np.concatenate([[False], np.diff(t) == 0]) if len(t) > 1 else np.zeros(len(t), bool)
    n = int(repeat.sum())
    if n == 0:
        return t, v, {}
    line = numbers[int(np.argmax(repeat))]
    note = (
        f"{path.name}: {n} pose(s) repeat the timestamp of the line before (first at line "
        f"{line}); kept the first of each"
    )
    return t[~repeat], v[~repeat], {"repeated_timestamps": str(n), "note": note}


def _tum_fast(lines: list[str]) -> tuple[list[int], NDArray[np.int64], FloatArray] | None:
    """Line numbers, times and values of a well-formed TUM file in bulk, or None (then the
    line-by-line reader finds and names the bad line)."""
    numbers, rows = [], []
    for k, raw in enumerate(lines, start=1):
        tokens = raw.split()
        if not tokens or tokens[0][0] in "#%":
            continue
        if len(tokens) != 8:
            return None
        numbers.append(k)
        rows.append(tokens)
    whole, frac = [], []
    for r in rows:
        w, _, f = r[0].partition(".")
        whole.append(w)
        frac.append(f.ljust(9, "0"))
    plain = all(w.isascii() and w.isdigit() and len(w) <= 10 for w in whole) and all(
        len(f) == 9 and f.isascii() and f.isdigit() for f in frac
    )
    if not rows or not plain:
        return None
    try:
        v = np.array([r[1:] for r in rows], dtype=np.float64)
    except ValueError:
        return None
    if not np.isfinite(v).all():
        return None
    t = np.array(whole, dtype=np.int64) * NS_PER_S + np.array(frac, dtype=np.int64)
    return numbers, t, v


def read_tum(path: Path) -> Trajectory:
    """TUM RGB-D format: ``t x y z qx qy qz qw`` per line, time in seconds. A pose whose
    timestamp repeats the one before is left out and counted (``meta``)."""
    path = Path(path)
    lines = _read_lines(path)
    fast = _tum_fast(lines)
    if fast is not None:
        numbers, t, v = fast
    else:
        numbers, rows = _rows(path, lines, 8, sep=None)
        t = np.array(
            [_seconds_to_ns(r[0], f"{path}:{k}") for k, r in zip(numbers, rows, strict=True)]
        )
        v = _floats(path, numbers, rows, slice(1, 8))
    t, v, meta = _first_of_repeats(path, numbers, t, v)
    return _build(path, t_ns=t, p_W_B=v[:, 0:3], q_W_B_xyzw=v[:, 3:7], name=path.stem, meta=meta)


def read_euroc(path: Path) -> Trajectory:
    """EuRoC ASL ground truth: ``#timestamp [ns], p_RS_R_x [m], ..., q_RS_w [], q_RS_x ...``.

    Extra columns (velocity, biases) are ignored; the quaternion is scalar-first in the file.
    """
    path = Path(path)
    lines = _read_lines(path)
    data = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    if not data:
        raise IoError(f"{path}: no poses in the file")
    n_cols = len(data[0].split(","))
    if n_cols < 8:
        raise IoError(f"{path}: an EuRoC file needs at least 8 columns, got {n_cols}")
    numbers, rows = _rows(path, lines, n_cols, sep=",")
    t = []
    for k, r in zip(numbers, rows, strict=True):
        if not re.fullmatch(r"[0-9]+", r[0]):
            raise IoError(f"{path}:{k}: timestamp must be integer nanoseconds, got {r[0]!r}")
        t.append(int(r[0]))
    v = _floats(path, numbers, rows, slice(1, 8))
    return _build(
        path, t_ns=np.array(t), p_W_B=v[:, 0:3], q_W_B_xyzw=v[:, [4, 5, 6, 3]], name=path.stem
    )


def read_kitti(path: Path) -> Trajectory:
    """KITTI odometry poses: 12 numbers per line (a row-major 3x4 ``T_W_B``), no timestamps."""
    path = Path(path)
    numbers, rows = _rows(path, _read_lines(path), 12, sep=None)
    v = _floats(path, numbers, rows, slice(0, 12)).reshape(-1, 3, 4)
    try:
        return Trajectory.from_matrices(np.arange(len(v)), v, timed=False, name=path.stem)
    except (GeometryError, ValueError) as exc:
        raise IoError(f"{path}: {exc}") from None


def read_quadnav_csv(path: Path) -> Trajectory:
    """A quadnav run-folder CSV: header line, ``t_ns`` first, ``x_m`` [``y_m``] ``z_m`` and an
    attitude as ``qx qy qz qw`` or (planar runs) ``theta_rad`` about +y. Variances ``var_x``...
    become a diagonal position covariance.
    """
    path = Path(path)
    lines = _read_lines(path)
    if not lines or not lines[0].startswith("t_ns"):
        raise IoError(f"{path}:1: a quadnav CSV starts with a header whose first column is t_ns")
    header = [h.strip() for h in lines[0].split(",")]
    col = {name: i for i, name in enumerate(header)}
    for needed in ("x_m", "z_m"):
        if needed not in col:
            raise IoError(f"{path}:1: no {needed} column")
    numbers, rows = _rows(path, lines, len(header), sep=",", skip_header=True)
    t = []
    for k, r in zip(numbers, rows, strict=True):
        if not re.fullmatch(r"-?[0-9]+", r[0]):
            raise IoError(f"{path}:{k}: t_ns must be an integer, got {r[0]!r}")
        t.append(int(r[0]))
    v = _floats(path, numbers, rows, slice(1, len(header)))

    def column(name: str) -> FloatArray:
        return v[:, col[name] - 1]

    n = len(rows)
    p = np.column_stack(
        [column("x_m"), column("y_m") if "y_m" in col else np.zeros(n), column("z_m")]
    )
    if all(c in col for c in ("qx", "qy", "qz", "qw")):
        q = np.column_stack([column(c) for c in ("qx", "qy", "qz", "qw")])
    elif "theta_rad" in col:
        q = Rotation.from_rotvec(np.outer(column("theta_rad"), [0.0, 1.0, 0.0])).as_quat()
    else:
        q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    cov = None
    if "var_x" in col and "var_z" in col:
        diag = np.column_stack(
            [column("var_x"), column("var_y") if "var_y" in col else np.zeros(n), column("var_z")]
        )
        cov = np.zeros((n, 3, 3))
        cov[:, [0, 1, 2], [0, 1, 2]] = diag
    return _build(path, t_ns=np.array(t), p_W_B=p, q_W_B_xyzw=q, cov_p=cov, name=path.stem)


def guess_format(path: Path) -> TrajectoryFormat:
    """The format of a trajectory file, from its name and first lines."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".ulg":
        return "ulog"
    if suffix in (".bag", ".db3", ".mcap") or (path.is_dir() and (path / "metadata.yaml").exists()):
        return "rosbag"
    lines = _read_lines(path, head_bytes=65536)
    first = next((ln.strip() for ln in lines if ln.strip()), "")
    if first.startswith("t_ns"):
        return "quadnav"
    if "p_RS_R_x" in first or first.startswith("#timestamp"):
        return "euroc"
    data = next((ln.strip() for ln in lines if ln.strip() and not ln.lstrip().startswith("#")), "")
    n = len(data.split(",")) if "," in data else len(data.split())
    if n == 8:
        return "tum"
    if n == 12:
        return "kitti"
    if "," in data and n >= 8:
        return "euroc"
    raise IoError(
        f"{path}: cannot tell the trajectory format ({n} values per line); pass --format "
        f"(one of {', '.join(FORMATS)})"
    )


def read_trajectory(path: Path, fmt: str | None = None, *, topic: str | None = None) -> Trajectory:
    """Read a trajectory in any supported format (guessed when ``fmt`` is ``None``). A file
    of a run folder that is not marked complete (interrupted, failed) is refused."""
    path = Path(path)
    require_complete(path)
    if fmt is None:
        fmt = guess_format(path)
    if fmt not in FORMATS:
        raise IoError(f"unknown trajectory format {fmt!r}; choose from {', '.join(FORMATS)}")
    if fmt == "tum":
        return read_tum(path)
    if fmt == "euroc":
        return read_euroc(path)
    if fmt == "kitti":
        return read_kitti(path)
    if fmt == "quadnav":
        return read_quadnav_csv(path)
    if fmt == "rosbag":
        from quadnav.io.rosbag import read_bag_trajectory

        return read_bag_trajectory(path, topic=topic)
    from quadnav.io.ulog import read_ulog_trajectory

    return read_ulog_trajectory(path)


def _ns_to_seconds(t_ns: NDArray[np.int64]) -> list[str]:
    """Exact decimal seconds, ``-1.500000000`` for -1.5 s."""
    whole, ns = np.divmod(np.abs(t_ns), NS_PER_S)
    sign = np.where(t_ns < 0, "-", "").tolist()
    return [
        "%s%d.%09d" % x  # noqa: UP031 - one format per line, 3x faster than an f-string
        for x in zip(sign, whole.tolist(), ns.tolist(), strict=True)
    ]


def _table(prefix: list[str], values: FloatArray, sep: str) -> str:
    line = sep.join(["%s", *["%.9g"] * values.shape[1]])  # one format per line: 4x faster
    body = [line % (pre, *row) for pre, row in zip(prefix, values.tolist(), strict=True)]
    return "\n".join(body) + ("\n" if body else "")


#: Rows a trajectory file is formatted at a time.
_ROWS_AT_A_TIME = 8192


def write_tum(path: Path, traj: Trajectory) -> None:
    """TUM: ``t x y z qx qy qz qw``, time in seconds written exactly from ``t_ns``; formatted
    a block of rows at a time (a 30-minute ground truth at 200 Hz is 180,000 rows)."""

    def blocks() -> Iterator[str]:
        for a in range(0, len(traj.t_ns), _ROWS_AT_A_TIME):
            b = a + _ROWS_AT_A_TIME
            values = np.column_stack([traj.p_W_B[a:b], traj.q_W_B_xyzw[a:b]])
            yield _table(_ns_to_seconds(traj.t_ns[a:b]), values, " ")

    write_text_chunks(Path(path), blocks())


def write_euroc(path: Path, traj: Trajectory) -> None:
    header = "#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []\n"
    q = traj.q_W_B_xyzw[:, [3, 0, 1, 2]]
    write_text(
        Path(path),
        header
        + _table([str(t) for t in traj.t_ns.tolist()], np.column_stack([traj.p_W_B, q]), ","),
    )


def write_kitti(path: Path, traj: Trajectory) -> None:
    rows = traj.matrices()[:, :3, :].reshape(len(traj), 12)
    lines = [" ".join(f"{x:.9e}" for x in row) for row in rows]
    write_text(Path(path), "\n".join(lines) + ("\n" if lines else ""))


def write_trajectory(path: Path, traj: Trajectory, fmt: Literal["tum", "euroc", "kitti"]) -> None:
    {"tum": write_tum, "euroc": write_euroc, "kitti": write_kitti}[fmt](path, traj)
