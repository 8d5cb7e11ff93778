"""Run folders: ``runs/<YYYY-mm-dd_HH-MM-SS>_<name>/`` with config, CSV, metrics and plots."""

from __future__ import annotations

import datetime as _dt
import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError

__all__ = ["CsvAppender", "create_run_folder", "write_csv", "write_json", "write_text"]


def create_run_folder(root: Path, name: str, *, now: _dt.datetime | None = None) -> Path:
    """Create a fresh run folder under ``root``; a clash gets a ``-2``, ``-3``... suffix."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "-", name).strip("-") or "run"
    stamp = (now or _dt.datetime.now()).strftime("%Y-%m-%d_%H-%M-%S")
    base = Path(root) / f"{stamp}_{safe}"
    try:
        Path(root).mkdir(parents=True, exist_ok=True)
        for k in range(1, 1000):
            candidate = base if k == 1 else base.with_name(f"{base.name}-{k}")
            try:
                candidate.mkdir()
            except FileExistsError:
                continue
            (candidate / "plots").mkdir()
            return candidate
    except OSError as exc:
        raise IoError(f"cannot create a run folder under {root}: {exc.strerror}") from None
    raise IoError(f"too many run folders named {base.name} under {root}")


def write_text(path: Path, text: str) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise IoError(f"cannot write {path}: {exc.strerror}") from None


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return _jsonable(value.item())
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no NaN; null says "not defined" (e.g. NEES with no fix)
    return value


def write_json(path: Path, data: Mapping[str, Any]) -> None:
    write_text(path, json.dumps(_jsonable(data), indent=2) + "\n")


def write_csv(path: Path, columns: Mapping[str, NDArray[Any]]) -> None:
    """Write equal-length columns with a header line; the first column must be ``t_ns``."""
    names = list(columns)
    if not names or names[0] != "t_ns":
        raise IoError(f"{path.name}: the first CSV column must be t_ns, got {names[:1]}")
    arrays = [np.asarray(columns[n]) for n in names]
    n_rows = len(arrays[0])
    if any(a.ndim != 1 or len(a) != n_rows for a in arrays):
        raise IoError(f"{path.name}: CSV columns must be 1-D and of equal length")
    if not np.issubdtype(arrays[0].dtype, np.integer):
        raise IoError(f"{path.name}: t_ns must be integer nanoseconds")
    fmts = [
        "%s"
        if a.dtype.kind in "UO"
        else "%d"
        if np.issubdtype(a.dtype, np.integer) or a.dtype == bool
        else "%.9g"
        for a in arrays
    ]
    table = np.empty((n_rows, len(names)), dtype=object)
    for j, a in enumerate(arrays):
        table[:, j] = a.astype(np.int64) if a.dtype == bool else a
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savetxt(path, table, fmt=fmts, delimiter=",", header=",".join(names), comments="")
    except OSError as exc:
        raise IoError(f"cannot write {path}: {exc.strerror}") from None


def _cell(value: Any) -> str:
    """One CSV cell as :func:`write_csv` writes it: integers as such, floats to 9 digits."""
    if isinstance(value, bool | np.bool_):
        return str(int(value))
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        return f"{float(value):.9g}"
    return str(value)


class CsvAppender:
    """A CSV written one row at a time and flushed after each, so that a run stopped half way
    (an error, Ctrl-C) keeps every row it made. Same header and number format as
    :func:`write_csv`; the first column must be ``t_ns``."""

    def __init__(self, path: Path, names: Sequence[str]) -> None:
        if not names or names[0] != "t_ns":
            raise IoError(f"{path.name}: the first CSV column must be t_ns, got {list(names[:1])}")
        self.path = path
        self.names = list(names)
        self.n_rows = 0
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file: IO[str] = path.open("w", encoding="utf-8", newline="")
            self._write(",".join(self.names))
        except OSError as exc:
            raise IoError(f"cannot write {path}: {exc.strerror}") from None

    def _write(self, line: str) -> None:
        self._file.write(line + "\n")
        self._file.flush()

    def append(self, row: Sequence[Any]) -> None:
        if len(row) != len(self.names):
            raise IoError(
                f"{self.path.name}: a row of {len(row)} values for {len(self.names)} columns"
            )
        if not isinstance(row[0], int | np.integer):
            raise IoError(f"{self.path.name}: t_ns must be integer nanoseconds")
        try:
            self._write(",".join(_cell(v) for v in row))
        except OSError as exc:
            raise IoError(f"cannot write {self.path}: {exc.strerror}") from None
        self.n_rows += 1

    def close(self) -> None:
        self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:  # fmt: skip
        self.close()
