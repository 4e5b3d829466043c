"""Who may open the live view: the address it listens on, the token, TLS, the stop button.

Imports no rclpy. ``seft run --live [HOST][:PORT]`` (:func:`parse_address`): the Foxglove
server listens on ``HOST:PORT`` and the web page on ``HOST:PORT+1``; HOST defaults to
127.0.0.1 (this machine only) and PORT to 8765 (Foxglove's default). Naming another address
(a lab's interface, ``0.0.0.0``) opens the view to other sites, so then a token is required:
``$SEFT_LIVE_TOKEN`` if set, else one made at random and printed with the URLs. With a token
the page asks for it (``?token=`` in the URL, then a cookie) and the Foxglove server sits on
an internal port of this machine behind a proxy that asks for it too
(``ws://HOST:PORT/?token=...``); a client with a wrong or no token is refused with one line
in the run's output. ``--live-tls CERT KEY`` (PEM files) serves both over TLS
(``https://``, ``wss://``). The view is read-only; ``--live-stop`` adds the operator's stop
button to the page (:mod:`seft_ros.live.node`).
"""

from dataclasses import dataclass
import errno
import hmac
import ipaddress
import os
from pathlib import Path
import secrets
import ssl

from seft_msgs_py.errors import InputError

__all__ = ['LiveOptions', 'parse_address', 'listen_error', 'token_matches', 'DEFAULT_HOST',
           'DEFAULT_PORT', 'TOKEN_ENV', 'is_loopback']

DEFAULT_HOST = '127.0.0.1'
#: Foxglove's default port; the web page is on the next one.
DEFAULT_PORT = 8765
#: Environment variable of the token (never on the command line, where ``ps`` shows it).
TOKEN_ENV = 'SEFT_LIVE_TOKEN'


def parse_address(text: str | None) -> tuple[str, int]:
    """``HOST``, ``HOST:PORT``, ``:PORT``, ``[IPv6]:PORT`` or a bare IPv6 address ->
    ``(host, port)``.

    Raises
    ------
    InputError
        Not of that form, or a port outside 1-65534 (the page takes PORT+1); one line
        naming ``--live``.
    """
    text = (text or '').strip()
    host, port, ok = text, None, True
    if text.startswith('['):
        inside, _, rest = text[1:].partition(']')
        host = inside
        if rest:
            ok, port = rest.startswith(':'), rest[1:]
    elif text.count(':') == 1:
        host, port = text.split(':')
    elif ':' in text:                        # a bare IPv6 address, no port
        try:
            ipaddress.IPv6Address(text)
        except ValueError:
            ok = False
    host = host or DEFAULT_HOST
    try:
        number = DEFAULT_PORT if port is None else int(port)
    except ValueError:
        number = -1
    if not ok or not 1 <= number <= 65534 or any(c in host for c in '/?#@ '):
        raise InputError(f'--live {text}: expected [HOST][:PORT] with PORT 1-65534 (the web '
                         'page takes PORT+1), e.g. --live 0.0.0.0:8765')
    return host, number


def is_loopback(host: str) -> bool:
    """Whether `host` is this machine only (127.0.0.0/8, ::1, localhost)."""
    if host == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass
class LiveOptions:
    """How the live view is served (``seft run --live ...``).

    Attributes
    ----------
    host : str
    port : int
        The Foxglove server's; the web page is on ``port + 1``.
    token : str
        '' : none (this machine only).
    tls_cert, tls_key : str
        PEM files ('' : no TLS).
    stop : bool
        The page offers the operator's stop (``--live-stop``).
    rate_hz : float
        Display rate [Hz].
    """

    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    token: str = ''
    tls_cert: str = ''
    tls_key: str = ''
    stop: bool = False
    rate_hz: float = 50.0

    @classmethod
    def from_command_line(cls, address: str | None, tls=None, stop: bool = False,
                          environ=None) -> 'LiveOptions':
        """The options of ``--live [ADDRESS]``, ``--live-tls CERT KEY``, ``--live-stop`` and
        ``$SEFT_LIVE_TOKEN``; a token is made when the address is not this machine's only.

        Raises
        ------
        InputError
            A bad address, an unreadable certificate or key, or a pair that does not load
            (one line naming the option and the file).
        """
        environ = os.environ if environ is None else environ
        host, port = parse_address(address)
        token = environ.get(TOKEN_ENV, '').strip()
        if not token and not is_loopback(host):
            token = secrets.token_urlsafe(18)
        cert, key = (str(tls[0]), str(tls[1])) if tls else ('', '')
        if tls:
            for what, path in (('certificate', cert), ('key', key)):
                if not Path(path).is_file():
                    raise InputError(f'--live-tls: {path}: no such {what} file (expected PEM)')
            try:
                ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(cert, key)
            except (ssl.SSLError, OSError, ValueError) as exc:
                raise InputError(f'--live-tls {cert} {key}: not a PEM certificate and its '
                                 f'private key ({exc})') from None
        return cls(host, port, token, cert, key, stop)

    @property
    def scheme(self) -> tuple[str, str]:
        """``('http', 'ws')`` or with TLS ``('https', 'wss')``."""
        return ('https', 'wss') if self.tls_cert else ('http', 'ws')

    def urls(self) -> tuple[str, str]:
        """The web page's URL and the Foxglove address (with the token, if any)."""
        shown = f'[{self.host}]' if ':' in self.host else self.host
        query = f'?token={self.token}' if self.token else ''
        web, ws = self.scheme
        return (f'{web}://{shown}:{self.port + 1}/{query}',
                f'{ws}://{shown}:{self.port}{"/" + query if query else ""}')

    def tls_pem(self) -> tuple[bytes, bytes] | None:
        """The certificate and key as PEM bytes (None without TLS)."""
        if not self.tls_cert:
            return None
        return Path(self.tls_cert).read_bytes(), Path(self.tls_key).read_bytes()

    def ssl_context(self) -> ssl.SSLContext | None:
        """A server TLS context (None without TLS)."""
        if not self.tls_cert:
            return None
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        context.load_cert_chain(self.tls_cert, self.tls_key)
        return context


def token_matches(expected: str, given: str | None) -> bool:
    """Whether `given` is the token (constant time); any client when there is none."""
    if not expected:
        return True
    return given is not None and hmac.compare_digest(expected.encode(), given.encode())


def listen_error(what: str, host: str, port: int, exc: BaseException) -> str:
    """One line for a server that could not listen (port in use, address not on this
    host, unknown host name, bad TLS pair)."""
    text = str(exc)
    code = getattr(exc, 'errno', None)
    if code == errno.EADDRINUSE or 'in use' in text:
        why = f'port {port} is in use (another live view or program?)'
    elif code == errno.EADDRNOTAVAIL or 'assign requested address' in text:
        why = f'{host} is not an address of this host'
    elif 'lookup' in text or 'Name or service' in text or isinstance(exc, OSError) and \
            code in (-2, -3, -5):
        why = f'{host}: unknown host name'
    elif code == errno.EACCES or 'denied' in text:
        why = f'port {port} needs privileges (choose one above 1023)'
    else:
        why = text.replace('FoxgloveError: ', '').splitlines()[0] if text else repr(exc)
    return f'live view: {what} cannot listen on {host}:{port}: {why}'
