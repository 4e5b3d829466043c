"""Loading OpenSeesPy, and keeping OpenSees' own messages (no rclpy).

The Linux wheel of ``openseespy`` (3.7.1.2, its binary package ``openseespylinux``) fails to
import on a machine without a system BLAS: its bundled ``liblapack.so.3`` needs the bundled
``libblas.so.3``, which is not on the loader's path ("Failed to import openseespy on Linux").
:func:`opensees` loads that library first (``ctypes.CDLL(..., RTLD_GLOBAL)``, found without
importing the package), then imports ``openseespy.opensees``: a model script that does
``import openseespy.opensees as ops`` afterwards gets the loaded module.

OpenSees writes its messages to the process's standard error and raises ``OpenSeesError('See
stderr output')``. :func:`captured` sends them to a file instead (OpenSees' ``logFile`` with
``-noEcho``) so that an error names OpenSees' own words in one line. As the process ends,
after seft's last line, OpenSees writes ``Process 0 Terminating`` there; a process that
loaded it sends its standard error to ``/dev/null`` at its exit (``_quiet_exit``).
"""

import atexit
from contextlib import contextmanager
import ctypes
import importlib
import importlib.util
import math
import os
from pathlib import Path
import sys
import tempfile

from seft_msgs_py.errors import ParameterError

__all__ = ['opensees', 'captured', 'Capture', 'last_message', 'message_lines', 'FAULT_WORDS',
           'rayleigh_calls']

_MODULE = None


def opensees():
    """The ``openseespy.opensees`` module, its bundled BLAS loaded first (module notes).

    Returns
    -------
    module
        ``openseespy.opensees`` (one interpreter per process: one model at a time).

    Raises
    ------
    ParameterError
        ``openseespy`` is not installed, or its library does not load (the loader's message).
    """
    global _MODULE
    if _MODULE is not None:
        return _MODULE
    spec = importlib.util.find_spec('openseespylinux')
    if spec is not None and spec.origin:
        blas = Path(spec.origin).parent / 'lib' / 'libblas.so.3'
        if blas.is_file():
            try:
                ctypes.CDLL(str(blas), mode=ctypes.RTLD_GLOBAL)
            except OSError as exc:
                raise ParameterError(f'openseespy: cannot load its {blas} ({exc})') from None
    try:
        _MODULE = importlib.import_module('openseespy.opensees')
    except ImportError as exc:
        raise ParameterError(f'openseespy: cannot import it ({exc}); tools/setup.sh installs '
                             'the pinned version') from None
    except Exception as exc:              # openseespy raises a bare Exception on Linux
        raise ParameterError(f'openseespy: cannot import it ({exc})') from None
    _log_rayleigh(_MODULE)
    atexit.register(_quiet_exit)
    return _MODULE


def _quiet_exit() -> None:
    """At the exit of a process that loaded OpenSees (an ``atexit`` hook, run before those
    registered earlier): Python's ``sys.stderr`` moves to a duplicate of descriptor 2, and
    descriptor 2 itself is pointed at ``/dev/null``, so that OpenSees' ``Process 0
    Terminating``, which its library writes there as the process ends, does not follow
    seft's last line (a new user read it as an error, session 35), while what Python writes
    after this (other exit hooks, 'Exception ignored' at shut-down) still reaches the
    standard error (the session's review: the first hook sent those to ``/dev/null`` too)."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    try:
        kept = os.dup(2)
        null = os.open(os.devnull, os.O_WRONLY)
    except OSError:
        return
    try:
        sys.stderr = open(kept, 'w', buffering=1, encoding=getattr(
            sys.stderr, 'encoding', None) or 'utf-8', errors='backslashreplace', closefd=True)
    except (OSError, ValueError):
        os.close(kept)
        os.close(null)
        return
    os.dup2(null, 2)
    os.close(null)


#: The Rayleigh damping factors the model set since its last ``wipe``: ``(command,
#: (alpha_M, beta_K, beta_K_init, beta_K_comm))`` per call of ``rayleigh`` (``'rayleigh'``),
#: ``region ... -rayleigh`` (``'region'``) and ``setElementRayleighDampingFactors``
#: (``'element'``). OpenSees keeps no way to read them back; the OpenSees part needs to
#: know whether the damping follows the current or committed stiffness
#: (:func:`rayleigh_calls`).
_RAYLEIGH: list = []


def rayleigh_calls() -> tuple:
    """The Rayleigh damping commands the model gave since its last ``wipe``, in order:
    ``(command, (alpha_M, beta_K, beta_K_init, beta_K_comm))``."""
    return tuple(_RAYLEIGH)


def _log_rayleigh(module) -> None:
    """Wrap `module`'s ``rayleigh``, ``region``, ``setElementRayleighDampingFactors`` and
    ``wipe`` so that the factors a model sets are kept (a model script imports the same
    module object after this, so its calls go through the wrappers)."""
    def factors(values) -> tuple:
        out = []
        for v in list(values)[:4]:
            try:
                out.append(float(v))
            except (TypeError, ValueError):
                out.append(math.nan)
        return tuple(out + [0.0] * (4 - len(out)))

    def wrap(name, record):
        original = getattr(module, name, None)
        if original is None or getattr(original, '_seft_wrapped', False):
            return

        def wrapper(*args, **kwargs):
            result = original(*args, **kwargs)
            record(args)
            return result
        wrapper._seft_wrapped = True
        wrapper.__doc__ = original.__doc__
        setattr(module, name, wrapper)

    def region(args):
        if '-rayleigh' in args:
            i = args.index('-rayleigh')
            _RAYLEIGH.append(('region', factors(args[i + 1:i + 5])))

    wrap('rayleigh', lambda args: _RAYLEIGH.append(('rayleigh', factors(args))))
    wrap('region', region)
    wrap('setElementRayleighDampingFactors',
         lambda args: _RAYLEIGH.append(('element', factors(args[1:]))))
    wrap('wipe', lambda args: _RAYLEIGH.clear())


class Capture:
    """OpenSees' messages while :func:`captured` is active (``text`` after it ends)."""

    text = ''


@contextmanager
def captured():
    """Send OpenSees' messages to a temporary file while the block runs.

    Yields
    ------
    Capture
        Its ``text`` holds the messages once the block has ended (also when it raised).
    """
    ops = opensees()
    fd, path = tempfile.mkstemp(prefix='seft-opensees-', suffix='.log')
    os.close(fd)
    out = Capture()
    try:
        ops.logFile(path, '-noEcho')
        yield out
    finally:
        try:
            ops.logFile(os.devnull, '-noEcho')
        except Exception:          # pragma: no cover - OpenSees refused its own log file
            pass
        try:
            out.text = Path(path).read_text(errors='replace')
        finally:
            os.unlink(path)


#: Words of an OpenSees message line that names a fault (:func:`last_message`), lower case.
FAULT_WORDS = ('unknown', 'error', 'not found', 'does not exist', 'could not', 'failed',
               'invalid', 'cannot', 'insufficient', 'not enough', 'no ', 'bad ')


def message_lines(text: str) -> list[str]:
    """OpenSees' message lines of `text`, whitespace collapsed, blank lines and its
    'Process 0 Terminating' left out."""
    lines = (' '.join(line.split()) for line in text.splitlines())
    return [line for line in lines if line and not line.startswith('Process 0 Terminating')]


def last_message(text: str, limit: int = 240) -> str:
    """OpenSees' message line of `text` that names the fault: the first that reads as one
    (:data:`FAULT_WORDS`), else the first; whitespace collapsed and cut to `limit`
    characters ('' if none). A model's harmless warning before its fault (a zeroLength
    element longer than the tolerance) was quoted in place of the fault ('material type
    Steel1 is unknown'; a new user, session 38)."""
    lines = message_lines(text)
    if not lines:
        return ''
    line = next((line for line in lines if any(w in line.lower() for w in FAULT_WORDS)),
                lines[0])
    return line if len(line) <= limit else line[:limit - 3] + '...'
