"""Trajectories: time-stamped poses ``T_W_B`` as arrays, the unit of evaluation.

A :class:`Trajectory` holds N poses of a body B in a world W: times ``t_ns`` (N,),
positions ``p_W_B`` (N, 3) and attitudes ``q_W_B_xyzw`` (N, 4), optionally position
covariances ``cov_p`` (N, 3, 3). ``timed=False`` marks a sequence without timestamps
(KITTI): its ``t_ns`` is the frame index and association is by index.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from quadnav.errors import GeometryError

__all__ = ["Trajectory"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True, kw_only=True)
class Trajectory:
    """N time-stamped poses; validated on construction (shapes, finiteness, time order)."""

    t_ns: IntArray
    p_W_B: FloatArray
    q_W_B_xyzw: FloatArray
    cov_p: FloatArray | None = None
    timed: bool = True
    name: str = ""
    meta: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns)
        if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
            raise GeometryError(f"trajectory {self.name!r}: t_ns must be a 1-D integer array")
        n = len(t)
        p = np.asarray(self.p_W_B, dtype=np.float64)
        q = np.asarray(self.q_W_B_xyzw, dtype=np.float64)
        if p.shape != (n, 3) or q.shape != (n, 4):
            raise GeometryError(
                f"trajectory {self.name!r}: need p (N, 3) and q (N, 4) for N = {n}, "
                f"got {p.shape} and {q.shape}"
            )
        if not (np.isfinite(p).all() and np.isfinite(q).all()):
            raise GeometryError(
                f"trajectory {self.name!r}: positions and quaternions must be finite"
            )
        norms = np.linalg.norm(q, axis=1)
        if n and norms.min() < 1e-9:
            raise GeometryError(f"trajectory {self.name!r}: a quaternion is zero")
        if n > 1 and np.any(np.diff(t) <= 0):
            k = int(np.argmax(np.diff(t) <= 0))
            raise GeometryError(
                f"trajectory {self.name!r}: timestamps must increase (pose {k + 1} is not after pose {k})"
            )
        cov = None
        if self.cov_p is not None:
            cov = np.asarray(self.cov_p, dtype=np.float64)
            if cov.shape != (n, 3, 3) or not np.isfinite(cov).all():
                raise GeometryError(f"trajectory {self.name!r}: cov_p must be finite (N, 3, 3)")
        object.__setattr__(self, "t_ns", t.astype(np.int64))
        object.__setattr__(self, "p_W_B", p)
        # unit already (a selection, a copy): kept as it is, not copied (scipy normalises
        # anyway); a long trajectory's views stay views
        unit = not n or float(np.max(np.abs(norms - 1.0))) <= 1e-12
        object.__setattr__(self, "q_W_B_xyzw", q if unit else q / norms[:, None])
        object.__setattr__(self, "cov_p", cov)

    def __len__(self) -> int:
        return len(self.t_ns)

    @property
    def t_s(self) -> FloatArray:
        """Seconds since the first pose (for plotting)."""
        return (self.t_ns - (self.t_ns[0] if len(self) else 0)) * 1e-9

    @property
    def R_W_B(self) -> Rotation:
        return Rotation.from_quat(self.q_W_B_xyzw)

    def matrices(self) -> FloatArray:
        """Homogeneous ``T_W_B`` matrices (N, 4, 4)."""
        T = np.zeros((len(self), 4, 4))
        T[:, :3, :3] = self.R_W_B.as_matrix()
        T[:, :3, 3] = self.p_W_B
        T[:, 3, 3] = 1.0
        return T

    @classmethod
    def from_matrices(cls, t_ns: IntArray, T: FloatArray, **kwargs: object) -> Trajectory:
        """From (N, 4, 4) or (N, 3, 4) pose matrices; rotation blocks are projected onto SO(3)."""
        M = np.asarray(T, dtype=np.float64)
        if M.ndim != 3 or M.shape[1:] not in ((4, 4), (3, 4)):
            raise GeometryError(f"pose matrices must be (N, 4, 4) or (N, 3, 4), got {M.shape}")
        q = Rotation.from_matrix(M[:, :3, :3]).as_quat() if len(M) else np.zeros((0, 4))
        return cls(t_ns=np.asarray(t_ns), p_W_B=M[:, :3, 3], q_W_B_xyzw=q, **kwargs)  # type: ignore[arg-type]

    def select(self, idx: IntArray | slice) -> Trajectory:
        """The poses at ``idx``, in that order (time must still increase)."""
        return replace(
            self,
            t_ns=self.t_ns[idx],
            p_W_B=self.p_W_B[idx],
            q_W_B_xyzw=self.q_W_B_xyzw[idx],
            cov_p=None if self.cov_p is None else self.cov_p[idx],
        )

    def transformed(self, R: Rotation, t: FloatArray, s: float = 1.0) -> Trajectory:
        """Apply ``p -> s R p + t`` and ``R_W_B -> R R_W_B`` (a similarity of the world frame)."""
        p = s * R.apply(self.p_W_B) + np.asarray(t, dtype=np.float64) if len(self) else self.p_W_B
        q = (R * self.R_W_B).as_quat() if len(self) else self.q_W_B_xyzw
        cov = None
        if self.cov_p is not None:
            Rm = R.as_matrix()
            cov = s**2 * np.einsum("ij,njk,lk->nil", Rm, self.cov_p, Rm)
        return replace(self, p_W_B=p, q_W_B_xyzw=q, cov_p=cov)

    def interpolate(self, t_ns: IntArray) -> Trajectory:
        """Poses at ``t_ns`` (inside this trajectory's time span): positions linearly, attitudes by
        slerp, covariances linearly. Times outside the span are a :class:`GeometryError`.
        """
        tq = np.asarray(t_ns, dtype=np.int64)
        if len(self) < 2:
            raise GeometryError(f"trajectory {self.name!r}: interpolation needs at least 2 poses")
        if len(tq) and (tq.min() < self.t_ns[0] or tq.max() > self.t_ns[-1]):
            raise GeometryError(f"trajectory {self.name!r}: interpolation outside its time span")
        # Interpolate in a float time relative to the first pose so large stamps keep precision.
        t0 = self.t_ns[0]
        ts = (self.t_ns - t0).astype(np.float64)
        tqs = (tq - t0).astype(np.float64)
        p = np.column_stack([np.interp(tqs, ts, self.p_W_B[:, k]) for k in range(3)])
        q = _slerp(ts, self.q_W_B_xyzw, tqs)
        cov = None
        if self.cov_p is not None:
            flat = self.cov_p.reshape(len(self), 9)
            cov = np.column_stack([np.interp(tqs, ts, flat[:, k]) for k in range(9)]).reshape(
                -1, 3, 3
            )
        return replace(self, t_ns=tq, p_W_B=p, q_W_B_xyzw=q, cov_p=cov)

    def shifted(self, dt_ns: int) -> Trajectory:
        return replace(self, t_ns=self.t_ns + int(dt_ns))

    def path_length_m(self) -> float:
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.p_W_B, axis=0), axis=1).sum())


#: Query times a slerp takes at once (:meth:`Trajectory.interpolate`).
SLERP_CHUNK = 8192


def _slerp(ts: FloatArray, q_xyzw: FloatArray, tqs: FloatArray) -> FloatArray:
    """Quaternions (xyzw) slerped at ``tqs`` between those at ``ts``, :data:`SLERP_CHUNK`
    queries at a time on the poses around them only: one slerp over a 30-minute ground truth at
    100 Hz held ~25 MB of rotations at once, as many as the poses."""
    out = np.empty((len(tqs), 4))
    for s in range(0, len(tqs), SLERP_CHUNK):
        tq = tqs[s : s + SLERP_CHUNK]
        a = max(int(np.searchsorted(ts, tq.min(), side="right")) - 1, 0)
        b = min(int(np.searchsorted(ts, tq.max(), side="right")) + 1, len(ts))
        a = min(a, b - 2)  # a slerp needs two poses
        out[s : s + SLERP_CHUNK] = Slerp(ts[a:b], Rotation.from_quat(q_xyzw[a:b]))(tq).as_quat()
    return out
