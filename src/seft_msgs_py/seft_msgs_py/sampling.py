"""Sampled-data helpers shared by the rigs, the compensators and the stability analysis (here,
below both the controller side and the plant simulation, which both use them)."""

import math
import sys
import threading

import numpy as np
from scipy.signal import cont2discrete
from threadpoolctl import ThreadpoolController

__all__ = ['zoh', 'split_delay', 'linear_map', 'LazyLinearMap', 'COMPILE_AFTER_CALLS',
           'chained_linear_map', 'single_blas_thread']

_BLAS = None


def single_blas_thread():
    """Context manager limiting the BLAS libraries of numpy and scipy to one thread.

    The set-up of a run (matrix exponentials, the force-loop inverse's 4098 x 48 least-squares
    fit) is too small to gain from BLAS threads, and idle BLAS threads spinning beside the
    pure-Python step loop, or beside the other runs of a sweep, slow it down. Measured on the
    2-core development machine: the ``model`` set-up took 19 ms on one thread and 32 ms on
    two; a sweep of 8 runs in a 2-worker pool took 0.3 s with one BLAS thread per worker and
    1.2-1.5 s (slower than one run after the other) with two. One thread also makes the fit
    independent of the machine's thread count, so a node and ``seft simulate`` get the same
    numbers. Uses :class:`threadpoolctl.ThreadpoolController`, which finds the BLAS libraries
    loaded when it is made: made again once modules were imported since (a module imported
    later may bring its own BLAS, e.g. python-control's slycot; a controller kept from before
    left it at its threads), else kept (making one takes about 0.7 ms).
    """
    global _BLAS
    modules = len(sys.modules)
    if _BLAS is None or _BLAS[0] != modules:
        _BLAS = (modules, ThreadpoolController())
    return _BLAS[1].limit(limits=1)


def zoh(a, b, h: float):
    """Zero-order-hold discretization of ``x' = a x + b u`` over a hold of length `h`.

    Parameters
    ----------
    a : ndarray, shape (n, n)
    b : ndarray, shape (n, m)
    h : float >= 0
        Hold length [s]; 0 gives the identity and a zero input matrix.

    Returns
    -------
    phi : ndarray, shape (n, n)
        ``exp(a h)``.
    gamma : ndarray, shape (n, m)
        ``int_0^h exp(a s) ds b`` (``scipy.signal.cont2discrete(method='zoh')``).
    """
    if h <= 0.0:
        return np.eye(a.shape[0]), np.zeros_like(b)
    phi, gamma, *_ = cont2discrete((a, b, np.eye(a.shape[0]), np.zeros_like(b)), h, 'zoh')
    return phi, gamma


def split_delay(tau_s: float, dt: float) -> tuple[int, float]:
    """Split a delay into whole steps and a remainder: ``tau = n dt + delta``.

    ``0 <= delta < dt``; a remainder within 1e-9 dt of a step multiple snaps to 0, so that
    0.01 s at dt = 0.002 s is exactly 5 steps despite floating point.

    Returns
    -------
    n : int
        Whole steps.
    delta : float
        Remainder [s].
    """
    n = int(math.floor(tau_s / dt + 1e-9))
    delta = tau_s - n * dt
    if abs(delta) < 1e-9 * dt:
        delta = 0.0
    return n, max(delta, 0.0)


def linear_map(matrix, *, name: str = 'linear_map', unpack: bool = False):
    """Compile ``y = M x`` for a fixed matrix into straight-line Python float code.

    Stepping a small sampled system once per control period with numpy costs about a
    microsecond per call in overhead alone (argument checks, a temporary array, the result
    back to Python floats); the same products written out in Python take about 25 ns each.
    This writes them out once: each output row becomes one expression
    ``m_i0*x[0] + m_i1*x[1] + ...`` with the coefficients as literals (``repr`` of a float
    round-trips exactly), summed left to right, exact zeros left out and unit coefficients
    not multiplied (both exact). The code is compiled with :func:`exec`, the way
    :mod:`dataclasses` builds ``__init__``.

    Parameters
    ----------
    matrix : array_like, shape (m, n) or (n,)
        Finite coefficients. A 1-d array gives a function returning one float.
    name : str
        Name of the function (shown in profiles and tracebacks).
    unpack : bool
        The caller passes exactly n floats: the function unpacks `x` into locals once
        instead of indexing it at each term (two instructions fewer a term: a tenth of a
        48-tap FIR's time). The same products summed in the same order.

    Returns
    -------
    callable(x) -> tuple of float, length m (or float for a 1-d `matrix`)
        `x` is any sequence of at least n floats that supports indexing (a list is fastest);
        with `unpack`, a sequence of exactly n (otherwise the call raises ValueError).

    Raises
    ------
    ValueError
        If a coefficient is not finite, the array is not 1-d or 2-d or `name` is not an
        identifier.

    Notes
    -----
    The sum of row i is ``((m_i0 x_0 + m_i1 x_1) + m_i2 x_2) + ...``: the same value as
    ``sum(m_ij * x_j for j)``, and within rounding of ``numpy.dot``.
    """
    m = _coefficients(matrix, name, 'linear_map')
    key = (name, m.shape, m.tobytes(), unpack)
    fn = _COMPILED.get(key)
    if fn is not None:
        return fn
    operand, head = _operands(m.shape[-1], unpack)
    exprs = [_row(row, operand) for row in ([m] if m.ndim == 1 else list(m))]
    body = exprs[0] if m.ndim == 1 else '(' + ', '.join(exprs) + ',)'
    namespace = {}
    exec(f'def {name}(x):\n{head}    return {body}\n', namespace)
    fn = namespace[name]
    with _COMPILED_LOCK:                # the background fits' thread compiles too
        if len(_COMPILED) >= _COMPILED_KEPT:
            _COMPILED.pop(next(iter(_COMPILED)))
        _COMPILED[key] = fn
    return fn


#: The functions :func:`linear_map` compiled last, by their name and exact coefficients (a
#: function of literals keeps no state: a copy of a compensator, the stability guard's
#: identification drives a copy a few hundred times per design, gets the same function
#: back instead of compiling it again, 0.2-0.4 ms for fifty terms).
_COMPILED: dict = {}
_COMPILED_KEPT = 256
_COMPILED_LOCK = threading.Lock()


#: Calls of a :class:`LazyLinearMap` before it compiles itself.
COMPILE_AFTER_CALLS = 16


class LazyLinearMap:
    """``y = M x`` for a fixed matrix, computed term by term in Python at first and compiled
    (:func:`linear_map`) after :data:`COMPILE_AFTER_CALLS` calls.

    Compiling costs 0.2-0.4 ms for a row of about fifty terms, paid where the map is made. A
    map made anew at nearly every step and called once or twice (the interface prediction
    of a computational part that yields: a new tangent each step) pays it every step, on the
    real-time step's critical path: on the yielding steel frame the compiles were 0.5-2 ms of
    the 2-6 ms steps at its first yield. Here each call before the compile sums the same
    products in the same order as the compiled code, so every result is the same float, bit
    for bit, before and after it (a few microseconds per call for fifty terms instead of
    about 1.5); a map that lives compiles itself once.

    Parameters
    ----------
    matrix : array_like, shape (m, n) or (n,)
        Finite coefficients. A 1-d array gives a map returning one float.
    name : str
        Name of the compiled function.

    Raises
    ------
    ValueError
        As :func:`linear_map`, when made.
    """

    __slots__ = ('_rows', '_single', '_calls', '_compiled', '_matrix', '_name')

    def __init__(self, matrix, *, name: str = 'linear_map'):
        m = _coefficients(matrix, name, 'linear_map')
        self._single = m.ndim == 1
        self._rows = [_terms(row) for row in ([m] if self._single else list(m))]
        self._matrix, self._name = m, name
        self._calls = 0
        self._compiled = None

    def __call__(self, x):
        """``M x`` (a tuple of floats; one float for a 1-d matrix)."""
        if self._compiled is not None:
            return self._compiled(x)
        self._calls += 1
        if self._calls > COMPILE_AFTER_CALLS:
            self._compiled = linear_map(self._matrix, name=self._name)
            return self._compiled(x)
        out = []
        for terms in self._rows:
            if not terms:
                out.append(0.0)
                continue
            c, j = terms[0]
            total = x[j] if c is None else c * x[j]
            for c, j in terms[1:]:
                total = total + (x[j] if c is None else c * x[j])
            out.append(total)
        return out[0] if self._single else tuple(out)

    @property
    def compiled(self) -> bool:
        """Whether the map has compiled itself."""
        return self._compiled is not None


def chained_linear_map(matrix, then, *, name: str = 'chained_linear_map',
                       unpack: bool = False):
    """Compile ``y = M x`` and ``z = N y`` for fixed matrices into one straight-line function.

    A sampled system's step and its readings (``s[k+1] = [Phi, Gamma] [s[k], u]``, then
    ``y = C s[k+1]``) in one call: the same products and sums as ``linear_map(M)`` followed by
    ``linear_map(N)`` on its result (the same floats, bit for bit), without the second call
    and its indexing. See :func:`linear_map` for how the code is written.

    Parameters
    ----------
    matrix : array_like, shape (m, n)
        M; finite coefficients.
    then : array_like, shape (p, m)
        N; finite coefficients.
    name : str
        Name of the function (shown in profiles and tracebacks).
    unpack : bool
        The caller passes exactly n floats (see :func:`linear_map`).

    Returns
    -------
    callable(x) -> (tuple of float, tuple of float)
        ``(y, z)``, lengths m and p; `x` as for :func:`linear_map`.

    Raises
    ------
    ValueError
        If a coefficient is not finite, a matrix is not 2-d, their shapes do not chain, or
        `name` is not an identifier.
    """
    m = _coefficients(matrix, name, 'chained_linear_map')
    n = _coefficients(then, name, 'chained_linear_map')
    if m.ndim != 2 or n.ndim != 2 or n.shape[1] != m.shape[0]:
        raise ValueError(f'chained_linear_map: expected matrices (m, n) and (p, m), got shapes '
                         f'{m.shape} and {n.shape}')
    operand, head = _operands(m.shape[1], unpack)
    lines = [f'    y{i} = {_row(row, operand)}' for i, row in enumerate(m)]
    y = '(' + ', '.join(f'y{i}' for i in range(m.shape[0])) + ',)'
    z = '(' + ', '.join(_row(row, 'y{}') for row in n) + ',)'
    namespace = {}
    exec(f'def {name}(x):\n{head}' + '\n'.join(lines) + f'\n    return {y}, {z}\n',
         namespace)
    return namespace[name]


def _coefficients(matrix, name: str, caller: str) -> np.ndarray:
    """`matrix` as a finite 1-d or 2-d float array (`name` checked as an identifier)."""
    if not name.isidentifier():
        raise ValueError(f'{caller}: name {name!r} is not an identifier')
    m = np.asarray(matrix, dtype=float)
    if m.ndim not in (1, 2):
        raise ValueError(f'{caller}: expected a 1-d or 2-d matrix, got shape {m.shape}')
    if not np.all(np.isfinite(m)):
        raise ValueError(f'{caller}: expected finite coefficients')
    return m


def _operands(n: int, unpack: bool) -> tuple[str, str]:
    """How the compiled code reads entry j of its argument ``x`` of `n` entries: the
    operand's format string and the function's first line (``x[j]``, none; or ``xj`` with
    ``x0, x1, ... = x``)."""
    if not unpack:
        return 'x[{}]', ''
    return 'x{}', '    ' + ''.join(f'x{j}, ' for j in range(n)) + '= x\n'


def _terms(row) -> list:
    """The terms of one output of a linear map, ``[(c_j or None for a unit coefficient, j)]``
    in order, exact zeros left out: what the compiled code (:func:`_row`) and
    :class:`LazyLinearMap` both sum, left to right."""
    return [(None if c == 1.0 else c, j) for j, c in enumerate(row.tolist()) if c != 0.0]


def _row(row, operand: str) -> str:
    """One output of a linear map as Python source: ``c_0*operand_0 + c_1*operand_1 + ...``
    (`operand` a format string of the index), summed left to right, exact zeros left out
    and unit coefficients not multiplied (:func:`_terms`)."""
    terms = [operand.format(j) if c is None else f'({c!r})*{operand.format(j)}'
             for c, j in _terms(row)]
    return ' + '.join(terms) if terms else '0.0'
