"""Visual-inertial datasets: one type (:class:`VisualInertialDataset`) read from EuRoC ASL and
TUM-VI folders, KITTI odometry image folders and ROS 1/2 bags, and written as EuRoC ASL folders
(with Kalibr's calibration files beside them) and ROS 2 bags.

``open_dataset(path)`` sniffs the kind: a folder with ``mav0/`` (TUM-VI when ``dso/camchain.yaml``
is beside it), a KITTI sequence (``times.txt`` + ``calib.txt`` + ``image_0/``), or a bag
(a ``.bag`` file, or a folder with ``metadata.yaml``)."""

from __future__ import annotations

from pathlib import Path

from quadnav.errors import IoError
from quadnav.io.datasets.bagwriter import Ros2BagWriter, write_ros2_bag
from quadnav.io.datasets.types import DatasetIssues, GroundTruth, ImuTable, VisualInertialDataset
from quadnav.io.datasets.writer import EurocWriter

__all__ = [
    "DATASET_KINDS",
    "DatasetIssues",
    "EurocWriter",
    "GroundTruth",
    "ImuTable",
    "Ros2BagWriter",
    "VisualInertialDataset",
    "open_dataset",
    "sniff_dataset",
    "write_ros2_bag",
]

DATASET_KINDS = ("euroc", "tumvi", "kitti", "bag")


def sniff_dataset(path: Path) -> str:
    """The kind of dataset at ``path`` (one of :data:`DATASET_KINDS`)."""
    from quadnav.io.datasets.euroc import find_mav0

    p = Path(path)
    if not p.exists():
        raise IoError(f"dataset not found: {p}")
    if p.is_file() and p.suffix in (".bag", ".db3", ".mcap"):
        return "bag"
    if p.is_dir() and (p / "metadata.yaml").is_file():
        return "bag"
    mav0 = find_mav0(p) if p.is_dir() else None
    if mav0 is not None:
        return "tumvi" if (mav0.parent / "dso" / "camchain.yaml").is_file() else "euroc"
    if p.is_dir() and (p / "times.txt").is_file() and (p / "calib.txt").is_file():
        return "kitti"
    raise IoError(
        f"{p}: not a dataset quadnav reads (an EuRoC/TUM-VI folder with mav0/, a KITTI "
        "sequence with times.txt and calib.txt, or a ROS bag)"
    )


def open_dataset(
    path: Path | str,
    *,
    kind: str | None = None,
    calibration: Path | str | None = None,
    groundtruth: Path | str | None = None,
    image_topics: tuple[str, ...] | None = None,
    imu_topic: str | None = None,
) -> VisualInertialDataset:
    """The dataset at ``path``. ``calibration`` (a Kalibr camchain or an EuRoC folder) replaces
    the files' own; ``groundtruth`` is KITTI's poses file; ``image_topics`` / ``imu_topic`` choose
    a bag's topics when it has several."""
    p = Path(path)
    k = kind or sniff_dataset(p)
    if k not in DATASET_KINDS:
        raise IoError(f"dataset kind {k!r} is not one of {', '.join(DATASET_KINDS)}")
    calib = Path(calibration) if calibration is not None else None
    if calib is not None and not calib.exists():
        raise IoError(f"calibration not found: {calib}")
    if k in ("euroc", "tumvi"):
        from quadnav.io.datasets.euroc import read_asl

        return read_asl(p, calibration=calib, kind=k)
    if k == "kitti":
        from quadnav.io.datasets.kitti import read_kitti_sequence

        return read_kitti_sequence(p, poses=Path(groundtruth) if groundtruth else None)
    from quadnav.io.datasets.bags import read_bag_dataset

    return read_bag_dataset(p, calibration=calib, image_topics=image_topics, imu_topic=imu_topic)
