"""PX4 EKF2's GNSS quality checks: which fixes may be fused, and why the others were refused.

The checks of PX4's ``GnssChecks`` (``aid_sources/gnss/gnss_checks.cpp``), selected by the bits
of ``EKF2_GPS_CHECK`` with the ``EKF2_REQ_*`` limits: fix type (always), satellites, PDOP,
reported horizontal / vertical / speed accuracy, and, while the vehicle is landed and at rest,
the low-pass filtered (10 s) horizontal and vertical drift of the position and the filtered
horizontal and vertical speed. A receiver qualifies once every selected check has passed for
``EKF2_REQ_GPS_H`` (10 s by default) since the last failure; after that only the fix type and
coarse accuracy limits apply (50 m, 10 m/s) and a failure costs ``max(1 s, REQ_GPS_H / 10)``
of passing again. A fix that does not pass is not fused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quadnav.errors import EstimationError
from quadnav.estimation.horizon import require_positive
from quadnav.units import s_to_ns

__all__ = ["CHECK_NAMES", "GnssCheckConfig", "GnssChecks", "run_gnss_checks"]

# Bit k of a fix's failure mask is CHECK_NAMES[k]; bits 0-8 are EKF2_GPS_CHECK's bits.
CHECK_NAMES = (
    "satellites", "pdop", "eph", "epv", "speed_accuracy", "horizontal_drift",
    "vertical_drift", "horizontal_speed", "vertical_speed", "fix_type",
)  # fmt: skip
FIX_BIT = 1 << 9
_EARTH_RADIUS_M = 6_371_000.0


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssCheckConfig:
    """PX4's limits: ``EKF2_GPS_CHECK`` (mask), ``EKF2_REQ_NSATS``, ``_PDOP``, ``_EPH``,
    ``_EPV``, ``_SACC``, ``_HDRIFT``, ``_VDRIFT``, ``_GPS_H`` and the minimum fix type."""

    mask: int = 245
    min_fix: int = 3
    min_sats: int = 6
    max_pdop: float = 2.5
    max_eph_m: float = 3.0
    max_epv_m: float = 5.0
    max_sacc_m_s: float = 0.5
    max_hdrift_m_s: float = 0.1
    max_vdrift_m_s: float = 0.2
    pass_s: float = 10.0

    def __post_init__(self) -> None:
        require_positive(
            self,
            (
                "max_pdop",
                "max_eph_m",
                "max_epv_m",
                "max_sacc_m_s",
                "max_hdrift_m_s",
                "max_vdrift_m_s",
            ),
        )
        if not (math.isfinite(self.pass_s) and self.pass_s >= 0):
            raise EstimationError(f"GnssCheckConfig.pass_s must be >= 0, got {self.pass_s}")


@dataclass(frozen=True, slots=True, kw_only=True)
class GnssChecks:
    """Per fix: ``failed`` (bit k: ``CHECK_NAMES[k]`` failed and is selected) and ``usable``
    (the receiver had qualified and this fix passed). ``t_qualified_ns``: when it first did."""

    t_ns: NDArray[np.int64]
    failed: NDArray[np.int64]
    usable: NDArray[np.bool_]
    t_qualified_ns: int | None

    def reasons(self, k: int) -> tuple[str, ...]:
        """Why fix ``k`` was refused: its failed checks, or that the receiver had not yet
        passed them for long enough."""
        if self.usable[k]:
            return ()
        bits = tuple(n for b, n in enumerate(CHECK_NAMES) if int(self.failed[k]) >> b & 1)
        return bits or ("not_yet_passed_long_enough",)

    def refused_counts(self) -> dict[str, int]:
        """How many refused fixes each reason covers (a fix may have several)."""
        out: dict[str, int] = {}
        for k in np.flatnonzero(~self.usable).tolist():
            for r in self.reasons(k):
                out[r] = out.get(r, 0) + 1
        return out


@dataclass(slots=True)
class _Drift:
    """The at-rest drift filters (10 s low-pass) and the previous fix."""

    t_prev_ns: int | None = None
    prev: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pos_rate: NDArray[np.float64] | None = None
    vel_ne: NDArray[np.float64] | None = None
    vel_d: float = 0.0

    def reset(self) -> None:
        self.pos_rate, self.vel_ne, self.vel_d = np.zeros(3), np.zeros(2), 0.0

    def update(
        self,
        t_ns: int,
        lla: tuple[float, float, float],
        v_ned: NDArray[np.float64],
        c: GnssCheckConfig,
    ) -> int:
        """Filter one fix taken at rest; return the drift and speed failure bits."""
        if self.pos_rate is None or self.vel_ne is None:
            self.reset()
        assert self.pos_rate is not None and self.vel_ne is not None
        if self.t_prev_ns is None:
            self.t_prev_ns, self.prev = t_ns, lla
        dt = min(max((t_ns - self.t_prev_ns) * 1e-9, 0.001), 10.0)
        k = dt / 10.0
        lat0 = math.radians(self.prev[0])
        d = np.array(
            [
                math.radians(lla[0] - self.prev[0]) * _EARTH_RADIUS_M,
                math.radians(lla[1] - self.prev[1]) * _EARTH_RADIUS_M * math.cos(lat0),
                self.prev[2] - lla[2],
            ]
        )
        lim = np.array([c.max_hdrift_m_s, c.max_hdrift_m_s, c.max_vdrift_m_s])
        self.pos_rate = np.clip(d / dt * k + self.pos_rate * (1 - k), -10 * lim, 10 * lim)
        v_ne = np.clip(v_ned[0:2], -10 * c.max_hdrift_m_s, 10 * c.max_hdrift_m_s)
        self.vel_ne = v_ne * k + self.vel_ne * (1 - k)
        vz = min(max(float(v_ned[2]), -10 * c.max_vdrift_m_s), 10 * c.max_vdrift_m_s)
        self.vel_d = vz * k + self.vel_d * (1 - k)
        bits = (1 << 5) * bool(np.hypot(*self.pos_rate[0:2]) > c.max_hdrift_m_s)
        bits |= (1 << 6) * bool(abs(self.pos_rate[2]) > c.max_vdrift_m_s)
        bits |= (1 << 7) * bool(np.hypot(*self.vel_ne) > c.max_hdrift_m_s)
        bits |= (1 << 8) * bool(abs(self.vel_d) > c.max_vdrift_m_s)
        return int(bits)


def _fix_bits(
    fix: int, sats: int, pdop: float, eph: float, epv: float, sacc: float, c: GnssCheckConfig
) -> int:
    """The receiver's own quality figures against the limits (NaN counts as a failure)."""
    ok = (
        sats >= c.min_sats, not pdop > c.max_pdop and math.isfinite(pdop), eph <= c.max_eph_m,
        epv <= c.max_epv_m, sacc <= c.max_sacc_m_s,
    )  # fmt: skip
    bits = sum(1 << b for b, good in enumerate(ok) if not good)
    return bits | (FIX_BIT if fix < c.min_fix else 0)


def run_gnss_checks(
    gps: dict[str, NDArray[np.float64]], at_rest: NDArray[np.bool_], cfg: GnssCheckConfig
) -> GnssChecks:
    """Run PX4's checks over the fixes of ``gps`` (keys ``t_ns``, ``lat``, ``lon``, ``alt``,
    ``v_enu``, ``eph``, ``epv``, ``s_var``, ``fix``, and ``nsats``/``pdop`` when logged),
    ``at_rest[k]`` saying whether the vehicle stood landed and still at fix ``k``."""
    n = len(gps["t_ns"])
    nsats = gps.get("nsats", np.full(n, 99))
    pdop = gps.get("pdop", np.zeros(n))
    failed = np.zeros(n, np.int64)
    usable = np.zeros(n, bool)
    drift = _Drift()
    sel = cfg.mask & 0x1FF | FIX_BIT
    t_fail: int | None = None
    t_qualified: int | None = None
    coarse = GnssCheckConfig(
        mask=cfg.mask,
        min_fix=cfg.min_fix,
        min_sats=0,
        max_pdop=1e9,
        max_eph_m=50.0,
        max_epv_m=50.0,
        max_sacc_m_s=10.0,
    )
    for k in range(n):
        t = int(gps["t_ns"][k])
        t_fail = t if t_fail is None else t_fail  # PX4: assume failed first time through
        v_ned = np.array([gps["v_enu"][k][1], gps["v_enu"][k][0], -gps["v_enu"][k][2]])
        lla = (float(gps["lat"][k]), float(gps["lon"][k]), float(gps["alt"][k]))
        if t_qualified is None:
            bits = _fix_bits(
                int(gps["fix"][k]),
                int(nsats[k]),
                float(pdop[k]),
                float(gps["eph"][k]),
                float(gps["epv"][k]),
                float(gps["s_var"][k]),
                cfg,
            )
            if at_rest[k]:
                bits |= drift.update(t, lla, v_ned, cfg)
            else:
                drift.reset()  # moving (PX4: in the air, these checks pass)
            need_ns = s_to_ns(cfg.pass_s)
        else:  # qualified: the coarse checks only
            bits = _fix_bits(
                int(gps["fix"][k]),
                99,
                0.0,
                float(gps["eph"][k]),
                float(gps["epv"][k]),
                float(gps["s_var"][k]),
                coarse,
            )
            need_ns = s_to_ns(max(1.0, cfg.pass_s / 10))
        drift.t_prev_ns, drift.prev = t, lla
        failed[k] = bits & sel
        if failed[k]:
            t_fail = t
        elif t - t_fail > need_ns:
            usable[k] = True
            t_qualified = t if t_qualified is None else t_qualified
    return GnssChecks(
        t_ns=np.asarray(gps["t_ns"], np.int64),
        failed=failed,
        usable=usable,
        t_qualified_ns=t_qualified,
    )
