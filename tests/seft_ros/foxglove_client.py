"""A Foxglove WebSocket client for the tests: subscribes to every channel a server advertises
and keeps every message, as the Foxglove app would receive them.

The protocol (foxglove.sdk.v1 / foxglove.websocket.v1): text frames carry JSON operations
(``serverInfo``, ``advertise``, ``unadvertise``, ...); the client subscribes with
``{"op": "subscribe", "subscriptions": [{"id", "channelId"}]}``; binary frames of opcode 1
carry a message: ``uint32`` subscription id, ``uint64`` log time [ns], the payload.

foxglove-sdk 0.30.3 advertises a channel made while a client is connected a moment before it
takes subscriptions to it: a client that subscribes at once is told ``Unknown channel ID``
now and then (5 of 200 channels made 5 ms apart, here) and would never receive that channel.
This client subscribes again 50 ms later when told so.
"""

from collections import defaultdict
import json
import re
import ssl
import struct
import threading

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

SUBPROTOCOLS = ['foxglove.sdk.v1', 'foxglove.websocket.v1']


#: The handshake's timeout [s]: a live view on a host at load 15 took more than 10 s.
OPEN_TIMEOUT_S = 30.0


def _connect_or_fail(url: str, context):
    """``websockets.sync.client.connect`` in a daemon thread, joined with a timeout: when
    a TLS handshake times out, websockets 17 joins its reader thread, which can stay blocked
    on the SSL socket for good (a CI run hung 15 min there); fail instead."""
    out: dict = {}

    def run():
        try:
            out['ws'] = connect(url, subprotocols=SUBPROTOCOLS, ssl=context,
                                open_timeout=OPEN_TIMEOUT_S, max_size=None).__enter__()
        except Exception as exc:                    # noqa: BLE001 - handed to the caller
            out['error'] = exc

    thread = threading.Thread(target=run, daemon=True, name='foxglove-connect')
    thread.start()
    thread.join(OPEN_TIMEOUT_S + 15.0)
    if 'error' in out:
        raise out['error']
    if 'ws' not in out:
        raise TimeoutError(f'{url}: no websocket after {OPEN_TIMEOUT_S + 15:g} s (the '
                           'handshake timed out and websockets hangs closing it)')
    return out['ws']


class FoxgloveClient:
    """Connect to `url`, subscribe to everything, collect in a thread until :meth:`close`.

    Attributes
    ----------
    advertised : dict
        Topic -> its channel description (every channel ever advertised).
    messages : dict
        Topic -> list of (log time [ns], decoded payload: dict for JSON, bytes otherwise).
    server_info : dict
    """

    def __init__(self, url: str, *, insecure_tls: bool = False):
        context = None
        if url.startswith('wss:'):
            context = ssl.create_default_context()
            if insecure_tls:
                context.check_hostname = False
                context.verify_mode = ssl.CERT_NONE
        self.ws = _connect_or_fail(url, context)
        self.advertised: dict[str, dict] = {}
        self.messages: dict[str, list] = defaultdict(list)
        self.server_info: dict = {}
        #: The text operations received (channels by id and topic), for a failure's message.
        self.ops: list[dict] = []
        self._by_sub: dict[int, dict] = {}
        self._by_id: dict[int, dict] = {}
        self._next = 1
        self.lock = threading.Lock()
        #: How the connection ended if the server closed it (at its end; a slow client is
        #: dropped).
        self.closed_by = ''
        self._closing = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            for frame in self.ws:
                if isinstance(frame, str):
                    self._on_text(json.loads(frame))
                elif frame and frame[0] == 1:
                    sub, log_time = struct.unpack_from('<IQ', frame, 1)
                    channel = self._by_sub.get(sub)
                    if channel is None:
                        continue
                    payload = bytes(frame[13:])
                    if channel.get('encoding') == 'json':
                        payload = json.loads(payload)
                    with self.lock:
                        self.messages[channel['topic']].append((log_time, payload))
        except ConnectionClosed as exc:
            if not self._closing:
                self.closed_by = f'closed by the server ({exc})'
            return

    def _on_text(self, op: dict) -> None:
        self.ops.append({k: v for k, v in op.items() if k != 'channels'}
                        | {'channels': [(c['id'], c['topic']) for c in op.get('channels', [])]})
        if op.get('op') == 'serverInfo':
            self.server_info = op
        elif op.get('op') == 'advertise':
            for channel in op['channels']:
                self.advertised[channel['topic']] = channel
                self._by_id[channel['id']] = channel
            self._subscribe(op['channels'])
        elif op.get('op') == 'status':
            unknown = re.match(r'Unknown channel ID: (\d+)', op.get('message', ''))
            if unknown and int(unknown.group(1)) in self._by_id:
                channel = self._by_id[int(unknown.group(1))]
                threading.Timer(0.05, self._subscribe, ([channel],)).start()

    def _subscribe(self, channels) -> None:
        subs = []
        with self.lock:
            for channel in channels:
                sub = self._next
                self._next += 1
                self._by_sub[sub] = channel
                subs.append({'id': sub, 'channelId': channel['id']})
        try:
            self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
        except ConnectionClosed:
            return

    def json_messages(self, topic: str) -> list[dict]:
        """The JSON payloads received on `topic`, in order."""
        with self.lock:
            return [m for _, m in self.messages.get(topic, [])]

    def close(self) -> None:
        """Disconnect and stop collecting."""
        self._closing = True
        self.ws.close()
        self.thread.join(5.0)
