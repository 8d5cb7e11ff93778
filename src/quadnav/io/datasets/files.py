"""The pieces every dataset format shares: ASL csv tables (``#timestamp [ns],...``), YAML
calibration files (EuRoC's start with ``%YAML:1.0``, which PyYAML refuses), lazy image files,
and floats written so that they read back exactly."""

from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Self

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from quadnav.errors import GeometryError, IoError, SampleError
from quadnav.geometry.multiview import nearest_rotation
from quadnav.geometry.rotations import Pose
from quadnav.io.config import yaml_problem
from quadnav.io.datasets.types import IN_ORDER, REPEATED, IssueLog, order_faults
from quadnav.units import NS_PER_S

__all__ = [
    "PartialWriter",
    "Table",
    "float_text",
    "load_image",
    "pose_of_4x4",
    "rate_of_stamps",
    "read_image_list",
    "read_table",
    "read_yaml",
    "yaml_numbers",
]

FloatArray = NDArray[np.float64]
_INT = re.compile(r"[0-9]+")


class PartialWriter:
    r"""A writer that fills ``<path>.partial/`` and renames it at :meth:`close`: used as a
    context manager it closes on success and :meth:`abort`\ s (removes the partial folder) on an
    exception, so nothing half-written looks complete."""

    def __enter__(self) -> Self:
        return self

    def close(self) -> Path:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def float_text(x: float) -> str:
    """``repr`` of a float (exact on reading back), with a mantissa dot so that PyYAML (YAML
    1.1) reads ``1.0e-05`` as a number and not as the string ``1e-05``."""
    s = repr(float(x))
    if not math.isfinite(float(x)):
        raise IoError(f"cannot write the non-finite number {s}")
    if "e" in s and "." not in s.split("e")[0]:
        mant, exp = s.split("e")
        s = f"{mant}.0e{exp}"
    return s


def read_yaml(path: Path) -> dict[str, Any]:
    """A YAML mapping; EuRoC's ``%YAML:1.0`` directive stripped; a parse error in one line."""
    if not path.is_file():
        raise IoError(f"{path}: no such file")
    text = path.read_text(encoding="utf-8", errors="replace")
    text = re.sub(r"\A%YAML[: ]?1\.[0-9]\s*\n", "\n", text)
    text = text.replace("!!opencv-matrix", "")
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise IoError(yaml_problem(path, exc)) from None
    if not isinstance(doc, dict):
        raise IoError(f"{path}: expected a mapping of keys, got {type(doc).__name__}")
    return doc


def yaml_numbers(
    doc: dict[str, Any], key: str, path: Path, count: int | None = None
) -> list[float]:
    """``doc[key]`` as a flat list of finite numbers (``count`` of them when given); a matrix
    node (``rows``/``cols``/``data``) gives its data."""
    if key not in doc:
        raise IoError(f"{path}: missing key {key!r}")
    value = doc[key]
    if isinstance(value, dict) and "data" in value:
        value = value["data"]
    flat = np.asarray(value, dtype=object).ravel().tolist() if isinstance(value, list) else [value]
    try:
        nums = [float(v) for v in flat]
    except (TypeError, ValueError):
        raise IoError(f"{path}: {key} must be numbers, got {value!r}") from None
    if not all(math.isfinite(v) for v in nums):
        raise IoError(f"{path}: {key} has a non-finite number")
    if count is not None and len(nums) != count:
        raise IoError(f"{path}: {key} must have {count} numbers, got {len(nums)}")
    return nums


def pose_of_4x4(values: Sequence[float], path: Path, key: str) -> Pose:
    """A calibration's 4x4 (row major) as a pose, its rotation made exactly orthonormal (SVD):
    calibration files print 9-12 digits."""
    M = np.asarray(values, dtype=np.float64).reshape(4, 4)
    R = M[:3, :3]
    if not np.allclose(M[3], [0, 0, 0, 1], atol=1e-9) or abs(np.linalg.det(R) - 1.0) > 1e-4:
        raise IoError(f"{path}: {key} is not a rigid transform (last row or rotation block)")
    try:
        return Pose.from_matrix(np.block([[nearest_rotation(R), M[:3, 3:]], [M[3:]]]))
    except GeometryError as exc:
        raise IoError(f"{path}: {key}: {exc}") from None


@dataclass(frozen=True, slots=True, eq=False)
class Table:
    """The kept rows of an ASL csv: 1-based line numbers, stamps, the numeric columns."""

    lines: list[int]
    t_ns: NDArray[np.int64]
    values: FloatArray


def _data_rows(path: Path) -> list[tuple[int, list[str]]]:
    if not path.is_file():
        raise IoError(f"{path}: no such file")
    rows = []
    with path.open(encoding="utf-8", errors="replace") as fh:
        for k, raw in enumerate(fh, start=1):
            line = raw.strip()
            if line and not line.startswith(("#", "%")):
                rows.append((k, [t.strip() for t in line.split(",")]))
    return rows


def _numbers(
    rows: list[tuple[int, list[str]]], n_values: int
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """The value columns as floats (NaN where a token is not a number) and which rows are whole."""
    cols = [r[1 : n_values + 1] for _, r in rows]
    try:
        vals = np.array(cols, dtype=np.float64).reshape(-1, n_values)
    except ValueError:  # a token that is not a number: find it row by row
        vals = np.full((len(cols), n_values), np.nan)
        for i, c in enumerate(cols):
            with contextlib.suppress(ValueError):
                vals[i] = [float(x) for x in c]
    return vals, np.asarray(np.isfinite(vals).all(axis=1), dtype=np.bool_)


class _Rejects:
    """Where a reader's bad rows go: counted in ``issues`` as ``<what> <fault>``, or without
    an issue log a one-line error naming the file and the line."""

    def __init__(self, path: Path, issues: IssueLog | None, what: str, camera: str = "") -> None:
        self.path, self.issues, self.what, self.camera = path, issues, what, camera

    def reject(self, line: int, fault: str, detail: str) -> None:
        if self.issues is None:
            raise IoError(f"{self.path}:{line}: {detail}")
        where = f"{self.path.parent.name}/{self.path.name}:{line}"
        self.issues.reject(f"{self.what} {fault}", where, camera=self.camera)

    def ordered(self, lines: Sequence[int], t_ns: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Which rows keep the stamps increasing; the others rejected (repeated, out of order)."""
        faults = order_faults(t_ns)
        for i in np.flatnonzero(faults).tolist():
            if faults[i] == REPEATED:
                self.reject(lines[i], "repeated", f"timestamp {int(t_ns[i])} repeats")
            else:
                self.reject(lines[i], "out of order", f"timestamp {int(t_ns[i])} is out of order")
        return np.asarray(faults == IN_ORDER, dtype=np.bool_)


def _readable(
    rows: list[tuple[int, list[str]]], columns: int, rejects: _Rejects
) -> list[tuple[int, list[str]]]:
    """The rows with ``columns`` columns and an integer stamp; the others rejected."""
    kept = []
    for k, tokens in rows:
        if len(tokens) < columns:
            rejects.reject(k, "unreadable", f"expected {columns} columns, got {len(tokens)}")
        elif not _INT.fullmatch(tokens[0]):
            detail = f"timestamp must be integer nanoseconds, got {tokens[0]!r}"
            rejects.reject(k, "unreadable", detail)
        else:
            kept.append((k, tokens))
    return kept


def read_table(path: Path, n_values: int, issues: IssueLog | None, what: str) -> Table:
    """Rows ``t_ns, v1..v_n`` (extra columns ignored). A row that cannot be read (too few
    columns, a stamp that is not integer nanoseconds), that has a NaN or an unreadable number,
    or whose stamp repeats or goes out of order is rejected and counted in ``issues`` as
    ``<what> unreadable``, ``with a NaN``, ``repeated`` or ``out of order`` (a one-line error
    naming the line when ``issues`` is None); the stamps kept increase."""
    rejects = _Rejects(path, issues, what)
    rows = _readable(_data_rows(path), n_values + 1, rejects)
    vals, ok = _numbers(rows, n_values)
    for i in np.flatnonzero(~ok):
        rejects.reject(rows[i][0], "with a NaN", "a value is not a finite number")
    rows = [r for r, good in zip(rows, ok, strict=True) if good]
    lines = [k for k, _ in rows]
    t = np.array([int(tokens[0]) for _, tokens in rows], dtype=np.int64)
    ordered = rejects.ordered(lines, t)
    return Table(
        [k for k, o in zip(lines, ordered, strict=True) if o], t[ordered], vals[ok][ordered]
    )


def read_image_list(
    path: Path, issues: IssueLog | None = None
) -> tuple[list[int], list[int], list[str]]:
    """(line numbers, stamps, file names) of an ASL camera ``data.csv``; unreadable, repeated
    and out-of-order rows rejected and counted as ``image rows ...`` of the camera (the folder's
    name), or without ``issues`` a one-line error."""
    rejects = _Rejects(path, issues, "image rows", camera=path.parent.name)
    rows = []
    for k, tokens in _readable(_data_rows(path), 2, rejects):
        if tokens[1]:
            rows.append((k, tokens))
        else:
            rejects.reject(k, "unreadable", "expected 2 columns (timestamp, filename), got 1")
    lines = [k for k, _ in rows]
    t = np.array([int(tokens[0]) for _, tokens in rows], dtype=np.int64)
    ordered = rejects.ordered(lines, t)
    kept = [(k, tokens) for (k, tokens), o in zip(rows, ordered, strict=True) if o]
    return [k for k, _ in kept], [int(tok[0]) for _, tok in kept], [tok[1] for _, tok in kept]


def rate_of_stamps(t_ns: Sequence[int] | NDArray[np.int64], fallback_hz: float = 20.0) -> float:
    """A sensor's nominal rate from its stamps (the median interval, rounded to 1 mHz: stamps
    jitter by nanoseconds); ``fallback_hz`` for fewer than two distinct stamps."""
    d = np.diff(np.sort(np.asarray(t_ns, dtype=np.int64)))
    d = d[d > 0]
    return round(NS_PER_S / float(np.median(d)), 3) if d.size else fallback_hz


def to_uint8(img: NDArray[Any]) -> NDArray[np.uint8]:
    """8 bits: 16-bit pictures (TUM-VI's ``_16`` sequences, mono16) keep their high byte."""
    if img.dtype == np.uint16:
        return np.asarray(img >> 8, dtype=np.uint8)
    return np.asarray(img, dtype=np.uint8)


def load_image(path: str) -> NDArray[np.uint8]:
    """The pixels of one image file, as stored (grey stays grey); a :class:`SampleError` naming
    the file when it is missing or not a picture."""
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SampleError(f"image {path} is missing or corrupt (cannot be decoded)")
    return to_uint8(img)
