"""Tidy tables on disk: named columns written as Parquet (pyarrow), atomically.

A column of numbers (``None`` for a missing value) is a float or integer column, a column of
text a string column, a column of booleans a boolean one; a column that mixes kinds (a grid
value that is a list in one row and a number in another) is written as JSON text, so that
every table can be written whatever its values. pyarrow is imported on first use.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from quadnav.errors import IoError
from quadnav.io.run_folder import _replace_atomically

__all__ = ["read_parquet_columns", "write_parquet"]


def _column(values: Sequence[object]) -> tuple[list[Any], str]:
    """The values and their Arrow type name (``double``, ``int64``, ``bool``, ``string``)."""
    present = [v for v in values if v is not None]
    if all(isinstance(v, bool) for v in present) and present:
        return list(values), "bool"
    if all(isinstance(v, int) and not isinstance(v, bool) for v in present) and present:
        return list(values), "int64"
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in present):
        out = [None if v is None or not math.isfinite(float(v)) else float(v) for v in values]  # type: ignore[arg-type]
        return out, "double"
    if all(isinstance(v, str) for v in present):
        return list(values), "string"
    return [None if v is None else json.dumps(v) for v in values], "string"


def write_parquet(path: Path, columns: Mapping[str, Sequence[object]]) -> None:
    """Write equal-length named columns as one Parquet file, atomically (temporary file then
    rename: a reader never sees half a table). NaN and infinite numbers are written as null."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    lengths = {len(v) for v in columns.values()}
    if len(lengths) > 1:
        raise IoError(f"{Path(path).name}: columns of different lengths {sorted(lengths)}")
    arrays = {}
    for name, values in columns.items():
        data, kind = _column(values)
        arrays[name] = pa.array(data, type=getattr(pa, "float64" if kind == "double" else kind)())
    table = pa.table(arrays)
    _replace_atomically(Path(path), lambda tmp: pq.write_table(table, tmp))


def read_parquet_columns(path: Path) -> dict[str, list[object]]:
    """A Parquet file's columns as lists (nulls as ``None``)."""
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(Path(path))
    except (OSError, ValueError) as exc:
        raise IoError(f"cannot read {path}: {exc}") from None
    return {str(k): list(v) for k, v in table.to_pydict().items()}
