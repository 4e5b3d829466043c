"""A lab's own model of its actuator and specimen as a simulated rig (``rig_model:
state_space``): rehearse the test on it before the hardware.

The rig steps the ``plant_model`` (:class:`~seft_msgs_py.plant.PlantModel`: the valve command
[V] to the measured force, displacement, velocity and acceleration, discrete at ``dt``, the
specimen in it) exactly, as the compensators and the guard model it, through the rig's
sensors (noise, accelerometer range) and its stroke and force limits. A model the lab wrote
from its hardware, or the one ``seft identify`` made of its bags: the test and everything seft
predicts of it then run on the same plant, so what differs between the rehearsal and the
hardware is what the model leaves out.

``rig_plant_model`` (same schema) gives the rig a plant of its own, apart from the
``plant_model`` the compensators and the guard read: the lab's model of its hardware as the
rig, the identified model (``seft identify --params``) as the design's, so that the
rehearsal shows what the gap between the two does to the test.
"""

import math
from typing import Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_VALVE, Measurement
from seft_msgs_py.parameters import rig_plant_parameter
from seft_msgs_py.plant import OUTPUTS, PlantModel, parse_plant
from seft_msgs_py.sampling import linear_map
from seft_plant_sim.sensors import Sensors
from seft_plant_sim.specimen import SafetyLimits

__all__ = ['StateSpaceRig']


_F, _X, _V, _A = (OUTPUTS.index(n) for n in ('force_N', 'displacement_m', 'velocity_m_s',
                                             'acceleration_m_s2'))


class StateSpaceRig:
    """A discrete plant model driven by the valve command (Rig protocol).

    Parameters
    ----------
    plant : PlantModel
        Its ``dt`` is the rig's.
    sensors : Sensors, optional
    limits : SafetyLimits, optional

    Notes
    -----
    ``s[k+1] = A s[k] + B u[k]``, readings ``C s[k]``, both as straight-line float code
    (:func:`~seft_msgs_py.sampling.linear_map`).
    """

    command_kind = COMMAND_VALVE

    def __init__(self, plant: PlantModel, sensors: Sensors | None = None,
                 limits: SafetyLimits | None = None):
        self.plant = plant
        self.dt = plant.dt
        self.sensors = sensors or Sensors()
        self.limits = limits or SafetyLimits()
        self.step = 0
        n = plant.order
        self._n = n
        self._advance = linear_map(np.hstack([plant.a, plant.b]), name='advance')
        self._read = linear_map(plant.c, name='read')
        self._w = [0.0] * (n + 1)                       # [state, command]
        self._y = self._read(self._w)

    @classmethod
    def from_parameters(cls, params: Mapping, *, rk4_substeps: int = 1) -> 'StateSpaceRig':
        """Build from the rig's plant
        (:func:`~seft_msgs_py.parameters.rig_plant_parameter`: ``rig_plant_model``, else
        ``plant_model``; one is required), ``dt``, the sensors and the limits
        (``rk4_substeps``, of :func:`~seft_plant_sim.rigs.make_rig`, is unused: the model is
        linear and stepped exactly).

        Raises
        ------
        ParameterError
            Neither model, or one that does not parse (the message names the parameter and
            the field).
        """
        name = rig_plant_parameter(params)
        if name is None:
            raise ParameterError("rig_model 'state_space': expected plant_model (the lab's model "
                                 'of its actuator and specimen: a state space or transfer '
                                 'function, or the file seft identify --params wrote) or '
                                 "rig_plant_model (the rig's own, apart from plant_model)")
        plant = parse_plant(params[name], dt=float(params['dt']), where=f'parameter {name}')
        rng = float(params.get('accelerometer_range_m_s2', 0.0) or 0.0)
        return cls(plant, Sensors.from_parameters(params, rng if rng > 0 else None),
                   SafetyLimits.from_parameters(params))

    @property
    def time_s(self) -> float:
        """Time of the current sample [s]."""
        return self.step * self.dt

    @property
    def state(self) -> np.ndarray:
        """Copy of the plant state at t_k."""
        return np.array(self._w[:self._n])

    def true_force(self) -> float:
        """The model's force at the current sample [N]."""
        return self._y[_F]

    def measure(self) -> Measurement:
        """Sensor readings at the current sample."""
        y = self._y
        return self.sensors.read(self.step, self.step * self.dt, y[_X], y[_V], y[_A], y[_F])

    def apply(self, command: float) -> None:
        """Hold `command` [V] over the current step and advance."""
        w = self._w
        w[self._n] = float(command)
        w[:self._n] = self._advance(w)
        self._y = self._read(w)
        self.step += 1

    def limit_violation(self) -> str | None:
        """Stroke/force limit check at the current sample (non-finite: named)."""
        y = self._y
        if not (math.isfinite(y[_X]) and math.isfinite(y[_F])):
            return f'non-finite rig state at t={self.time_s:.3f} s'
        return self.limits.violation(self.time_s, y[_X], y[_F])
