"""The link commands' options: `quadnav link serial` and `quadnav sim --mavlink` take only
finite numbers within their stated bounds, bind loopback unless --allow-remote, and read the
signing key from a file or the environment (the command line shows it in `ps`)."""

from __future__ import annotations

import os
import re
import socket
import threading
import time
from pathlib import Path

from typer.testing import CliRunner, Result

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink: MAVLink 2, which signs
from pymavlink import mavutil

from quadnav.cli.main import app
from tests.loopback import free_port
from tests.loopback import no_remote_bind as no_remote_bind_fixture

no_remote_bind = no_remote_bind_fixture  # the fixture, for the tests below
runner = CliRunner()


def one_line_error(res: Result, fragment: str) -> None:
    assert res.exit_code == 2, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], res.stderr


def test_link_serial_rate_and_baud_must_be_finite_and_bounded(tmp_path: Path) -> None:
    """Over a real pseudo-terminal (so nothing else stops the command first): --rate -1, nan,
    inf or above 1000 and --baud 0, negative or above 4000000 are refused naming the option."""
    traj = tmp_path / "t.tum"
    traj.write_text("".join(f"{k * 0.1:.1f} {k} 0 1 0 0 0 1\n" for k in range(3)))
    master, slave = os.openpty()
    try:
        port = os.ttyname(slave)
        for opt, value in (("--rate", "-1"), ("--rate", "nan"), ("--rate", "inf"),
                           ("--rate", "1001"), ("--baud", "0"), ("--baud", "-9600"),
                           ("--baud", "99999999")):  # fmt: skip
            res = runner.invoke(app, ["link", "serial", port, "--from", str(traj), opt, value])
            one_line_error(res, f"{opt} must be a finite number in")
        ok = runner.invoke(app, ["link", "serial", port, "--from", str(traj), "--rate", "1000",
                                 "--baud", "9600"])  # fmt: skip
        assert ok.exit_code == 0, ok.output
        assert "3 frames sent" in ok.stdout
    finally:
        os.close(slave)
        os.close(master)


def test_sim_mavlink_duration_must_be_finite_and_positive() -> None:
    """--duration -5 used to exit 0 at once and nan to run until killed: both, 0, inf and more
    than a day are refused naming --duration, before anything binds the port."""
    port = free_port()
    url = f"udpin:127.0.0.1:{port}"
    for value in ("-5", "nan", "0", "inf", "1e9"):  # -5 first: before the fix nan never returns
        res = runner.invoke(app, ["sim", "--mavlink", url, "--duration", value])
        one_line_error(res, "--duration must be a finite number in (0, 86400] seconds")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", port))  # still free: the refusals bound nothing
    one_line_error(runner.invoke(app, ["sim", "--duration", "5"]), "only with --mavlink")


def test_sim_refuses_a_remote_bind_without_allow_remote(no_remote_bind: list[object]) -> None:
    port = free_port()
    for url in (f"udpin:0.0.0.0:{port}", f"udpin::{port}"):
        res = runner.invoke(app, ["sim", "--mavlink", url, "--duration", "1"])
        one_line_error(res, "--allow-remote")
    assert all(a[1] != port for a in no_remote_bind if isinstance(a, tuple))


def run_signed_sitl(args: list[str], key: bytes, env: dict[str, str] | None = None) -> Result:
    """`quadnav sim --mavlink` for 3 s in a thread, with a client that signs with ``key`` and
    needs the vehicle's signed telemetry back: the command's result once the client has it."""
    port = free_port()
    box: list[Result] = []
    cmd = ["sim", "--mavlink", f"udpin:127.0.0.1:{port}", "--duration", "3", *args]
    th = threading.Thread(target=lambda: box.append(runner.invoke(app, cmd, env=env)))
    th.start()
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
    gcs.setup_signing(key, sign_outgoing=True)
    got = None
    t_end = time.monotonic() + 10.0
    while got is None and time.monotonic() < t_end:
        gcs.mav.heartbeat_send(
            mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
        )
        got = gcs.recv_match(type="ATTITUDE", blocking=True, timeout=0.2)
    gcs.close()
    th.join(timeout=15)
    assert not th.is_alive() and box, "the command did not finish"
    assert got is not None and got.get_signed(), box[0].output  # signed with our key
    return box[0]


def test_sim_reads_the_signing_key_from_a_file_or_the_environment(tmp_path: Path) -> None:
    key = bytes(range(50, 82))
    f = tmp_path / "mavlink.key"
    f.write_text(key.hex() + "\n")
    f.chmod(0o600)
    for args, env in (
        (["--signing-key-file", str(f)], None),
        ([], {"QUADNAV_SIGNING_KEY": key.hex()}),
    ):
        res = run_signed_sitl(args, key, env)
        assert res.exit_code == 0, res.output
        assert "(signed)" in res.stdout and "refused unsigned 0" in res.stdout
        assert key.hex() not in " ".join(args) and res.stderr == ""  # nothing to warn about
        assert "no peer heard" not in res.stdout and "no peer connected" not in res.stdout
    res = run_signed_sitl(["--signing-key", key.hex()], key)  # still works, with a warning
    assert res.exit_code == 0, res.output
    assert (
        "warning: --signing-key shows the key" in res.stderr and "--signing-key-file" in res.stderr
    )


def test_markers_companion_refuses_a_remote_bind_before_reading_anything(
    no_remote_bind: list[object], tmp_path: Path
) -> None:
    """The check comes first: no source, camera or run folder is needed to be refused, none
    is written, and --allow-remote is named (the markers command has it too)."""
    res = runner.invoke(app, ["markers", str(tmp_path / "absent.mp4"), "--out", str(tmp_path / "runs"),
                              "--mavlink", "udpin:0.0.0.0:14540"])  # fmt: skip
    one_line_error(res, "--allow-remote")
    assert no_remote_bind == [] and not (tmp_path / "runs").exists()


def test_a_second_sitl_vehicle_on_a_port_in_use_fails_clearly() -> None:
    from quadnav.io.mavlink import MavlinkLink

    port = free_port()
    first = MavlinkLink(f"udpin:127.0.0.1:{port}", system=1, component=1)
    try:
        res = runner.invoke(app, ["sim", "--mavlink", f"udpin:127.0.0.1:{port}", "--duration", "1"])
        one_line_error(res, f"port {port} is already in use")
    finally:
        first.close()


def test_a_bad_signing_key_is_one_line_naming_where_it_came_from(tmp_path: Path) -> None:
    url = f"udpin:127.0.0.1:{free_port()}"
    short = tmp_path / "short.key"
    short.write_text("ab" * 31)
    for args, env, fragment in (
        (["--signing-key", "abc"], None, "--signing-key: the signing key must be 64 hexadecimal"),
        (["--signing-key-file", str(short)], None, f"--signing-key-file {short}: the signing key"),
        (["--signing-key-file", str(tmp_path / "nope")], None, "cannot read it"),
        (["--signing-key-file", str(short), "--signing-key", "ab" * 32], None, "not both"),
        ([], {"QUADNAV_SIGNING_KEY": "not hex"}, "QUADNAV_SIGNING_KEY: the signing key"),
    ):
        res = runner.invoke(app, ["sim", "--mavlink", url, "--duration", "1", *args], env=env)
        one_line_error(res, fragment)  # (no warning line before the error either)


def test_a_mavlink_port_out_of_range_is_one_line_naming_mavlink(
    frames: tuple[Path, Path, list[object]], tmp_path: Path
) -> None:
    """Issue 21, item 4: `markers --mavlink udpout:127.0.0.1:99999` was pymavlink's
    OverflowError traceback after the first frame, and port 0 "sent" 82 messages to nowhere.
    Every endpoint's port is checked where endpoints are parsed, before anything runs: markers
    and run (a VIO scenario) refuse it naming --mavlink, and write no run folder."""
    folder, cal, _ = frames
    out = tmp_path / "runs"
    for url in ("udpout:127.0.0.1:99999", "udpout:127.0.0.1:0", "tcp:127.0.0.1:65536",
                "udpin:127.0.0.1:0", "udpout::14540", "udpout:127.0.0.1:port"):  # fmt: skip
        res = runner.invoke(app, ["markers", str(folder), "--camera", str(cal), "--out", str(out),
                                  "--mavlink", url])  # fmt: skip
        one_line_error(res, f"--mavlink {url!r}: ")
        assert "PORT from 1 to 65535" in res.stderr
        res = runner.invoke(
            app, ["run", "indoor_vio_odometry", "--out", str(out), "--mavlink", url]
        )
        one_line_error(res, f"--mavlink {url!r}: ")
    assert not out.exists()
    ok = runner.invoke(app, ["markers", str(folder), "--camera", str(cal), "--out", str(out),
                             "--mavlink", f"udpout:127.0.0.1:{free_port()}"])  # fmt: skip
    assert ok.exit_code == 0, ok.output


def test_a_key_file_other_users_may_read_is_used_with_an_ssh_style_warning(tmp_path: Path) -> None:
    """Issue 21, item 14: a world-readable signing key file was taken silently. As ssh does
    for a private key, one line on stderr names the file and its mode (mode 0600: none)."""
    key = bytes(range(90, 122))
    f = tmp_path / "shared.key"
    f.write_text(key.hex() + "\n")
    f.chmod(0o644)
    res = run_signed_sitl(["--signing-key-file", str(f)], key)
    assert res.exit_code == 0, res.output
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "UNPROTECTED KEY FILE" in lines[0], res.stderr
    assert f"{f} has mode 0644" in lines[0] and "chmod 600" in lines[0]


def test_sim_says_when_no_peer_heard_what_it_sent() -> None:
    """Issue 21, item 14: `sim --mavlink` said "sent 1500" with nobody there. A listener with
    no peer sends nothing (and says how many it could not send); a UDP sender that hears
    nothing back says "(no peer heard)"."""
    res = runner.invoke(app, ["sim", "--mavlink", f"udpin:127.0.0.1:{free_port()}", "--duration", "0.5"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert re.search(r"sent 0 \(\d+ not sent: no peer connected\), received 0", res.stdout)
    res = runner.invoke(app, ["sim", "--mavlink", f"udpout:127.0.0.1:{free_port()}", "--duration", "0.5"])  # fmt: skip
    assert res.exit_code == 0, res.output
    assert "(no peer heard), received 0" in res.stdout and "sent 0" not in res.stdout


def test_run_says_when_no_peer_heard_the_odometry_it_sent(tmp_path: Path) -> None:
    """Issue 21, item 14: `run indoor_vio_odometry --mavlink udpout:...` said "sent N ODOMETRY"
    with nobody listening. As `sim` and `markers` do, it now says no peer heard them."""
    url = f"udpout:127.0.0.1:{free_port()}"
    args = ["run", "indoor_vio_odometry", "--out", str(tmp_path), "--mavlink", url,
            "--set", "plan.duration_s=4", "--set", "plan.height_m=1", "--set", "plan.forward_m=1"]  # fmt: skip
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    line = next(x for x in res.stdout.splitlines() if x.startswith("MAVLink to"))
    assert re.search(r"\d+ ODOMETRY", line), line
    assert re.search(r"sent [1-9]\d* \(no peer heard\), received 0", line), line
