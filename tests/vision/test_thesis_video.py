"""The thesis's own footage (../shared/data/thesis_rig/board12_17.mp4): a 12x17 ChArUco board
filmed by the Raspberry Pi camera of thesis 000, with its calibration."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from quadnav.experiments.markers_run import MarkersStats, load_markers_config, run_markers
from tests.shared_data import SHARED, needs

DATA = SHARED / "thesis_rig"
needs_data = needs(DATA)


@needs_data
def test_board_pose_in_more_frames_than_opencvs_defaults(tmp_path: Path) -> None:
    common = [f"camera_file={DATA / 'cal.yml'}", "video=false", "max_frames=250"]
    stats: dict[str, MarkersStats] = {}
    for name, extra in (
        ("opencv", ["charuco.marker_fallback=false", "detector={}"]),
        ("quadnav", []),
    ):
        cfg, ignored = load_markers_config(DATA / "vision_params.yml", [*common, *extra])
        assert cfg.target == "charuco" and cfg.charuco.squares_x == 12 and cfg.dictionary == 2
        assert "mav_connect" in ignored
        stats[name] = run_markers(cfg, str(DATA / "board12_17.mp4"), tmp_path / name)
    assert stats["opencv"].frames == stats["quadnav"].frames == 250
    # OpenCV's defaults find too few chessboard corners close up; the board's marker corners
    # still give a pose (measured on all 1,086 frames: 20 % -> 70 %, the fallback gated)
    assert stats["quadnav"].fraction_with_pose >= 1.5 * stats["opencv"].fraction_with_pose
    assert stats["quadnav"].jitter_median_mm < 5.0


@needs_data
def test_the_board_puts_the_vehicle_above_it_upright(tmp_path: Path) -> None:
    """The thesis's mount looks down at the board on the floor: z out of the printed face puts
    the vehicle above it with roll and pitch near 0 (OpenCV 4.6+'s board frame, z into the
    board, put it 0.195 m below, upside down: median |roll| 178 degrees)."""
    common = [f"camera_file={DATA / 'cal.yml'}", "video=false", "max_frames=300"]
    cfg, _ = load_markers_config(DATA / "vision_params.yml", common)
    stats = run_markers(cfg, str(DATA / "board12_17.mp4"), tmp_path)
    rows = list(csv.DictReader((stats.run_dir / "poses.csv").open()))
    posed = [r for r in rows if r["z_m"] != "nan"]
    assert len(posed) == stats.frames_with_pose > 150
    assert np.median([float(r["z_m"]) for r in posed]) > 0.1
    assert np.median([abs(float(r["roll_deg"])) for r in posed]) < 10
    assert np.median([abs(float(r["pitch_deg"])) for r in posed]) < 10
