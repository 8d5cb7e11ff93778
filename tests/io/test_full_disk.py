"""A full disk (issue 21, item 8): every writer says which file in one line, leaves nothing that
looks complete, lets no library print its own message, and a run folder ends ``failed``.

Two ways to fill a disk without one: ``/dev/full`` (every write fails with ENOSPC, as on a full
disk, through whatever library writes), and a patched write raising ENOSPC."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from quadnav.errors import IoError
from quadnav.io.datasets import EurocWriter
from quadnav.io.frames import VideoOut
from quadnav.io.run_folder import create_run_folder, read_run_status, run_guard
from quadnav.messages import ImuSample
from tests.io.test_datasets_roundtrip import H, W, _rig

DEV_FULL = Path("/dev/full")
needs_dev_full = pytest.mark.skipif(not DEV_FULL.exists(), reason="no /dev/full on this system")


def enospc(path: object = None) -> OSError:
    if path is None:  # a buffered write's flush names no file
        return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


@needs_dev_full
def test_a_png_on_a_full_disk_is_one_error_naming_it_and_libpng_says_nothing(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    rig = _rig("radtan", stereo=False)
    root = tmp_path / "seq"
    with pytest.raises(IoError) as err, EurocWriter(root, rig) as w:
        png = w.mav0 / "cam0" / "data" / "1000.png"
        png.symlink_to(DEV_FULL)  # the next image goes to a "disk" with no room
        w.add_frame("cam0", 1000, np.zeros((H, W), np.uint8))
    assert str(err.value) == f"cannot write {png}: No space left on device"
    assert capfd.readouterr().err == ""  # no "libpng error: Write Error"
    assert not root.exists() and not root.with_name("seq.partial").exists()


def test_csv_rows_on_a_full_disk_are_one_error_naming_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The IMU rows are buffered: the disk's refusal comes at a write or when the file closes."""
    rig = _rig("radtan", stereo=False)
    root = tmp_path / "seq"
    with pytest.raises(IoError) as err, EurocWriter(root, rig) as w:
        w.add_imu(ImuSample(t_ns=1, gyro_rad_s=np.zeros(3), accel_m_s2=np.zeros(3)))
        csv = w.mav0 / "imu0" / "data.csv"
        real_close = w._files["imu0"].close

        def full_close() -> None:
            real_close()
            raise enospc()  # what a buffered file says when its last rows find no room

        monkeypatch.setattr(w._files["imu0"], "close", full_close, raising=False)
        w.close()
    assert str(err.value) == f"cannot write {csv}: No space left on device"
    assert not root.exists() and not root.with_name("seq.partial").exists()


def test_a_video_stops_with_one_error_before_the_disk_is_full(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    """OpenCV's FFmpeg writer only warns on stderr, per frame, when its writes fail."""
    import shutil

    video = VideoOut(tmp_path / "tracks.mp4", 20.0)
    frame = np.zeros((48, 64, 3), np.uint8)
    video.write(frame)
    usage = shutil.disk_usage(tmp_path)
    monkeypatch.setattr(
        "quadnav.io.frames.shutil.disk_usage", lambda p: usage._replace(free=100_000)
    )
    with pytest.raises(IoError, match=r"cannot write .*tracks\.mp4: no space left on device"):
        video.write(frame)
    video.close()
    assert video.frames == 1 and "FFmpeg" not in capfd.readouterr().err


def test_a_run_on_a_full_disk_ends_failed_with_its_own_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The status file is written last; on a full disk its atomic write (a new file) fails
    too: it is rewritten in place, and the run's error is the one raised."""
    real = Path.write_text

    def full(self: Path, *a: Any, **kw: Any) -> int:
        if self.name.endswith(".partial"):  # every atomic write's temporary file
            raise enospc(self)
        return real(self, *a, **kw)

    with pytest.raises(IoError, match="the run's own error"), run_guard():
        run_dir = create_run_folder(tmp_path, "full")
        (run_dir / "estimate.tum").write_text("0 0 0 0 0 0 0 1\n")
        monkeypatch.setattr(Path, "write_text", full)
        raise IoError("the run's own error")
    assert read_run_status(run_dir) == "failed"


@needs_dev_full
def test_an_overlay_image_on_a_full_disk_is_one_error_naming_it_and_libpng_says_nothing(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """``quadnav markers``' ``write_images`` (issue 21, item 8: every writer)."""
    from quadnav.io.frames import ImagesOut

    out = ImagesOut(tmp_path / "images")
    png = tmp_path / "images" / "frame_000003.png"
    png.symlink_to(DEV_FULL)
    with pytest.raises(IoError) as err:
        out.write(3, np.zeros((H, W, 3), np.uint8))
    assert str(err.value) == f"cannot write {png}: No space left on device"
    assert capfd.readouterr().err == ""  # no "libpng error: Write Error"
