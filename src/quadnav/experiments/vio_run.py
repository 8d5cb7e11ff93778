"""``quadnav vio``: the VIO's settings (our YAML or VINS-Mono's) on a dataset's rig, and
:class:`quadnav.vio.VioEstimator` run over it by the one odometry runner
(:mod:`quadnav.experiments.odometry_run`)."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel

from quadnav.errors import ConfigError
from quadnav.experiments.odometry_run import (
    OdometryRun,
    OdometryRunOptions,
    Progress,
    check_out_and_rig,
    resolve_dataset,
    run_odometry,
)
from quadnav.io.config import load_config
from quadnav.odometry import VisualOdometry
from quadnav.rig import Rig
from quadnav.units import ns_to_s
from quadnav.viz.background import RecordingProcess
from quadnav.viz.odometry_capture import capture_if
from quadnav.viz.recording import require_rerun
from quadnav.viz.stream import RerunOptions

__all__ = [
    "VioRequest",
    "check_request",
    "check_vio_rig",
    "resolve_vio_config",
    "run_vio_source",
]

M = TypeVar("M", bound=BaseModel)


def _is_vins_yaml(path: Path) -> bool:
    try:
        head = path.read_text(encoding="utf-8", errors="replace")[:4000]
    except OSError as exc:
        raise ConfigError(f"--config {path}: cannot be read ({exc.strerror})") from None
    return head.lstrip().startswith("%YAML") or "extrinsicRotation" in head


def resolve_vio_config(
    model: type[M],
    config: Path | None,
    overrides: Iterable[str],
    dataset_rig: Rig,
    *,
    camera: str = "cam0",
) -> tuple[M, Rig]:
    """The estimator's settings (``model``, e.g. ``VioConfig``) and the rig it runs on: from
    VINS-Mono's YAML (its camera, extrinsic and IMU noise replace the dataset's calibration;
    its front end, ``g_norm``, ``estimate_td`` and ``td`` set those fields), from our own YAML
    of ``model``'s fields (unknown keys refused), or the defaults on the dataset's calibration."""
    if config is not None and not config.is_file():
        raise ConfigError(f"--config {config}: no such file")
    rig = dataset_rig
    if config is not None and _is_vins_yaml(config):
        from quadnav.io.vins_config import read_vins_config

        cam = dataset_rig.camera(camera) if camera in dataset_rig.camera_names else None
        imu_rate = dataset_rig.imu.rate_hz if dataset_rig.imu is not None else 200.0
        vins = read_vins_config(
            config, imu_rate_hz=imu_rate, camera_rate_hz=cam.rate_hz if cam else 20.0
        )
        only = dataclasses.replace(vins.rig.cameras[0], name=camera)  # the camera it describes
        rig = dataclasses.replace(vins.rig, cameras=(only,))
        known = model.model_fields
        values: dict[str, object] = {
            "tracker": vins.tracker.model_dump(), "g_norm": vins.g_norm_m_s2,
            "estimate_td": vins.estimate_td, "td_s": ns_to_s(rig.cameras[0].time_offset_ns),
        }  # fmt: skip
        base = {k: v for k, v in values.items() if k in known}
        return load_config(model, None, overrides, base=base), rig
    return load_config(model, config, overrides), rig


def check_vio_rig(rig: Rig, source: str) -> None:
    """Refuse a rig VIO cannot run on: no IMU, or no IMU noise (what a bag without its
    calibration gives, whose camera extrinsic is then unknown too)."""
    n = rig.imu.noise if rig.imu is not None else None
    if n is None or n.gyro_noise_density <= 0.0 or n.accel_noise_density <= 0.0:
        raise ConfigError(
            f"DATASET {source}: its files give no IMU noise (a bag without calibration?): "
            "give --calibration (a Kalibr camchain or an EuRoC folder) or --config "
            "(VINS-Mono's YAML)"
        )


# -- the command's request ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True, kw_only=True)
class VioRequest:
    """What ``quadnav vio`` was asked: the datasets (folders, bags or built-in sequence names),
    the estimator's configuration file and ``--set`` overrides, the span and outputs, the seed
    (``seeds`` for a study), the rig a built-in sequence is made with, the runs' folder, and
    whether loop closure runs on the odometry (``loop``), with ``--loop-set`` overrides
    (``loop_overrides``), on a map saved before (``load_map``; ``options.save_map`` saves one)."""

    sources: tuple[str, ...]
    config: Path | None = None
    overrides: tuple[str, ...] = ()
    options: OdometryRunOptions = field(default_factory=OdometryRunOptions)
    seed: int = 0
    seeds: tuple[int, ...] | None = None
    rig: str = "euroc_mono"
    out: Path = Path("runs")
    calibration: Path | None = None
    loop: bool = False
    load_map: Path | None = None
    loop_overrides: tuple[str, ...] = ()
    #: write the run's rerun recording (``recording.rrd``, with ``viz.npz``) into its folder
    rerun: RerunOptions | None = None


def check_request(request: VioRequest) -> None:
    """Refuse a bad configuration, ``--set``, rig or ``--out`` before any dataset is read or
    made."""
    from quadnav.vio import VioConfig

    if request.rerun:
        require_rerun("--rerun")
    rig = check_out_and_rig(request.out, request.rig)
    cfg, _ = resolve_vio_config(VioConfig, request.config, request.overrides, rig)
    if request.loop_overrides:
        from quadnav.loop.settings import loop_config_with

        loop_config_with(request.loop_overrides)
    several = len(request.sources) > 1 or (request.seeds is not None and len(request.seeds) > 1)
    if request.options.save_map is not None and several:
        raise ConfigError(
            f"--save-map {request.options.save_map}: one run saves one map; give one dataset "
            "and one seed"
        )

    from quadnav.experiments.datasets import SEQUENCES

    builtin = [s for s in request.sources if s in SEQUENCES and not Path(s).exists()]
    if cfg.stereo and not rig.stereo and builtin:
        raise ConfigError(
            f"--stereo: rig {request.rig!r} has one camera; a built-in sequence needs a stereo "
            "rig (--rig euroc or zed)"
        )


def run_vio_source(
    request: VioRequest, source: str, seed: int, out: Path, progress: Progress | None = None
) -> OdometryRun:
    """One run of ``quadnav vio``: the dataset, the configuration on its rig, VINS-Mono-class
    :class:`quadnav.vio.VioEstimator` over it, into a run folder under ``out``."""
    from quadnav.io.config import dump_config
    from quadnav.vio import VioConfig, VioEstimator

    opt = request.options
    loop_map = None
    if request.load_map is not None:  # a missing or corrupt map fails before anything is made
        from quadnav.io.loop_map import load_loop_map

        loop_map = load_loop_map(request.load_map)
    dataset = resolve_dataset(
        source, seed=seed, rig=request.rig, duration_s=opt.duration_s, start_s=opt.start_s,
        cache_root=request.out, calibration=request.calibration, progress=progress,
    )  # fmt: skip
    cfg, rig = resolve_vio_config(
        VioConfig, request.config, request.overrides, dataset.rig, camera=opt.camera
    )
    check_vio_rig(rig, source)
    if cfg.final_smoothing and request.load_map is not None:
        raise ConfigError(
            "final_smoothing: not with --load-map (the run reports in the map's frame, which "
            "the smoothing does not hold); --save-map --final-ba saves the smoothed keyframes"
        )
    text = f"# dataset: {dataset.root}\n# rig: {rig.name}\n{dump_config(cfg)}"
    name = Path(source).name if Path(source).exists() else f"{source}_s{seed}"

    def make(r: Rig) -> VisualOdometry:
        vio = VioEstimator(r, cfg, camera=opt.camera)
        if not request.loop:
            return vio
        from quadnav.errors import LoopError
        from quadnav.loop import LoopClosure
        from quadnav.loop.settings import loop_config_with

        config = loop_config_with(request.loop_overrides)
        try:
            return LoopClosure(vio, r.camera(opt.camera), config=config, loop_map=loop_map)
        except LoopError as exc:
            raise LoopError(f"--load-map {request.load_map}: {exc}") from None

    recorder = RecordingProcess(request.rerun) if request.rerun else None  # imports rerun meanwhile
    run = run_odometry(
        dataset, rig, make, out, config_text=text, options=opt, name=name,
        progress=progress, observer=capture_if(request.rerun is not None),
    )  # fmt: skip
    if recorder is not None:  # from the folder's files and viz.npz, as quadnav view would
        recorder.record(run.run_dir, "odometry")
    return run
