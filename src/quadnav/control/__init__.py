"""Controllers and setpoint profiles."""

from quadnav.control.planar import PlanarSetpointProfile, ThesisPlanarController
from quadnav.errors import ControlError

__all__ = ["ControlError", "PlanarSetpointProfile", "ThesisPlanarController"]
