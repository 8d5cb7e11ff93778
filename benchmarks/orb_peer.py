"""What the side-by-side benchmarks with ORB-SLAM3 share (``vio_peer.py``, ``slam_peer.py``,
``slam.py``): where the peer lives (:class:`OrbPeer`), its settings and its runner's command
line, a process run with a timeout and its wall time, the scoring of a TUM trajectory against
the ground truth through ``quadnav.eval`` (the same code for every system), ORB-SLAM3's log
(resets, new maps, loops) and trajectory files, the median over repeats and the Markdown table.

The peer is never a dependency of the package or of the tests: nothing here imports it; it
runs in its own venv, as a subprocess (``../shared/peers/orbslam3/README.md``)."""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from quadnav.errors import QuadnavError
from quadnav.eval.evaluate import EvalOptions, evaluate_pair
from quadnav.eval.na import Metric, fmt_metric, median_or_na, na
from quadnav.geometry.trajectory import Trajectory
from quadnav.io.trajectory_io import read_tum

ROOT = Path(__file__).resolve().parents[1]

RESET_LINE = "Reseting active map"  # ORB-SLAM3's spelling, once per active-map reset
NEW_MAP_LINE = "Creation of new map with id"  # its Atlas starting a map (the first one too)
LOOP_LINE = "*Loop detected"
MERGE_LINE = "*Merge detected"


def fail(message: str) -> None:
    """A bad input: one line naming the option or path, exit code 2 (as the CLI does)."""
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def parse_systems(text: str, choices: Sequence[str]) -> list[str]:
    """The ``--systems`` list, in the order given; an unknown name is a one-line error."""
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names or any(s not in choices for s in names):
        raise ValueError(f"--systems {text!r}: choose among {', '.join(choices)} (comma-separated)")
    return list(dict.fromkeys(names))


def peer_parser(description: str, systems: Sequence[str], out: str) -> argparse.ArgumentParser:
    """The options every peer benchmark takes (checked by :func:`check_arguments`)."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--systems", default=",".join(systems))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per process")
    parser.add_argument("--orb-venv", type=Path, default=ROOT.parent / "orb-venv")
    parser.add_argument("--orb-dir", type=Path, default=ROOT.parent / "shared/peers/orbslam3")
    parser.add_argument("--keep", type=Path, default=None, help="keep every run's output here")
    parser.add_argument("--out", type=Path, default=Path(out))
    return parser


def check_arguments(args: argparse.Namespace, systems: Sequence[str]) -> None:
    """``--systems`` parsed in place; a bad ``--systems``, ``--repeats`` or ``--timeout`` is a
    one-line error."""
    try:
        args.systems = parse_systems(args.systems, systems)
    except ValueError as exc:
        fail(str(exc))
    if args.repeats < 1:
        fail(f"--repeats must be at least 1, got {args.repeats}")
    if not args.timeout > 0:
        fail(f"--timeout must be a positive number of seconds, got {args.timeout}")


def count_resets(log: str) -> int:
    """ORB-SLAM3's active-map resets in its output."""
    return log.count(RESET_LINE)


def log_counts(log: str) -> dict[str, float]:
    """ORB-SLAM3's active-map resets, maps started after the first (its Atlas starts a new map
    when the track is lost on a map of 10 keyframes or more), loops and map merges."""
    maps = log.count(NEW_MAP_LINE)
    return {"resets": float(count_resets(log)), "new_maps": float(max(maps - 1, 0)),
            "loops": float(log.count(LOOP_LINE)), "merges": float(log.count(MERGE_LINE))}  # fmt: skip


def summarise(
    runs: Sequence[Mapping[str, Metric]], key: str = "ape_se3_m"
) -> dict[str, Metric | str]:
    """The median over repeats of each metric (numbers only; the first reason when no repeat
    has a number), ``runs_ok``: repeats with ``key`` (the causal trajectory) scored, of all, and
    ``error``: the first failed repeat's reason, if any."""
    keys = dict.fromkeys(k for r in runs for k in r if k != "error")
    out: dict[str, Metric | str] = {
        k: median_or_na(r.get(k, r.get("error", na("not measured"))) for r in runs) for k in keys
    }
    ok = sum(1 for r in runs if not isinstance(r.get(key, na("")), str))
    out["runs_ok"] = f"{ok}/{len(runs)}"
    errors = [r["error"] for r in runs if "error" in r]
    if errors:
        out["error"] = errors[0]
    return out


def markdown_table(
    rows: Sequence[tuple[str, str, Mapping[str, Metric | str]]],
    columns: Sequence[tuple[str, str, str]],
) -> str:
    """One Markdown row per (dataset, system, medians). A metric that is n/a prints ``n/a (k)``,
    its reason the k-th note under the table (a failed run's reason once, not in every cell)."""
    head = ["dataset", "system", "runs ok", *(c[1] for c in columns)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    reasons: list[str] = []
    for dataset, system, med in rows:
        cells = [dataset, system, str(med.get("runs_ok", "0/0"))]
        for key, _, spec in columns:
            value = med.get(key, med.get("error", na("not measured")))
            if isinstance(value, str):
                why = value.removeprefix("n/a: ")
                reasons += [why] if why not in reasons else []
                cells.append(f"n/a ({reasons.index(why) + 1})")
            else:
                cells.append(fmt_metric(value, spec))
        lines.append("| " + " | ".join(cells) + " |")
    notes = [f"({k}) {why}" for k, why in enumerate(reasons, start=1)]
    return "\n".join(lines + ([""] + notes if notes else []))


def score(
    groundtruth: Path, estimate: Path | Trajectory, aligns: Sequence[str]
) -> dict[str, Metric]:
    """APE RMSE (m) of a trajectory (a TUM file or one read) after each alignment, the poses
    matched (``matched``) and, with ``sim3``, the scale it found (``sim3_scale``)."""
    if isinstance(estimate, Path) and (not estimate.is_file() or estimate.stat().st_size == 0):
        why = na(f"no poses ({estimate.name} {'empty' if estimate.is_file() else 'missing'})")
        return {**{a: why for a in aligns}, "matched": why, "sim3_scale": why}
    out: dict[str, Metric] = {}
    try:
        ref = read_tum(groundtruth)
        est = read_tum(estimate) if isinstance(estimate, Path) else estimate
        for align in aligns:
            res = evaluate_pair(ref, est, EvalOptions(align=align, plots=False))  # type: ignore[arg-type]
            out[align] = res.metrics.ape_trans_m.rmse
            out["matched"] = float(res.n_matched)
            if align == "sim3":
                out["sim3_scale"] = float(res.alignment.s)
    except QuadnavError as exc:
        return {**{a: na(str(exc)) for a in aligns}, "matched": na(str(exc)),
                "sim3_scale": na(str(exc))}  # fmt: skip
    return out


def frames(dataset: Path) -> int:
    """The dataset's camera frames (``cam0``'s)."""
    rows = (dataset / "mav0" / "cam0" / "data.csv").read_text(encoding="utf-8").splitlines()
    return sum(1 for line in rows if line.strip() and not line.startswith("#"))


def coverage(matched: Metric, n_frames: int) -> Metric:
    """``matched`` poses in % of ``n_frames`` (a reason stays one)."""
    return matched if isinstance(matched, str) else 100.0 * float(matched) / n_frames


def run_process(cmd: list[str], log: Path, timeout_s: float) -> tuple[int | str, float]:
    """Run ``cmd``, output to ``log``: the exit code (or why it has none) and the wall time."""
    t0 = time.perf_counter()
    with log.open("w", encoding="utf-8") as out:
        try:
            code: int | str = subprocess.run(
                cmd, stdout=out, stderr=subprocess.STDOUT, timeout=timeout_s, check=False,
                env=dict(os.environ, MPLBACKEND="Agg"),
            ).returncode  # fmt: skip
        except subprocess.TimeoutExpired:
            code = f"timed out after {timeout_s:g} s (--timeout)"
    return code, time.perf_counter() - t0


def last_line(log: Path) -> str:
    """The last line of a log (200 characters at most), for a failure's reason."""
    lines = [s for s in log.read_text(encoding="utf-8", errors="replace").splitlines() if s]
    return lines[-1][:200] if lines else "no output"


def orb_failure(code: int | str, log: str, resets: int) -> str:
    """Why an ORB-SLAM3 run left no statistics (it ``exit``s or crashes on some inputs, e.g.
    saving a map that never initialised)."""
    hint = ""
    if "not enough acceleration" in log:
        hint = f"; 'not enough acceleration' {log.count('not enough acceleration')} times"
    return f"ORB-SLAM3 exit {code}, no stats.json ({resets} map resets{hint})"


class OrbPeer:
    """Where the peer lives: its venv's interpreter, its vocabulary, its scripts."""

    def __init__(self, venv: Path, scripts: Path) -> None:
        self.python, self.vocab, self.dir = venv / "bin" / "python", venv / "orbvoc.txt", scripts

    def missing(self) -> str:
        """Empty when usable, else what is missing (one line)."""
        gone = [
            str(p) for p in (self.python, self.vocab, self.dir / "run_orb.py") if not p.exists()
        ]
        return ", ".join(gone)

    def version(self) -> str:
        done = subprocess.run(
            [str(self.python), "-c", "from importlib.metadata import version as v; print(v('pyorbslam3'))"],
            capture_output=True, text=True, check=False, timeout=60,
        )  # fmt: skip
        return done.stdout.strip() or "?"

    def command(
        self, dataset: Path, mode: str, settings: Path, out: Path, *, paced: bool
    ) -> list[str]:
        """``run_orb.py`` in one mode with the settings ``settings/MODE.yaml`` into ``out``
        (``--no-pace`` unless ``paced``: then it sleeps to the camera rate, as ORB-SLAM3's
        examples do)."""
        return [str(self.python), str(self.dir / "run_orb.py"), str(dataset), mode,
                str(self.vocab), str(settings / f"{mode}.yaml"), str(out)] + (
            [] if paced else ["--no-pace"])  # fmt: skip

    def make_settings(self, dataset: Path, settings: Path) -> None:
        """ORB-SLAM3's settings for the dataset's rig (``make_settings.py``); a failure is a
        one-line error naming the dataset."""
        done = subprocess.run(
            [str(self.python), str(self.dir / "make_settings.py"), str(dataset), str(settings)],
            capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip
        if done.returncode != 0:
            last = (done.stdout + done.stderr).strip().splitlines()[-1:] or ["no output"]
            fail(f"DATASET {dataset}: ORB-SLAM3's make_settings.py failed: {last[0][:200]}")


def available(
    systems: Sequence[str], is_orb: Mapping[str, bool], peer: OrbPeer, orb_dir: Path
) -> list[str]:
    """The systems to run: the ORB-SLAM3 ones dropped, with one line, without its venv."""
    gone = peer.missing()
    if not gone or not any(is_orb[s] for s in systems):
        return list(systems)
    print(f"ORB-SLAM3 not run: missing {gone} (set up as {orb_dir}/README.md says); "
          "running quadnav's side only")  # fmt: skip
    left = [s for s in systems if not is_orb[s]]
    if not left:
        fail("--systems: only ORB-SLAM3 chosen, and its venv is missing (see the line above)")
    return left


def read_orb_euroc(path: Path, T_C_B: np.ndarray | None) -> Trajectory:
    """A trajectory ORB-SLAM3 saved in its EuRoC layout (``t_ns x y z qx qy qz qw``: its
    ``SaveTrajectoryEuRoC``, ``SaveKeyFrameTrajectoryEuRoC``) as the body's: a camera's poses
    (a mode without IMU) turned by ``T_C_B`` (4x4, the body in the camera; None: the body's
    already)."""
    from scipy.spatial.transform import Rotation

    rows = np.loadtxt(path, ndmin=2)
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    if len(rows):
        T[:, :3, :3] = Rotation.from_quat(rows[:, 4:8]).as_matrix()
        T[:, :3, 3] = rows[:, 1:4]
    if T_C_B is not None:
        T = T @ T_C_B
    t_ns = np.rint(rows[:, 0]).astype(np.int64) if len(rows) else np.zeros(0, np.int64)
    keep = np.concatenate([[True], np.diff(t_ns) > 0]) if len(t_ns) else np.zeros(0, bool)
    return Trajectory.from_matrices(t_ns[keep], T[keep], name=path.stem)


def camera_T_C_B(dataset: Path, camera: str = "cam0") -> np.ndarray:
    """The body in ``camera`` (4x4) from its ``sensor.yaml``'s ``T_BS``, as ``run_orb.py``
    turns ORB-SLAM3's camera poses."""
    import yaml

    text = (dataset / "mav0" / camera / "sensor.yaml").read_text(encoding="utf-8")
    T_B_C = np.array(yaml.safe_load(text.replace("%YAML:1.0", ""))["T_BS"]["data"], float)
    return np.linalg.inv(T_B_C.reshape(4, 4))


def dataset_record(ds: Path) -> dict[str, object]:
    """What a results file says of a dataset: its path, frames, sequence and how it was made."""
    meta_path = ds / "dataset.json"
    meta = json.loads(meta_path.read_text(encoding="utf-8")) if meta_path.is_file() else {}
    spec = meta.get("spec", {})
    keep = ("world", "rig", "motion", "duration_s", "seed", "imu_noise", "sensors", "still_s",
            "time_offset_s")  # fmt: skip
    return {"path": str(ds.resolve()), "frames": frames(ds), "sequence": meta.get("sequence"),
            **{k: spec.get(k) for k in keep if k in spec}}  # fmt: skip


def git_commit() -> str:
    """The repository's commit (``?`` outside git)."""
    done = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=False
    )
    return done.stdout.strip() or "?"


def repeated(
    ds: Path, name: str, repeats: int, work: Path, run_one: Callable[[Path], dict[str, Metric]]
) -> dict[str, object]:
    """``repeats`` runs of system ``name`` on ``ds`` (``run_one(run_dir)``, each in its folder
    ``work/name/runK``), the 1-min load average before each recorded; one line per run as it
    ends. The runs and their medians (:func:`summarise`)."""
    runs: list[dict[str, Metric]] = []
    for k in range(repeats):
        run_dir = work / name / f"run{k}"
        run_dir.mkdir(parents=True)
        load = os.getloadavg()[0]
        r = run_one(run_dir)
        r["load_1min_before"] = load
        runs.append(r)
        print(f"  {ds.name} {name} run {k + 1}/{repeats}: "
              f"APE SE(3) {fmt_metric(r['ape_se3_m'], '.3f')} m, "
              f"whole process {float(r['process_s']):.1f} s", flush=True)  # fmt: skip
    return {"runs": runs, "median": summarise(runs)}


def each_dataset(
    datasets: Sequence[Path],
    keep: Path | None,
    prefix: str,
    run_dataset: Callable[[Path, Path], dict[str, object]],
) -> list[dict[str, object]]:
    """``run_dataset(dataset, work)`` for each dataset, its work folder under ``keep`` (kept:
    ``--keep``) or a temporary one; a work folder that exists already is a one-line error."""
    results = []
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        for i, ds in enumerate(datasets):
            work = (keep.resolve() if keep is not None else Path(tmp)) / f"{i}_{ds.name}"
            if work.exists():
                fail(f"--keep {keep}: {work} exists already; choose an empty folder")
            results.append(run_dataset(ds, work))
    return results


def write_results(
    out: Path, head: Mapping[str, object], results: Sequence[object], text: str
) -> None:
    """The results file: ``head`` (what was run), the commit, the interpreter, the cores, the
    results and the table as printed."""
    from quadnav.io.run_folder import write_text

    record = {**head, "commit": git_commit(), "python": platform.python_version(),
              "cpus": os.cpu_count(), "results": results, "table_markdown": text}  # fmt: skip
    write_text(out, json.dumps(record, indent=2) + "\n")
    print(f"wrote {out}")
