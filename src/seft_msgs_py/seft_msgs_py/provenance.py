"""Which run a message came from: the run's seal on every message that commands the rig.

The DDS of seft's ROS 2 wheels has no security plugins (no SROS2): any process that reaches a
run's ``ROS_DOMAIN_ID`` and its DDS ports can publish on its topics. So the graph tells its
own messages from others' itself. ``seft run`` hands each run's nodes a **run token**
(``run_token``: 16 hex digits drawn at random per run) and every data message of the run
carries the run's **seal**:

* ``header.frame_id`` of a stamped message (the rig's measurement, the reference force, the
  valve command, a builder's specimen model) is ``'actuator#' + seal`` instead of
  ``'actuator'``;
* ``layout.dim[0].label`` of a record batch (``std_msgs/Float64MultiArray``, the ground
  motion the builder reads and every stream the recorder writes) is ``'step#' + seal``
  instead of ``'step'``;
* ``hardware_id`` of a status report (``/seft/status``, ``diagnostic_msgs/DiagnosticStatus``:
  a node's state, an abort, the recorder's 'closed', a runner's or the live view's report)
  is ``'seft#' + seal`` instead of ``'seft'`` (:meth:`RunSeal.seal_status`). A status ends
  nodes (a rig's final status, the recorder's 'closed', an abort), so a node, the runner,
  the recorder, the live view and ``seft rig-check`` act only on the run's
  (:meth:`RunSeal.status_ok`) and drop, count and name the others: a stray rig's 'aborted'
  from another test never ends this run.

With ``message_auth: token`` the seal is the run token itself: it keeps out the messages of
another test on the same domain and of an earlier run (their token differs), but not a sender
that reads the domain and copies it. With ``message_auth: hmac`` it is an HMAC-SHA256 (RFC
2104), truncated to :data:`MAC_BYTES` bytes (32 hex digits), keyed with the test's shared key
(``auth_key_file``, never on the wire) over the run token, the topic, the stamp and the values
(:func:`mac_input`; a status: over the run token, the topic, the node's name, the level, the
message and every key/value, :func:`status_mac_input`): only a holder of the key can make a
message the nodes take, and a sealed message cannot be replayed in another run or on another
topic. A status has no stamp: a copier on the domain can replay a status of this run within
this run (the same node's same report again, unchanged; it cannot alter a word of it nor make
one the node did not send). A node drops a message whose seal is not the run's before it
reads a value of it (:class:`RunSeal`), counts it, and names its publisher
(``seft_msgs_py.node_support``).

Nodes started by hand without a token (``run_token: none``) keep the plain ``'actuator'``,
``'step'`` and ``'seft'``: a graph with no token takes only unsealed messages.

The UDP bridge's datagrams are sealed with the same key (``message_auth: hmac``): a trailer
of :data:`MAC_BYTES` bytes, the HMAC over the datagram (:func:`datagram_mac`).

Imports no rclpy.

References
----------
H. Krawczyk, M. Bellare, R. Canetti, *HMAC: Keyed-Hashing for Message Authentication*,
RFC 2104 (1997); NIST FIPS 180-4 (SHA-256); NIST SP 800-107 Rev. 1, Sec. 5.3.3 (a MAC
truncated to 128 bits).
"""

import hashlib
import hmac
import os
from pathlib import Path
import secrets
import struct
from typing import Mapping, Sequence

from seft_msgs_py.errors import ParameterError

__all__ = ['RunSeal', 'new_run_token', 'read_key', 'key_of', 'mac_input', 'datagram_mac',
           'status_mac_input', 'status_id_of_run', 'FRAME_ID', 'LABEL', 'STATUS_ID',
           'SEPARATOR', 'TOKEN_HEX', 'MAC_BYTES', 'MIN_KEY_BYTES', 'AUTH_TOKEN', 'AUTH_HMAC',
           'AUTH_MODES', 'NONE']

#: The frame id of an unsealed stamped message (the actuator axis, ``seft_msgs_py.topics``).
FRAME_ID = 'actuator'
#: The first label of an unsealed record batch.
LABEL = 'step'
#: The hardware id of an unsealed status report (``diagnostic_msgs/DiagnosticStatus``).
STATUS_ID = 'seft'
#: Between the frame id (or label) and the seal.
SEPARATOR = '#'
#: Hex digits of a run token (64 random bits).
TOKEN_HEX = 16
#: Bytes of a truncated HMAC-SHA256 (a seal of 32 hex digits; a datagram's trailer).
MAC_BYTES = 16
#: The shortest key a key file may hold [bytes].
MIN_KEY_BYTES = 16
#: ``run_token`` and ``auth_key_file`` of a graph without them (nodes by hand).
NONE = 'none'
#: ``message_auth``: the run token in the clear, or an HMAC keyed with the test's key.
AUTH_TOKEN = 'token'
AUTH_HMAC = 'hmac'
AUTH_MODES = (AUTH_TOKEN, AUTH_HMAC)
#: Domain separation of the seal's HMAC input (its version).
_DOMAIN = b'seft-seal-1'
#: Domain separation of a status report's HMAC input (its version).
_STATUS_DOMAIN = b'seft-status-1'


def new_run_token() -> str:
    """A fresh run token: :data:`TOKEN_HEX` hex digits from the system's random source."""
    return secrets.token_hex(TOKEN_HEX // 2)


def read_key(path: str, *, name: str = 'auth_key_file') -> bytes:
    """The shared key in the file `path`: its bytes, leading and trailing white space removed
    (a key written by ``python -c "import secrets; print(secrets.token_hex(32))"`` is its 64
    hex digits as text).

    Raises
    ------
    ParameterError
        No file name, the file cannot be read, or it holds fewer than :data:`MIN_KEY_BYTES`
        bytes (the message names the parameter and the file).
    """
    if not str(path).strip() or path == NONE:
        raise ParameterError(f'parameter {name}={path!r}: message_auth hmac needs the file '
                             "of the test's shared key")
    try:
        key = Path(os.path.expanduser(str(path))).read_bytes().strip()
    except OSError as exc:
        raise ParameterError(f'parameter {name}={path!r}: cannot read it '
                             f'({exc.strerror or exc})') from None
    if len(key) < MIN_KEY_BYTES:
        raise ParameterError(f'parameter {name}={path!r}: {len(key)} bytes, expected a key '
                             f'of at least {MIN_KEY_BYTES} (e.g. 64 hex digits)')
    return key


def key_of(params: Mapping) -> bytes | None:
    """The shared key of a run's parameters (``message_auth`` 'hmac'), or None ('token').

    Raises
    ------
    ParameterError
        An unknown ``message_auth``, or the key file as :func:`read_key`.
    """
    mode = params.get('message_auth', AUTH_TOKEN)
    if mode not in AUTH_MODES:
        raise ParameterError(f'parameter message_auth={mode!r}: expected one of '
                             + ', '.join(repr(m) for m in AUTH_MODES))
    if mode == AUTH_TOKEN:
        return None
    return read_key(params.get('auth_key_file', NONE))


def mac_input(token: str, topic: str, stamp_ns: int, values: Sequence[float]) -> bytes:
    """What the seal's HMAC is computed over, as bytes.

    ``b'seft-seal-1' 0x00 token 0x00 topic 0x00`` (ASCII), then the stamp as a big-endian
    int64 [ns] and each value as a big-endian IEEE 754 binary64, in the message's order (the
    measurement: force, displacement, velocity, acceleration; a scalar: its one value; a
    record batch: its data, rows after one another, stamp 0). A lab's own node computes the
    same bytes from its message's fields, whatever its language.
    """
    head = b'\0'.join((_DOMAIN, token.encode('ascii'), topic.encode('ascii'), b''))
    return head + struct.pack(f'>q{len(values)}d', stamp_ns, *values)


def status_mac_input(token: str, topic: str, name: str, level: int, message: str,
                     pairs: Sequence[tuple[str, str]]) -> bytes:
    """What a status report's seal (``message_auth: hmac``) is computed over, as bytes.

    ``b'seft-status-1' 0x00 token 0x00 topic 0x00`` (ASCII), the level as one byte, then the
    node's name, the message and each key and value in the report's order, each as its
    UTF-8 length (big-endian uint32) and its UTF-8 bytes.

    Parameters
    ----------
    token, topic : str
        The run token and the status topic (``/seft/status``).
    name : str
        The reporting node's (qualified) name, ``DiagnosticStatus.name``.
    level : int
        ``DiagnosticStatus.level`` (0 OK, 1 WARN, 2 ERROR, 3 STALE).
    message : str
        ``DiagnosticStatus.message``.
    pairs : sequence of (str, str)
        The key/values, ``DiagnosticStatus.values``, in order.
    """
    out = [b'\0'.join((_STATUS_DOMAIN, token.encode('ascii'), topic.encode('ascii'), b'')),
           struct.pack('>B', level & 0xff)]
    for text in (name, message, *(t for pair in pairs for t in pair)):
        raw = str(text).encode('utf-8')
        out.append(struct.pack('>I', len(raw)) + raw)
    return b''.join(out)


def status_id_of_run(hardware_id: str, token: str, message_auth: str = AUTH_TOKEN) -> bool:
    """Whether a status report's ``hardware_id`` has the form of the run's seal, for a reader
    without the shared key (the bag reader, a live view on a host without the key file).

    ``message_auth: token``: ``'seft#' + token``, the seal itself. ``hmac``: ``'seft#'`` and
    ``2 * MAC_BYTES`` hex digits; the MAC is not checked (the key is needed): the recorder
    checks it before it writes a report to the bag. A run without a token (``'none'``):
    the plain :data:`STATUS_ID`.
    """
    token = '' if token in (None, NONE) else str(token)
    if not token:
        return hardware_id == STATUS_ID
    head, sep, seal = str(hardware_id).partition(SEPARATOR)
    if head != STATUS_ID or not sep:
        return False
    if message_auth == AUTH_HMAC:
        return len(seal) == 2 * MAC_BYTES and all(c in '0123456789abcdef' for c in seal)
    return seal == token


def _level_of(level) -> int:
    """A status level as an int (rclpy: one byte, rosbags: an int)."""
    if isinstance(level, (bytes, bytearray)):
        return level[0] if level else 0
    return int(level)


def datagram_mac(key: bytes, datagram: bytes) -> bytes:
    """The trailer of an authenticated UDP datagram: HMAC-SHA256 of its bytes with `key`,
    the first :data:`MAC_BYTES` bytes."""
    return hmac.new(key, datagram, hashlib.sha256).digest()[:MAC_BYTES]


class RunSeal:
    """The seal of one run's messages (module notes).

    Parameters
    ----------
    token : str
        The run token ('' or ``'none'``: no seal, the plain frame id and label).
    key : bytes, optional
        The test's shared key (``message_auth: hmac``); None: the token is the seal.

    Attributes
    ----------
    frame_id : str
        The frame id of the run's stamped messages as a template (hmac: the seal's place
        filled with '0'): its length is every sealed message's.
    label : str
        The first label of the run's record batches, likewise.
    sealed : bool
        The run has a token (its messages carry a seal).

    Raises
    ------
    ParameterError
        A token that is not '' or :data:`TOKEN_HEX` hex digits, or a key without a token.
    """

    def __init__(self, token: str = '', key: bytes | None = None):
        token = '' if token in (None, NONE) else str(token)
        if token and (len(token) != TOKEN_HEX
                      or any(c not in '0123456789abcdef' for c in token)):
            raise ParameterError(f'parameter run_token={token!r}: expected {TOKEN_HEX} hex '
                                 "digits (seft run draws one per run) or 'none'")
        if key is not None and not token:
            raise ParameterError("parameter message_auth='hmac': expected a run_token (seft "
                                 'run draws one per run)')
        self.token = token
        self.key = key
        self.sealed = bool(token)
        width = 2 * MAC_BYTES if key is not None else len(token)
        self._fixed = token if key is None else None
        placeholder = token if key is None else '0' * width
        self.frame_id = FRAME_ID + (SEPARATOR + placeholder if token else '')
        self.label = LABEL + (SEPARATOR + placeholder if token else '')
        #: Where the seal starts in the frame id and in the label [characters].
        self.frame_offset = len(FRAME_ID) + 1
        self.label_offset = len(LABEL) + 1
        self._frame_bytes = self.frame_id.encode('ascii')

    @classmethod
    def from_parameters(cls, params: Mapping) -> 'RunSeal':
        """The seal of a run's parameters (``run_token``, ``message_auth``,
        ``auth_key_file``).

        Raises
        ------
        ParameterError
            As :func:`key_of` and the constructor.
        """
        return cls(params.get('run_token', NONE), key_of(params))

    @property
    def authenticated(self) -> bool:
        """The seal is an HMAC (``message_auth: hmac``)."""
        return self.key is not None

    def seal(self, topic: str, stamp_ns: int, values: Sequence[float]) -> str:
        """The seal of one message [hex text] ('' for a run without a token).

        Parameters
        ----------
        topic : str
            The message's topic (fully qualified: ``/pier_a/seft/measurement``).
        stamp_ns : int
            Its stamp [ns] (0 for a record batch).
        values : sequence of float
            Its values in order (:func:`mac_input`).
        """
        if self._fixed is not None:
            return self._fixed
        return hmac.new(self.key, mac_input(self.token, topic, stamp_ns, values),
                        hashlib.sha256).hexdigest()[:2 * MAC_BYTES]

    def frame_id_of(self, topic: str, stamp_ns: int, values: Sequence[float]) -> str:
        """The frame id of one sealed stamped message."""
        if not self.sealed:
            return FRAME_ID
        return FRAME_ID + SEPARATOR + self.seal(topic, stamp_ns, values)

    def label_of(self, topic: str, values: Sequence[float]) -> str:
        """The first label of one sealed record batch (`values`: its data)."""
        if not self.sealed:
            return LABEL
        return LABEL + SEPARATOR + self.seal(topic, 0, values)

    def frame_ok(self, frame_id: str | bytes, topic: str, stamp_ns: int,
                 values: Sequence[float]) -> bool:
        """Whether a stamped message's frame id is this run's seal of it."""
        if isinstance(frame_id, str):
            frame_id = frame_id.encode('ascii', 'replace')
        if self._fixed is not None:
            return frame_id == self._frame_bytes
        head, sep, got = frame_id.partition(SEPARATOR.encode())
        return (head == FRAME_ID.encode() and bool(sep) and hmac.compare_digest(
            got, self.seal(topic, stamp_ns, values).encode('ascii')))

    def label_ok(self, label: str, topic: str, values: Sequence[float]) -> bool:
        """Whether a record batch's first label is this run's seal of it."""
        if self._fixed is not None:
            return label == self.label
        head, sep, got = label.partition(SEPARATOR)
        return (head == LABEL and bool(sep) and hmac.compare_digest(
            got.encode('ascii', 'replace'), self.seal(topic, 0, values).encode('ascii')))

    def status_seal(self, topic: str, msg) -> str:
        """The seal of one status report `msg` (``diagnostic_msgs/DiagnosticStatus`` or an
        object with its fields: ``name``, ``level``, ``message``, ``values``) on `topic`
        [hex text] ('' for a run without a token; :func:`status_mac_input`)."""
        if self._fixed is not None:
            return self._fixed
        data = status_mac_input(self.token, topic, str(msg.name), _level_of(msg.level),
                                str(msg.message), [(kv.key, kv.value) for kv in msg.values])
        return hmac.new(self.key, data, hashlib.sha256).hexdigest()[:2 * MAC_BYTES]

    def seal_status(self, msg, topic: str):
        """Put this run's seal on the status report `msg` (its ``hardware_id``:
        ``'seft#' + seal``, or :data:`STATUS_ID` without a token), once its fields are
        final; returns `msg`."""
        msg.hardware_id = (STATUS_ID + SEPARATOR + self.status_seal(topic, msg)
                           if self.sealed else STATUS_ID)
        return msg

    def status_ok(self, msg, topic: str) -> bool:
        """Whether the status report `msg` on `topic` carries this run's seal (a run
        without a token: whether it carries none, ``hardware_id`` :data:`STATUS_ID`)."""
        got = str(msg.hardware_id)
        if not self.sealed:
            return got == STATUS_ID
        head, sep, mac = got.partition(SEPARATOR)
        if head != STATUS_ID or not sep:
            return False
        return hmac.compare_digest(mac.encode('ascii', 'replace'),
                                   self.status_seal(topic, msg).encode('ascii'))

    def describe(self) -> str:
        """What seals the run, in words (logs and reports)."""
        if not self.sealed:
            return 'no run token (nodes by hand): unsealed messages only'
        if self.key is None:
            return f'run token {self.token} in the clear (message_auth token)'
        return 'HMAC-SHA256 with the shared key (message_auth hmac)'
