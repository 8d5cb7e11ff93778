"""Vehicle dynamics and sensor models."""

from quadnav.errors import SimError
from quadnav.sim.planar import PlanarParams, PlanarQuadrotor, PlanarState
from quadnav.sim.sensors import DelayLine, ImuSensor, PositionSensor, Sensor

__all__ = [
    "DelayLine",
    "ImuSensor",
    "PlanarParams",
    "PlanarQuadrotor",
    "PlanarState",
    "PositionSensor",
    "Sensor",
    "SimError",
]
