"""An emulated laboratory controller at the far end of the UDP bridge (``seft
emulate-controller``).

It is what a lab's real-time target does, with seft's simulated rig as the plant: it owns the
test's clock (samples at ``t0 + k dt`` on its own monotonic clock, whatever the PC does),
sends each sample to the PC, takes the PC's commands as they arrive and lets each act as the
rig contract says (:class:`~seft_plant_sim.realtime.WallClockRig`: held from its sample's
output instant, or from its arrival if later, then the hardware latency), and runs its own
safe state: on the PC's request, when the PC has been silent for ``watchdog_timeout_s``, when
too many datagrams were rejected, or at its own limits. So a run through the bridge with the
emulator is the simulated rig in real time with one more hop each way, and a lab can see what
its own controller must do.

Between runs it sends a heartbeat every ``udp_heartbeat_s`` (to the address that spoke last);
a datagram with the start flag and a new session starts a run (sample 0 at once); one with
the end flag ends it. It follows the rig contract's session rules
(:data:`~seft_plant_sim.udp_layout.SESSION_RULES`): while a session is live it answers the
PC that started it alone and takes datagrams from it alone; a start of another session is
refused (``{"event": "start_refused", ...}``, and reason
:data:`~seft_plant_sim.udp_layout.REASON_START_REFUSED` in its datagrams to the live PC), a
datagram from another address dropped (``"foreign_datagram"``, once per address); a new
session starts only after an end (the PC's end flag, its safe state held
:data:`~seft_plant_sim.udp_layout.SAFE_LINGER_S`, the PC silent for ``watchdog_timeout_s``
after the last sample). With ``message_auth: hmac`` every datagram carries the HMAC of the
test's key. It reports what happens as JSON lines (``{"event": "start", ...}``,
``"safe_state"``, ``"bad_datagram"``, ``"end"`` with its counts) through `events`.

The controller fault :data:`CONTROLLER_FAULTS` ``takes_any_session`` (``seft
emulate-controller --inject takes_any_session``, a test fault) breaks the session rules as the
emulator did before them: it takes a start of any session at any time and answers whoever
spoke last, so that ``seft rig-check`` shows what its ``second sender`` check says of such a
controller.

Imports no rclpy.
"""

from collections import deque
import json
import select
import signal
import socket
import sys
import time
from typing import Callable, Mapping

from seft_msgs_py import provenance, rig_contract
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.interface import COMMAND_VALVE
from seft_msgs_py.scheduling import set_fifo
from seft_plant_sim import udp_layout as ul
from seft_plant_sim.faults import CONTROLLER_FAULTS, Fault, FaultyRig, check_supported
from seft_plant_sim.realtime import WallClockRig
from seft_plant_sim.udp_bridge import RECEIVE_BYTES, parse_address

__all__ = ['ControllerEmulator', 'SAFE_LINGER_S', 'CONTROLLER_FAULTS', 'main',
           'realtime_priority', 'serve_until_stopped']

#: After its command reached zero the emulator keeps sampling the safe state at least this
#: long, waiting for the PC's end [s]; then it stops its run by itself (the PC may be gone).
SAFE_LINGER_S = ul.SAFE_LINGER_S


class ControllerEmulator:
    """seft's simulated rig behind a UDP socket, on its own clock (module notes).

    Parameters
    ----------
    params : mapping
        Resolved parameters: the rig's (``rig_model``, specimen, ``dt``, latencies,
        ``safe_ramp_s``, ``realtime_substep_s``, ``realtime_output``, limits) and the
        bridge's: it binds ``udp_controller_address``, and uses ``udp_heartbeat_s``,
        ``udp_max_bad_datagrams``, ``watchdog_timeout_s``.
    events : callable(dict), optional
        Receives each event (default: one JSON line on stdout).
    bind : (str, int), optional
        Bind this address instead of ``udp_controller_address`` (a test's proxy).
    fault : Fault, optional
        A wiring fault in what it sends (one of :data:`~seft_plant_sim.faults.SENSOR_FAULTS`:
        a lab controller sending a channel reversed, in another unit, stuck, swapped).
    controller_fault : str, optional
        One of :data:`CONTROLLER_FAULTS` (a test fault: the session rules broken).

    Attributes
    ----------
    foreign : int
        Datagrams of the live session's time from another address (dropped).
    refused_starts : int
        Datagrams with the start flag of another session refused while a session was live
        (each sender and session named once in the events).

    Raises
    ------
    ParameterError
        A bad address or rig parameter, the address cannot be bound, a fault it cannot
        send, or the key file of ``message_auth: hmac`` (``auth_key_file``).
    """

    def __init__(self, params: Mapping, *, events: Callable[[dict], None] | None = None,
                 bind: tuple[str, int] | None = None, fault: Fault | None = None,
                 controller_fault: str | None = None):
        if controller_fault is not None and controller_fault not in CONTROLLER_FAULTS:
            raise ParameterError(f'--inject {controller_fault!r}: expected one of '
                                 + ', '.join(CONTROLLER_FAULTS))
        #: The session rules are kept (False: the test fault takes_any_session).
        self.session_rules = controller_fault != 'takes_any_session'
        self.key = provenance.key_of(params)
        self.params = dict(params)
        self.dt = float(params['dt'])
        self.dt_ns = int(round(self.dt * 1e9))
        if fault is not None:
            check_supported(fault, params, emulator=True)
        self.fault = fault
        self._next_rig = self._plant()    # the next run's plant (checked now)
        kind = rig_contract.command_kind(params)
        self.wire_kind = ul.COMMAND_VALVE if kind == COMMAND_VALVE else ul.COMMAND_FORCE
        # the instant a command of source sample j is output (latched), after t_j
        self.latch_s = (min(self.dt, float(params['io_latency_s'])) if kind == COMMAND_VALVE
                        else self.dt)
        self.watchdog_s = float(params['watchdog_timeout_s'])
        self.heartbeat_s = float(params['udp_heartbeat_s'])
        self.max_bad = int(params['udp_max_bad_datagrams'])
        self.events = events or (lambda e: print(json.dumps(e), flush=True))
        address = bind or parse_address(params['udp_controller_address'])
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(address)
        except OSError as exc:
            self.sock.close()
            raise ParameterError(f'parameter udp_controller_address={address[0]}:'
                                 f'{address[1]}: cannot bind it ({exc.strerror})') from None
        self.sock.setblocking(False)
        self.address = self.sock.getsockname()
        self.pc = None
        self._sequence = 0
        self.session = 0
        self.state, self.reason = ul.STATE_IDLE, ul.REASON_NONE
        #: Running: the reason its datagrams give (a start it refused), else none.
        self.notice = ul.REASON_NONE
        self.filter = ul.SequenceFilter()
        self.late = self.bad = 0
        self.foreign = self.refused_starts = 0
        self._named: set = set()            # the foreign addresses already named
        self.rig: WallClockRig | None = None
        self.ticking = False
        self.runs = 0
        self._reset_run()

    def _reset_run(self) -> None:
        self.k = 0
        self.t0 = 0.0
        self.n_steps = 0
        self.last_pc: float | None = None
        self.safe_since: float | None = None
        self.latencies: deque = deque(maxlen=ul.LATENCY_SLOTS)
        self._unreported = 0            # latencies not yet sent

    # -- sending ----------------------------------------------------------------------------

    def _send(self, kind: int) -> None:
        if self.pc is None:
            return
        self._sequence = (self._sequence + 1) % 2 ** 32
        rig = self.rig
        if rig is not None and kind == ul.KIND_MEASUREMENT:
            m = rig.measure()
            values = (m.force_N, m.displacement_m, m.velocity_m_s, m.acceleration_m_s2,
                      rig.held_command, rig.held_source)
        else:
            values = (0.0, 0.0, 0.0, 0.0, 0.0, -1)
        sources = [s for s, _ in self.latencies] + [-1] * ul.LATENCY_SLOTS
        lat = [v for _, v in self.latencies] + [0.0] * ul.LATENCY_SLOTS
        sample = self.k if kind == ul.KIND_MEASUREMENT else max(self.k - 1, -1)
        reason = self.reason if self.reason != ul.REASON_NONE else self.notice
        d = ul.ToPC(kind, self.state, self.session, self._sequence, sample, *values,
                    reason, self.late, self.filter.lost, self.filter.duplicate,
                    self.filter.reordered, self.bad, tuple(sources[:ul.LATENCY_SLOTS]),
                    tuple(lat[:ul.LATENCY_SLOTS]))
        self._unreported = 0
        try:
            self.sock.sendto(ul.encode(d, self.key), self.pc)
        except OSError:
            pass

    # -- the run ----------------------------------------------------------------------------

    def _start(self, d: ul.ToController, address, now: float) -> None:
        self._reset_run()
        self.session = d.session
        self.pc = address                   # the live session's PC: the one it answers
        self.notice = ul.REASON_NONE
        self.foreign = self.refused_starts = 0
        self._named.clear()
        self.filter.reset()
        self.filter.take(d.sequence)
        self.late = self.bad = 0
        self.last_pc = now
        if d.dt_ns != self.dt_ns or d.command_kind != self.wire_kind:
            self.state, self.reason, self.rig, self.ticking = (
                ul.STATE_FAULT, ul.REASON_DT_MISMATCH, None, False)
            self.events({'event': 'refused', 'dt_ns': d.dt_ns, 'own_dt_ns': self.dt_ns,
                         'command_kind': d.command_kind, 'own_command_kind': self.wire_kind})
            self._send(ul.KIND_CONTROLLER_HEARTBEAT)
            return
        # the plant was built beforehand (a few ms): sample 0 is now, not behind the clock
        self.rig, self._next_rig = self._next_rig or self._plant(), None
        self.n_steps = int(d.n_steps)
        self.state, self.reason = ul.STATE_RUNNING, ul.REASON_NONE
        self.t0 = time.monotonic()
        self.ticking = True
        self.events({'event': 'start', 'session': d.session, 'n_steps': self.n_steps})

    def _safe(self, reason: int, **detail) -> None:
        if self.rig is None or self.rig.in_safe_state:
            return
        self.rig.enter_safe_state()
        self.state, self.reason = ul.STATE_SAFE_RAMP, reason
        self.events({'event': 'safe_state', 'reason': ul.REASON_NAMES[reason],
                     't_s': round(self.k * self.dt, 6), **detail})

    def _end(self, why: str) -> None:
        if self.ticking or self.state != ul.STATE_IDLE:
            self.events({'event': 'end', 'why': why, 'samples': self.k, 'late': self.late,
                         'lost': self.filter.lost, 'duplicate': self.filter.duplicate,
                         'reordered': self.filter.reordered, 'bad': self.bad,
                         'discarded': self.rig.discarded if self.rig is not None else 0,
                         'predicted': self.rig.predicted if self.rig is not None else 0,
                         'foreign': self.foreign, 'refused_starts': self.refused_starts})
            self.runs += 1
        self.ticking = False
        self.state = ul.STATE_IDLE
        self.notice = ul.REASON_NONE
        self.session = 0            # idle: the next run's PC hears it as free

    def _tick(self) -> None:
        """Sample k: integrate up to t_k (k > 0), check, send it; then k + 1."""
        rig = self.rig
        if self.k > 0:
            rig.advance()
        if rig.in_safe_state:
            self.state = ul.STATE_SAFE if rig.safe_ramp_done else ul.STATE_SAFE_RAMP
            if rig.safe_ramp_done and self.safe_since is None:
                self.safe_since = self.k * self.dt
        elif self.k <= self.n_steps:
            why = rig.limit_violation()
            if why:
                self._safe(ul.REASON_LIMIT, why=why)
        self._send(ul.KIND_MEASUREMENT)
        if self.k >= self.n_steps and not rig.in_safe_state:
            self.state = ul.STATE_FINISHED
            self.ticking = False
        elif (self.safe_since is not None
              and self.k * self.dt - self.safe_since >= SAFE_LINGER_S):
            self.ticking = False          # the PC did not end the run: it may be gone
            self._end('safe state held, no end from the PC')
            self.state = ul.STATE_SAFE
        self.k += 1

    def _prepare(self) -> None:
        """Between runs: build the next run's plant, so that a start does not wait for it."""
        if self._next_rig is None and not self.ticking:
            self._next_rig = self._plant()

    def _plant(self) -> WallClockRig:
        """A run's plant: seft's simulated rig on the wall clock, with the fault if any."""
        rig = WallClockRig(self.params)
        if self.fault is None:
            return rig
        return FaultyRig(rig, self.fault, seed=int(self.params['noise_seed']))

    def _take(self, data: bytes, address, now: float) -> None:
        live = self.session != 0 and self.session_rules
        if live and address != self.pc:
            self._from_another(data, address)
            return
        try:
            d = ul.decode_to_controller(data, self.key)
        except ul.DatagramError as exc:
            self.bad += 1
            print(f'emulate-controller: rejected {exc} ({self.bad} of at most '
                  f'{self.max_bad})', file=sys.stderr, flush=True)
            self.events({'event': 'bad_datagram', 'why': str(exc), 'count': self.bad})
            if self.bad >= self.max_bad:
                self._safe(ul.REASON_BAD_DATAGRAMS)
            return
        if not live:
            self.pc = address           # idle: its heartbeats go to whoever spoke last
        if d.session != self.session:
            starts = d.flags & ul.FLAG_START and not d.flags & ul.FLAG_END
            if starts and live:
                self._refuse(d, address)
            elif starts:
                self._start(d, address, now)
            return
        if not self.filter.take(d.sequence):
            return
        self.last_pc = now
        if d.flags & ul.FLAG_END:
            self._end('the PC ended the run')
            return
        if d.flags & ul.FLAG_SAFE:
            self._safe(ul.REASON_REQUESTED)
        if d.kind == ul.KIND_COMMAND and self.rig is not None:
            arrival = now - self.t0
            if arrival > d.source * self.dt + self.latch_s:
                self.late += 1
            self.rig.arrive(d.sample, d.value, arrival)
            self.latencies.appendleft((d.source, arrival - d.source * self.dt))
            self._unreported += 1
            # after its last sample, or when commands come in a burst (a PC that caught up
            # after a stall) faster than the samples report them: their latency at once
            if not self.ticking or self._unreported >= ul.LATENCY_SLOTS // 2:
                self._send(ul.KIND_CONTROLLER_HEARTBEAT)

    def _from_another(self, data: bytes, address) -> None:
        """A datagram from another address than the live session's PC: dropped, never
        answered; a start flag in it refused, anything else named once."""
        try:
            d = ul.decode_to_controller(data, self.key)
        except ul.DatagramError:
            d = None
        if d is not None and d.flags & ul.FLAG_START and not d.flags & ul.FLAG_END \
                and d.session != self.session:
            self._refuse(d, address)
            return
        self.foreign += 1
        if address not in self._named:
            self._named.add(address)
            self.events({'event': 'foreign_datagram', 'from': f'{address[0]}:{address[1]}',
                         'live_session': self.session, 'session': getattr(d, 'session', None),
                         'count': self.foreign})

    def _refuse(self, d: ul.ToController, address) -> None:
        """A start of another session while one is live: refused (events, and the reason of
        the datagrams to the live PC); its sender gets no answer."""
        self.refused_starts += 1
        self.notice = ul.REASON_START_REFUSED
        if (address, d.session) in self._named:
            return                          # named once per sender and session
        self._named.add((address, d.session))
        self.events({'event': 'start_refused', 'session': d.session,
                     'from': f'{address[0]}:{address[1]}', 'live_session': self.session,
                     'state': ul.STATE_NAMES[self.state], 'count': self.refused_starts})
        if not self.ticking:
            self._send(ul.KIND_CONTROLLER_HEARTBEAT)    # the live PC hears it now

    # -- the loop ---------------------------------------------------------------------------

    def serve(self, *, runs: int | None = None, stop: Callable[[], bool] = lambda: False
              ) -> None:
        """Serve runs until `runs` have ended (None: until `stop()` is true).

        Real time on the monotonic clock: it waits for datagrams up to the next sample's
        instant ``t0 + k dt`` (between runs: the next heartbeat), takes every datagram that
        came, and catches up the samples that are due (late ones are taken at once, never
        skipped).
        """
        next_beat = time.monotonic()
        while not stop() and (runs is None or self.runs < runs):
            now = time.monotonic()
            due = self.t0 + self.k * self.dt if self.ticking else next_beat
            ready, _, _ = select.select([self.sock], [], [], max(0.0, min(due - now, 0.05)))
            now = time.monotonic()
            while ready:
                try:
                    data, address = self.sock.recvfrom(RECEIVE_BYTES)
                except (BlockingIOError, OSError):
                    break
                self._take(data, address, now)
            if (self.ticking and self.state == ul.STATE_RUNNING and self.last_pc is not None
                    and now - self.last_pc > self.watchdog_s):
                self._safe(ul.REASON_PC_SILENT, silent_s=now - self.last_pc)
            if (not self.ticking and self.session and self.last_pc is not None
                    and now - self.last_pc > self.watchdog_s):
                # after its last sample (or a refused run) the PC is gone: the session ends
                self._end(f'PC silent for {now - self.last_pc:.3f} s after the last sample')
            while self.ticking and now >= self.t0 + self.k * self.dt:
                self._tick()
            if not self.ticking and now >= next_beat:
                self._send(ul.KIND_CONTROLLER_HEARTBEAT)
                next_beat = now + self.heartbeat_s
                self._prepare()

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


def main(argv=None) -> int:
    """``python -m seft_plant_sim.udp_emulator PARAMS_FILE [RUNS]``: serve RUNS runs (default:
    until interrupted) with the parameters of a ROS 2 parameter file (``seft emulate-
    controller`` does the same from a configuration)."""
    import yaml

    from seft_msgs_py import parameters
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        data = yaml.safe_load(open(args[0]).read())
        values = next(iter(data.values()))['ros__parameters']
        params = parameters.resolve({k: v for k, v in values.items()
                                     if k in parameters.defaults()})
        emulator = ControllerEmulator(params)
    except (OSError, IndexError, ValueError, KeyError, TypeError, ParameterError) as exc:
        print(f'emulate-controller: error: {exc}', file=sys.stderr)
        return 2
    serve_until_stopped(emulator, int(args[1]) if len(args) > 1 else None,
                        int(params['realtime_priority']))
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt(signal.Signals(signum).name)


def serve_until_stopped(emulator: ControllerEmulator, runs: int | None, priority: int,
                        announce: Callable[[], None] = lambda: None) -> None:
    """Serve `runs` runs (None: until stopped) at the rig's real-time `priority`
    (:func:`realtime_priority`), until SIGINT (Ctrl-C), SIGTERM or SIGHUP; then close the
    socket. `announce` says that it runs (after the signals are taken: a Ctrl-C from then on
    ends it).

    The signals are taken whatever the process inherited: a shell starts a background job
    (``(seft emulate-controller ... &)``) with SIGINT ignored, and Python then leaves it
    ignored (measured: such an emulator ran on 12 s after a SIGINT; in a test suite started
    that way each emulator test's teardown waited 10 s for its SIGKILL). Call from the main
    thread."""
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _interrupt)
    signal.signal(signal.SIGHUP, _interrupt)        # its terminal closed: as SIGTERM
    try:
        announce()
        realtime_priority(priority)
        emulator.serve(runs=runs)
    except KeyboardInterrupt:
        pass
    finally:
        emulator.close()


def realtime_priority(base: int) -> None:
    """SCHED_FIFO at the rig's priority (``realtime_priority`` + 3), where it may."""
    if base <= 0:
        return
    try:
        set_fifo(base + 3)
    except (OSError, AttributeError):
        pass


if __name__ == '__main__':
    sys.exit(main())
