"""Run folders: ``runs/<YYYY-mm-dd_HH-MM-SS>_<name>/`` with config, CSV, metrics and plots.

Every folder carries ``status.json``: ``running`` from its creation, then ``complete``,
``interrupted`` (Ctrl-C: what finished is kept) or ``failed`` (with the error). A process killed
outright leaves ``running``. Readers check it (:func:`require_complete`). Files are written
atomically (a temporary file renamed into place), so none is ever cut mid-line. A folder that
holds nothing but its configuration when the work fails is removed: an input error leaves no
folder behind.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import re
import shutil
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Literal, Self

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import IoError

__all__ = [
    "STATUS_FILE",
    "CsvAppender",
    "RunStatus",
    "append_jsonl",
    "checked_run_folder",
    "create_run_folder",
    "finish_run_folder",
    "open_run_folder",
    "read_json",
    "read_jsonl",
    "read_run_status",
    "require_complete",
    "run_guard",
    "write_csv",
    "write_json",
    "write_text",
]

STATUS_FILE = "status.json"
RunStatus = Literal["running", "complete", "interrupted", "failed"]
#: Run folders created by this process and not yet finished, oldest first.
_OPEN: list[Path] = []


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
            _write_status(candidate, "running")
            _OPEN.append(candidate)
            return candidate
    except OSError as exc:
        raise IoError(f"cannot create a run folder under {root}: {exc.strerror}") from None
    raise IoError(f"too many run folders named {base.name} under {root}")


def open_run_folder(path: Path) -> Path:
    """Create the run folder ``path`` or open it again (a sweep resumed into its own folder):
    its status is ``running`` until it is finished, as a folder of :func:`create_run_folder`."""
    path = Path(path)
    try:
        (path / "plots").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise IoError(f"cannot create the run folder {path}: {exc.strerror}") from None
    _write_status(path, "running")
    if path not in _OPEN:
        _OPEN.append(path)
    return path


def _now() -> str:
    return _dt.datetime.now().isoformat(timespec="seconds")


def _write_status(run_dir: Path, status: RunStatus, reason: str = "") -> None:
    record = {"status": status, "updated": _now()}
    if reason:
        record["reason"] = reason
    path = run_dir / STATUS_FILE
    try:
        write_json(path, record)
    except IoError:
        if not _overwrite_in_place(path, record):
            raise


def _overwrite_in_place(path: Path, record: dict[str, str]) -> bool:
    """Rewrite an existing status file where it lies, for a full disk: its first block is
    already allocated, where the atomic write's new file needs one (the reason is shortened to
    stay in it). True when it was written."""
    short = {**record, "reason": record["reason"][:500]} if "reason" in record else record
    try:
        with path.open("r+b") as f:
            f.write((json.dumps(short, indent=2) + "\n").encode())
            f.truncate()
    except OSError:
        return False
    return True


def finish_run_folder(run_dir: Path, status: RunStatus = "complete", reason: str = "") -> None:
    """Mark a run folder finished (``complete``, ``interrupted`` or ``failed``)."""
    _write_status(run_dir, status, reason)
    if run_dir in _OPEN:
        _OPEN.remove(run_dir)


def read_run_status(run_dir: Path) -> RunStatus | None:
    """The folder's status; ``None`` for a folder written before statuses existed."""
    path = Path(run_dir) / STATUS_FILE
    if not path.is_file():
        return None
    try:
        status = json.loads(path.read_text(encoding="utf-8")).get("status")
    except (OSError, ValueError, AttributeError):
        return "failed"  # an unreadable status is no evidence of a complete run
    return status if status in ("running", "complete", "interrupted", "failed") else "failed"


def require_complete(path: Path) -> None:
    """Refuse to read a file of a run folder (or the folder) that is not complete."""
    path = Path(path)
    for folder in (path, *path.parents[:2]) if path.is_dir() else path.parents[:3]:
        status = read_run_status(folder)
        if status is None:
            continue
        if status != "complete":
            raise IoError(
                f"{folder} is a run folder marked {status!r} in its {STATUS_FILE}: "
                "its files may be incomplete"
            )
        return


def checked_run_folder(
    run_dir: Path,
    what: str,
    required: Iterable[str],
    is_kind: Callable[[Path], bool],
    *,
    complete: bool,
    not_kind: str = "another kind's",
) -> Path:
    """``run_dir`` when ``is_kind`` says it is a ``what`` folder (``quadnav sim``...) and, with
    ``complete``, it is marked complete; otherwise one line naming it and why: the ``required``
    files it lacks, or that its metrics.json is ``not_kind``."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir() or not is_kind(run_dir):
        missing = [n for n in required if not (run_dir / n).exists()]
        why = f"no {', '.join(missing)}" if missing else f"its metrics.json is {not_kind}"
        raise IoError(f"{run_dir}: not a {what} folder ({why})")
    if complete:
        require_complete(run_dir)
    return run_dir


def _only_configuration(run_dir: Path) -> bool:
    """True when nothing but the configuration, the status and empty folders was written."""
    for p in run_dir.rglob("*"):
        if p.is_file() and p.name not in ("config.yaml", STATUS_FILE):
            return False
    return True


def _close_open_folders(first: int, status: RunStatus, reason: str) -> list[Path]:
    kept = []
    for run_dir in list(_OPEN[first:]):
        if status != "complete" and _only_configuration(run_dir):
            shutil.rmtree(run_dir, ignore_errors=True)  # nothing was computed: no folder
            _OPEN.remove(run_dir)
            continue
        finish_run_folder(run_dir, status, reason)
        kept.append(run_dir)
    return kept


@contextmanager
def run_guard() -> Iterator[list[Path]]:
    """Finish every run folder created inside: ``complete`` on success, ``interrupted`` on
    Ctrl-C, ``failed`` on an error (folders with nothing but their configuration are removed).
    Yields the list of the folders kept on an interrupt or a failure, filled on the way out."""
    first = len(_OPEN)
    kept: list[Path] = []
    try:
        yield kept
    except KeyboardInterrupt:
        kept.extend(_close_open_folders(first, "interrupted", "interrupted (Ctrl-C)"))
        raise
    except BaseException as exc:
        kept.extend(_close_open_folders(first, "failed", str(exc) or type(exc).__name__))
        raise
    _close_open_folders(first, "complete", "")


def _replace_atomically(path: Path, write: Any) -> None:
    """Write through ``write(tmp_path)`` to a temporary file, then rename it onto ``path``."""
    tmp = path.with_name(f".{path.name}.partial")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise IoError(f"cannot write {path}: {exc.strerror}") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text(path: Path, text: str) -> None:
    _replace_atomically(Path(path), lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_text_chunks(path: Path, chunks: Iterable[str]) -> None:
    """:func:`write_text` a piece at a time (a long trajectory is never one string in memory)."""

    def write(tmp: Path) -> None:
        with tmp.open("w", encoding="utf-8") as f:
            for chunk in chunks:
                f.write(chunk)

    _replace_atomically(Path(path), write)


def append_jsonl(path: Path, record: Mapping[str, Any]) -> None:
    """Append one JSON line (one finished seed, say): what is done survives an interrupt."""
    try:
        with Path(path).open("a", encoding="utf-8") as f:
            f.write(json.dumps(_jsonable(record)) + "\n")
    except OSError as exc:
        raise IoError(f"cannot write {path}: {exc.strerror}") from None


def read_json(path: Path) -> dict[str, object]:
    """A JSON object written by :func:`write_json` (an error naming the file otherwise)."""
    try:
        record = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise IoError(f"cannot read {path}: {exc}") from None
    if not isinstance(record, dict):
        raise IoError(f"{path}: not a JSON object")
    return record


def read_jsonl(path: Path, *, repair: bool = False) -> list[dict[str, object]]:
    """The records of an append-only JSON-lines file (an empty list when it does not exist).
    A last line cut by a killed process (no newline, not JSON) is left out, and with
    ``repair`` cut off the file, so that the next line appended starts a line of its own; a
    bad line elsewhere is an error naming the file and the line."""
    path = Path(path)
    if not path.is_file():
        return []
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise IoError(f"cannot read {path}: {exc.strerror}") from None
    lines = data.split(b"\n")
    records: list[dict[str, object]] = []
    for k, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except ValueError:
            if k < len(lines) - 1:
                raise IoError(f"{path}: line {k + 1} is not JSON") from None
            if repair:  # the last line, cut as it was written
                _truncate(path, len(data) - len(line))
            return records
        if not isinstance(record, dict):
            raise IoError(f"{path}: line {k + 1} is not a JSON object")
        records.append(record)
    if repair and data and not data.endswith(b"\n"):  # whole, but cut before its newline
        append_text(path, "\n")
    return records


def append_text(path: Path, text: str) -> None:
    try:
        with Path(path).open("a", encoding="utf-8") as f:
            f.write(text)
    except OSError as exc:
        raise IoError(f"cannot write {path}: {exc.strerror}") from None


def _truncate(path: Path, size: int) -> None:
    try:
        with path.open("r+b") as f:
            f.truncate(size)
    except OSError as exc:
        raise IoError(f"cannot repair {path}: {exc.strerror}") from None


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
    _replace_atomically(
        Path(path),
        lambda tmp: np.savetxt(
            tmp, table, fmt=fmts, delimiter=",", header=",".join(names), comments=""
        ),
    )


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

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
