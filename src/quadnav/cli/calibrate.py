"""``quadnav calibrate SOURCE``: camera calibration from ChArUco views (an image folder or a
video), with bad views rejected, written as OpenCV YAML."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from quadnav.cli.common import (
    CommandParams,
    command_help,
    console,
    err_console,
    handle_errors,
    param,
    progress_bar,
)
from quadnav.errors import ConfigError
from quadnav.experiments.calibration import (
    SourceCalibration,
    calibrate_source,
    write_source_calibration,
)
from quadnav.io.frames import quiet_libraries
from quadnav.vision.calibration import (
    MIN_VIEWS,
    BoardNames,
    charuco_board_problem,
    rejection_summary,
)
from quadnav.vision.markers import CharucoSpec

__all__ = ["EXAMPLES", "calibrate_command", "check_example", "print_calibration"]

_OPTIONS = BoardNames(
    squares_x="--squares",
    squares_y="--squares",
    square_m="--square-m",
    marker_m="--marker-m",
    dictionary="--dictionary",
)


def _check_options(
    squares: tuple[int, int], square_m: float, marker_m: float, dictionary: str, out: Path
) -> None:
    problem = charuco_board_problem(squares, square_m, marker_m, dictionary, _OPTIONS)
    if problem:
        raise ConfigError(problem)
    if out.is_dir() or not out.parent.is_dir():
        why = "is a folder" if out.is_dir() else f"there is no folder {out.parent}"
        raise ConfigError(f"--out {out}: cannot write the calibration there ({why})")


def check_example(p: CommandParams) -> None:
    """Validate an example's board and output as the command would, reading no image."""
    squares = param(p, "squares", tuple)
    _check_options(
        (int(squares[0]), int(squares[1])),
        param(p, "square_m", float),
        param(p, "marker_m", float),
        param(p, "dictionary", str),
        param(p, "out", Path),
    )


#: The examples of ``quadnav calibrate --help`` (each parsed and validated by the tests).
EXAMPLES = (
    "quadnav calibrate ../shared/data/aruco/img_00.jpg ../shared/data/aruco/img_02.jpg ../shared/data/aruco/img_03.jpg --out camera.yml",
    "quadnav calibrate calibration_images/ --out camera.yml",
    "quadnav calibrate board.mp4 --squares 5 7 --square-m 0.04 --marker-m 0.02 --every 10",
    "quadnav calibrate views/ --squares 12 17 --square-m 0.066 --marker-m 0.0397 --dictionary DICT_4X4_250",
)


@handle_errors
def calibrate_command(
    source: Annotated[
        list[str], typer.Argument(help="folder of ChArUco images, a video, or image files")
    ],
    squares: Annotated[
        tuple[int, int], typer.Option("--squares", help="squares across and down")
    ] = (5, 7),
    square_m: Annotated[float, typer.Option("--square-m", help="square side (m)")] = 0.04,
    marker_m: Annotated[float, typer.Option("--marker-m", help="marker side (m)")] = 0.02,
    dictionary: Annotated[str, typer.Option("--dictionary")] = "DICT_6X6_250",
    every: Annotated[
        int, typer.Option("--every", min=1, help="use every n-th frame of a video")
    ] = 1,
    out: Annotated[Path, typer.Option("--out", help="calibration file to write")] = Path(
        "camera.yml"
    ),
) -> None:
    _check_options(squares, square_m, marker_m, dictionary, out)
    spec = CharucoSpec(squares[0], squares[1], square_m, marker_m, dictionary)
    with progress_bar("calibrate") as update, quiet_libraries():
        result = calibrate_source(source, spec, every=every, progress=update)
    write_source_calibration(out, result)
    print_calibration(" ".join(source), result, out)


SHOWN_REJECTIONS = 10  # the first rejected frames listed by name (all are counted by reason)


def print_calibration(source: str, result: SourceCalibration, out: Path) -> None:
    """The terminal summary: frames and views used, the RMS error, the intrinsics with the
    solver's 1-sigma, the image covered, the rejections by reason; the warnings on stderr."""
    cal = result.calibration
    sd = cal.std_intrinsics
    table = Table(title=f"calibration from {source}")
    table.add_column("measure")
    table.add_column("value", justify="right")
    table.add_row("frames read / unreadable", f"{result.frames_read} / {len(result.unreadable)}")
    table.add_row("views used / rejected", f"{len(cal.per_view_rms_px)} / {len(cal.rejected)}")
    table.add_row("RMS reprojection error (px)", f"{cal.rms_px:.3f}")
    table.add_row("fx, fy (px)", f"{cal.camera.fx:.2f}, {cal.camera.fy:.2f}")
    table.add_row("cx, cy (px)", f"{cal.camera.K[0, 2]:.2f}, {cal.camera.K[1, 2]:.2f}")
    table.add_row("distortion", " ".join(f"{d:.4g}" for d in cal.camera.dist))
    if sd:
        table.add_row(
            "1-sigma of fx, fy, cx, cy (px)",
            ", ".join(f"{sd[n]:.2f}" for n in ("fx", "fy", "cx", "cy")),
        )
    table.add_row("image reached by the corners", f"{cal.coverage:.0%}")
    console.print(table)
    if cal.rejected:
        console.print(f"views {rejection_summary(cal.rejected)}", highlight=False)
    for k, why in sorted(cal.rejected.items())[:SHOWN_REJECTIONS]:
        console.print(f"rejected frame {k}: {why}", highlight=False)
    for text in cal.warnings:
        err_console.print(f"warning: {text}", highlight=False, soft_wrap=True)
    console.print(str(out), highlight=False)


calibrate_command.__doc__ = command_help(
    "Calibrate a camera from views of a ChArUco board; write OpenCV YAML.",
    "SOURCE is a folder of images, a video, or image files (several SOURCEs are taken in "
    "turn). The defaults are OpenCV's tutorial board (5x7 "
    "squares of 4 cm, markers of 2 cm, DICT_6X6_250). Views with too few or collinear corners "
    "or a reprojection error far above the others' are rejected, counted by reason and listed. "
    f"At least {MIN_VIEWS} good views from distinct poses are needed; 10 or more, with the board "
    "tilted 20-40 degrees in different directions and reaching the image's edges and corners, "
    "make a good calibration. It is refused, with the reasons, when the views do not determine "
    "the camera (a focal length or principal point known worse than 10 %, the principal point "
    "outside the image, fx and fy more than 10 % apart, a distortion that folds back inside the "
    "image), and written with warnings when it is weak (RMS error above 1 px, corners reaching "
    "less than half the image, a focal length known worse than 2 %, one viewing angle).",
    examples=EXAMPLES,
)
