"""The simulated IMU: true motion, the certificate's sensor model with switchable effects,
fault injection. ``simulate(certificate, trajectory, seed, effects, faults)``."""

from .effects import BiasStep, Effects, PeriodicDisturbance, TemperatureProfile
from .faults import Fault, apply_faults, parse_fault
from .simulator import SimResult, Simulator, simulate, true_certificate
from .trajectories import (
    Trajectory,
    multi_position,
    relative_rotation,
    still,
    turntable,
    vehicle_run,
)

__all__ = [
    "BiasStep",
    "Effects",
    "Fault",
    "PeriodicDisturbance",
    "SimResult",
    "Simulator",
    "TemperatureProfile",
    "Trajectory",
    "apply_faults",
    "multi_position",
    "parse_fault",
    "relative_rotation",
    "simulate",
    "still",
    "true_certificate",
    "turntable",
    "vehicle_run",
]
