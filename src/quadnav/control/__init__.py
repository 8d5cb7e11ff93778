"""Controllers and setpoint profiles: every controller is a :class:`Controller` (a state
estimate and a setpoint in, a :class:`Command` out)."""

from quadnav.control.base import Command, Controller, Setpoint, SetpointSource, truth_estimate
from quadnav.control.planar import PlanarSetpointProfile, ThesisPlanarController
from quadnav.errors import ControlError

__all__ = [
    "Command",
    "ControlError",
    "Controller",
    "PlanarSetpointProfile",
    "Setpoint",
    "SetpointSource",
    "ThesisPlanarController",
    "truth_estimate",
]
