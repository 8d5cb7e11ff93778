"""Online camera-IMU time offset (VINS-Mono's ``estimate_td``, here on its own): vision's
rotations between image pairs against the gyro's over a sliding buffer of the last seconds.

Convention (VINS'): ``t_imu = t_image + td``. A rotation ``R_C0_C1`` between image stamps
``t0`` and ``t1`` is the gyro's motion over ``[t0 + td, t1 + td]``. Each span is compared as a
mean rate: the camera's ``Log(R_C0_C1) / (t1 - t0)`` turned into the body by ``R_B_C``, the
gyro's ``Log(Q(t0 + td)^T Q(t1 + td)) / (t1 - t0)`` with ``Q`` the gyro's attitude integrated
with the rate linear between samples (so spans of any length, consecutive frames or keyframes, compare exactly),
less one constant (the gyro bias, a nuisance). Without ``R_B_C`` the rotation between the two
is fitted too (Kabsch on the centred rates, per candidate offset). The cost is scanned on a
5 ms grid over ``±max_td_s`` (or, once settled, near the last estimate), then at 1 ms and at
0.1 ms around its minimum, where a parabola gives the offset. ``sigma_s`` is the largest of
that parabola's, one through ±10 ms (the curvature of a shift, not of the noise of the gyro
samples the spans end on) and the delete-a-quarter jackknife of the window (a curvature takes
the residuals as independent; errors that follow the motion are not).

A constant rate says nothing about a shift: while the camera's rate varies by less than
``min_rate_change_rad_s`` (RMS about its mean; without ``R_B_C``, on every axis), or fewer
than ``min_rotations`` spans are buffered, :meth:`TimeOffsetEstimator.estimate` answers None.
A rate that changes slowly says too little: the estimate's ``excitation_rad_s2`` is the RMS
change of the gyro's rate over the spans per second of shift (the ±10 ms parabola's curvature
per span), and under ``min_rate_slope_rad_s2`` it is marked not ``excited``. On steady laps
(0.1-0.4 rad/s^2; realistic MH_01 1.3-1.7, V1_02 1.9-3.2) vision's errors that follow the
motion (the translation's share of a rotation follows a lap's sway as a shifted rate would)
gave answers 10-20 ms off with sigmas of 1-3 ms; no sigma from the residuals can see such an
error, since it is itself a shift (on motions degenerate for the offset see Yang et al.,
"Degenerate motion analysis for aided INS with online spatial and temporal sensor
calibration", RA-L 2019).

Bad input: a non-finite or malformed rate or rotation, or a span with ``t1 <= t0``, is refused
with a :class:`~quadnav.errors.VioError` naming it; a sample whose stamp is not after the last
one of its kind is ignored and counted in :attr:`TimeOffsetEstimator.rejected`. Push the
images' own stamps: an estimate is the whole offset, not a correction to one already applied.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from quadnav.errors import VioError
from quadnav.geometry.multiview import kabsch
from quadnav.geometry.rotations import compose_quats_xyzw, unit_quats_xyzw
from quadnav.units import NS_PER_S

__all__ = ["TdEstimate", "TimeOffsetEstimator"]

FloatArray = NDArray[np.float64]

#: The middle scan's step (s): the wide one is 5 times coarser, the fine one 10 times finer.
_GRID_S = 1e-3
#: The steps of ``_GRID_S`` either side of the minimum whose parabola gives the excitation and
#: the sigma: ±10 ms, the scale of a shift, not of the gyro's sample noise (at 0.1 ms steps the
#: cost's curvature is mostly the noise of the spans' end samples: 0.4-0.6 rad/s^2 of rate
#: change on the realistic room laps, 0.2-0.4 at this scale).
_WIDE = 10
#: The jackknife's groups (consecutive parts of the window).
_QUARTERS = 4


@dataclass(frozen=True, slots=True, kw_only=True)
class TdEstimate:
    """The time offset ``td_s`` (``t_imu = t_image + td``), its standard deviation, whether it
    has settled (``sigma_s`` under the estimator's threshold) and how many spans it used."""

    td_s: float
    sigma_s: float
    converged: bool
    n_rotations: int
    #: the RMS change of the gyro's rate over the spans per second of shift (rad/s^2): what
    #: an offset is measured by (the square root of the cost's curvature per span)
    excitation_rad_s2: float
    #: ``excitation_rad_s2`` at least the estimator's ``min_rate_slope_rad_s2``; if not, the
    #: motion does not tell the offset from vision's errors and the answer is not to be used
    excited: bool


@dataclass(frozen=True, slots=True)
class _Buffer:
    """The gyro (times in s from the first sample, rates, their slopes, attitudes) and the spans
    the whole search range keeps inside its cover (starts, ends in s; camera rates)."""

    tg: FloatArray
    wg: FloatArray
    dw: FloatArray
    Q: Rotation
    t0: FloatArray
    t1: FloatArray
    w_cam: FloatArray


def _parabola(x: FloatArray, y: FloatArray) -> tuple[float, float, float] | None:
    """``(a2, a1, a0)`` of the least-squares parabola through ``(x, y)``, or None unless it
    opens upwards."""
    a2, a1, a0 = (float(v) for v in np.polyfit(x, y, 2))
    return (a2, a1, a0) if a2 > 0.0 else None


def _rotation(R: Rotation | ArrayLike) -> Rotation:
    if isinstance(R, Rotation):
        if not R.single or not np.isfinite(R.as_quat()).all():
            raise VioError("push_rotation: R_C0_C1 must be one finite rotation")
        return R
    M = np.asarray(R, dtype=np.float64)
    if M.shape != (3, 3) or not np.isfinite(M).all():
        raise VioError(f"push_rotation: R_C0_C1 must be a finite 3x3 matrix, got shape {M.shape}")
    if not np.allclose(M @ M.T, np.eye(3), atol=1e-6) or np.linalg.det(M) <= 0.0:
        raise VioError("push_rotation: R_C0_C1 is not a rotation matrix")
    return Rotation.from_matrix(M)


def _slopes(tg: FloatArray, wg: FloatArray) -> FloatArray:
    """The rate's change per second after each sample (the last one holds)."""
    out = np.zeros_like(wg)
    out[:-1] = np.diff(wg, axis=0) / np.diff(tg)[:, None]
    return out


def _attitudes(tg: FloatArray, wg: FloatArray) -> Rotation:
    """The gyro's attitude at each sample, the rate linear between samples (a sample is the
    rate at its instant: holding it would shift the gyro by half a period). The running product
    of the steps by a prefix scan: log2(n) vectorised compositions, not n single ones (each
    SciPy's to the bit: :func:`~quadnav.geometry.rotations.compose_quats_xyzw`)."""
    q = np.empty((len(tg), 4))
    q[0] = [0.0, 0.0, 0.0, 1.0]
    q[1:] = Rotation.from_rotvec(0.5 * (wg[:-1] + wg[1:]) * np.diff(tg)[:, None]).as_quat()
    d = 1
    while d < len(q):
        q[d:] = compose_quats_xyzw(unit_quats_xyzw(q[:-d]), unit_quats_xyzw(q[d:]))
        d *= 2
    return Rotation.from_quat(q)


def _gyro_rates(buf: _Buffer, td: FloatArray) -> FloatArray:
    """The gyro's mean rate over each span shifted by each offset: (len(td), spans, 3)."""
    a = (buf.t0[None, :] + td[:, None]).ravel()
    b = (buf.t1[None, :] + td[:, None]).ravel()
    Q = buf.Q.as_quat()

    def at(t: FloatArray) -> FloatArray:
        k = np.clip(np.searchsorted(buf.tg, t, side="right") - 1, 0, len(buf.tg) - 1)
        u = (t - buf.tg[k])[:, None]
        step = Rotation.from_rotvec((buf.wg[k] + 0.5 * buf.dw[k] * u) * u).as_quat()
        return compose_quats_xyzw(Q[k], step)

    qa = at(a)
    qa[:, :3] = -qa[:, :3]  # the inverse
    # the product as the unit quaternion it is (no second normalisation)
    rel_q = Rotation(compose_quats_xyzw(qa, at(b)), normalize=False, copy=False)
    rel = rel_q.as_rotvec() / (b - a)[:, None]
    return np.asarray(rel.reshape(len(td), len(buf.t0), 3), dtype=np.float64)


class TimeOffsetEstimator:
    """The camera-IMU time offset from gyro readings and vision's rotations between images.

    ``R_B_C`` is the camera's mount (None: fitted from the data, which then needs rotation
    about every axis); ``window_s`` the buffer kept; ``max_td_s`` the search's half range;
    ``converged_sigma_s`` the standard deviation under which an estimate counts as settled;
    ``refresh_spans`` how many new spans make :meth:`estimate` search again;
    ``min_rate_slope_rad_s2`` the rate's change an estimate needs to be ``excited``."""

    def __init__(
        self,
        R_B_C: Rotation | None = None,
        *,
        window_s: float = 6.0,
        max_td_s: float = 0.1,
        min_rotations: int = 20,
        min_rate_change_rad_s: float = 0.05,
        converged_sigma_s: float = 5e-4,
        refresh_spans: int = 10,
        min_rate_slope_rad_s2: float = 0.6,
    ) -> None:
        if not (0.0 < max_td_s < window_s / 4):
            raise VioError(f"max_td_s must be in (0, window_s / 4), got {max_td_s}")
        self._R_B_C = R_B_C
        self._window_ns = int(window_s * NS_PER_S)
        self._max_td_s = float(max_td_s)
        self._min_rotations = int(min_rotations)
        self._min_change = float(min_rate_change_rad_s)
        self._converged_sigma_s = float(converged_sigma_s)
        self._min_slope = float(min_rate_slope_rad_s2)
        self._gyro: deque[tuple[int, FloatArray]] = deque()
        self._spans: deque[tuple[int, int, FloatArray]] = deque()
        self._rejected = {"gyro_out_of_order": 0, "rotation_out_of_order": 0}
        self._refresh_spans = max(int(refresh_spans), 1)
        self._new_spans = 0
        self._last: TdEstimate | None = None

    @property
    def rejected(self) -> dict[str, int]:
        """Samples ignored for a stamp not after the last of their kind, per kind."""
        return dict(self._rejected)

    def push_gyro(self, t_ns: int, w_B: ArrayLike) -> None:
        """One gyro reading (rad/s, body) at IMU time ``t_ns``."""
        w = np.asarray(w_B, dtype=np.float64)
        if w.shape != (3,) or not np.isfinite(w).all():
            raise VioError(f"push_gyro: w_B must be 3 finite rates (rad/s), got {w.tolist()}")
        if self._gyro and int(t_ns) <= self._gyro[-1][0]:
            self._rejected["gyro_out_of_order"] += 1
            return
        self._gyro.append((int(t_ns), w))
        self._trim()

    def push_rotation(self, t0_ns: int, t1_ns: int, R_C0_C1: Rotation | ArrayLike) -> None:
        """Vision's rotation of the camera from the image at ``t0_ns`` to the one at ``t1_ns``
        (``R_C0_C1``: camera 1's attitude in camera 0), the images' own stamps."""
        if int(t1_ns) <= int(t0_ns):
            raise VioError(f"push_rotation: t1_ns ({t1_ns}) must be after t0_ns ({t0_ns})")
        R = _rotation(R_C0_C1)
        if self._spans and int(t0_ns) < self._spans[-1][0]:
            self._rejected["rotation_out_of_order"] += 1
            return
        dt_s = (int(t1_ns) - int(t0_ns)) / NS_PER_S
        self._spans.append((int(t0_ns), int(t1_ns), R.as_rotvec() / dt_s))
        self._new_spans += 1
        self._trim()

    def _trim(self) -> None:
        newest = max(
            self._gyro[-1][0] if self._gyro else 0, self._spans[-1][1] if self._spans else 0
        )
        while self._spans and self._spans[0][0] < newest - self._window_ns:
            self._spans.popleft()
        margin = int(2 * self._max_td_s * NS_PER_S)
        while len(self._gyro) > 2 and self._gyro[1][0] < newest - self._window_ns - margin:
            self._gyro.popleft()

    def _usable(self) -> _Buffer | None:
        """The buffer the search runs on, or None: fewer than ``min_rotations`` spans inside
        the gyro's cover, or too little change of rate (:meth:`_excited`). Both are known from
        the spans: the gyro's arrays are built only for a search."""
        if len(self._gyro) < 3:
            return None
        base = self._gyro[0][0]
        first, last = (self._gyro[0][0] - base) / NS_PER_S, (self._gyro[-1][0] - base) / NS_PER_S
        m = self._max_td_s
        spans = [
            ((a - base) / NS_PER_S, (b - base) / NS_PER_S, w)
            for a, b, w in self._spans
            if (a - base) / NS_PER_S - m >= first and (b - base) / NS_PER_S + m <= last
        ]
        if len(spans) < self._min_rotations:
            return None
        w_cam = np.array([s[2] for s in spans])
        if self._R_B_C is not None:
            w_cam = self._R_B_C.apply(w_cam)
        if not self._excited(w_cam):
            return None
        tg = np.array([(t - base) / NS_PER_S for t, _ in self._gyro])
        wg = np.array([w for _, w in self._gyro])
        return _Buffer(
            tg=tg,
            wg=wg,
            dw=_slopes(tg, wg),
            Q=_attitudes(tg, wg),
            t0=np.array([s[0] for s in spans]),
            t1=np.array([s[1] for s in spans]),
            w_cam=w_cam,
        )

    def _costs(self, buf: _Buffer, td: FloatArray) -> FloatArray:
        """The cost at each offset of ``td``: squared residuals, bias (and mount) removed."""
        return self._costs_of(_gyro_rates(buf, td), buf.w_cam)

    def _costs_of(self, g: FloatArray, w_cam: FloatArray) -> FloatArray:
        """:meth:`_costs` from the gyro's rates ``g`` (offsets, spans, 3) and the camera's."""
        g = g - g.mean(axis=1, keepdims=True)
        c = np.broadcast_to(w_cam - w_cam.mean(axis=0), g.shape)
        if self._R_B_C is None:
            c = np.einsum("mij,mnj->mni", kabsch(c, g)[0], c)
        return np.asarray(np.sum((g - c) ** 2, axis=(1, 2)), dtype=np.float64)

    def _excited(self, w_cam: FloatArray) -> bool:
        centred = w_cam - w_cam.mean(axis=0)
        if self._R_B_C is not None:
            return bool(np.sqrt(np.mean(np.sum(centred**2, axis=1))) >= self._min_change)
        weakest = np.linalg.svd(centred, compute_uv=False)[-1] / np.sqrt(len(centred))
        return bool(weakest >= self._min_change / np.sqrt(3.0))

    def _search(self, buf: _Buffer) -> float:
        """The coarse minimum: a 5 ms scan over the whole range then 1 ms around its best, or,
        once an estimate has settled, 1 ms steps within 5 ms of it."""
        last = self._last
        if last is not None and last.converged:
            centre = last.td_s
        else:
            wide = np.arange(-self._max_td_s, self._max_td_s + 1e-9, 5 * _GRID_S)
            centre = float(wide[int(np.argmin(self._costs(buf, wide)))])
        near = np.asarray(
            np.clip(centre + np.arange(-5, 6) * _GRID_S, -self._max_td_s, self._max_td_s),
            dtype=np.float64,
        )
        return float(near[int(np.argmin(self._costs(buf, near)))])

    def estimate(self) -> TdEstimate | None:
        """The offset over the buffer, or None while it holds too few spans or too little
        change of rotation rate (marked not ``excited`` while the rate changes too slowly). Recomputed once ``refresh_spans`` new spans have come in
        (the search costs tens of milliseconds), the last answer returned in between."""
        if self._last is not None and self._new_spans < self._refresh_spans:
            return self._last
        buf = self._usable()
        if buf is None:
            return None
        self._new_spans = 0
        fit = self._fine(buf, self._search(buf))
        if fit is None:
            return None
        td, (a2, a1, a0) = fit
        n = len(buf.t0)
        unknowns = 2 if self._R_B_C is not None else 5
        dof = max(3 * n - unknowns - 3, 1)
        var_r = float(a0 - a1**2 / (4.0 * a2)) / dof
        sigma = float(np.sqrt(max(var_r, 0.0) / a2))  # cost'' = 2 a2; var = 2 var_r / cost''
        m = self._max_td_s
        wide = np.asarray(
            np.clip(td + np.arange(-_WIDE, _WIDE + 1) * _GRID_S, -m, m), dtype=np.float64
        )
        g_wide = _gyro_rates(buf, wide)
        curve = _parabola(wide - td, self._costs_of(g_wide, buf.w_cam))
        if curve is None:
            return None
        excitation = float(np.sqrt(curve[0] / n))
        var_w = float(curve[2] - curve[1] ** 2 / (4.0 * curve[0])) / dof
        sigma = max(
            sigma, float(np.sqrt(max(var_w, 0.0) / curve[0])), self._jackknife(buf, wide, g_wide)
        )
        self._last = TdEstimate(
            td_s=td,
            sigma_s=sigma,
            converged=sigma < self._converged_sigma_s,
            n_rotations=n,
            excitation_rad_s2=excitation,
            excited=excitation >= self._min_slope,
        )
        return self._last

    def _fine(self, buf: _Buffer, centre: float) -> tuple[float, tuple[float, float, float]] | None:
        """The minimum near ``centre`` (the 1 ms scan's best): 0.1 ms steps within 1 ms of it,
        a parabola through the seven around the least; the offset and the parabola (about the
        step nearest the minimum), or None where it does not open upwards."""
        fine = np.asarray(centre + np.arange(-10, 11) * (_GRID_S / 10), dtype=np.float64)
        costs = self._costs(buf, fine)
        k = int(np.clip(np.argmin(costs), 3, len(fine) - 4))
        fit = _parabola(fine[k - 3 : k + 4] - fine[k], costs[k - 3 : k + 4])
        if fit is None:
            return None
        return float(fine[k] - fit[1] / (2.0 * fit[0])), fit

    def _jackknife(self, buf: _Buffer, wide: FloatArray, g_wide: FloatArray) -> float:
        """The offset's standard deviation by the delete-a-group jackknife: the search's last
        two steps (1 ms on ``wide``, whose gyro rates are ``g_wide``, then 0.1 ms) with each
        quarter of the window left out in turn. Where vision's errors follow the motion the
        quarters disagree far beyond what the residuals' spread says (infinite if a quarter's
        answer has no minimum)."""
        mid = 0.5 * (buf.t0 + buf.t1)
        edges = np.quantile(mid, np.linspace(0.0, 1.0, _QUARTERS + 1))
        part = np.clip(np.searchsorted(edges, mid, side="right") - 1, 0, _QUARTERS - 1)
        tds = []
        for q in range(_QUARTERS):
            keep = part != q
            rest = dataclasses.replace(buf, t0=buf.t0[keep], t1=buf.t1[keep], w_cam=buf.w_cam[keep])
            coarse = self._costs_of(g_wide[:, keep], rest.w_cam)
            fit = self._fine(rest, float(wide[int(np.argmin(coarse))]))
            if fit is None:
                return float("inf")
            tds.append(fit[0])
        spread = np.asarray(tds) - np.mean(tds)
        return float(np.sqrt((_QUARTERS - 1) / _QUARTERS * np.sum(spread**2)))
