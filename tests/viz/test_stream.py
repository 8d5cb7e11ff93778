"""Issue 27, part 3: ``--rerun-connect ADDR`` and ``--rerun-spawn``: a bad or remote ADDR is one
line naming the option before the run; nothing listening, or no display, is one line after it
and the file is written all the same; a real stream reaches a rerun server on 127.0.0.1 (the
viewer binary saving what it receives, headless) with the rows of the file."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
from typer.testing import CliRunner

from quadnav.cli.main import app
from quadnav.errors import VizError
from quadnav.viz.stream import listening_problem, rerun_url

pytest.importorskip("rerun")

from rerun.chunk import RrdReader

from tests.viz.rrd import rows_and_static

runner = CliRunner()
SIM = ["sim", "thesis002_pd_stabilization", "--set", "duration_s=1"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_addresses_become_rerun_urls_and_bad_ones_one_line() -> None:
    assert rerun_url("127.0.0.1:9876") == "rerun+http://127.0.0.1:9876/proxy"
    assert rerun_url("localhost:1234") == "rerun+http://localhost:1234/proxy"
    assert rerun_url("rerun+http://[::1]:9876/proxy") == "rerun+http://[::1]:9876/proxy"
    bad = {
        "10.0.0.1:9876": "not a loopback address",
        "example.com:9876": "not a loopback address",
        "127.0.0.1": "give HOST:PORT",
        "127.0.0.1:70000": "out of range",
        "http://127.0.0.1:9876": "the scheme is not one of",
        "rerun+http://127.0.0.1:9876/x": "the path of a rerun gRPC URL is /proxy",
    }
    for addr, why in bad.items():
        with pytest.raises(VizError) as err:
            rerun_url(addr)
        assert str(err.value).startswith(f"--rerun-connect {addr}: ") and why in str(err.value)
        assert "\n" not in str(err.value)


def test_a_bad_address_stops_every_command_before_it_runs(tmp_path: Path) -> None:
    for args in (SIM, ["run"], ["replay", "x.ulg"], ["view", str(tmp_path)]):
        option = "--connect" if args[0] == "view" else "--rerun-connect"
        result = runner.invoke(app, [*args, option, "192.168.1.2:9876", "--out", str(tmp_path / "o.rrd" if args[0] == "view" else tmp_path)])  # fmt: skip
        assert result.exit_code == 2, result.output
        lines = result.stderr.strip().splitlines()
        assert lines == [f"error: {option} 192.168.1.2:9876: 192.168.1.2 is not a loopback "
                         "address (127.0.0.1, ::1, localhost); only loopback"]  # fmt: skip
    assert not any(p.is_dir() for p in tmp_path.iterdir())  # nothing flown, no run folder


def test_nothing_listening_or_no_display_is_a_line_and_the_file_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    port = _free_port()
    assert listening_problem(f"rerun+http://127.0.0.1:{port}/proxy") is not None
    args = [*SIM, "--rerun-connect", f"127.0.0.1:{port}", "--rerun-spawn", "--out", str(tmp_path)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    (folder,) = [p for p in tmp_path.iterdir() if p.is_dir()]  # --rerun implied
    rows, _ = rows_and_static(folder / "recording.rrd")
    assert rows["/world/flown"] == 101
    out = result.stdout.replace("\n", " ")
    assert (
        f"--rerun-connect 127.0.0.1:{port}: connection refused; the recording is in the file" in out
    )
    assert "--rerun-spawn: no display (DISPLAY, WAYLAND_DISPLAY unset)" in out


def _viewer() -> str | None:
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() else None


def _wait_listening(port: int, proc: subprocess.Popen[bytes], seconds: float = 20.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end and proc.poll() is None:
        if listening_problem(f"rerun+http://127.0.0.1:{port}/proxy") is None:
            return True
        time.sleep(0.2)
    return False


def _stop(server: subprocess.Popen[bytes], seconds: float = 60.0) -> None:
    """Ctrl-C to the server, which saves what it received and exits; a loaded machine (CI's
    two workers) has taken over 20 s, and once more than 60. Then a second Ctrl-C, and at
    last a kill: what the server saved by then is what the test checks (every row sent)."""
    for sig, wait_s in ((signal.SIGINT, seconds), (signal.SIGINT, 10.0), (signal.SIGKILL, 10.0)):
        server.send_signal(sig)
        try:
            server.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue


def test_a_run_streams_its_recording_to_a_server_on_loopback(tmp_path: Path) -> None:
    viewer = _viewer()
    if viewer is None:
        pytest.skip("rerun's viewer binary is not installed beside this Python (rerun-sdk's)")
    port, got = _free_port(), tmp_path / "received.rrd"
    server = subprocess.Popen(
        [viewer, "--bind", "127.0.0.1", "--port", str(port), "--save", str(got)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env={**os.environ, "RUST_LOG": "warn"},
    )  # fmt: skip
    try:
        if not _wait_listening(port, server):
            pytest.skip(f"rerun --save did not listen on 127.0.0.1:{port} here")
        args = [*SIM, "--rerun-connect", f"127.0.0.1:{port}", "--out", str(tmp_path / "runs")]
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        assert f"streamed to rerun+http://127.0.0.1:{port}/proxy" in result.stdout
        time.sleep(1.0)
    finally:
        _stop(server)
    (folder,) = [p for p in (tmp_path / "runs").iterdir() if p.is_dir()]
    written, _ = rows_and_static(folder / "recording.rrd")
    with warnings.catch_warnings():  # (a streamed file may have no footer: read whole)
        warnings.simplefilter("ignore")
        received, static = rows_and_static(got)
        assert RrdReader(got).blueprints()  # the layout went with the stream
    assert RrdReader(folder / "recording.rrd").blueprints()  # and into the file
    assert received == written and written["/world/flown"] == 101
    assert "/world/trajectories/flown" in static
