"""The link between two hosts, measured with NTP-style pings (no rclpy).

A ping carries four timestamps (RFC 5905, Sec. 8): ``t1`` when host A sends it (A's clock),
``t2`` when host B receives it and ``t3`` when B sends the answer (B's clock), ``t4`` when A
receives the answer (A's clock). Then

    round trip  d = (t4 - t1) - (t3 - t2)
    offset      θ = ((t2 - t1) + (t3 - t4)) / 2      (B's clock minus A's)

exact when the two directions take equally long; an asymmetry ``a`` (one way longer by
``a`` than the other) biases θ by ``a/2`` at most ``d/2``. NTP's clock filter keeps the
offset of the sample of least round trip (the one least delayed by queues); here the median
offset of the quarter of the samples with the least round trip, which is as good on an idle
link and steadier under jitter (:func:`estimate`).

The playout delay of a reference force that crosses the link (``network_delay_s``, the
builder on another host than the controller) must cover the round trip; the ground
motion's preview (``preview_steps``, the ground-motion publisher on another host than a
builder) must cover it too, as the publisher follows the rig's ``/clock`` over the link
(:func:`playout_steps`, :func:`preview_steps`).
"""

from dataclasses import dataclass
import math

import numpy as np

from seft_msgs_py.errors import ParameterError

__all__ = ['PingSample', 'LinkEstimate', 'estimate', 'playout_steps', 'preview_steps',
           'PLAYOUT_MARGIN_S', 'PREVIEW_MARGIN_S']

#: Added to the measured round trip's p99 for the playout delay [s]: the processing of the
#: reference force on both sides (the builder's compute p99 about 0.5 ms, the controller's
#: wake-up) and a tail beyond the p99 of a short measurement.
PLAYOUT_MARGIN_S = 0.003
#: Added to the round trip's p99 for the ground motion's preview [s]: generous, the preview
#: costs nothing (the record is known before the test), and it keeps the ground motion out of
#: the loop's timing: the publisher's host or its link may stall this long before a ground
#: sample is late (then replaced by the latest, and the builder's watchdog counts it). A lost
#: lab is found by the builders' measurement watchdogs, not by this preview running dry.
#: 50 ms was too little on a loaded host: a lab's builder ran out of samples 0.2 s into a
#: 3-host run (the publisher's host and the link emulator starved, load average 3.5).
PREVIEW_MARGIN_S = 0.5


@dataclass(frozen=True)
class PingSample:
    """One exchange: ``t1, t4`` on the pinging host's clock, ``t2, t3`` on the other's [ns]."""

    t1: int
    t2: int
    t3: int
    t4: int

    @property
    def round_trip_s(self) -> float:
        """``(t4 - t1) - (t3 - t2)`` [s]."""
        return ((self.t4 - self.t1) - (self.t3 - self.t2)) * 1e-9

    @property
    def offset_s(self) -> float:
        """``((t2 - t1) + (t3 - t4)) / 2`` [s]: the other host's clock minus this one's."""
        return 0.5 * ((self.t2 - self.t1) + (self.t3 - self.t4)) * 1e-9


@dataclass(frozen=True)
class LinkEstimate:
    """The link as measured from a set of pings.

    Attributes
    ----------
    samples : int
    round_trip_s : dict of str to float
        ``{'p50', 'p99', 'max'}`` of the round trips [s].
    offset_s : float
        The other host's clock minus this one's [s] (module notes).
    offset_spread_s : float
        Half the range of the offsets of the samples used: a bound of the estimate's own
        scatter [s].
    """

    samples: int
    round_trip_s: dict
    offset_s: float
    offset_spread_s: float

    def as_dict(self) -> dict:
        """JSON-ready: round trip and offset in ms."""
        return {'samples': self.samples,
                'round_trip_ms': {k: 1e3 * v for k, v in self.round_trip_s.items()},
                'offset_ms': 1e3 * self.offset_s,
                'offset_spread_ms': 1e3 * self.offset_spread_s}


def estimate(samples) -> LinkEstimate:
    """Round trip percentiles and clock offset of a set of pings (module notes).

    Parameters
    ----------
    samples : sequence of PingSample
        At least one.

    Returns
    -------
    LinkEstimate

    Raises
    ------
    ParameterError
        No sample, or a sample with a negative round trip (timestamps out of order).
    """
    samples = list(samples)
    if not samples:
        raise ParameterError('link estimate: expected at least one ping')
    rtt = np.array([s.round_trip_s for s in samples])
    if np.any(rtt < 0):
        raise ParameterError(f'link estimate: a ping with a negative round trip '
                             f'({1e3 * float(rtt.min()):.3f} ms): timestamps out of order')
    offsets = np.array([s.offset_s for s in samples])
    best = np.argsort(rtt, kind='stable')[:max(1, len(samples) // 4)]
    chosen = offsets[best]
    return LinkEstimate(
        samples=len(samples),
        round_trip_s={'p50': float(np.percentile(rtt, 50)),
                      'p99': float(np.percentile(rtt, 99)), 'max': float(rtt.max())},
        offset_s=float(np.median(chosen)),
        offset_spread_s=0.5 * float(chosen.max() - chosen.min()))


def _check(value: float, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value >= 0):
        raise ParameterError(f'{name}={value!r}: expected a finite number >= 0')
    return value


def playout_steps(round_trip_p99_s: float, dt: float,
                  margin_s: float = PLAYOUT_MARGIN_S) -> int:
    """Whole steps of playout delay that cover the round trip: ``ceil((d99 + margin) / dt)``.

    Raises
    ------
    ParameterError
        A negative or non-finite input, or ``dt <= 0``.
    """
    d = _check(round_trip_p99_s, 'round trip p99') + _check(margin_s, 'margin')
    if not dt > 0:
        raise ParameterError(f'dt={dt!r}: expected > 0')
    return int(math.ceil(d / float(dt) - 1e-9))


def preview_steps(round_trip_p99_s: float, dt: float, at_least: int,
                  margin_s: float = PREVIEW_MARGIN_S) -> int:
    """Steps of ground-motion preview that cover the round trip:
    ``max(at_least, ceil((d99 + margin) / dt))``.

    Raises
    ------
    ParameterError
        As :func:`playout_steps`.
    """
    return max(int(at_least), playout_steps(round_trip_p99_s, dt, margin_s))
