"""What the reference-force builder does with a sample read at a sensor's range.

A sensor saturates at its full scale (:mod:`seft_msgs_py.sensor_range`): the reference rig's
4 g accelerometer reads 39.2 m/s^2 while the specimen accelerates at 48 m/s^2. Each rig the
builder commands gets a :class:`RangeGuard` that, for every sample of the rig:

1. flags the readings at their range and counts them per channel
   (:class:`~seft_msgs_py.sensor_range.RangeCount`);
2. tells the rig's compensator (its ``at_range(step, flags)``, where it has one), whose
   online identifications then skip the sample (``adaptive``'s specimen RLS, delay and gain
   fit and latency fit; a yielding member's model);
3. while the accelerometer is at its range, replaces the acceleration fed back by an
   estimate from the specimen's equation of motion (paper Eq. 5.1) with the measured force,
   velocity and displacement::

       a_hat = (f_m - c v - r) / m

   where ``m, c`` and the restoring force ``r`` are the compensator's specimen model
   (``adaptive``: the identified one; a yielding member: its hysteretic model carried along
   the measured displacement,
   :meth:`~seft_ros.core.hysteresis.HystereticMember.restoring_force_at`; otherwise
   ``k x``). With the load cell at its range as well, or a compensator that models
   a yielding member by a tangent stiffness only, it is the backward difference of the
   measured velocity, ``(v[k] - v[k-1]) / dt``. The sensor's own reading is used again from
   the first sample back inside its range.

The estimate is exact for a specimen the model describes (noise-free sensors): the same
equation the load cell measures. It is what the builder feeds back and what the compensator
sees; the bag keeps what the sensor read.
"""

from typing import Callable

from seft_msgs_py.interface import Measurement
from seft_msgs_py.sensor_range import (
    ACCELERATION,
    CHANNEL_UNITS,
    FORCE,
    RangeCount,
    SensorRanges,
)

__all__ = ['RangeGuard', 'range_warning']


def range_warning(rig: str, channel: str, range_value: float, time_s: float) -> str:
    """The line the builder says when a rig's `channel` first reads its range
    (`range_value` in the channel's SI unit) at `time_s` [s]."""
    who = f'{rig}: ' if rig else ''
    what = ('; the acceleration fed back is estimated from the measured force and motion '
            'while it lasts' if channel == 'acceleration' else '')
    return (f'{who}{channel} at its sensor range ({range_value:g} {CHANNEL_UNITS[channel]}) '
            f'at t={time_s:.3f} s: flagged and counted, the identifications skip such '
            f'samples{what}')


class RangeGuard:
    """One rig's samples against its sensors' ranges, in the builder (module notes).

    Parameters
    ----------
    ranges : SensorRanges
        The rig's sensor ranges.
    dt : float > 0
        Control period [s].
    predictor : object
        The rig's compensator (``at_range``, ``member`` are used where it has them).
    specimen_model : callable() -> SpecimenModel
        The compensator's specimen model now (``mass_kg``, ``damping_N_s_per_m``,
        ``stiffness_N_per_m``).
    tangent_only : bool
        The compensator models a yielding member by a tangent stiffness without a
        hysteretic model (the estimate is then the velocity's difference).

    Attributes
    ----------
    count : RangeCount
        The samples at a range, per channel, and those whose acceleration was estimated.
    news : list of (str, int)
        ``(channel, step)`` of each channel the first time it is at its range (the builder
        says so once:
        :meth:`~seft_ros.core.reference_force.ReferenceForceBuilder.range_warnings`); the
        reader empties it.
    """

    def __init__(self, ranges: SensorRanges, dt: float, predictor,
                 specimen_model: Callable, *, tangent_only: bool = False):
        self.ranges = ranges
        self.dt = float(dt)
        self.count = RangeCount()
        self._predictor = predictor
        self._hook = getattr(predictor, 'at_range', None)
        self._model = specimen_model
        self._tangent_only = bool(tangent_only)
        self._thresholds = ranges.thresholds
        self._previous = None           # the latest sample
        self.news: list[tuple[str, int]] = []

    def take(self, m: Measurement) -> Measurement:
        """Flag, count and tell (module notes); return the measurement to feed back: `m`, or
        `m` with the acceleration estimated while the accelerometer is at its range."""
        f, x, v, a = self._thresholds
        if (abs(m.force_N) < f and abs(m.displacement_m) < x and abs(m.velocity_m_s) < v
                and abs(m.acceleration_m_s2) < a):     # no flag (the common case, one test)
            self._previous = m
            return m
        flags = self.ranges.flags(m)
        previous, self._previous = self._previous, m
        if not flags:
            return m
        first = len(self.count.first_step)
        self.count.add(m.step, flags)
        if len(self.count.first_step) > first:
            self.news.extend((c, m.step) for c, j in self.count.first_step.items()
                             if j == m.step)
        if self._hook is not None:
            self._hook(m.step, flags)
        if not flags & ACCELERATION:
            return m
        self.count.acceleration_estimated += 1
        a = self.estimate(m, flags, None if previous is None else (previous.step,
                                                                   previous.velocity_m_s))
        return Measurement(m.step, m.time_s, m.displacement_m, m.velocity_m_s, a, m.force_N)

    def estimate(self, m: Measurement, flags: int, previous=None) -> float:
        """The acceleration [m/s^2] of sample `m` (module notes); `previous`: ``(step,
        velocity)`` of the sample before, for the velocity's difference (without it, or
        after a gap, the sensor's reading is kept)."""
        member = getattr(self._predictor, 'member', None)
        if not flags & FORCE and not (self._tangent_only and member is None):
            if member is not None:
                mass, damping = member.mass_kg, member.damping_N_s_per_m
                restoring = member.restoring_force_at(m.displacement_m, m.velocity_m_s)
            else:
                model = self._model()
                mass, damping = model.mass_kg, model.damping_N_s_per_m
                restoring = model.stiffness_N_per_m * m.displacement_m
            return (m.force_N - damping * m.velocity_m_s - restoring) / mass
        if previous is not None and previous[0] == m.step - 1:
            return (m.velocity_m_s - previous[1]) / self.dt
        return m.acceleration_m_s2
