"""Shared pieces of the command line: error mapping, progress bars, tables."""

from __future__ import annotations

import functools
import math
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, ParamSpec, TypeVar

import typer
from rich.console import Console

from quadnav.errors import ConfigError, QuadnavError
from quadnav.io.run_folder import run_guard

if TYPE_CHECKING:
    from quadnav.viz.background import RecordingProcess
    from quadnav.viz.recording import RecordingInfo
    from quadnav.viz.stream import RerunOptions

__all__ = [
    "CommandParams",
    "RerunConnectOpt",
    "RerunOpt",
    "RerunSpawnOpt",
    "check_range",
    "command_help",
    "console",
    "err_console",
    "finish_recording",
    "handle_errors",
    "optional_param",
    "param",
    "print_recording",
    "progress_bar",
    "rerun_param",
    "rerun_request",
    "start_recording",
    "strings_param",
]

# Piped output (CI logs, files) gets a width that fits the summary tables, not rich's 80.
console = Console() if sys.stdout.isatty() else Console(width=120)
err_console = Console(stderr=True)

P = ParamSpec("P")
R = TypeVar("R")
T = TypeVar("T")

#: A command's parameters as click parsed them (``ctx.params``: name -> converted value), which
#: each command's ``check_example`` validates as the command would.
CommandParams = Mapping[str, object]


def param(params: CommandParams, name: str, kind: type[T]) -> T:
    """The value click parsed for the parameter ``name``, which must be a ``kind``."""
    value = params[name]
    if not isinstance(value, kind):
        raise TypeError(f"parameter {name}: {value!r} is not of type {kind.__name__}")
    return value


def optional_param(params: CommandParams, name: str, kind: type[T]) -> T | None:
    """:func:`param` for a parameter that may be unset (None)."""
    return None if params[name] is None else param(params, name, kind)


def strings_param(params: CommandParams, name: str) -> list[str]:
    """The values of a repeatable option (``--set``; click gives a tuple or a list)."""
    value = params[name]
    if value is None:
        return []
    if not isinstance(value, list | tuple) or not all(isinstance(v, str) for v in value):
        raise TypeError(f"parameter {name}: {value!r} is not a list of text")
    return list(value)


def command_help(
    summary: str,
    body: str = "",
    *,
    lists: Sequence[tuple[str, Mapping[str, str]]] = (),
    examples: Sequence[str] = (),
) -> str:
    """A command's help text, made from its registries (built-in scenarios, examples) so it
    cannot drift from them: one paragraph per entry, as typer lays out a docstring."""
    parts = [summary]
    if body:
        parts.append(body)
    for title, entries in lists:
        parts.append(f"{title}:")
        parts.extend(f"  {name}: {text}" for name, text in entries.items())
    if examples:
        parts.append("Examples:")
        parts.extend(f"  {e}" for e in examples)
    return "\n\n".join(parts)


def handle_errors(fn: Callable[P, R]) -> Callable[P, R]:
    """Turn a :class:`QuadnavError` into one line on stderr and exit code 2, Ctrl-C into one
    line and exit code 130; every run folder the command created is marked complete,
    interrupted or failed (and removed when it holds nothing but its configuration)."""

    @functools.wraps(fn)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        kept: list[Path] = []
        try:
            with run_guard() as kept:
                return fn(*args, **kwargs)
        except QuadnavError as exc:
            print(f"error: {exc}", file=sys.stderr)
            for run_dir in kept:
                print(f"partial results (marked failed): {run_dir}", file=sys.stderr)
            raise typer.Exit(code=2) from None
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            for run_dir in kept:
                print(f"partial results (marked interrupted): {run_dir}", file=sys.stderr)
            raise typer.Exit(code=130) from None

    return wrapper


@contextmanager
def progress_bar(
    description: str, *, line_step: float = 0.1, eta: bool = False
) -> Iterator[Callable[[int, int, str], None]]:
    """A progress bar on stderr; yields ``update(done, total, what)``; with ``eta`` the time
    left too. When stderr is not a terminal (CI logs, pipes), a few plain lines instead
    (:class:`_ProgressLines`)."""
    if not err_console.is_terminal:
        lines = _ProgressLines(description, line_step, eta=eta)
        yield lines.update
        lines.finish()
        return
    from rich.progress import (  # 70 ms of start-up for commands that do not need it
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[what]}"),
        TimeElapsedColumn(),
        *([TextColumn("left"), TimeRemainingColumn()] if eta else []),
        console=err_console,
        transient=True,
    ) as progress:
        task = progress.add_task(description, total=None, what="")

        def update(done: int, total: int, what: str) -> None:
            progress.update(task, completed=done, total=total, what=what)

        yield update


#: Piped progress: at most this many lines for the work's progress (and one at its end)...
PIPED_PROGRESS_LINES = 4
#: ...and, while nothing else is said, one after this long, then after twice as long, ...
PIPED_QUIET_S = 60.0
#: ...and for work of unknown length (a raw stream, a camera), a line this often.
PIPED_UNKNOWN_TOTAL_S = 10.0


class _ProgressLines:
    """:func:`progress_bar`'s plain lines: a line each time another ``line_step`` of the work is
    done (0: every item, a seed say), but no more than :data:`PIPED_PROGRESS_LINES` over the work
    and one at its end; a long silence is broken after :data:`PIPED_QUIET_S`, then after twice as
    long each time, so that a log of any length gets a few lines. Work of unknown length gets a
    line every :data:`PIPED_UNKNOWN_TOTAL_S` and its last update at the end."""

    def __init__(self, description: str, line_step: float, *, eta: bool = False) -> None:
        self.description, self.line_step, self.eta = description, line_step, eta
        self.start = self.t_last = time.monotonic()
        self.done_last = 0
        self.quiet_s = PIPED_QUIET_S
        self.pending: tuple[int, int, str] | None = None  # the last update not printed

    def update(self, done: int, total: int, what: str) -> None:
        now = time.monotonic()
        if done <= self.done_last:
            return
        if total:
            step = max(1.0, self.line_step * total, total / PIPED_PROGRESS_LINES)
            by_work = done >= total or done - self.done_last >= step
            quiet = now - self.t_last >= self.quiet_s
            if quiet and not by_work:
                self.quiet_s *= 2
            due = by_work or quiet
        else:  # no total: every item only when asked (line_step 0), else by the clock
            due = self.line_step == 0 or now - self.t_last >= PIPED_UNKNOWN_TOTAL_S
        if not due:
            self.pending = (done, total, what)
            return
        self._print(done, total, what, now)

    def _print(self, done: int, total: int, what: str, now: float) -> None:
        self.done_last, self.t_last, self.pending = done, now, None
        of = f"/{total}" if total else ""
        took = now - self.start
        left = f", about {took * (total - done) / done:.0f} s left" if self.eta and total else ""
        print(
            f"{self.description}: {done}{of} {what} ({took:.1f} s{left})",
            file=sys.stderr,
            flush=True,
        )

    def finish(self) -> None:
        """The last update, if it was not printed (the end of a stream of unknown length)."""
        if self.pending is not None:
            self._print(*self.pending, time.monotonic())


def check_range(
    value: float, option: str, low: float, high: float, unit: str, *, low_open: bool = False
) -> float:
    """``value`` if it is finite and within ``[low, high]`` (``(low, high]`` when ``low_open``);
    otherwise a :class:`ConfigError` naming ``option`` and its bounds."""
    ok = math.isfinite(value) and (value > low if low_open else value >= low) and value <= high
    if not ok:
        bound = f"{'(' if low_open else '['}{_num(low)}, {_num(high)}]"
        raise ConfigError(f"{option} must be a finite number in {bound} {unit}, got {_num(value)}")
    return value


def _num(x: float) -> str:
    return str(int(x)) if math.isfinite(x) and float(x).is_integer() else f"{x:g}"


RerunConnectOpt = Annotated[
    str | None,
    typer.Option(
        "--rerun-connect",
        help="with or without --rerun: stream the recording to a rerun viewer or server "
        "listening at ADDR too (HOST:PORT or rerun+http://HOST:PORT/proxy, loopback only; "
        "`rerun` listens on 127.0.0.1:9876); nothing listening is one line, the file written",
        metavar="ADDR",
    ),
]
RerunSpawnOpt = Annotated[
    bool,
    typer.Option(
        "--rerun-spawn",
        help="with or without --rerun: open rerun's viewer on the recording when written "
        "(without a display or the viewer, one line says so; the file is written)",
    ),
]


def rerun_request(rerun: bool, connect: str | None, spawn: bool) -> RerunOptions | None:
    """``--rerun``, ``--rerun-connect`` and ``--rerun-spawn`` checked (rerun installed, a
    loopback ADDR); None when none is given."""
    from quadnav.viz.stream import rerun_options

    return rerun_options(rerun, connect, spawn)


def rerun_param(params: CommandParams) -> RerunOptions | None:
    """:func:`rerun_request` of an example's parameters."""
    connect = optional_param(params, "rerun_connect", str) if "rerun_connect" in params else None
    return rerun_request(bool(params.get("rerun")), connect, bool(params.get("rerun_spawn")))


def print_recording(info: RecordingInfo | None = None, run_dir: Path | None = None) -> None:
    """The recording written (``info``, or the one in ``run_dir``), in a line, and what could
    not be done with it (streamed, opened) in another."""
    from quadnav.viz.stream import recording_info

    info = info if info is not None else recording_info(run_dir) if run_dir else None
    if info is None:
        return
    console.print(f"{info.path} ({info.size_bytes / 1e6:.2f} MB)", soft_wrap=True, highlight=False)
    if info.streamed_to and not info.note:
        console.print(f"streamed to {info.streamed_to}", soft_wrap=True, highlight=False)
    if info.note:
        console.print(info.note, soft_wrap=True, highlight=False)


RerunOpt = Annotated[
    bool,
    typer.Option(
        "--rerun",
        help="write the rerun recording of the folder, recording.rrd, into it (quadnav\\[viz]; "
        "as quadnav view, from the finished folder's files)",
    ),
]


def start_recording(options: RerunOptions | None) -> RecordingProcess | None:
    """The child that records the folder the command writes (rerun imported meanwhile)."""
    if options is None:
        return None
    from quadnav.viz.background import RecordingProcess

    return RecordingProcess(options)


def finish_recording(recorder: RecordingProcess | None, folder: Path, kind: str) -> None:
    """The recording of the finished ``folder`` (a ``kind`` of ``quadnav.viz.folders``), said."""
    if recorder is not None:
        print_recording(recorder.record(folder, kind))
