"""The rig interface: what a simulated rig and a hardware DAQ/servo bridge both implement.

It lives in seft_msgs_py, below both sides, so that the controller side (the reference-force
builder and its compensators) installs and runs without the plant simulation.

After OpenFresco's split of experimental control from setup and site
(``SRC/experimentalControl/ExperimentalControl.h``): the test loop only ever calls
:meth:`Rig.measure`, :meth:`Rig.apply` and :meth:`Rig.limit_violation`, so the simulated rigs
of this package and a future hardware bridge are interchangeable.

Timing convention (sampled data, control period ``dt``):

* ``measure()`` returns the sensor readings at ``t_k = k*dt`` (the current step ``k``);
* ``apply(command)`` holds ``command`` over ``[t_k, t_k+1)`` (zero-order hold) and advances
  the rig to step ``k+1``.
"""

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

__all__ = ['Measurement', 'Rig', 'COMMAND_VALVE', 'COMMAND_FORCE']

#: ``Rig.command_kind`` of a rig driven by a servo-valve voltage [V].
COMMAND_VALVE = 'valve_command_V'
#: ``Rig.command_kind`` of a rig driven directly by the reference force [N].
COMMAND_FORCE = 'reference_force_N'


@dataclass(frozen=True)
class Measurement:
    """Sensor readings of one sample, SI units (REP-103).

    Attributes
    ----------
    step : int
        Sample index k (``time_s = k*dt``).
    time_s : float
        Sample time [s].
    displacement_m : float
        Specimen displacement x [m].
    velocity_m_s : float
        Specimen velocity [m/s].
    acceleration_m_s2 : float
        Specimen acceleration (accelerometer) [m/s^2].
    force_N : float
        Measured (load-cell) actuator force on the specimen [N].
    """

    step: int
    time_s: float
    displacement_m: float
    velocity_m_s: float
    acceleration_m_s2: float
    force_N: float


@runtime_checkable
class Rig(Protocol):
    """An actuator driving a specimen, sampled every ``dt`` seconds.

    Attributes
    ----------
    dt : float
        Control period [s].
    step : int
        Index of the current sample.
    command_kind : str
        :data:`COMMAND_VALVE` (the force servo controller closes the loop) or
        :data:`COMMAND_FORCE` (the rig takes the reference force, controller bypassed).
    """

    dt: float
    step: int
    command_kind: str

    def measure(self) -> Measurement:
        """Return the sensor readings at the current step."""

    def apply(self, command: float) -> None:
        """Hold `command` over the current step and advance to the next one."""

    def limit_violation(self) -> str | None:
        """Return why the rig is outside its safe envelope at the current step, or None."""
