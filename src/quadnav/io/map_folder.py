"""A map on disk, whatever made it (loop closure's, ``io/loop_map.py``; the SLAM's,
``io/slam_map.py``): a folder of ``map.json`` (its ``format``, ``version`` and what else the map
says of itself, plus the ``quadnav`` version that wrote it) and one NumPy archive of arrays
(uncompressed, no pickles).

A map is written to a temporary folder beside it and renamed into place, so a folder that
exists is complete; a folder holding something other than a map is never replaced. A missing,
truncated, corrupt or foreign map, or one of another version, is a one-line error of the kind
the caller names, naming the user's option and folder.
"""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from quadnav.errors import QuadnavError

__all__ = ["HEAD", "read_map_folder", "write_map_folder"]

HEAD = "map.json"


def write_map_folder(
    folder: Path, head: dict[str, Any], arrays: dict[str, np.ndarray], *, archive: str,
    error: type[QuadnavError], option: str = "--save-map",
) -> Path:  # fmt: skip
    """Write ``head`` and ``arrays`` (into ``archive``) to ``folder``, replacing a map there."""
    from quadnav import __version__

    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise error(f"{option} {folder}: is a file, not a folder")
    if folder.is_dir() and any(folder.iterdir()) and not (folder / HEAD).exists():
        raise error(f"{option} {folder}: the folder holds something other than a map")
    head = {**head, "quadnav": __version__}
    tmp = folder.with_name(folder.name + ".writing")
    try:
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        np.savez(tmp / archive, **arrays)  # type: ignore[arg-type]
        (tmp / HEAD).write_text(json.dumps(head, indent=2) + "\n", encoding="utf-8")
        if folder.exists():
            shutil.rmtree(folder)
        tmp.rename(folder)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise error(f"{option} {folder}: cannot write ({exc.strerror or exc})") from None
    return folder


def read_map_folder(
    folder: Path, *, fmt: str, version: int, archive: str, error: type[QuadnavError],
    option: str = "--load-map",
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:  # fmt: skip
    """The head and arrays of the map in ``folder``, checked to be of format ``fmt`` and
    ``version``."""
    folder = Path(folder)
    where = f"{option} {folder}"
    if not folder.is_dir():
        raise error(f"{where}: no such folder")
    try:
        head = json.loads((folder / HEAD).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise error(f"{where}: no {HEAD}: not a quadnav map") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{where}: {HEAD} is corrupt ({type(exc).__name__})") from None
    if not isinstance(head, dict) or head.get("format") != fmt:
        found = head.get("format") if isinstance(head, dict) else None
        raise error(f"{where}: {HEAD} is not a quadnav map of this kind ({fmt}; it says {found!r})")
    if head.get("version") != version:
        raise error(f"{where}: map version {head.get('version')}, this quadnav reads {version}")
    try:
        with np.load(folder / archive, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise error(f"{where}: no {archive}") from None
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise error(f"{where}: {archive} is truncated or corrupt ({type(exc).__name__})") from None
    return head, arrays
