"""Named layouts of a filter's state vector: which entries are which, by name, not by index.

A :class:`StateLayout` is a sequence of contiguous :class:`StateBlock`\\ s (``att``, ``vel``,
``pos``, ...), each with its slice and the names of its entries. Filters index their state,
covariance and Jacobians through it (``H[:, NAV_ERROR["pos"]]``, ``NAV_ERROR.index("z")``) and a
:class:`~quadnav.messages.StateEstimate` carries the names of its ``x`` from it.

The navigation EKF has two: its 15-element **error state** (``NAV_ERROR``: body-frame
attitude error ``dtheta``, velocity, position, gyro bias, accelerometer bias; the rows and
columns of ``P``) and its **nominal state** as ``NavEkf.x`` reports it (``NAV_NOMINAL``: the
attitude ``R_W_B`` as a rotation vector, then the same blocks). Its output predictor carries
position, velocity and the flattened rotation matrix (``NAV_OUTPUT``). The columns of its
noise-input matrix ``G`` are ``NAV_NOISE``.
"""

from __future__ import annotations

from dataclasses import dataclass

from quadnav.errors import EstimationError

__all__ = [
    "NAV_ERROR",
    "NAV_NOISE",
    "NAV_NOMINAL",
    "NAV_OUTPUT",
    "StateBlock",
    "StateLayout",
]


@dataclass(frozen=True, slots=True)
class StateBlock:
    """One named block of a state vector: ``name`` (``"pos"``), its slice, its entry names."""

    name: str
    slice: slice
    names: tuple[str, ...]

    @property
    def size(self) -> int:
        return len(self.names)


@dataclass(frozen=True, slots=True, init=False)
class StateLayout:
    """Contiguous named blocks making up a state vector, built from ``(name, entries)`` pairs.

    ``layout["pos"]`` is the position block's slice; :meth:`block` gives the whole block."""

    blocks: tuple[StateBlock, ...]

    def __init__(self, *blocks: tuple[str, tuple[str, ...]]) -> None:
        out: list[StateBlock] = []
        start = 0
        for name, entries in blocks:
            if not entries:
                raise EstimationError(f"StateLayout: block {name!r} has no entries")
            out.append(StateBlock(name, slice(start, start + len(entries)), tuple(entries)))
            start += len(entries)
        names = [n for b in out for n in b.names]
        if len(set(names)) != len(names) or len({b.name for b in out}) != len(out):
            raise EstimationError(f"StateLayout: repeated block or entry names in {names}")
        object.__setattr__(self, "blocks", tuple(out))

    @property
    def size(self) -> int:
        return sum(b.size for b in self.blocks)

    @property
    def names(self) -> tuple[str, ...]:
        """Every entry's name, in order (``len(names) == size``)."""
        return tuple(n for b in self.blocks for n in b.names)

    def block(self, name: str) -> StateBlock:
        for b in self.blocks:
            if b.name == name:
                return b
        raise EstimationError(
            f"StateLayout has no block {name!r}; it has {[b.name for b in self.blocks]}"
        )

    def __getitem__(self, name: str) -> slice:
        return self.block(name).slice

    def index(self, entry: str) -> int:
        """The position of one named entry (``index("z")``)."""
        try:
            return self.names.index(entry)
        except ValueError:
            raise EstimationError(f"StateLayout has no entry {entry!r}") from None


_VEL = ("vel", ("vx", "vy", "vz"))
_POS = ("pos", ("x", "y", "z"))
_BIASES = (("gyro_bias", ("bgx", "bgy", "bgz")), ("accel_bias", ("bax", "bay", "baz")))

#: The navigation EKF's error state: rows and columns of its covariance and Jacobians.
NAV_ERROR = StateLayout(("att", ("dtheta_x", "dtheta_y", "dtheta_z")), _VEL, _POS, *_BIASES)
#: The navigation EKF's nominal state as ``NavEkf.x``: the attitude as a rotation vector.
NAV_NOMINAL = StateLayout(("att", ("rotvec_x", "rotvec_y", "rotvec_z")), _VEL, _POS, *_BIASES)
#: The output predictor's state (``NavKinematics``): position, velocity, ``R_W_B`` row-major.
NAV_OUTPUT = StateLayout(
    _POS, _VEL, ("att", tuple(f"R_W_B_{i}{j}" for i in range(3) for j in range(3)))
)
#: The navigation EKF's process-noise inputs (columns of ``G``): white noise of the gyro and the
#: accelerometer, random walks of their biases.
NAV_NOISE = StateLayout(
    ("gyro", ("n_gx", "n_gy", "n_gz")),
    ("accel", ("n_ax", "n_ay", "n_az")),
    ("gyro_bias", ("n_bgx", "n_bgy", "n_bgz")),
    ("accel_bias", ("n_bax", "n_bay", "n_baz")),
)
