"""The byte layout of the UDP bridge between seft and a laboratory's real-time controller.

Two fixed-layout datagrams, network byte order (big-endian), no padding but the explicit pad
bytes, IEEE 754 binary64 floats, SI units (REP-103). A lab implements the other end in
LabVIEW, Simulink or C from the tables in ``docs/rig_contract.md`` (generated from
:data:`TO_CONTROLLER_FIELDS` and :data:`TO_PC_FIELDS`).

* **To the controller** (:class:`ToController`, :data:`TO_CONTROLLER_SIZE` bytes): the PC's
  command (kind :data:`KIND_COMMAND`: the valve voltage [V] or the force reference [N] of
  sample ``sample``, computed from sample ``source``) and its heartbeat
  (:data:`KIND_HEARTBEAT`), with the run's flags (start, safe state, end).
* **To the PC** (:class:`ToPC`, :data:`TO_PC_SIZE` bytes): the controller's measurement of
  its sample ``sample`` (:data:`KIND_MEASUREMENT`) or its heartbeat between runs, with its
  state, the command in effect, its counters and the latency of the last commands it took.

Every datagram carries ``magic`` (``b'SEFT'``), the layout ``version``
(:data:`LAYOUT_VERSION`), the ``session`` (the PC's run, chosen at random per run; the
controller echoes it) and a ``sequence`` number, +1 per datagram its sender sends in a
session. A receiver rejects a datagram of another length, magic, version or kind
(:class:`DatagramError`), and applies datagrams in the order of their sequence numbers only
(:class:`SequenceFilter`): a duplicate or one older than the newest taken is dropped and
counted, a gap is counted as lost.

**Sessions** (:data:`SESSION_RULES`, the rig contract's table): a controller runs one session
at a time and serves only the PC that started it. While a session is live it answers that
PC's address alone and takes datagrams from it alone; a start flag of another session, from
any address, is refused (:data:`REASON_START_REFUSED` in the reason of its datagrams to the
live PC, and in its events); a new session starts only after an end: the PC's end flag, the
safe state held :data:`SAFE_LINGER_S`, or the PC silent after the last sample. The PC takes
datagrams from the configured controller address alone (``udp_bridge``).

**Authenticated** (``message_auth: hmac``, a shared key per test): every datagram carries a
trailer of :data:`~seft_msgs_py.provenance.MAC_BYTES` bytes, the HMAC-SHA256 of the datagram
with the key (:func:`~seft_msgs_py.provenance.datagram_mac`); a datagram whose trailer does
not verify is rejected as a bad one. The session and the sequence number are inside the MAC,
so a datagram cannot be replayed into another session, nor out of order.

Imports no rclpy.
"""

from dataclasses import astuple, dataclass, fields
import hmac
import struct

from seft_msgs_py.provenance import MAC_BYTES, datagram_mac

__all__ = [
    'LAYOUT_VERSION', 'MAGIC', 'KIND_COMMAND', 'KIND_HEARTBEAT', 'KIND_MEASUREMENT',
    'KIND_CONTROLLER_HEARTBEAT', 'FLAG_START', 'FLAG_SAFE', 'FLAG_END', 'COMMAND_VALVE',
    'COMMAND_FORCE', 'STATE_IDLE', 'STATE_RUNNING', 'STATE_SAFE_RAMP', 'STATE_SAFE',
    'STATE_FINISHED', 'STATE_FAULT', 'STATE_NAMES', 'REASON_NONE', 'REASON_REQUESTED',
    'REASON_PC_SILENT', 'REASON_BAD_DATAGRAMS', 'REASON_LIMIT', 'REASON_DT_MISMATCH',
    'REASON_START_REFUSED', 'REASON_NAMES', 'LATENCY_SLOTS', 'ToController', 'ToPC',
    'TO_CONTROLLER_SIZE', 'TO_PC_SIZE', 'TO_CONTROLLER_FIELDS', 'TO_PC_FIELDS', 'DatagramError',
    'encode', 'decode_to_controller', 'decode_to_pc', 'SequenceFilter', 'markdown_tables',
    'SAFE_LINGER_S', 'SESSION_RULES', 'size_of',
]

#: Version of the byte layout; a datagram of another version is rejected.
LAYOUT_VERSION = 1
MAGIC = b'SEFT'

#: ``kind`` of a datagram to the controller: a command, or the PC's heartbeat.
KIND_COMMAND = 1
KIND_HEARTBEAT = 2
#: ``kind`` of a datagram to the PC: a measurement of a new sample, or the controller's
#: heartbeat (no new sample: between runs, or after its last sample).
KIND_MEASUREMENT = 3
KIND_CONTROLLER_HEARTBEAT = 4

#: ``flags`` bits of the PC's datagrams: start the run (sample 0 at the controller's next
#: tick), go to the safe state (ramp the command to zero), the run is over.
FLAG_START = 1
FLAG_SAFE = 2
FLAG_END = 4

#: ``command_kind``: the valve voltage [V] (the PC closes the force loop) or the force
#: reference [N] (the controller closes it).
COMMAND_VALVE = 1
COMMAND_FORCE = 2

#: The controller's ``state``.
STATE_IDLE = 0          # no run: heartbeats only
STATE_RUNNING = 1       # sampling, commands applied
STATE_SAFE_RAMP = 2     # sampling, the command ramping to zero, commands ignored
STATE_SAFE = 3          # sampling, the command at zero (valve closed / force zero)
STATE_FINISHED = 4      # the run's last sample was sent
STATE_FAULT = 5         # refused the run (reason)
STATE_NAMES = {STATE_IDLE: 'idle', STATE_RUNNING: 'running', STATE_SAFE_RAMP: 'safe ramp',
               STATE_SAFE: 'safe', STATE_FINISHED: 'finished', STATE_FAULT: 'fault'}

#: The controller's ``reason`` for a safe state or a fault.
REASON_NONE = 0
REASON_REQUESTED = 1        # the PC set FLAG_SAFE
REASON_PC_SILENT = 2        # no datagram from the PC for its watchdog time
REASON_BAD_DATAGRAMS = 3    # too many datagrams rejected
REASON_LIMIT = 4            # its own stroke or force limit
REASON_DT_MISMATCH = 5      # the PC's dt_ns is not its sample period
#: Running: the controller refused a start flag of another session (another sender tried
#: to take the rig); it says so in every datagram to the live PC until the run ends.
REASON_START_REFUSED = 6
REASON_NAMES = {REASON_NONE: 'none', REASON_REQUESTED: 'requested by the PC',
                REASON_PC_SILENT: 'PC silent', REASON_BAD_DATAGRAMS: 'bad datagrams',
                REASON_LIMIT: 'limit', REASON_DT_MISMATCH: 'dt mismatch',
                REASON_START_REFUSED: 'start refused (another session is live)'}

#: After its command reached zero a controller keeps sampling the safe state at least this
#: long, waiting for the PC's end [s]; then it ends the session by itself (the PC may be
#: gone) and a new session may start.
SAFE_LINGER_S = 0.5

#: How many (source sample, latency) pairs a datagram to the PC carries.
LATENCY_SLOTS = 8


@dataclass(frozen=True)
class ToController:
    """A datagram from the PC to the controller (module notes).

    Attributes
    ----------
    kind : int
        :data:`KIND_COMMAND` or :data:`KIND_HEARTBEAT`.
    flags : int
        :data:`FLAG_START` | :data:`FLAG_SAFE` | :data:`FLAG_END`.
    session : int
        The run (uint32, chosen by the PC).
    sequence : int
        +1 per datagram of the PC in the session (uint32).
    sample : int
        Command: its sample j (it is held from t_j); heartbeat: the newest sample the PC
        received (-1: none).
    source : int
        Command: the sample it was computed from (j for a valve command, j - 1 for a force
        reference); heartbeat: -1.
    value : float
        Command value [V or N]; heartbeat 0.
    dt_ns : int
        The PC's sample period [ns]; the controller refuses a run of another.
    n_steps : int
        Samples of the run (the controller sends samples 0 .. n_steps).
    command_kind : int
        :data:`COMMAND_VALVE` or :data:`COMMAND_FORCE`.
    """

    kind: int
    flags: int
    session: int
    sequence: int
    sample: int
    source: int
    value: float
    dt_ns: int
    n_steps: int
    command_kind: int


@dataclass(frozen=True)
class ToPC:
    """A datagram from the controller to the PC (module notes).

    Attributes
    ----------
    kind : int
        :data:`KIND_MEASUREMENT` or :data:`KIND_CONTROLLER_HEARTBEAT`.
    state : int
        The controller's state (:data:`STATE_NAMES`).
    session : int
        The PC's session it runs (0: none).
    sequence : int
        +1 per datagram of the controller (uint32).
    sample : int
        Its sample index k (the master clock of the test: ``t_k = k dt``).
    force_N, displacement_m, velocity_m_s, acceleration_m_s2 : float
        The sensors at t_k [N, m, m/s, m/s^2] (REP-103; x positive in extension).
    command : float
        The command in effect at the actuator at t_k [V or N].
    held_source : int
        The sample that command was computed from (-1: none yet).
    reason : int
        Why it is in a safe or fault state (:data:`REASON_NAMES`).
    late, lost, duplicate, reordered, bad : int
        Its counts of the PC's datagrams: commands that came after their sample's output
        instant, sequence gaps, repeats, ones older than the newest taken, rejected ones.
    latency_sources : tuple of int
        The source samples of its last :data:`LATENCY_SLOTS` commands, newest first (-1:
        empty).
    latency_s : tuple of float
        Their loop latency: arrival at the controller minus their source sample's instant,
        on its clock [s].
    """

    kind: int
    state: int
    session: int
    sequence: int
    sample: int
    force_N: float
    displacement_m: float
    velocity_m_s: float
    acceleration_m_s2: float
    command: float
    held_source: int
    reason: int
    late: int
    lost: int
    duplicate: int
    reordered: int
    bad: int
    latency_sources: tuple
    latency_s: tuple


#: The session rules: (what happens, what the controller does), the rig contract's table.
SESSION_RULES = (
    ('a datagram with the start flag and a new session, no session live (idle, or after an '
     'end)', "starts the run: sample 0 at once; from then on it answers that datagram's "
     'source address alone and takes datagrams from it alone'),
    ('a datagram from any other address while a session is live (another PC, a second '
     'sender, a copy of the live session number)', 'drops it and never answers it; names the '
     'address in its events (once) and counts it; the live run goes on'),
    ('a start flag of another session while a session is live, from any address (the live '
     "PC's included)", f'refuses it: no answer to its sender, the live run goes on; names it '
     f'in its events and sets reason {REASON_START_REFUSED} '
     f"'{REASON_NAMES[REASON_START_REFUSED]}' in every datagram to the live PC until the run "
     'ends'),
    ("the live PC's end flag", 'ends the session (idle: the next start may come from any '
     'address)'),
    (f"its safe state held {SAFE_LINGER_S:g} s (command at zero) without the PC's end",
     'ends the session by itself (the PC may be gone)'),
    ('after the last sample, the PC silent for watchdog_timeout_s',
     'ends the session by itself'),
    ('any datagram it sends', 'goes out from the address and port it listens on '
     '(udp_controller_address): the PC takes datagrams from that address alone, and names '
     'and counts any other (udp_foreign)'),
    ('message_auth hmac: a datagram whose trailer is not the HMAC of its bytes with the '
     "test's key", 'rejects it as a bad datagram (udp_max_bad_datagrams of them: its safe '
     'state)'),
)

#: (name, struct code, unit, meaning) of each field of a datagram to the controller, in order.
TO_CONTROLLER_FIELDS = (
    ('magic', '4s', '', "b'SEFT'"),
    ('version', 'B', '', f'layout version ({LAYOUT_VERSION})'),
    ('kind', 'B', '', f'{KIND_COMMAND} command, {KIND_HEARTBEAT} heartbeat'),
    ('flags', 'H', '', f'bits: {FLAG_START} start, {FLAG_SAFE} safe state, {FLAG_END} end'),
    ('session', 'I', '', 'the run, chosen by the PC'),
    ('sequence', 'I', '', '+1 per datagram of the PC in the session'),
    ('sample', 'q', '', 'command: its sample j; heartbeat: newest sample received (-1 none)'),
    ('source', 'q', '', 'command: the sample it was computed from; heartbeat: -1'),
    ('value', 'd', 'V or N', 'command value; heartbeat 0'),
    ('dt_ns', 'q', 'ns', 'sample period of the run'),
    ('n_steps', 'q', '', 'samples of the run (the controller sends 0 .. n_steps)'),
    ('command_kind', 'B', '', f'{COMMAND_VALVE} valve voltage, {COMMAND_FORCE} force'),
    ('pad', '3x', '', 'zero'),
)
_SLOTS = tuple((f'latency_source_{i}', 'q', '', f'source sample of the command {i} back '
                '(0: newest; -1 empty)') for i in range(LATENCY_SLOTS))
_LATENCIES = tuple((f'latency_{i}', 'd', 's', 'its loop latency (arrival - t_source)')
                   for i in range(LATENCY_SLOTS))
#: (name, struct code, unit, meaning) of each field of a datagram to the PC, in order.
TO_PC_FIELDS = (
    ('magic', '4s', '', "b'SEFT'"),
    ('version', 'B', '', f'layout version ({LAYOUT_VERSION})'),
    ('kind', 'B', '', f'{KIND_MEASUREMENT} measurement, {KIND_CONTROLLER_HEARTBEAT} '
     'heartbeat'),
    ('state', 'H', '', ', '.join(f'{k} {v}' for k, v in STATE_NAMES.items())),
    ('session', 'I', '', "the PC's session it runs (0 none)"),
    ('sequence', 'I', '', '+1 per datagram of the controller'),
    ('sample', 'q', '', 'its sample index k (t_k = k dt, the master clock)'),
    ('force_N', 'd', 'N', 'load cell'),
    ('displacement_m', 'd', 'm', 'x, positive in extension'),
    ('velocity_m_s', 'd', 'm/s', ''),
    ('acceleration_m_s2', 'd', 'm/s^2', ''),
    ('command', 'd', 'V or N', 'command in effect at t_k'),
    ('held_source', 'q', '', 'the sample it was computed from (-1 none)'),
    ('reason', 'H', '', ', '.join(f'{k} {v}' for k, v in REASON_NAMES.items())),
    ('pad', '2x', '', 'zero'),
    ('late', 'I', '', 'commands after their output instant'),
    ('lost', 'I', '', 'sequence gaps'),
    ('duplicate', 'I', '', 'repeated datagrams'),
    ('reordered', 'I', '', 'datagrams older than the newest taken'),
    ('bad', 'I', '', 'rejected datagrams'),
) + _SLOTS + _LATENCIES

_TO_CONTROLLER = struct.Struct('!' + ''.join(f[1] for f in TO_CONTROLLER_FIELDS))
_TO_PC = struct.Struct('!' + ''.join(f[1] for f in TO_PC_FIELDS))
#: Datagram sizes [bytes].
TO_CONTROLLER_SIZE = _TO_CONTROLLER.size
TO_PC_SIZE = _TO_PC.size


class DatagramError(ValueError):
    """A datagram of the wrong length, magic, version or kind, or whose HMAC does not verify
    (the message says which)."""


def size_of(size: int, key: bytes | None) -> int:
    """A datagram's length [bytes]: `size` and, authenticated (a `key`), the trailer."""
    return size + (MAC_BYTES if key is not None else 0)


def encode(datagram: ToController | ToPC, key: bytes | None = None) -> bytes:
    """The bytes of a datagram (layout version :data:`LAYOUT_VERSION`); with the test's
    `key`, followed by its HMAC trailer (module notes).

    Raises
    ------
    struct.error
        A field out of its range (a negative session, a sequence beyond uint32).
    """
    values = astuple(datagram)
    if isinstance(datagram, ToController):
        data = _TO_CONTROLLER.pack(MAGIC, LAYOUT_VERSION, *values)
    else:
        head, slots, latencies = values[:-2], values[-2], values[-1]
        data = _TO_PC.pack(MAGIC, LAYOUT_VERSION, *head, *slots, *latencies)
    return data if key is None else data + datagram_mac(key, data)


def _check(data: bytes, size: int, kinds: tuple, what: str, key: bytes | None) -> bytes:
    """The datagram without its trailer, checked (length, HMAC, magic, version, kind)."""
    if len(data) != size_of(size, key):
        raise DatagramError(f'{what}: {len(data)} bytes, expected {size_of(size, key)}'
                            + (' (authenticated: with its HMAC trailer)' if key else ''))
    if key is not None:
        data, mac = data[:size], data[size:]
        if not hmac.compare_digest(mac, datagram_mac(key, data)):
            raise DatagramError(f'{what}: its HMAC does not verify (another key, or forged)')
    if data[:4] != MAGIC:
        raise DatagramError(f'{what}: magic {data[:4]!r}, expected {MAGIC!r}')
    if data[4] != LAYOUT_VERSION:
        raise DatagramError(f'{what}: layout version {data[4]}, expected {LAYOUT_VERSION}')
    if data[5] not in kinds:
        raise DatagramError(f'{what}: kind {data[5]}, expected one of '
                            + ', '.join(str(k) for k in kinds))
    return data


def decode_to_controller(data: bytes, key: bytes | None = None) -> ToController:
    """Read a datagram to the controller (with the test's `key`: authenticated).

    Raises
    ------
    DatagramError
        Wrong length, magic, layout version or kind, or an HMAC that does not verify.
    """
    data = _check(data, TO_CONTROLLER_SIZE, (KIND_COMMAND, KIND_HEARTBEAT),
                  'datagram to the controller', key)
    return ToController(*_TO_CONTROLLER.unpack(data)[2:])


def decode_to_pc(data: bytes, key: bytes | None = None) -> ToPC:
    """Read a datagram to the PC (with the test's `key`: authenticated).

    Raises
    ------
    DatagramError
        Wrong length, magic, layout version or kind, or an HMAC that does not verify.
    """
    data = _check(data, TO_PC_SIZE, (KIND_MEASUREMENT, KIND_CONTROLLER_HEARTBEAT),
                  'datagram to the PC', key)
    v = _TO_PC.unpack(data)[2:]
    n = len(fields(ToPC)) - 2
    return ToPC(*v[:n], tuple(v[n:n + LATENCY_SLOTS]), tuple(v[n + LATENCY_SLOTS:]))


class SequenceFilter:
    """Take datagrams in the order of their sequence numbers only, and count what was not.

    Attributes
    ----------
    lost : int
        Sequence numbers skipped (datagrams never seen, or seen after newer ones).
    duplicate : int
        Datagrams with the newest sequence number taken again.
    reordered : int
        Datagrams older than the newest taken (dropped: never applied out of order).
    """

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        """Forget the sequence (a new session)."""
        self.newest: int | None = None
        self.lost = self.duplicate = self.reordered = 0

    def take(self, sequence: int) -> bool:
        """Whether the datagram numbered `sequence` is to be applied (it is newer than every
        one taken); counts it otherwise."""
        if self.newest is None or sequence > self.newest:
            if self.newest is not None:
                self.lost += sequence - self.newest - 1
            self.newest = sequence
            return True
        if sequence == self.newest:
            self.duplicate += 1
        else:
            self.reordered += 1
        return False


def markdown_tables() -> str:
    """The byte tables of both datagrams (offset, type, name, unit, meaning), the trailer of
    an authenticated one, and the session rules."""
    out = []
    for title, spec, size in (('PC to controller', TO_CONTROLLER_FIELDS, TO_CONTROLLER_SIZE),
                              ('controller to PC', TO_PC_FIELDS, TO_PC_SIZE)):
        rows = [f'**{title}** ({size} bytes, layout version {LAYOUT_VERSION}, big-endian)', '',
                '| offset | type | field | unit | meaning |', '|---|---|---|---|---|']
        offset = 0
        for name, code, unit, meaning in spec:
            width = struct.calcsize('!' + code)
            ctype = {'4s': 'char[4]', 'B': 'uint8', 'H': 'uint16', 'I': 'uint32',
                     'q': 'int64', 'd': 'float64'}.get(code, f'{width} pad bytes')
            rows.append(f'| {offset} | {ctype} | `{name}` | {unit or "-"} | {meaning} |')
            offset += width
        rows.append(f'| {offset} | uint8[{MAC_BYTES}] | `hmac` | - | message_auth hmac only: '
                    'the first 16 bytes of HMAC-SHA256(key, bytes 0 .. '
                    f'{offset - 1}) |')
        out.append('\n'.join(rows))
    rules = ['**Sessions**', '', '| when | the controller |', '|---|---|']
    rules += [f'| {when} | {does} |' for when, does in SESSION_RULES]
    out.append('\n'.join(rules))
    return '\n\n'.join(out)
