"""A network link between two hosts, as delay, jitter and loss (ROS-free).

The link emulator (``seft_ros.cli.link_emulator``) forwards the IP packets between two
network namespaces ("hosts") and holds each packet for the time this model gives. It is the
stand-in for ``tc netem`` where the kernel has none.

Model (one direction): a packet that arrives at time ``t`` leaves at

    t_out = max(t + delay + U(-jitter, +jitter) [+ retransmit if lost], t_out_previous)

- ``delay``: one-way network delay [s];
- ``jitter``: half-width of a uniform jitter [s] (the issue's "± 20 %" is jitter = 0.2 delay);
- ``loss``: probability that a packet is lost. With ``resend=False`` (the packet emulator)
  a lost packet is dropped, as netem drops it, and DDS's reliability protocol has to resend
  it; with ``resend=True`` (a model of one reliable topic) it arrives ``retransmit`` later
  (default ``2 delay + 5 ms``: the reader's negative acknowledgement and the resend);
- the ``max`` keeps the packets in order (a FIFO link, as ``netem`` with a rate or a
  pfifo child): a late packet holds the ones behind it (head-of-line blocking).

References
----------
Fast DDS documentation, "Reliability": a reliable reader acknowledges (ACKNACK) the samples it
is missing and the writer resends them. Linux ``tc-netem(8)`` for the delay/jitter/loss
parameters this mirrors.
"""

from dataclasses import dataclass, field
import random

__all__ = ['LinkModel']


@dataclass
class LinkModel:
    """Departure times of the messages of one topic in one direction over an emulated link.

    Parameters
    ----------
    delay_s : float >= 0
        One-way delay [s].
    jitter_s : float >= 0, <= delay_s
        Half-width of the uniform jitter [s].
    loss : float in [0, 1)
        Probability that a packet is lost and resent.
    retransmit_s : float >= 0, optional
        Extra delay of a resent packet [s] (default ``2 delay_s + 0.005``).
    seed : int
        Seed of the random draws (a run is reproducible).
    resend : bool
        True: a lost packet arrives `retransmit_s` later; False: it is dropped
        (:meth:`departure` returns None).

    Raises
    ------
    ValueError
        A parameter out of its range (the message names it).
    """

    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    retransmit_s: float | None = None
    seed: int = 0
    resend: bool = True
    _last_out: float = field(default=float('-inf'), init=False, repr=False)
    _rng: random.Random = field(init=False, repr=False)

    def __post_init__(self):
        if not self.delay_s >= 0.0:
            raise ValueError(f'delay {self.delay_s!r} s: expected >= 0')
        if not 0.0 <= self.jitter_s <= self.delay_s:
            raise ValueError(f'jitter {self.jitter_s!r} s: expected 0 .. delay '
                             f'({self.delay_s} s): a message cannot leave before it arrived')
        if not 0.0 <= self.loss < 1.0:
            raise ValueError(f'loss {self.loss!r}: expected a probability in [0, 1)')
        if self.retransmit_s is None:
            self.retransmit_s = 2.0 * self.delay_s + 0.005
        if not self.retransmit_s >= 0.0:
            raise ValueError(f'retransmit {self.retransmit_s!r} s: expected >= 0')
        self._rng = random.Random(self.seed)
        self.lost = 0

    def departure(self, arrival_s: float) -> float | None:
        """When a packet that arrived at `arrival_s` [s] leaves the link [s] (in order);
        None if it is lost and dropped (``resend=False``)."""
        hold = self.delay_s
        if self.jitter_s:
            hold += self._rng.uniform(-self.jitter_s, self.jitter_s)
        if self.loss and self._rng.random() < self.loss:
            self.lost += 1
            if not self.resend:
                return None
            hold += self.retransmit_s
        out = max(arrival_s + hold, self._last_out)
        self._last_out = out
        return out
