"""Fly `quadnav sim --mavlink` with MAVSDK's offboard API (MAVSDK is not a quadnav dependency):

    python3 -m venv /tmp/mavsdk && /tmp/mavsdk/bin/pip install mavsdk -e .
    /tmp/mavsdk/bin/python examples/mavsdk_offboard_square.py

Starts the simulated vehicle on loopback, connects MAVSDK (v4, the native binding), sets an
offboard setpoint, arms, starts offboard and flies a 2 m square at 1.5 m, printing how close the
vehicle came to each corner.
"""

from __future__ import annotations

import time

import numpy as np
from mavsdk import ComponentType, Configuration, Mavsdk  # type: ignore[import-not-found]
from mavsdk.plugins.action import Action  # type: ignore[import-not-found]
from mavsdk.plugins.offboard import Offboard, PositionNedYaw  # type: ignore[import-not-found]

from quadnav.experiments.sitl import SitlVehicle

PORT = 14613


def main() -> None:
    sitl = SitlVehicle(url=f"udpin:127.0.0.1:{PORT}")
    sitl.start()
    try:
        mav = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        mav.add_any_connection(f"udpout://127.0.0.1:{PORT}")
        system = mav.first_autopilot(10.0)
        offboard, action = Offboard(system), Action(system)
        offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -1.5, 0.0))
        print("arm:", action.arm(), " offboard:", offboard.start())
        for n, e in [(0, 0), (0, 2), (2, 2), (2, 0), (0, 0)]:
            offboard.set_position_ned(PositionNedYaw(float(n), float(e), -1.5, 0.0))
            best, t_end = np.inf, time.monotonic() + 8.0
            while time.monotonic() < t_end and best >= 0.1:
                time.sleep(0.05)
                best = min(best, float(np.linalg.norm(sitl.truth_log[-1][1] - [e, n, 1.5])))
            print(f"corner N {n} E {e}: within {best:.3f} m")
    finally:
        sitl.stop()


if __name__ == "__main__":
    main()
