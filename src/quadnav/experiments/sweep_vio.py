"""The sweep's ``vio`` task kind: ``quadnav vio`` on a built-in sequence, one seed per task.

A task makes the sequence for its seed and rig (ideal sensors, as ``quadnav vio`` makes it)
in a folder of this process's temporary directory, reused by the next task of the same
sequence, rig, seed and length (a sweep runs every grid point's first seed first) and
removed when another is made, runs :class:`quadnav.vio.VioEstimator` over the span into a
temporary run folder (no video), and returns ``metrics.json``'s numbers flat
(``ape_4dof.rmse_m``, ``nees_pose.mean_over_dof``, ``final_error_m`` ...).
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path
from typing import Self

from pydantic import Field, model_validator

from quadnav.config_model import ConfigModel
from quadnav.errors import ConfigError, GeometryError
from quadnav.eval.na import Metric
from quadnav.vio.config import VioConfig

__all__ = ["VioTaskConfig", "run_vio_task", "vio_task_config"]


class VioTaskConfig(ConfigModel):
    """A sweep's VIO task: a built-in sequence made for the task's seed with ``rig``, the VIO
    (``vio.*``: ``quadnav vio``'s ``--set`` keys) over ``duration_s`` from ``start_s``."""

    name: str = "room_easy"
    sequence: str = Field("room_easy", description="a built-in sequence (quadnav dataset list)")
    rig: str = Field("euroc_mono", description="the rig the sequence is made with")
    start_s: float = Field(0.0, ge=0, le=1e6, description="skip this much of the sequence")
    duration_s: float | None = Field(
        None, gt=0, le=1e6, description="seconds to run (None: the whole sequence)"
    )
    seed: int = Field(0, ge=0, description="the first seed (the sweep's --seeds)")
    vio: VioConfig = VioConfig()

    @model_validator(mode="after")
    def _known(self) -> Self:
        from quadnav.experiments.datasets import SEQUENCES
        from quadnav.rig import rig_named

        if self.sequence not in SEQUENCES:
            raise ValueError(f"sequence {self.sequence!r}: choose from {', '.join(SEQUENCES)}")
        try:
            rig = rig_named(self.rig)
        except GeometryError as exc:
            raise ValueError(f"rig: {exc}") from None
        if self.vio.stereo and not rig.stereo:
            raise ValueError(f"vio.stereo: rig {self.rig!r} has one camera (rig=euroc or zed)")
        return self


def vio_task_config(scenario: str, overrides: list[str] | tuple[str, ...]) -> VioTaskConfig:
    """A built-in sequence's VIO task with overrides."""
    from quadnav.experiments.datasets import SEQUENCES
    from quadnav.io.config import load_config

    if scenario not in SEQUENCES:
        raise ConfigError(
            f"SCENARIO {scenario!r}: not a built-in sequence of the kind vio "
            f"({', '.join(SEQUENCES)})"
        )
    return load_config(
        VioTaskConfig, None, overrides, base={"name": scenario, "sequence": scenario}
    )


#: This process's sequence made last: (its key, its folder's parent).
_MADE: dict[str, tuple[str, Path]] = {}


def _cache_root(key: str) -> Path:
    """The folder the sequence of ``key`` is made in (the one made before, for the same key);
    another key's is removed first."""
    made = _MADE.get("last")
    if made is not None and made[0] == key:
        return made[1]
    if made is not None:
        shutil.rmtree(made[1], ignore_errors=True)
    root = Path(tempfile.mkdtemp(prefix="quadnav_sweep_vio_"))
    atexit.register(shutil.rmtree, root, True)
    _MADE["last"] = (key, root)
    return root


def run_vio_task(config: VioTaskConfig, seed: int) -> dict[str, Metric]:
    """One seed: the sequence made (or reused), the VIO over it, its metrics flat."""
    import dataclasses

    from quadnav.experiments.odometry_run import OdometryRunOptions, resolve_dataset, run_odometry
    from quadnav.experiments.sweep_tasks import flat_metrics
    from quadnav.experiments.vio_run import check_vio_rig
    from quadnav.rig import Rig
    from quadnav.vio import VioEstimator

    key = f"{config.sequence}_{config.rig}_{seed}_{config.start_s}_{config.duration_s}"
    dataset = resolve_dataset(
        config.sequence, seed=seed, rig=config.rig, duration_s=config.duration_s,
        start_s=config.start_s, cache_root=_cache_root(key),
    )  # fmt: skip
    check_vio_rig(dataset.rig, config.sequence)
    options = OdometryRunOptions(start_s=config.start_s, duration_s=config.duration_s, video=False)

    def make(r: Rig) -> VioEstimator:
        return VioEstimator(r, config.vio, camera=options.camera)

    with tempfile.TemporaryDirectory(prefix="quadnav_sweep_vio_run_") as out:
        run = run_odometry(dataset, dataset.rig, make, Path(out), options=options,
                           name=f"{config.sequence}_s{seed}")  # fmt: skip
    metrics = dataclasses.asdict(run.metrics)
    return flat_metrics(metrics, skip=("drift_definitions",))
