"""The PC's end of the UDP bridge to a laboratory's real-time controller (``rig_interface:
udp_bridge``).

The lab's controller (an NI PXI under LabVIEW Real-Time, a Speedgoat or dSPACE target, or
``seft emulate-controller``) is the master clock of the test: it takes sample ``k`` at its own
``t_k = k dt`` and sends it (:class:`~seft_plant_sim.udp_layout.ToPC`); the rig node publishes
it on the graph stamped ``t_k`` as a simulated rig would, and sends each command of the graph
back (:class:`~seft_plant_sim.udp_layout.ToController`) the moment it arrives. What the
controller does with a command, and when, is the rig contract's promise (``docs/
rig_contract.md``): a command of sample j computed from sample ``j - lag`` is held from
``t_j`` and reaches the actuator ``command_latency_s`` after ``t_j`` (``io_latency_s`` of a
valve rig, ``tau_s`` of a force-controlled one), or from its arrival if it comes later.

:class:`UdpBridgeRig` is the rig object of the rig node in real-time mode, with the interface
of :class:`~seft_plant_sim.realtime.WallClockRig` (measure, arrive, advance, the safe state,
the loop latency of each sample), except that a step is taken when the controller's sample
arrives, not on the PC's clock (:attr:`external_clock`). It imports no rclpy; the node runs
:meth:`receive` in a thread of its own.

Faults at the socket:

* a datagram of the wrong length, magic, version or kind is rejected with one log line and
  counted (``bad``); :data:`udp_max_bad_datagrams` of them end the run safely;
* datagrams are applied in the order of their sequence numbers only
  (:class:`~seft_plant_sim.udp_layout.SequenceFilter`): duplicates and older ones are dropped
  and counted, gaps counted as lost; a sample whose datagram was lost is not published;
* a sample that arrives more than ``dt`` after its place on the controller's clock (as the
  least delayed sample so far places it) is counted late (and published);
* a silent controller (no datagram for ``watchdog_timeout_s``) ends the run: the rig node
  reports it, and asks the controller (if it still hears) for its safe state; a silent PC is
  the controller's to notice (its own watchdog), which it reports in its state;
* the safe state is the controller's to confirm (its state 3, safe): the PC waits for it at
  most :func:`~seft_msgs_py.rig_contract.safe_confirm_s` from its request
  (:meth:`UdpBridgeRig.safe_overdue`), and the final status says whether it came
  (:meth:`UdpBridgeRig.safe_state_values`); before, the PC waited for it without a bound, and
  said the rig ramped to its safe state without it;
* a datagram from any other address than ``udp_controller_address`` (the rig contract's
  session rules: a controller sends from the address it listens on) is dropped, whatever
  its session, counted (``foreign``) and its address named once (:meth:`take_notices`); a
  controller that refused another sender's start says so in its reason
  (:data:`~seft_plant_sim.udp_layout.REASON_START_REFUSED`), named once too;
* with ``message_auth: hmac`` every datagram carries the HMAC of the test's key
  (``auth_key_file``); one that does not verify is a bad datagram.
"""

from collections import deque
import math
import random
import socket
import time
from typing import Callable, Mapping

from seft_msgs_py import provenance, rig_contract
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_VALVE, Measurement
from seft_plant_sim import udp_layout as ul
from seft_plant_sim.realtime import CommandArrivals
from seft_plant_sim.specimen import SafetyLimits

__all__ = ['UdpBridgeRig', 'parse_address', 'resolve_address', 'RECEIVE_BYTES']

#: Receive buffer of one datagram [bytes] (larger than either layout: a longer datagram is
#: seen whole and rejected for its length).
RECEIVE_BYTES = 2048


def parse_address(text: str, name: str = 'udp_controller_address') -> tuple[str, int]:
    """``'host:port'`` as ``(host, port)``.

    Raises
    ------
    ParameterError
        Not ``host:port`` with a port 1-65535 (the message names the parameter).
    """
    host, _, port = str(text).rpartition(':')
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not host or not 0 < number < 65536:
        raise ParameterError(f'parameter {name}={text!r}: expected host:port with a port '
                             '1-65535')
    return host, number


def resolve_address(text: str, name: str = 'udp_controller_address') -> tuple[str, int]:
    """``'host:port'`` as the ``(IPv4 address, port)`` a datagram from it comes from.

    Raises
    ------
    ParameterError
        As :func:`parse_address`, or a host name that does not resolve.
    """
    host, port = parse_address(text, name)
    try:
        return socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4][:2]
    except (OSError, IndexError) as exc:
        raise ParameterError(f'parameter {name}={text!r}: cannot resolve {host!r} '
                             f'({getattr(exc, "strerror", None) or exc})') from None


class UdpBridgeRig(CommandArrivals):
    """A rig behind a UDP socket: the controller's samples in, the graph's commands out.

    Parameters
    ----------
    params : mapping
        Resolved parameters: ``dt`` [s], ``rig_model`` (the command kind: valve voltage for
        'servohydraulic', force reference for 'delay'), ``udp_controller_address``,
        ``udp_local_port`` (0: any), ``udp_heartbeat_s`` [s], ``udp_max_bad_datagrams``,
        ``watchdog_timeout_s`` [s], ``safe_ramp_s`` [s] and the command latency
        (:func:`~seft_msgs_py.rig_contract.safe_confirm_s`), ``stroke_limit_m`` [m],
        ``force_limit_N`` [N],
        ``message_auth`` and ``auth_key_file`` (the HMAC of each datagram).
    log : callable(str), optional
        Receives one line per rejected datagram.

    Attributes
    ----------
    external_clock : bool
        True: a step is the controller's sample arriving (the rig node does not tick).
    step : int
        The sample in effect (the latest taken; 0 before the first).
    counts : dict
        ``late``, ``lost``, ``duplicate``, ``reordered``, ``bad``, ``other_session`` of the
        controller's datagrams at the PC, and ``foreign``: datagrams from another address
        (dropped).
    start_refused : bool
        The controller said it refused another sender's start during this run.
    left : str or None
        Why the controller no longer runs this run's session (it ended it on its own, or
        restarted it: its samples went back); the rig node then ends the run aborted.
    safe_confirmed : bool
        The controller reported its safe state (state 3) during this run.
    safe_confirm_s : float
        How long the PC waits for that report from its request [s]
        (:func:`~seft_msgs_py.rig_contract.safe_confirm_s`).

    Raises
    ------
    ParameterError
        A bad or unresolvable address, the local port cannot be bound, or the key file.
    """

    external_clock = True

    def __init__(self, params: Mapping, *, log: Callable[[str], None] | None = None):
        self.dt = float(params['dt'])
        self.dt_ns = int(round(self.dt * 1e9))
        kind = rig_contract.command_kind(params)
        self.command_kind = kind
        self.source_lag = rig_contract.COMMAND_SOURCE_LAG[kind]
        self._wire_kind = ul.COMMAND_VALVE if kind == COMMAND_VALVE else ul.COMMAND_FORCE
        self.peer = resolve_address(params['udp_controller_address'])
        self.key = provenance.key_of(params)
        self.heartbeat_s = float(params['udp_heartbeat_s'])
        self.max_bad = int(params['udp_max_bad_datagrams'])
        self.limits = SafetyLimits.from_parameters(params)
        self.log = log or (lambda line: None)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(('', int(params['udp_local_port'])))
        except OSError as exc:
            self.sock.close()
            raise ParameterError(f"parameter udp_local_port={params['udp_local_port']!r}: "
                                 f'cannot bind it ({exc.strerror})') from None
        self.sock.settimeout(self.heartbeat_s)
        self.session = random.SystemRandom().randrange(1, 2 ** 32)
        self._sequence = 0
        self.filter = ul.SequenceFilter()
        self.counts = {'late': 0, 'bad': 0, 'other_session': 0, 'foreign': 0}
        self.start_refused = False
        #: Why the controller no longer runs this run's session (None: it does): it ended
        #: the session on its own, or restarted it (its samples went back).
        self.left: str | None = None
        self._named: set = set()                    # foreign addresses already named
        self._notices: list[str] = []               # named, not yet taken by the node
        self.last_bad = ''
        self.n_steps = 0
        self.started = self.ended = self.safe_requested = False
        self.safe_requested_at: float | None = None     # when [s, monotonic]
        self.safe_confirmed = False
        self.safe_confirm_s = rig_contract.safe_confirm_s(params)
        self.discarded = 0
        self._arrivals: dict[int, float] = {}
        self._pending: deque = deque()
        self.current: ul.ToPC | None = None
        self.step = 0
        self.controller: ul.ToPC | None = None     # the newest datagram of the controller
        self.last_heard: float | None = None        # when [s, monotonic]
        self._t0: float | None = None                # PC time of the controller's sample 0

    # -- sending ----------------------------------------------------------------------------

    def _flags(self) -> int:
        return ((ul.FLAG_START if self.started and not self.ended else 0)
                | (ul.FLAG_SAFE if self.safe_requested else 0)
                | (ul.FLAG_END if self.ended else 0))

    def _send(self, kind: int, sample: int, source: int, value: float) -> None:
        self._sequence = (self._sequence + 1) % 2 ** 32
        data = ul.encode(ul.ToController(
            kind, self._flags(), self.session, self._sequence, sample, source, float(value),
            self.dt_ns, self.n_steps, self._wire_kind), self.key)
        try:
            self.sock.sendto(data, self.peer)
        except OSError:
            pass            # an unreachable controller is its silence: the watchdogs act

    def heartbeat(self) -> None:
        """Send the PC's heartbeat (with the run's flags)."""
        newest = self.controller.sample if self.controller is not None else -1
        self._send(ul.KIND_HEARTBEAT, newest, -1, 0.0)

    def start(self, n_steps: int) -> None:
        """Start the run: the controller takes sample 0 at its next tick."""
        self.n_steps = int(n_steps)
        self.started = True
        self.heartbeat()

    def arrive(self, stamp: int, value: float, arrival_s: float) -> None:
        """Send the command stamped `stamp` (value [V or N]) to the controller at once (none
        after the safe state was asked for: counted in :attr:`discarded`)."""
        if self.safe_requested or self.ended:
            self.discarded += 1
            return
        self._send(ul.KIND_COMMAND, stamp, stamp - self.source_lag, value)

    def enter_safe_state(self) -> None:
        """Ask the controller for its safe state (now, and in every datagram from now on)."""
        if not self.safe_requested:
            self.safe_requested = True
            self.safe_requested_at = time.monotonic()
            self.heartbeat()

    def close(self) -> None:
        """The run is over: tell the controller (three times: UDP may lose one), close."""
        if self.sock.fileno() < 0:
            return
        self.ended = True
        for _ in range(3):
            self.heartbeat()
        self.sock.close()

    # -- receiving --------------------------------------------------------------------------

    def receive(self) -> bool:
        """Wait up to ``udp_heartbeat_s`` for a datagram of the controller and take it.

        Returns
        -------
        bool
            A datagram was taken (a sample may be pending: :meth:`due_step`).
        """
        try:
            data, source = self.sock.recvfrom(RECEIVE_BYTES)
        except (socket.timeout, OSError):
            return False
        now = time.monotonic()
        if source[:2] != self.peer:
            self._foreign(source)
            return False
        try:
            d = ul.decode_to_pc(data, self.key)
        except ul.DatagramError as exc:
            self.counts['bad'] += 1
            self.last_bad = str(exc)
            self.log(f'udp_bridge: rejected {exc} ({self.counts["bad"]} of at most '
                     f'{self.max_bad})')
            return False
        if d.session != self.session and d.session != 0:
            self.counts['other_session'] += 1      # a previous run's: not this one's
            return False
        if not self.filter.take(d.sequence):
            return False
        self.controller = d
        self.last_heard = now
        if d.state == ul.STATE_SAFE and self.started and d.session in (self.session, 0):
            # its command at zero (session 0: it ended the session after holding it)
            self.safe_confirmed = True
        if (d.reason == ul.REASON_START_REFUSED and d.session == self.session
                and not self.start_refused):
            self.start_refused = True
            self._notices.append(
                'udp_bridge: the controller refused a start of another session (another '
                'sender tried to take the rig; this run goes on)')
        for source, latency in zip(d.latency_sources, d.latency_s):
            if source >= 0 and math.isfinite(latency):
                self._arrivals.setdefault(source, source * self.dt + latency)
        had = (self._pending[-1].sample if self._pending
               else self.current.sample if self.current is not None else None)
        if had is not None and self.left is None:
            if d.session == 0:
                self.left = (f'udp_bridge: the controller ended the session on its own '
                             f'(state {ul.STATE_NAMES.get(d.state, d.state)}, after sample '
                             f'{had})')
            elif d.kind == ul.KIND_MEASUREMENT and d.sample <= had:
                self.left = (f'udp_bridge: the controller restarted the session (its sample '
                             f'{d.sample} after {had}): a start of another sender took it '
                             'over, or it was reset')
        if self.left is not None:
            return True
        if d.kind == ul.KIND_MEASUREMENT and d.session == self.session:
            # the controller's clock as the PC sees it: its sample 0 at the earliest arrival
            # less k dt (the least delayed sample so far)
            origin = now - d.sample * self.dt
            if self._t0 is None or origin < self._t0:
                self._t0 = origin
            elif now - (self._t0 + d.sample * self.dt) > self.dt:
                self.counts['late'] += 1
            self._pending.append(d)
        return True

    def _foreign(self, source) -> None:
        """A datagram from another address than the controller's: dropped, counted, its
        address named once."""
        self.counts['foreign'] += 1
        if source not in self._named:
            self._named.add(source)
            self._notices.append(
                f'udp_bridge: dropped a datagram from {source[0]}:{source[1]}, not the '
                f'controller ({self.peer[0]}:{self.peer[1]}); every datagram from another '
                'address is dropped and counted (udp_foreign)')

    def take_notices(self) -> list[str]:
        """What the bridge has to name since the last call (each once): a foreign address,
        the controller's refusal of another sender's start."""
        out, self._notices = self._notices, []
        return out

    @property
    def controller_heard(self) -> bool:
        """A valid datagram of the controller has arrived (it is up)."""
        return self.last_heard is not None

    def silent_s(self, now: float) -> float:
        """Time since the controller's last valid datagram [s] (inf: never heard)."""
        return math.inf if self.last_heard is None else now - self.last_heard

    def due_step(self) -> int:
        """The newest sample received (the rig node advances to it)."""
        return self._pending[-1].sample if self._pending else self.step

    @property
    def has_sample(self) -> bool:
        """A sample is taken or pending."""
        return self.current is not None or bool(self._pending)

    def advance(self) -> None:
        """Take the next sample received (a lost one is skipped)."""
        self.current = self._pending.popleft()
        self.step = self.current.sample

    # -- the rig interface ------------------------------------------------------------------

    @property
    def time_s(self) -> float:
        """Time of the sample in effect [s]."""
        return self.step * self.dt

    def measure(self) -> Measurement:
        """The controller's sensor readings of the sample in effect (SI units)."""
        c = self.current
        return Measurement(self.step, self.time_s, c.displacement_m, c.velocity_m_s,
                           c.acceleration_m_s2, c.force_N)

    @property
    def held_source(self) -> int:
        """The sample the command in effect at the actuator was computed from (-1: none)."""
        return self.current.held_source if self.current is not None else -1

    @property
    def in_safe_state(self) -> bool:
        """The safe state was asked for (:meth:`enter_safe_state`). A controller that went to
        its own is a :meth:`limit_violation`: the rig node then asks for it, with the
        reason."""
        return self.safe_requested

    @property
    def safe_ramp_done(self) -> bool:
        """The controller reports its command at zero (:data:`~udp_layout.STATE_SAFE`)."""
        return self.current is not None and self.current.state == ul.STATE_SAFE

    def view(self, now: float, watchdog_s: float) -> str | None:
        """What the PC saw of the controller that explains another node's watchdog (an
        input of the graph stopped), or None: the controller silent for half the watchdog
        `watchdog_s` [s] or more, or its samples lost or dropped as reordered (not published).
        Starts with ``rig_contract.BRIDGE_REASON``."""
        silent = self.silent_s(now)
        if silent >= watchdog_s / 2:
            return (f'udp_bridge: no datagram from the controller for {1e3 * silent:.1f} ms '
                    f'(limit {1e3 * watchdog_s:g} ms) after t = {self.time_s:.3f} s')
        lost, reordered = self.filter.lost, self.filter.reordered
        if lost or reordered:
            return (f'udp_bridge: samples of the controller not published by t = '
                    f'{self.time_s:.3f} s: {lost} lost, {reordered} reordered (dropped)')
        return None

    def safe_overdue(self, now: float) -> bool:
        """The safe state was asked for, the controller has not reported it (state 3), and
        :attr:`safe_confirm_s` has passed since the request (`now`: ``time.monotonic()``)."""
        return (self.safe_requested and not self.safe_confirmed
                and now - self.safe_requested_at > self.safe_confirm_s)

    def safe_state_values(self, now: float) -> dict:
        """For the final status, once the safe state was asked for (else empty):
        ``safe_confirmed`` (1: the controller reported its safe state; 0: it did not) and,
        when it did not, ``safe_unconfirmed``, the line that says so (how long after the
        request, the bound, the controller's last state)."""
        if not self.safe_requested:
            return {}
        if self.safe_confirmed:
            return {'safe_confirmed': 1}
        c = self.controller
        last = ul.STATE_NAMES.get(c.state, c.state) if c is not None else 'none heard'
        silent = self.silent_s(now)
        heard = (f'; nothing from it for {silent:.3f} s'
                 if self.heartbeat_s < silent < math.inf else '')
        return {'safe_confirmed': 0,
                'safe_unconfirmed': (
                    f'the safe state was NOT confirmed by the controller at {self.peer[0]}:'
                    f'{self.peer[1]}: no state {ul.STATE_SAFE} (safe) from it '
                    f'{now - self.safe_requested_at:.3f} s after the request (bound '
                    f'{self.safe_confirm_s:.3f} s: latency, safe ramp, hold and watchdog; its '
                    f'last state: {last}{heard}); check the rig')}

    def _rejected(self, when: str) -> str | None:
        """The line of ``udp_max_bad_datagrams`` rejected datagrams (`when`: after
        'rejected'), or None below the limit."""
        if self.counts['bad'] < self.max_bad:
            return None
        return (f'udp_bridge: {self.counts["bad"]} datagrams of the controller rejected{when} '
                f'(limit {self.max_bad}; last: {self.last_bad})')

    def start_violation(self) -> str | None:
        """Why the run cannot start, before its first sample, or None: too many rejected
        datagrams (a layout, byte-order or key mistake of the lab's encoder), or the
        controller's refusal of this run (its state ``fault``: ``dt_ns`` or the command kind
        not its own). :meth:`limit_violation` judges these only at a sample in effect, and
        a controller that refuses sends none: the run waited until the runner's 30 s stall
        bound, with a generic message."""
        rejected = self._rejected(' before its first sample')
        if rejected:
            return rejected
        d = self.controller
        if d is not None and d.session == self.session and d.state == ul.STATE_FAULT:
            return (f'udp_bridge: the controller at {self.peer[0]}:{self.peer[1]} refused the '
                    f'run ({ul.REASON_NAMES.get(d.reason, d.reason)})')
        return None

    def limit_violation(self) -> str | None:
        """Why the run must end safely at the sample in effect, or None: too many rejected
        datagrams, the controller's own fault or safe state, or the measured stroke or force
        beyond the limits."""
        rejected = self._rejected('')
        if rejected:
            return rejected
        c = self.current
        if c is not None and c.state in (ul.STATE_FAULT, ul.STATE_SAFE_RAMP, ul.STATE_SAFE):
            what = 'refused the run' if c.state == ul.STATE_FAULT else 'went to its safe state'
            return f'udp_bridge: the controller {what} ({ul.REASON_NAMES.get(c.reason, c.reason)})'
        if c is None:
            return None
        return self.limits.violation(self.time_s, c.displacement_m, c.force_N)

    def wire_counts(self) -> dict:
        """Counts for the final status: the PC's (``udp_*``) and the controller's
        (``controller_*``) of the datagrams each received."""
        out = {f'udp_{k}': v for k, v in self.counts.items()}
        out.update(udp_lost=self.filter.lost, udp_duplicate=self.filter.duplicate,
                   udp_reordered=self.filter.reordered)
        c = self.controller
        if c is not None:
            out.update(controller_late=c.late, controller_lost=c.lost,
                       controller_duplicate=c.duplicate, controller_reordered=c.reordered,
                       controller_bad=c.bad)
        out.update(controller_start_refused=int(self.start_refused))
        return out
