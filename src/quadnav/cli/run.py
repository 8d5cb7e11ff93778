"""``quadnav run``: the main job, with a built-in default scenario."""

from __future__ import annotations

from pathlib import Path

from quadnav.cli.common import handle_errors
from quadnav.cli.planar import ConfigArg, JobsOpt, OutOpt, SeedsOpt, SetOpt, run_planar_from_cli

__all__ = ["run_command"]


@handle_errors
def run_command(
    scenario: ConfigArg = None,
    set_: SetOpt = None,
    seeds: SeedsOpt = None,
    out: OutOpt = Path("runs"),
    jobs: JobsOpt = None,
) -> None:
    """Run the main job. With no arguments: the planar delayed-measurement experiment.

    Until the 3-D navigation filter lands, the default scenario is thesis 000's planar
    experiment (the same as `quadnav planar`); SCENARIO is a YAML config for it.

    Examples:

      quadnav run

      quadnav run --seeds 20 --out /tmp/runs
    """
    run_planar_from_cli(scenario, set_, seeds, out, jobs)
