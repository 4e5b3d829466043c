"""The live view as a Foxglove WebSocket server (the ``foxglove-sdk`` package).

Foxglove, the ROS community's live and bag viewer, connects to ``ws://HOST:PORT`` ("Open
connection", Foxglove WebSocket) and shows the channels of :mod:`seft_ros.live.channels`:
JSON messages with a JSON schema per channel (numbers, so that a Plot panel offers every
field), the run's state on ``/seft/live/run``, the events as ``foxglove.Log`` messages on
``/seft/live/events`` (the Log panel), and the link figures on ``/seft/live/link``. The
layout ``docs/foxglove/seft_live_layout.json`` opens the panels the docs show. The server is
read-only: it advertises no capability that lets a client publish, call or set anything.

The server's log time of a sample is the run's start (when the live view heard of it) plus
the sample's time ``k dt``, so that every channel of one instant lines up; the payload
carries ``step`` and ``t_s`` as the bag's stamps do.
"""

from typing import Mapping, Sequence

import foxglove
from foxglove.channels import LogChannel
from foxglove.messages import Log, LogLevel, Timestamp

from seft_ros.live import channels as ch

__all__ = ['FoxgloveSink', 'start_foxglove']

_LEVELS = {'info': LogLevel.Info, 'warning': LogLevel.Warning, 'error': LogLevel.Error}


def _number_schema(fields: Sequence[str]) -> dict:
    props = {'step': {'type': 'integer', 'description': 'sample k'},
             't_s': {'type': 'number', 'description': 'sample time k dt [s]'}}
    props.update({f: {'type': 'number'} for f in fields})
    return {'type': 'object', 'properties': props}


_RUN_SCHEMA = {'type': 'object', 'properties': {
    'state': {'type': 'string'}, 'label': {'type': 'string'}, 'step': {'type': 'integer'},
    'n_steps': {'type': 'integer'}, 't_s': {'type': 'number'}, 'mode': {'type': 'string'},
    'reason': {'type': 'string'}, 'bag_closed': {'type': 'boolean'},
    'stopped_by': {'type': 'string'}}}
_LINK_SCHEMA = {'type': 'object', 'properties': {
    'host': {'type': 'string'}, 'reference': {'type': 'string'},
    'round_trip_p50_ms': {'type': 'number'}, 'round_trip_p99_ms': {'type': 'number'},
    'round_trip_max_ms': {'type': 'number'}, 'offset_ms': {'type': 'number'}}}


def start_foxglove(host: str, port: int, tls: tuple[bytes, bytes] | None = None):
    """Start the Foxglove WebSocket server on `host`:`port` (read-only: no capabilities).

    Parameters
    ----------
    host : str
    port : int
        0: a free port (``server.port`` tells which).
    tls : (cert, key), optional
        PEM bytes: the server then takes ``wss://`` connections only.

    Returns
    -------
    foxglove.WebSocketServer

    Raises
    ------
    RuntimeError
        The SDK's bind or TLS error (:func:`seft_ros.live.access.listen_error` says it in one
        line).
    """
    kwargs = {'tls_cert': tls[0], 'tls_key': tls[1]} if tls else {}
    return foxglove.start_server(name='seft live view', host=host, port=port,
                                 capabilities=[], **kwargs)


class FoxgloveSink:
    """The live view's channels on the Foxglove server of this process (module notes).

    A run's channels are advertised when it begins (and the analytical one once it is
    computed); the next run keeps those it has too and withdraws the others. The run's
    state, the events and the link stay.
    """

    def __init__(self):
        self.channels: dict[str, foxglove.Channel] = {}
        self.fields: dict[str, tuple] = {}
        self.run_channel = foxglove.Channel(ch.RUN, schema=_RUN_SCHEMA)
        self.events = LogChannel(ch.EVENTS)
        self.link: foxglove.Channel | None = None

    def new_run(self, fields: Mapping[str, Sequence[str]]) -> None:
        """Advertise the run's channels: keep those the previous run had with the same
        fields, close the others, make the new ones."""
        for name in list(self.channels):
            if tuple(fields.get(name, ())) != self.fields.get(name):
                self.channels.pop(name).close()
        for name, f in fields.items():
            if name not in self.channels:
                self.channels[name] = foxglove.Channel(name, schema=_number_schema(f))
        self.fields = {name: tuple(f) for name, f in fields.items()}

    def log(self, channel: str, message: dict, log_time_ns: int) -> None:
        """One message on `channel` (a run's channel, the state or the link)."""
        if channel == ch.RUN:
            self.run_channel.log(message, log_time=log_time_ns)
        elif channel == ch.LINK:
            if self.link is None:
                self.link = foxglove.Channel(ch.LINK, schema=_LINK_SCHEMA)
            self.link.log(message, log_time=log_time_ns)
        elif channel in self.channels:
            self.channels[channel].log(message, log_time=log_time_ns)

    def event(self, level: str, node: str, message: str, log_time_ns: int) -> None:
        """A ``foxglove.Log`` on ``/seft/live/events``."""
        stamp = Timestamp(sec=log_time_ns // 1_000_000_000, nsec=log_time_ns % 1_000_000_000)
        self.events.log(Log(timestamp=stamp, level=_LEVELS.get(level, LogLevel.Unknown),
                            message=message, name=node), log_time=log_time_ns)
