"""The ranges of a rig's sensors (part of the rig contract) and the samples read at them.

Every sensor of a rig saturates at its full scale: a load cell, a displacement transducer, a
velocity sensor, an accelerometer (the reference rig's 4 g accelerometer reads 39.2 m/s^2 at
most). A reading at the range is not the quantity: an identification that regresses on it
learns a wrong specimen, a compensator that feeds it back commands a wrong force. The ranges
are parameters of the rig (:data:`RANGE_PARAMETERS`; seft's simulated rigs clip their readings
there, a lab declares its own), and whoever reads the measurement flags a sample at a range
(:meth:`SensorRanges.flags`), counts it (:class:`RangeCount`) and keeps it out of what it
would mislead.

Imports no rclpy (the rigs, the builder and the analysis share it).
"""

from dataclasses import dataclass, field
import math
from typing import Any, Mapping

from seft_msgs_py.interface import Measurement

__all__ = ['CHANNELS', 'RANGE_PARAMETERS', 'CHANNEL_UNITS', 'CHANNEL_FIELDS', 'FORCE',
           'DISPLACEMENT', 'VELOCITY', 'ACCELERATION', 'AT_RANGE_FRACTION', 'SensorRanges',
           'RangeCount', 'channel_names']

#: The sensors of a rig, in the order of their flag bits.
CHANNELS = ('force', 'displacement', 'velocity', 'acceleration')
#: Flag bit of each channel (:meth:`SensorRanges.flags`).
FORCE, DISPLACEMENT, VELOCITY, ACCELERATION = 1, 2, 4, 8
#: The parameter of each channel's range (0: unlimited).
RANGE_PARAMETERS = {'force': 'force_range_N', 'displacement': 'displacement_range_m',
                    'velocity': 'velocity_range_m_s',
                    'acceleration': 'accelerometer_range_m_s2'}
#: The SI unit of each channel.
CHANNEL_UNITS = {'force': 'N', 'displacement': 'm', 'velocity': 'm/s',
                 'acceleration': 'm/s^2'}
#: The :class:`~seft_msgs_py.interface.Measurement` field of each channel.
CHANNEL_FIELDS = {'force': 'force_N', 'displacement': 'displacement_m',
                  'velocity': 'velocity_m_s', 'acceleration': 'acceleration_m_s2'}
#: A reading at or beyond this fraction of its range counts as at the range: a saturated
#: sensor reads its full scale, and a lab's converter its last code or a little below it.
AT_RANGE_FRACTION = 0.999


def channel_names(flags: int) -> list[str]:
    """The channels of a flag word (bits :data:`FORCE` ... :data:`ACCELERATION`), in the
    order of :data:`CHANNELS`."""
    return [c for i, c in enumerate(CHANNELS) if flags >> i & 1]


@dataclass(frozen=True)
class SensorRanges:
    """The full scales of a rig's four sensors (``inf``: unlimited).

    Parameters
    ----------
    force_N, displacement_m, velocity_m_s, acceleration_m_s2 : float > 0
        Full scale of the load cell [N], the displacement transducer [m], the velocity sensor
        [m/s] and the accelerometer [m/s^2]; a reading ``|y| >= AT_RANGE_FRACTION * range``
        is at the range.

    Raises
    ------
    ValueError
        A range not > 0 (NaN included).
    """

    force_N: float = math.inf
    displacement_m: float = math.inf
    velocity_m_s: float = math.inf
    acceleration_m_s2: float = math.inf
    _at: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        values = self.ranges()
        for name, value in zip(CHANNELS, values):
            if not value > 0:
                raise ValueError(f'{RANGE_PARAMETERS[name]}={value!r}: expected a range > 0')
        object.__setattr__(self, '_at', tuple(AT_RANGE_FRACTION * v for v in values))

    @classmethod
    def from_parameters(cls, params: Mapping[str, Any]) -> 'SensorRanges':
        """Build from :data:`RANGE_PARAMETERS` (0 or absent: unlimited)."""
        def of(name):
            value = float(params.get(RANGE_PARAMETERS[name], 0.0) or 0.0)
            return value if value > 0 else math.inf
        return cls(*(of(c) for c in CHANNELS))

    def ranges(self) -> tuple:
        """``(force_N, displacement_m, velocity_m_s, acceleration_m_s2)``."""
        return (self.force_N, self.displacement_m, self.velocity_m_s, self.acceleration_m_s2)

    @property
    def thresholds(self) -> tuple:
        """``(force_N, displacement_m, velocity_m_s, acceleration_m_s2)``: the magnitude at
        which a reading is at its range (``AT_RANGE_FRACTION`` of it; ``inf``: unlimited)."""
        return self._at

    def range_of(self, channel: str) -> float:
        """The full scale of a channel (one of :data:`CHANNELS`) in its SI unit."""
        return self.ranges()[CHANNELS.index(channel)]

    @property
    def limited(self) -> bool:
        """Whether any sensor has a finite range."""
        return any(math.isfinite(v) for v in self.ranges())

    def flags_of(self, force_N: float, displacement_m: float, velocity_m_s: float,
                 acceleration_m_s2: float) -> int:
        """The flag word of one sample's readings: bit :data:`FORCE` set when the force is at
        its range, and so on (0: every reading inside its range; NaN is not flagged)."""
        f, x, v, a = self._at
        out = 0
        if abs(force_N) >= f:
            out = FORCE
        if abs(displacement_m) >= x:
            out |= DISPLACEMENT
        if abs(velocity_m_s) >= v:
            out |= VELOCITY
        if abs(acceleration_m_s2) >= a:
            out |= ACCELERATION
        return out

    def flags(self, m: Measurement) -> int:
        """:meth:`flags_of` of a :class:`~seft_msgs_py.interface.Measurement`."""
        return self.flags_of(m.force_N, m.displacement_m, m.velocity_m_s,
                             m.acceleration_m_s2)

    def clip(self, force_N: float, displacement_m: float, velocity_m_s: float,
             acceleration_m_s2: float) -> tuple:
        """The readings of a sensor set with these ranges: each value clipped to
        ``[-range, range]`` (NaN passes through)."""
        out = []
        for value, r in zip((force_N, displacement_m, velocity_m_s, acceleration_m_s2),
                            self.ranges()):
            out.append(r if value > r else -r if value < -r else value)
        return tuple(out)


class RangeCount:
    """The samples of one rig at a sensor's range, counted per channel.

    Attributes
    ----------
    samples : dict of str to int
        Per channel (:data:`CHANNELS`): the samples at its range.
    first_step, last_step : dict of str to int
        Per channel flagged at least once: the first and the last such sample.
    flagged : int
        Samples with any channel at its range.
    acceleration_estimated : int
        Samples whose acceleration was replaced by an estimate (the builder's feedback).
    """

    def __init__(self):
        self.samples = {c: 0 for c in CHANNELS}
        self.first_step: dict[str, int] = {}
        self.last_step: dict[str, int] = {}
        self.flagged = 0
        self.acceleration_estimated = 0

    def add(self, step: int, flags: int) -> None:
        """Count sample `step` with its flag word (0: nothing)."""
        if not flags:
            return
        self.flagged += 1
        for c in channel_names(flags):
            self.samples[c] += 1
            self.first_step.setdefault(c, int(step))
            self.last_step[c] = int(step)

    def as_dict(self) -> dict:
        """``{'samples': {channel: n}, 'flagged': n, 'acceleration_estimated': n,
        'first_step': {...}, 'last_step': {...}}`` (JSON)."""
        return {'samples': dict(self.samples), 'flagged': self.flagged,
                'acceleration_estimated': self.acceleration_estimated,
                'first_step': dict(self.first_step), 'last_step': dict(self.last_step)}
