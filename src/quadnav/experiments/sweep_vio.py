"""The sweep's ``vio`` and ``slam`` task kinds: ``quadnav vio`` or ``quadnav slam`` on a built-in
sequence, one seed per task.

A task makes the sequence for its seed and rig (ideal sensors, as ``quadnav vio`` and
``quadnav slam`` make it) in a folder of this process's temporary directory, reused by the next
task of the same sequence, rig, seed and length (a sweep runs every grid point's first seed
first) and removed when another is made, runs the estimator over the span into a temporary
run folder (no video), and returns ``metrics.json``'s numbers flat (``ape_4dof.rmse_m``,
``nees_pose.mean_over_dof``, ``final_error_m`` ...; the SLAM's also ``final.ape_se3.rmse_m``,
its map's final trajectory, as ``final_ape_se3.rmse_m``).
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Self, TypeVar

from pydantic import Field, model_validator

from quadnav.config_model import ConfigModel
from quadnav.errors import ConfigError, GeometryError
from quadnav.eval.na import Metric, na
from quadnav.vio.config import VioConfig

if TYPE_CHECKING:
    from quadnav.io.datasets import VisualInertialDataset
    from quadnav.rig import Rig

ConfigModelT = TypeVar("ConfigModelT", bound=ConfigModel)

__all__ = [
    "SlamTaskConfig",
    "VioTaskConfig",
    "run_slam_task",
    "run_vio_task",
    "slam_task_config",
    "vio_task_config",
]


class _SequenceTask(ConfigModel):
    """What a task on a built-in sequence shares: the sequence, made for the task's seed with
    ``rig``, run over ``duration_s`` from ``start_s``."""

    name: str = "room_easy"
    sequence: str = Field("room_easy", description="a built-in sequence (quadnav dataset list)")
    rig: str = Field("euroc_mono", description="the rig the sequence is made with")
    start_s: float = Field(0.0, ge=0, le=1e6, description="skip this much of the sequence")
    duration_s: float | None = Field(
        None, gt=0, le=1e6, description="seconds to run (None: the whole sequence)"
    )
    seed: int = Field(0, ge=0, description="the first seed (the sweep's --seeds)")

    def _rig_problem(self, rig: Rig) -> str | None:
        """Why the estimator cannot run on ``rig`` (None: it can)."""
        return None

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
        problem = self._rig_problem(rig)
        if problem is not None:
            raise ValueError(problem)
        return self


class VioTaskConfig(_SequenceTask):
    """A sweep's VIO task: a built-in sequence made for the task's seed with ``rig``, the VIO
    (``vio.*``: ``quadnav vio``'s ``--set`` keys) over ``duration_s`` from ``start_s``."""

    vio: VioConfig = VioConfig()

    def _rig_problem(self, rig: Rig) -> str | None:
        if self.vio.stereo and not rig.stereo:
            return f"vio.stereo: rig {self.rig!r} has one camera (rig=euroc or zed)"
        return None


class SlamTaskConfig(_SequenceTask):
    """A sweep's SLAM task: a built-in sequence made for the task's seed with a stereo or RGB-D
    ``rig``, ``quadnav slam``'s settings (``n_features``, ``th_depth_baselines``, ``loop``:
    its ``--features``, ``--th-depth``, ``--loop``) over ``duration_s`` from ``start_s``."""

    rig: str = Field("euroc", description="a stereo (euroc, zed) or RGB-D (rgbd) rig")
    n_features: int = Field(1200, ge=50, le=20000, description="ORB features a frame")
    th_depth_baselines: float = Field(
        40.0, gt=0, le=1e4, description="ThDepth in baselines: nearer points are close"
    )
    loop: bool = Field(True, description="close loops")

    def _rig_problem(self, rig: Rig) -> str | None:
        if not rig.stereo and rig.depth is None:
            return f"rig {self.rig!r}: one camera and no depth (rig=euroc, zed or rgbd)"
        return None


def _sequence_task(
    model: type[ConfigModelT], kind: str, scenario: str, overrides: Sequence[str]
) -> ConfigModelT:
    from quadnav.experiments.datasets import SEQUENCES
    from quadnav.io.config import load_config

    if scenario not in SEQUENCES:
        raise ConfigError(
            f"SCENARIO {scenario!r}: not a built-in sequence of the kind {kind} "
            f"({', '.join(SEQUENCES)})"
        )
    return load_config(model, None, overrides, base={"name": scenario, "sequence": scenario})


def vio_task_config(scenario: str, overrides: list[str] | tuple[str, ...]) -> VioTaskConfig:
    """A built-in sequence's VIO task with overrides."""
    return _sequence_task(VioTaskConfig, "vio", scenario, overrides)


def slam_task_config(scenario: str, overrides: list[str] | tuple[str, ...]) -> SlamTaskConfig:
    """A built-in sequence's SLAM task with overrides."""
    return _sequence_task(SlamTaskConfig, "slam", scenario, overrides)


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


def _sequence(config: VioTaskConfig | SlamTaskConfig, seed: int) -> VisualInertialDataset:
    """The task's sequence, made for ``seed`` (or the one made for the task before)."""
    from quadnav.experiments.odometry_run import resolve_dataset

    key = f"{config.sequence}_{config.rig}_{seed}_{config.start_s}_{config.duration_s}"
    return resolve_dataset(
        config.sequence, seed=seed, rig=config.rig, duration_s=config.duration_s,
        start_s=config.start_s, cache_root=_cache_root(key),
    )  # fmt: skip


def run_vio_task(config: VioTaskConfig, seed: int) -> dict[str, Metric]:
    """One seed: the sequence made (or reused), the VIO over it, its metrics flat."""
    import dataclasses

    from quadnav.experiments.odometry_run import OdometryRunOptions, run_odometry
    from quadnav.experiments.sweep_tasks import flat_metrics
    from quadnav.experiments.vio_run import check_vio_rig
    from quadnav.vio import VioEstimator

    dataset = _sequence(config, seed)
    check_vio_rig(dataset.rig, config.sequence)
    options = OdometryRunOptions(start_s=config.start_s, duration_s=config.duration_s, video=False)

    def make(r: Rig) -> VioEstimator:
        return VioEstimator(r, config.vio, camera=options.camera)

    with tempfile.TemporaryDirectory(prefix="quadnav_sweep_vio_run_") as out:
        run = run_odometry(dataset, dataset.rig, make, Path(out), options=options,
                           name=f"{config.sequence}_s{seed}")  # fmt: skip
    metrics = dataclasses.asdict(run.metrics)
    return flat_metrics(metrics, skip=("drift_definitions",))


def run_slam_task(config: SlamTaskConfig, seed: int) -> dict[str, Metric]:
    """One seed: the sequence made (or reused), ``quadnav slam`` over it, its metrics flat
    (the causal ones, and ``final_*``: its map's final trajectory, not causal)."""
    import dataclasses

    from quadnav.experiments.odometry_run import OdometryRunOptions
    from quadnav.experiments.slam_run import SlamRequest, run_slam_source
    from quadnav.experiments.sweep_tasks import flat_metrics

    dataset = _sequence(config, seed)
    options = OdometryRunOptions(start_s=config.start_s, duration_s=config.duration_s, video=False)
    with tempfile.TemporaryDirectory(prefix="quadnav_sweep_slam_run_") as out:
        request = SlamRequest(
            source=str(dataset.root), options=options, seed=seed, rig=config.rig, out=Path(out),
            n_features=config.n_features, th_depth_baselines=config.th_depth_baselines,
            loop=config.loop,
        )  # fmt: skip
        run = run_slam_source(request)
    metrics: dict[str, object] = dataclasses.asdict(run.metrics)
    for k in ("ape_se3", "ape_sim3"):  # its map's final trajectory (None: too short a run)
        metrics[f"final_{k}"] = run.final[k] if run.final else na("no final trajectory")
    return flat_metrics(metrics, skip=("drift_definitions",))
