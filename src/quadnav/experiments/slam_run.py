"""``quadnav slam``: the stereo SLAM (:class:`quadnav.slam.SlamOdometry`) over a dataset, through
the runner every visual estimator shares (:func:`~quadnav.experiments.odometry_run.run_odometry`:
the run folder, trajectory, metrics against the ground truth, report)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

from quadnav.errors import ConfigError
from quadnav.experiments.odometry_run import (
    OdometryRun,
    OdometryRunOptions,
    Progress,
    check_out_and_rig,
    resolve_dataset,
    run_odometry,
)

if TYPE_CHECKING:
    from quadnav.slam import SlamConfig

__all__ = ["SlamRequest", "check_slam_request", "run_slam_source"]


@dataclass(frozen=True, slots=True, kw_only=True)
class SlamRequest:
    """One ``quadnav slam`` run: the source, its span and outputs, the seed and rig of a
    built-in sequence, the runs' folder, and the SLAM's features and ThDepth."""

    source: str
    options: OdometryRunOptions = field(default_factory=OdometryRunOptions)
    seed: int = 0
    rig: str = "euroc"
    out: Path = Path("runs")
    n_features: int = 1200
    th_depth_baselines: float = 40.0


def check_slam_request(request: SlamRequest) -> None:
    """Refuse a bad rig, setting or ``--out`` before any dataset is read or made."""
    from quadnav.errors import QuadnavError

    rig = check_out_and_rig(request.out, request.rig)
    if not rig.stereo:
        raise ConfigError(
            f"--rig {request.rig}: one camera; the stereo SLAM needs two (euroc, zed)"
        )
    try:
        _config(request)
    except QuadnavError as exc:
        raise ConfigError(f"--features/--th-depth: {exc}") from None


def _config(request: SlamRequest) -> SlamConfig:
    from quadnav.slam import SlamConfig
    from quadnav.vision.orb import OrbConfig

    return SlamConfig(orb=OrbConfig(n_features=request.n_features),
                      th_depth_baselines=request.th_depth_baselines)  # fmt: skip


def run_slam_source(request: SlamRequest, progress: Progress | None = None) -> OdometryRun:
    """The dataset (made once if a built-in sequence), the SLAM on its rig, into a run folder."""
    import dataclasses

    import yaml

    from quadnav.rig import Rig
    from quadnav.slam import SlamOdometry

    opt = request.options
    dataset = resolve_dataset(
        request.source, seed=request.seed, rig=request.rig, duration_s=opt.duration_s,
        start_s=opt.start_s, cache_root=request.out, progress=progress,
    )  # fmt: skip
    if not dataset.rig.stereo:
        raise ConfigError(f"{request.source}: its rig has one camera; the stereo SLAM needs two")
    cfg = _config(request)
    settings = yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False)
    text = f"# dataset: {dataset.root}\n# rig: {dataset.rig.name}\n{settings}"
    source = request.source
    name = Path(source).name if Path(source).exists() else f"{source}_s{request.seed}"

    def make(rig: Rig) -> SlamOdometry:
        return SlamOdometry(rig, cfg)

    return run_odometry(
        dataset, dataset.rig, make, request.out, config_text=text,
        options=replace(opt, video=False), name=name, kind="slam", progress=progress,
    )  # fmt: skip
