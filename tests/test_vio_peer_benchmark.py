"""``benchmarks/vio_peer.py``'s pure parts: the median over repeats (a failed repeat neither
counts as a number nor hides the others), the table, the ORB-SLAM3 log's resets and ``--systems``
(its bad input: ``tests/test_benchmark_inputs.py``). No test runs ORB-SLAM3 or the VIO."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import pytest

from tests.script_module import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "vio_peer.py"


@pytest.fixture(scope="module")
def peer() -> ModuleType:
    return load_script(SCRIPT)


def test_median_over_repeats_skips_failed_ones_and_counts_them(peer: ModuleType) -> None:
    crashed = "n/a: ORB-SLAM3 exit -11, no stats.json (27 map resets)"
    runs = [
        {"ape_se3_m": 0.05, "estimator_fps": 40.0, "resets": 2.0},
        {"error": crashed, "ape_se3_m": crashed, "resets": 27.0},
        {"ape_se3_m": 0.01, "estimator_fps": 60.0, "resets": 0.0},
    ]
    med = peer.summarise(runs)
    assert med["ape_se3_m"] == pytest.approx(0.03)  # median of the two that scored
    assert med["estimator_fps"] == pytest.approx(50.0)  # the crashed run has none
    assert med["resets"] == pytest.approx(2.0)  # median of 2, 27, 0
    assert med["runs_ok"] == "2/3" and med["error"] == crashed


def test_a_metric_no_repeat_has_keeps_the_reason(peer: ModuleType) -> None:
    why = "n/a: quadnav vio failed (timed out after 5 s (--timeout)): ..."
    med = peer.summarise([{"error": why, "ape_se3_m": why, "process_s": 5.0}] * 3)
    assert med["ape_se3_m"] == why
    assert med["runs_ok"] == "0/3" and med["process_s"] == pytest.approx(5.0)


def test_table_prints_numbers_and_reasons_never_nan(peer: ModuleType) -> None:
    crash = {"runs_ok": "0/3", "error": "n/a: crash", "ape_se3_m": "n/a: crash"}
    rows = [
        ("room_medium", "quadnav VIO mono", {"runs_ok": "3/3", "ape_se3_m": 0.01234}),
        ("room_medium", "ORB-SLAM3 mono-inertial", crash),
    ]
    columns = (("ape_se3_m", "APE SE(3) (m)", ".3f"), ("process_s", "process (s)", ".1f"))
    lines = peer.markdown_table(rows, columns).splitlines()
    assert lines[0] == "| dataset | system | runs ok | APE SE(3) (m) | process (s) |"
    assert lines[2] == "| room_medium | quadnav VIO mono | 3/3 | 0.012 | n/a (1) |"
    # a failed run's reason once, under the table, for every metric it lacks
    assert lines[3] == "| room_medium | ORB-SLAM3 mono-inertial | 0/3 | n/a (2) | n/a (2) |"
    assert lines[5:] == ["(1) not measured", "(2) crash"]
    assert not any("nan" in line for line in lines)


def test_resets_are_counted_in_orb_slam3_output(peer: ModuleType) -> None:
    log = "SYSTEM-> Reseting active map in monocular case\nFail to track local map!\n" * 3
    assert peer.count_resets(log) == 3 and peer.count_resets("Vocabulary loaded!\n") == 0


def test_systems_option(peer: ModuleType) -> None:
    assert peer.parse_systems("orb_mono_inertial, quadnav_mono,orb_mono_inertial") == [
        "orb_mono_inertial",
        "quadnav_mono",
    ]
    with pytest.raises(ValueError, match="--systems 'vins'"):
        peer.parse_systems("vins")


@pytest.mark.parametrize("paced", [False, True])
def test_orb_slam3_is_paced_only_when_asked(
    peer: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, paced: bool
) -> None:
    """Unpaced by default (its speed); ``--paced`` runs it at the camera's rate, as its
    examples do (its accuracy, its mapping threads given the time)."""
    seen: list[list[str]] = []

    def fake_run(cmd: list[str], log: Path, timeout_s: float) -> tuple[int, float]:
        seen.append(cmd)
        log.write_text("", encoding="utf-8")
        return -11, 1.0

    monkeypatch.setattr(peer, "_run", fake_run)
    orb = peer.OrbPeer(tmp_path / "venv", tmp_path / "scripts")
    r = peer.run_orb(tmp_path, "stereo_inertial", orb, tmp_path, tmp_path, 10.0, paced=paced)
    assert ("--no-pace" in seen[0]) is not paced
    assert str(r["ape_se3_m"]).startswith("n/a: ORB-SLAM3 exit -11")
