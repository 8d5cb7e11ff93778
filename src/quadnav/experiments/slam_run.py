"""``quadnav slam``: the stereo SLAM (:class:`quadnav.slam.SlamOdometry`) over a dataset, through
the runner every visual estimator shares (:func:`~quadnav.experiments.odometry_run.run_odometry`:
the run folder, trajectory, metrics against the ground truth, report). ``load_map`` starts it
on a map saved before (by ``save_map``), ``localization_only`` without adding to it."""

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
    import numpy as np
    from numpy.typing import NDArray

    from quadnav.io.datasets.types import VisualInertialDataset
    from quadnav.odometry import VisualOdometry
    from quadnav.rig import Rig
    from quadnav.slam import SlamConfig, SlamOdometry
    from quadnav.slam.frame import StereoCamera
    from quadnav.slam.map import SlamMap
    from quadnav.slam.odometry import DepthSource

__all__ = ["SlamRequest", "check_slam_request", "run_slam_source"]


@dataclass(frozen=True, slots=True, kw_only=True)
class SlamRequest:
    """One ``quadnav slam`` run: the source, its span and outputs, the seed and rig of a
    built-in sequence, the runs' folder, the SLAM's features and ThDepth, its loop closing
    (``loop``), the map saved at the end (``save_map``) or started on (``load_map``), and
    ``localization_only``."""

    source: str
    options: OdometryRunOptions = field(default_factory=OdometryRunOptions)
    seed: int = 0
    rig: str = "euroc"
    out: Path = Path("runs")
    n_features: int = 1200
    th_depth_baselines: float = 40.0
    loop: bool = True
    save_map: Path | None = None
    load_map: Path | None = None
    localization_only: bool = False


def check_slam_request(request: SlamRequest) -> None:
    """Refuse a bad rig, setting or ``--out`` before any dataset is read or made."""
    from quadnav.errors import QuadnavError

    rig = check_out_and_rig(request.out, request.rig)
    if not rig.stereo and rig.depth is None:
        raise ConfigError(
            f"--rig {request.rig}: one camera and no depth; the SLAM needs a stereo rig (euroc, "
            "zed) or an RGB-D one (rgbd)"
        )
    try:
        _config(request)
    except QuadnavError as exc:
        raise ConfigError(f"--features/--th-depth: {exc}") from None
    if request.localization_only and request.load_map is None:
        raise ConfigError("--localization-only: give the map to localize in (--load-map DIR)")
    if request.localization_only and request.save_map is not None:
        raise ConfigError("--save-map with --localization-only: the map does not change")
    if request.save_map is not None and request.save_map == request.load_map:
        raise ConfigError(f"--save-map {request.save_map}: the map loaded; save to another folder")


def _config(request: SlamRequest) -> SlamConfig:
    from quadnav.slam import SlamConfig
    from quadnav.slam.config import LoopClosingConfig
    from quadnav.vision.orb import OrbConfig

    return SlamConfig(orb=OrbConfig(n_features=request.n_features),
                      th_depth_baselines=request.th_depth_baselines,
                      loop_closing=LoopClosingConfig(enabled=request.loop))  # fmt: skip


def run_slam_source(request: SlamRequest, progress: Progress | None = None) -> OdometryRun:
    """The dataset (made once if a built-in sequence), the SLAM on its rig, into a run folder;
    the map saved at the end if asked."""
    import dataclasses

    import yaml

    opt = request.options
    loaded = None
    if request.load_map is not None:  # (a missing or corrupt map fails before anything is made)
        from quadnav.io.slam_map import load_slam_map

        loaded = load_slam_map(request.load_map)
    dataset = resolve_dataset(
        request.source, seed=request.seed, rig=request.rig, duration_s=opt.duration_s,
        start_s=opt.start_s, cache_root=request.out, progress=progress,
    )  # fmt: skip
    if not dataset.rig.stereo and not dataset.depth:
        raise ConfigError(
            f"{request.source}: one camera and no depth images; the SLAM needs stereo or RGB-D"
        )
    cfg = _config(request)
    settings = yaml.safe_dump(dataclasses.asdict(cfg), sort_keys=False)
    text = f"# dataset: {dataset.root}\n# rig: {dataset.rig.name}\n{settings}"
    source = request.source
    name = Path(source).name if Path(source).exists() else f"{source}_s{request.seed}"
    made: list[SlamOdometry] = []

    depth = _depth_source(dataset) if not dataset.rig.stereo else None

    def make(rig: Rig) -> VisualOdometry:
        made.append(_slam(request, rig, cfg, loaded, depth))
        return made[-1]

    run = run_odometry(
        dataset, dataset.rig, make, request.out, config_text=text,
        options=replace(opt, video=False, save_map=None), name=name, kind="slam",
        progress=progress,
    )  # fmt: skip
    if request.save_map is not None and made:
        from quadnav.io.slam_map import save_slam_map

        save_slam_map(request.save_map, made[0].slam_map, made[0].camera)
    return run


def _depth_source(dataset: VisualInertialDataset) -> DepthSource:
    """The dataset's depth image at a time (None where it has none)."""
    by_t = {d.t_ns: d for d in dataset.depth}

    def depth(t_ns: int) -> NDArray[np.floating] | None:
        d = by_t.get(t_ns)
        return None if d is None else d.depth_m()

    return depth


def _slam(
    request: SlamRequest, rig: Rig, cfg: SlamConfig, loaded: tuple[SlamMap, StereoCamera] | None,
    depth: DepthSource | None,
) -> SlamOdometry:  # fmt: skip
    from quadnav.errors import SlamError
    from quadnav.slam import SlamOdometry

    if loaded is None:
        return SlamOdometry(rig, cfg, depth=depth)
    try:
        return SlamOdometry(rig, cfg, slam_map=loaded[0], map_camera=loaded[1],
                            mapping=not request.localization_only, depth=depth)  # fmt: skip
    except SlamError as exc:
        raise SlamError(f"--load-map {request.load_map}: {exc}") from None
