"""The live view's web page and its feed, and the token proxy in front of Foxglove.

Imports no rclpy. One asyncio loop in a thread of the live view's process (the ``websockets``
package) serves:

* the page, ``GET /`` (``static/index.html``) and its scripts and styles (``static/``, uPlot
  shipped with the package: no CDN, nothing fetched from elsewhere);
* the feed, a WebSocket at ``/live``: first ``{"type": "hello", ...}`` (the run, its plots,
  the analytical reference, every sample shown so far, the state), then every
  ``PUSH_PERIOD_S`` ``{"type": "data", ...}`` with what is new
  (:meth:`seft_ros.live.view.LiveView.delta`);
  the page sends ``{"op": "stop"}`` for the operator's stop, refused unless ``--live-stop``;
* with a token, the proxy of the Foxglove server (which then listens on a port of this
  machine only): ``ws[s]://HOST:PORT/?token=...``, each message passed through unchanged.

A request without the token (``?token=`` of the page's URL, passed on by the page to its
feed) is refused (403) and said in one line, once a minute per client address and kind
(page, Foxglove client). The feed
also refuses a page of another origin (a browser's cross-site WebSocket).
"""

import asyncio
from importlib import resources
import json
import logging
import threading
import time
from typing import Callable
from urllib.parse import parse_qs, urlsplit

from websockets.asyncio.client import connect
from websockets.asyncio.server import serve
from websockets.datastructures import Headers
from websockets.http11 import Response

from seft_ros.live.access import LiveOptions, listen_error, token_matches

__all__ = ['WebServer', 'PUSH_PERIOD_S', 'FOXGLOVE_SUBPROTOCOLS', 'STATIC_FILES']

#: How often the feed sends what is new to a page [s].
PUSH_PERIOD_S = 0.1
#: The Foxglove WebSocket protocol's names (the SDK's, then the older one).
FOXGLOVE_SUBPROTOCOLS = ('foxglove.sdk.v1', 'foxglove.websocket.v1')
#: The page's files (``seft_ros/live/static``) and their content types.
STATIC_FILES = {
    'index.html': 'text/html; charset=utf-8',
    'live.js': 'text/javascript; charset=utf-8',
    'live.css': 'text/css; charset=utf-8',
    'uPlot.iife.min.js': 'text/javascript; charset=utf-8',
    'uPlot.min.css': 'text/css; charset=utf-8',
}
#: A refused client is said once per this long per address [s].
REFUSED_QUIET_S = 60.0
#: How long a client's opening handshake (TLS, then the HTTP upgrade) may take [s]: the view
#: runs niced beside the test, and on a loaded host its TLS handshake took tens of seconds
#: (websockets' default, 10 s, hung up on a Foxglove client of the test suite; the proxy's
#: own connection to the Foxglove server has the same).
OPEN_TIMEOUT_S = 60.0
_HEADERS = {
    'Cache-Control': 'no-store',
    'X-Content-Type-Options': 'nosniff',
    'Referrer-Policy': 'no-referrer',
    'Content-Security-Policy': "default-src 'self'; connect-src 'self' ws: wss:; "
                               "style-src 'self' 'unsafe-inline'; img-src 'self' data:",
}


def _response(status: int, reason: str, body: bytes, content_type: str) -> Response:
    headers = Headers(_HEADERS)
    headers['Content-Type'] = content_type
    headers['Content-Length'] = str(len(body))
    return Response(status, reason, headers, body)


class WebServer:
    """The page, its feed and the Foxglove proxy (module notes), in a thread of their own.

    Parameters
    ----------
    view : LiveView
        What the feed sends.
    options : LiveOptions
        Address, token, TLS, stop.
    say : callable(str)
        Receives the one-line messages (a refused client, a stop).
    stop : callable(str) -> str
        The operator's stop, from the ROS side: takes who asked (the client's address),
        returns what was done (one line for the page).
    foxglove_port : int, optional
        With a token: the port of this machine's Foxglove server to proxy at
        ``options.port``.
    """

    def __init__(self, view, options: LiveOptions, say: Callable[[str], None],
                 stop: Callable[[str], str], foxglove_port: int | None = None):
        self.view = view
        self.options = options
        self.say = say
        self.request_stop = stop
        self.foxglove_port = foxglove_port
        self.files = resources.files('seft_ros.live') / 'static'
        self.refused_at: dict[tuple, float] = {}
        self.loop: asyncio.AbstractEventLoop | None = None
        self.thread: threading.Thread | None = None
        self.ready = threading.Event()
        self.lines: list[str] = []
        self.web_ok = False
        self.proxy_ok = False
        self._stopped: asyncio.Event | None = None
        logging.getLogger('websockets').setLevel(logging.CRITICAL)

    # -- life cycle -----------------------------------------------------------------------

    def start(self, timeout_s: float = 10.0) -> list[str]:
        """Listen; return the lines of what could not (empty: everything listens)."""
        self.thread = threading.Thread(target=self._thread, name='seft-live-web', daemon=True)
        self.thread.start()
        self.ready.wait(timeout_s)
        return list(self.lines)

    def close(self) -> None:
        """Stop listening and end the thread."""
        if self.loop is not None and self._stopped is not None:
            self.loop.call_soon_threadsafe(self._stopped.set)
        if self.thread is not None:
            self.thread.join(5.0)

    def _thread(self) -> None:
        asyncio.run(self._main())

    async def _main(self) -> None:
        self.loop = asyncio.get_running_loop()
        self._stopped = asyncio.Event()
        opts = self.options
        tls = opts.ssl_context()
        servers = []
        try:
            servers.append(await serve(self._page_handler, opts.host, opts.port + 1, ssl=tls,
                                       process_request=self._page_request,
                                       compression=None, max_size=2 ** 16,
                                       open_timeout=OPEN_TIMEOUT_S))
            self.web_ok = True
        except OSError as exc:
            self.lines.append(listen_error('the web page', opts.host, opts.port + 1, exc))
        if self.foxglove_port is not None:
            try:
                servers.append(await serve(
                    self._proxy_handler, opts.host, opts.port, ssl=tls,
                    process_request=self._proxy_request, compression=None, max_size=None,
                    subprotocols=list(FOXGLOVE_SUBPROTOCOLS), open_timeout=OPEN_TIMEOUT_S))
                self.proxy_ok = True
            except OSError as exc:
                self.lines.append(listen_error('Foxglove', opts.host, opts.port, exc))
        self.ready.set()
        try:
            await self._stopped.wait()
        finally:
            for server in servers:
                server.close()
            for server in servers:
                await server.wait_closed()

    # -- access ---------------------------------------------------------------------------

    def _authorized(self, connection, request, what: str) -> bool:
        query = parse_qs(urlsplit(request.path).query)
        given = query.get('token', [None])[0]
        if token_matches(self.options.token, given):
            return True
        client = _client(connection)
        now = time.monotonic()
        if now - self.refused_at.get((client, what), -1e9) >= REFUSED_QUIET_S:
            self.refused_at[(client, what)] = now
            self.say(f'live view: refused {what} from {client}: '
                     f'{"wrong" if given else "no"} token')
        return False

    def _page_request(self, connection, request):
        path = urlsplit(request.path).path
        if path == '/live':
            if not self._authorized(connection, request, 'a page'):
                return _response(403, 'Forbidden', b'wrong or missing token\n',
                                 'text/plain; charset=utf-8')
            origin = request.headers.get('Origin')
            host = request.headers.get('Host', '')
            if origin and urlsplit(origin).netloc != host:
                return _response(403, 'Forbidden', b'a page of another origin\n',
                                 'text/plain; charset=utf-8')
            return None                                  # the feed's WebSocket
        name = 'index.html' if path in ('/', '/index.html') else path.lstrip('/')
        if name not in STATIC_FILES:
            return _response(404, 'Not Found', b'not found\n', 'text/plain; charset=utf-8')
        if name == 'index.html' and not self._authorized(connection, request, 'a page'):
            return _response(403, 'Forbidden',
                             b'seft live view: wrong or missing token (open the URL that '
                             b'seft run printed, with its ?token=...)\n',
                             'text/plain; charset=utf-8')
        return _response(200, 'OK', (self.files / name).read_bytes(), STATIC_FILES[name])

    def _proxy_request(self, connection, request):
        if not self._authorized(connection, request, 'a Foxglove client'):
            return _response(403, 'Forbidden', b'wrong or missing token\n',
                             'text/plain; charset=utf-8')
        return None

    # -- the feed and the proxy -----------------------------------------------------------

    async def _page_handler(self, connection) -> None:
        msg, cursor = self.view.snapshot()
        await connection.send(json.dumps(msg, allow_nan=False))
        reader = asyncio.create_task(self._page_commands(connection))
        try:
            while not reader.done():
                await asyncio.sleep(PUSH_PERIOD_S)
                msg, cursor = self.view.delta(cursor)
                if msg is not None:
                    await connection.send(json.dumps(msg, allow_nan=False))
        except Exception:          # noqa: BLE001 - a page gone is not an error of the view
            pass
        finally:
            reader.cancel()

    async def _page_commands(self, connection) -> None:
        async for text in connection:
            try:
                op = json.loads(text).get('op')
            except (ValueError, AttributeError):
                continue
            if op != 'stop':
                continue
            client = _client(connection)
            if not self.view.stop_enabled:
                reply = {'type': 'stop', 'ok': False,
                         'message': 'this live view is read-only (seft run --live-stop '
                                    'offers the stop)'}
            else:
                done = await asyncio.get_running_loop().run_in_executor(
                    None, self.request_stop, client)
                reply = {'type': 'stop', 'ok': True, 'message': done}
            await connection.send(json.dumps(reply))

    async def _proxy_handler(self, connection) -> None:
        protocols = [connection.subprotocol] if connection.subprotocol else None
        url = f'ws://127.0.0.1:{self.foxglove_port}'
        try:
            async with connect(url, subprotocols=protocols, compression=None,
                               max_size=None, open_timeout=OPEN_TIMEOUT_S) as upstream:
                async def down():
                    async for message in upstream:
                        await connection.send(message)

                async def up():
                    async for message in connection:
                        await upstream.send(message)
                tasks = [asyncio.create_task(down()), asyncio.create_task(up())]
                _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
                for task in pending:
                    task.cancel()
        except Exception:          # noqa: BLE001 - a client gone is not an error of the view
            pass


def _client(connection) -> str:
    address = connection.remote_address
    return str(address[0]) if address else '?'
