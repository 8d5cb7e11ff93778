"""The KITTI drive of GTSAM's wheel (IMU + GPS): our navigation EKF against GTSAM's own
``IMUKittiExampleGPS`` (iSAM2) on the same data. Prints a table, writes
``benchmarks/results/kitti_gps.json`` and a top-view plot.

    python benchmarks/kitti_gps.py [--repeats 3] [--plot PATH]

GTSAM's example is first run unmodified as its own process (as a user runs it). Its
trajectory is then taken by calling its own functions (``gtsam.examples.IMUKittiExampleGPS``:
``loadKittiData``, ``optimize``) with its noise settings, except the zero precision its pose
priors give the rotation: GTSAM 4.3 refuses that system as indeterminate at the first update,
so the rotation gets a precision of 0.01 (a sigma of 10 rad: no information). Ours runs with
GTSAM's fixes (every 10th, ``gps_every=10``) and with every fix (``gps_every=1``).

Position errors are horizontal, at the GPS fixes' times, over the fixes from 3 on (where both
runs have an estimate). GTSAM's trajectory is its smoother's final estimate (each pose uses
the fixes after it too); ours is the filter's causal output. Times: the kernel (GTSAM's
``optimize``; our filter loop) best of ``--repeats``, and the whole process (imports, reading
the files, the run) as a user feels it.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from quadnav.experiments.kitti_gps import KittiGpsConfig, horizontal_errors_at, run_kitti_gps
from quadnav.io.gtsam_kitti import read_gtsam_kitti

ROOT = Path(__file__).resolve().parents[1]
ROT_PRECISION = 1e-2  # GTSAM's example's 0 makes GTSAM 4.3 refuse the first update


def gtsam_run() -> tuple[np.ndarray, float]:
    """GTSAM's example's trajectory at its fixes 1.. (its own functions and noise settings,
    the pose priors' rotation precision 0.01 instead of 0) and the time of its ``optimize``."""
    from gtsam import noiseModel
    from gtsam.examples import IMUKittiExampleGPS as ex  # noqa: N813
    from gtsam.symbol_shorthand import X

    with contextlib.redirect_stdout(io.StringIO()):
        cal, imu, gps = ex.loadKittiData()
        t0 = time.perf_counter()
        isam = ex.optimize(
            gps, imu,
            noiseModel.Diagonal.Precisions(np.asarray([ROT_PRECISION] * 3 + [1.0] * 3)),
            noiseModel.Diagonal.Sigmas(np.ones(3) * 1000.0),
            noiseModel.Diagonal.Sigmas(np.asarray([0.1] * 3 + [5.0e-05] * 3)),
            noiseModel.Diagonal.Precisions(np.asarray([ROT_PRECISION] * 3 + [1.0 / 0.07] * 3)),
            cal, 1, 10,
        )  # fmt: skip
        kernel = time.perf_counter() - t0
        est = isam.calculateEstimate()
    p = np.array([est.atPose3(X(i)).translation() for i in range(1, len(gps))])
    return p, kernel


def _worker(which: str) -> None:
    """One run as its own process, for the whole-process time."""
    if which == "gtsam":
        gtsam_run()
    else:
        run_kitti_gps(read_gtsam_kitti(), KittiGpsConfig(gps_every=int(which.split("_")[1])))


def _timed(cmd: list[str], cwd: Path) -> tuple[float, int, str]:
    env = dict(os.environ, MPLBACKEND="Agg")
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    lines = [x for x in (done.stderr or "").strip().splitlines() if x.strip()]
    said = [x.strip() for x in lines if "detected" in x] or [x.strip() for x in lines[-1:]]
    why = said[0] if said and done.returncode else ""
    return wall, done.returncode, why


def _whole(which: str, repeats: int) -> float:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", which]
    return min(_timed(cmd, ROOT)[0] for _ in range(repeats))


def _unmodified() -> dict[str, Any]:
    """GTSAM's example as shipped, in a scratch folder (it writes its CSV where it runs)."""
    import importlib.util

    spec = importlib.util.find_spec("gtsam.examples.IMUKittiExampleGPS")
    assert spec is not None and spec.origin is not None
    with tempfile.TemporaryDirectory() as tmp:
        wall, code, why = _timed([sys.executable, spec.origin], Path(tmp))
        wrote = (Path(tmp) / "IMUKittiExampleGPSResults.csv").exists()
    return {
        "script": spec.origin,
        "exit_code": code,
        "wall_s": wall,
        "error": why,
        "wrote_csv": wrote,
    }


def _metrics(p_fix: np.ndarray, gps: np.ndarray, used: np.ndarray) -> dict[str, float]:
    """Horizontal errors at the fixes (from fix 3 on): all, the held-out ones."""
    e = np.hypot(*(p_fix[3:, :2] - gps[3:, :2]).T)
    held = ~used[3:] & np.isfinite(e)
    return {
        "rmse_all_m": float(np.sqrt(np.nanmean(e**2))),
        "rmse_held_out_m": float(np.sqrt(np.mean(e[held] ** 2))) if held.any() else None,
        "max_m": float(np.nanmax(e)),
        "fixes": int(np.isfinite(e).sum()),
        "held_out": int(held.sum()),
    }


def _ours(data: Any, every: int, repeats: int) -> tuple[dict[str, Any], np.ndarray, Any]:
    best = None
    for _ in range(repeats):
        r = run_kitti_gps(data, KittiGpsConfig(gps_every=every))
        best = r if best is None or r.wall_s < best.wall_s else best
    assert best is not None
    at = np.full((len(data.gps_t_ns), 3), np.nan)
    e = horizontal_errors_at(best.t_ns, best.p, data.gps_t_ns, data.gps_p_m)
    ok = ~np.isnan(e)
    t = (best.t_ns - best.t_ns[0]) * 1e-9
    tf = (data.gps_t_ns[ok] - best.t_ns[0]) * 1e-9
    at[ok] = np.column_stack([np.interp(tf, t, best.p[:, k]) for k in range(3)])
    used = np.zeros(len(data.gps_t_ns), bool)
    used[best.given] = True
    used[: KittiGpsConfig().start_fix + 1] = True
    row = {"system": f"quadnav EKF, every {every} fix", **_metrics(at, data.gps_p_m, used)}
    row.update(kernel_s=best.wall_s, refused=len(best.refused), events=len(best.events))
    return row, at, best


def _plot(path: Path, data: Any, gtsam_p: np.ndarray, ours: dict[int, Any]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 7))
    ax.plot(data.gps_p_m[:, 0], data.gps_p_m[:, 1], ".", ms=3, color="0.5", label="GPS fixes")
    ax.plot(
        gtsam_p[:, 0], gtsam_p[:, 1], "-", lw=1.2, label="GTSAM's example (iSAM2, every 10th fix)"
    )
    for every, r in ours.items():
        ax.plot(r.p[:, 0], r.p[:, 1], "-", lw=1.0, label=f"quadnav EKF, every {every} fix")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("KITTI drive in GTSAM's wheel: top view")
    ax.legend(loc="best", fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    print(f"wrote {path}")


def _table(rows: list[dict[str, Any]]) -> None:
    print(
        f"| {'system':<28} | RMSE all fixes (m) | RMSE held-out (m) | max (m) | RMSE vs GTSAM (m) "
        "| max vs GTSAM (m) | kernel (s) | whole process (s) |"
    )
    print("|" + "---|" * 8)
    for r in rows:
        held = r["rmse_held_out_m"]
        held_s = "(none)" if held is None else f"{held:.2f}"
        vs = r.get("rmse_vs_gtsam_m")
        mx = r.get("max_vs_gtsam_m")
        print(
            f"| {r['system']:<28} | {r['rmse_all_m']:.2f} | {held_s} | {r['max_m']:.2f} "
            f"| {'' if vs is None else f'{vs:.2f}'} | {'' if mx is None else f'{mx:.2f}'} "
            f"| {r['kernel_s']:.2f} | {r['whole_s']:.2f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description="KITTI IMU + GPS: quadnav's EKF vs GTSAM's iSAM2 example"
    )
    parser.add_argument(
        "--repeats", type=int, default=3, help="best of this many (kernel and process)"
    )
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/kitti_gps.json"))
    parser.add_argument(
        "--plot", type=Path, default=Path("docs/results/img/2026-12-03-issue25-kitti.png")
    )
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        _worker(args.worker)
        return
    data = read_gtsam_kitti()
    unmodified = _unmodified()
    print(
        f"GTSAM's example as shipped: exit {unmodified['exit_code']} after {unmodified['wall_s']:.2f} s {unmodified['error']}"
    )
    gtsam_p = np.full((len(data.gps_t_ns), 3), np.nan)
    kernels = []
    for _ in range(args.repeats):
        p, k = gtsam_run()
        kernels.append(k)
    gtsam_p[1:] = p
    used = (np.arange(len(data.gps_t_ns)) % 10 == 0) | (np.arange(len(data.gps_t_ns)) == 1)
    g = {
        "system": "GTSAM example (iSAM2)",
        **_metrics(gtsam_p, data.gps_p_m, used),
        "kernel_s": min(kernels),
    }
    g["whole_s"] = _whole("gtsam", args.repeats)
    rows, runs = [g], {}
    for every in (10, 1):
        row, at, run = _ours(data, every, args.repeats)
        d = np.hypot(*(at[3:, :2] - gtsam_p[3:, :2]).T)
        row.update(
            rmse_vs_gtsam_m=float(np.sqrt(np.nanmean(d**2))), max_vs_gtsam_m=float(np.nanmax(d))
        )
        row["whole_s"] = _whole(f"ours_{every}", args.repeats)
        row["kernel_ratio_to_gtsam"] = row["kernel_s"] / g["kernel_s"]
        row["whole_ratio_to_gtsam"] = row["whole_s"] / g["whole_s"]
        rows.append(row)
        runs[every] = run
    _table(rows)
    for r in rows[1:]:
        print(
            f"{r['system']}: kernel {r['kernel_ratio_to_gtsam']:.2f}x GTSAM's, whole process {r['whole_ratio_to_gtsam']:.2f}x; {r['refused']} fixes refused"
        )
    _plot(args.plot, data, gtsam_p[1:], runs)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    out = {"benchmark": "kitti_gps", "python": platform.python_version(), "machine": platform.machine(),
           "gtsam_unmodified": unmodified, "gtsam_rotation_precision": ROT_PRECISION, "rows": rows}  # fmt: skip
    args.out.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
