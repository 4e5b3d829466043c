"""The wiring faults a lab makes, injected by name into seft's simulated rig.

One list (:data:`FAULTS`) and one wrapper (:class:`FaultyRig`) around any rig object of the
rig node (:class:`~seft_plant_sim.realtime.WallClockRig`, the lockstep rigs of
:func:`~seft_plant_sim.rigs.make_rig`, the UDP bridge's rig) or of the controller emulator:
it passes everything through and changes what the rig measures (a sign, a unit, two fields
exchanged, a stuck sensor, noise), and, for the faults of the rig node itself, how it stamps
its samples (:meth:`FaultyRig.stamp_ns`), how fast it ticks (``Fault.tick_factor``) or
whether it ramps its command on an abort (``Fault.holds_command``).

``seft rig-check --inject FAULT`` runs the check against seft's rig node with the fault
(``seft_plant_sim.fault_rig``), and ``seft emulate-controller --inject FAULT`` makes the
lab's controller behind the UDP bridge send it: a lab sees what each failure looks like,
and the tests check that each fault fails the checks it should and no other
(``docs/rig_contract.md`` has the table).

Imports no rclpy.
"""

from dataclasses import dataclass, replace
import math
from typing import Mapping

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import Measurement

__all__ = ['Fault', 'FAULTS', 'SENSOR_FAULTS', 'CONTROLLER_FAULTS', 'fault', 'FaultyRig',
           'check_supported', 'G']

#: Standard gravity [m/s^2] (an accelerometer read in g divides by it).
G = 9.80665
#: The measurement's fields as :class:`~seft_msgs_py.interface.Measurement` names them, in
#: the contract's order (force, displacement, velocity, acceleration).
_FIELDS = ('force_N', 'displacement_m', 'velocity_m_s', 'acceleration_m_s2')


@dataclass(frozen=True)
class Fault:
    """One wiring fault.

    Attributes
    ----------
    name : str
    description : str
        What the lab did, in its words.
    gains : tuple of 4 float
        Factor of each field (force, displacement, velocity, acceleration): -1 reversed,
        1e-3 a force in kN, 1e3 a displacement in mm, ``1/G`` an acceleration in g.
    swap : tuple of 2 int or None
        Two fields (indices as `gains`) exchanged.
    stuck : int or None
        A field frozen at its first reading (0 at rest).
    noise : tuple (int, float) or None
        A field and the standard deviation of the white noise added to it (its unit).
    stamp_offset_steps : int
        The rig node stamps sample ``k`` as ``k + stamp_offset_steps`` (its record rows too).
    stamp_offset_fraction : float
        The rig node stamps sample ``k`` this fraction of a period after ``k dt``.
    tick_factor : float
        The rig node ticks every ``tick_factor dt`` (its stamps still say ``k dt``).
    holds_command : bool
        On an abort the rig holds its last command instead of ramping it to zero.
    """

    name: str
    description: str
    gains: tuple = (1.0, 1.0, 1.0, 1.0)
    swap: tuple | None = None
    stuck: int | None = None
    noise: tuple | None = None
    stamp_offset_steps: int = 0
    stamp_offset_fraction: float = 0.0
    tick_factor: float = 1.0
    holds_command: bool = False

    @property
    def sensor(self) -> bool:
        """Whether the fault is in what the rig measures alone (a controller behind the UDP
        bridge can send it)."""
        return (self.stamp_offset_steps == 0 and self.stamp_offset_fraction == 0
                and self.tick_factor == 1.0 and not self.holds_command)

    def values(self, values: tuple, first: tuple, rng: np.random.Generator | None
               ) -> tuple:
        """The fields (force, displacement, velocity, acceleration) as the faulty rig reads
        them, from the true ones; `first` are the first readings (a stuck field keeps its
        own), `rng` draws the noise."""
        out = [g * v for g, v in zip(self.gains, values)]
        if self.swap is not None:
            i, j = self.swap
            out[i], out[j] = out[j], out[i]
        if self.stuck is not None:
            out[self.stuck] = first[self.stuck]
        if self.noise is not None and rng is not None:
            i, sigma = self.noise
            out[i] += sigma * float(rng.standard_normal())
        return tuple(out)


def _gains(**changes) -> tuple:
    g = dict(zip(('force', 'displacement', 'velocity', 'acceleration'), (1.0,) * 4))
    g.update(changes)
    return tuple(g.values())


#: The faults, by name.
FAULTS: Mapping[str, Fault] = {f.name: f for f in (
    Fault('force_reversed', 'the load cell reads reversed (its wiring or the sign of its '
          'calibration)', _gains(force=-1.0)),
    Fault('force_kN', 'the force in kN instead of N', _gains(force=1e-3)),
    Fault('transducer_reversed', 'the displacement transducer mounted the other way round, '
          'the velocity and acceleration taken from it: all three reversed against the force',
          _gains(displacement=-1.0, velocity=-1.0, acceleration=-1.0)),
    Fault('displacement_reversed', 'the displacement alone reversed',
          _gains(displacement=-1.0)),
    Fault('displacement_mm', 'the displacement in mm instead of m',
          _gains(displacement=1e3)),
    Fault('velocity_reversed', 'the velocity alone reversed', _gains(velocity=-1.0)),
    Fault('velocity_mm_s', 'the velocity in mm/s instead of m/s', _gains(velocity=1e3)),
    Fault('acceleration_reversed', 'the accelerometer mounted the other way round',
          _gains(acceleration=-1.0)),
    Fault('acceleration_g', 'the acceleration in g instead of m/s^2',
          _gains(acceleration=1 / G)),
    Fault('acceleration_stuck', 'the accelerometer stuck at its first reading (0 at rest)',
          stuck=3),
    Fault('displacement_stuck', 'the displacement transducer stuck at its first reading',
          stuck=1),
    Fault('swapped_force_displacement', 'the force and displacement fields exchanged',
          swap=(0, 1)),
    Fault('swapped_velocity_acceleration', 'the velocity and acceleration fields exchanged',
          swap=(2, 3)),
    Fault('force_noise', 'load-cell noise of 100 N RMS (an unshielded cable): it would trip '
          'the instability monitor at rest', noise=(0, 100.0)),
    Fault('stamps_ahead', 'each sample stamped two periods after the instant it was taken',
          stamp_offset_steps=2),
    Fault('stamps_off_grid', 'each sample stamped a quarter period off the grid of k dt',
          stamp_offset_fraction=0.25),
    Fault('slow_clock', 'the rig ticks every 1.25 dt (its stamps still say k dt)',
          tick_factor=1.25),
    Fault('no_safe_state', 'on an abort the rig holds its last command instead of ramping '
          'it to zero', holds_command=True),
)}
#: The faults in what the rig measures alone (``seft emulate-controller --inject``).
SENSOR_FAULTS = tuple(name for name, f in FAULTS.items() if f.sensor)
#: Faults of a lab's controller behind the UDP bridge itself, not of what it measures
#: (``seft emulate-controller --inject``; ``seft_plant_sim.udp_emulator``), by name: what it
#: does wrong.
CONTROLLER_FAULTS = {
    'takes_any_session': 'the controller takes a start of another session while a run is '
                         'live and answers whichever address spoke last (a second PC takes '
                         'the rig over)',
}


def fault(name: str, *, where: str = '--inject', allowed=None) -> Fault:
    """The fault called `name`.

    Raises
    ------
    ParameterError
        Not one of :data:`FAULTS` (or of `allowed`); the message names `where`.
    """
    names = tuple(FAULTS) if allowed is None else tuple(allowed)
    if name not in names:
        raise ParameterError(f'{where} {name!r}: expected one of {", ".join(names)}')
    return FAULTS[name]


class FaultyRig:
    """A rig with one fault: every attribute is the wrapped rig's, but what it measures.

    Parameters
    ----------
    rig : object
        A rig with ``measure() -> Measurement`` (and whatever else its node uses).
    fault : Fault
    seed : int
        Seed of the noise (a run is reproducible sample for sample).

    Notes
    -----
    ``Fault.holds_command`` replaces the wrapped
    :class:`~seft_plant_sim.realtime.WallClockRig`'s safe-state command (``_safe_command``)
    by the command it held when the safe state began.
    """

    def __init__(self, rig, fault: Fault, seed: int = 1):
        self._rig = rig
        self.fault = fault
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self._first = None
        if fault.holds_command:
            rig._safe_command = lambda sub: rig._safe_from_value

    def __getattr__(self, name):
        return getattr(self._rig, name)

    def measure(self) -> Measurement:
        """The wrapped rig's measurement with the fault."""
        m = self._rig.measure()
        true = tuple(getattr(m, f) for f in _FIELDS)
        if self._first is None:
            self._first = true
        return replace(m, **dict(zip(_FIELDS, self.fault.values(true, self._first,
                                                                 self._rng))))

    def stamp_ns(self, k: int, dt_ns: int) -> int:
        """The stamp the faulty rig gives sample `k` [ns] (the contract: ``k dt_ns``)."""
        f = self.fault
        return (k + f.stamp_offset_steps) * dt_ns + int(math.floor(f.stamp_offset_fraction
                                                                   * dt_ns))


def check_supported(fault_: Fault, params: Mapping, *, emulator: bool = False) -> None:
    """Refuse a fault where it cannot be injected (the controller emulator sends sensor
    faults only; a UDP bridge rig node takes none: its controller's are the lab's).

    Raises
    ------
    ParameterError
        The message says where the fault goes instead.
    """
    if emulator and not fault_.sensor:
        raise ParameterError(f'--inject {fault_.name}: the controller emulator injects what '
                             'it measures only (' + ', '.join(SENSOR_FAULTS) + ')')
    if not emulator and params.get('rig_interface') == 'udp_bridge':
        raise ParameterError(f'--inject {fault_.name}: with rig_interface=udp_bridge the '
                             "fault is the lab controller's: seft emulate-controller "
                             f'--inject {fault_.name}')
