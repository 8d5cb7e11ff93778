"""The ``quadnav`` command."""

from __future__ import annotations

import typer

from quadnav.cli.calibrate import calibrate_command
from quadnav.cli.eval import eval_command
from quadnav.cli.link import link_app
from quadnav.cli.markers import markers_command
from quadnav.cli.planar import planar_command
from quadnav.cli.replay import replay_command
from quadnav.cli.run import run_command
from quadnav.cli.sim import sim_command

__all__ = ["app", "main"]

app = typer.Typer(
    name="quadnav",
    help="GPS-denied quadrotor navigation: simulate, estimate with delayed measurements, evaluate.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
app.command("run")(run_command)
app.command("planar")(planar_command)
app.command("eval")(eval_command)
app.command("sim")(sim_command)
app.command("markers")(markers_command)
app.command("calibrate")(calibrate_command)
app.command("replay")(replay_command)
app.add_typer(link_app, name="link")


def main() -> None:
    app()
