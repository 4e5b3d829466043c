"""Ground-motion records: PEER NGA ``.AT2`` and CSV readers, the embedded default, preparation.

A record is a :class:`GroundMotion`, a uniformly sampled ground acceleration in SI units.
:func:`load_record` turns the ``record`` parameter (``'default'``, an ``.AT2`` or a ``.csv``
path) into one; :func:`prepare` time-scales, resamples, truncates and scales it for a run at
the control period. The module imports no rclpy.
"""

from dataclasses import dataclass
from fractions import Fraction
import math
import os
from pathlib import Path
import re

import numpy as np
from scipy import signal
from scipy.integrate import cumulative_trapezoid

from seft_msgs_py.errors import InputError, ParameterError
from seft_msgs_py.parameters import identification_run

__all__ = [
    'G', 'GroundMotion', 'read_at2', 'read_csv', 'synthetic_default', 'load_record', 'prepare',
    'prepared_record', 'record_read', 'record_read_line', 'record_start_warning',
    'record_quiet_warning', 'record_warnings', 'QUIET_PART_FRACTION',
    'resampling_method', 'RESAMPLING_METHODS', 'MAX_RECORD_DT_S', 'START_STEP_FRACTION',
]

#: Standard gravity [m/s^2] (CGPM 1901), used to convert records in g.
G = 9.80665

#: A Fortran-style real: optional sign, digits with an optional point, optional exponent with
#: ``E`` or ``D`` (``-.1416764E-03``, ``1.234D-03``, ``7``). No ``nan``/``inf``.
_REAL = r'[+-]?(?:\d+\.?\d*|\.\d+)(?:[EeDd][+-]?\d+)?'
_REAL_RE = re.compile(_REAL)
#: Standard PEER line 4, tolerant of case, blanks around ``=`` and ``,``, a missing comma.
#: A word after DT is its unit (:data:`_SECONDS`, else the line is refused).
_NPTS_DT_RE = re.compile(
    r'^\s*NPTS\s*=\s*(?P<npts>[+-]?\d+)\s*,?\s*DT\s*=\s*(?P<dt>' + _REAL + r')'
    r'(?:\s*[A-Za-z]\w*)?(?:[\s,(/].*)?$', re.IGNORECASE)
#: The word after DT's number, if any.
_DT_WORD_RE = re.compile(r'\s*(?P<word>[A-Za-z]\w*)')
#: Older layout of line 4: ``7500   0.0200`` (NPTS then DT), possibly followed by text.
_OLD_NPTS_DT_RE = re.compile(
    r'^\s*(?P<npts>[+-]?\d+)\s*[,\s]\s*(?P<dt>' + _REAL + r')(?:[\s,].*)?$')
#: The units of DT that are seconds (upper case).
_SECONDS = ('S', 'SEC', 'SECS', 'SECOND', 'SECONDS')
#: Time units other than seconds, refused after DT in the older layout too (upper case).
_OTHER_TIME_UNITS = ('MS', 'MSEC', 'MSECS', 'MILLISEC', 'MILLISECOND', 'MILLISECONDS', 'US',
                     'USEC', 'MIN', 'MINS', 'MINUTE', 'MINUTES', 'HZ', 'SPS')
#: Largest DT a record file may have [s]: earthquake records are sampled every 0.001-0.04 s
#: (PEER NGA: 0.005-0.02 s); at DT = 0.1 s the Nyquist frequency, 5 Hz, is inside the band
#: of a structure's response, so a larger DT is a unit mistake (``DT= 10`` meant in ms).
MAX_RECORD_DT_S = 0.1
#: An explicit statement of the units on line 3: ``UNITS OF G``, ``UNITS: m/s2``.
_UNITS_RE = re.compile(r'\bUNITS?\s*(?:\bOF\b|[:=])\s*(?P<unit>[^\s,;]+?)[.]?(?=$|[\s,;])',
                       re.IGNORECASE)
_LENGTH = (r'(?:CM|MM|M|IN|INCH(?:ES)?|FT|FEET|MET(?:ER|RE)S?|CENTIMET(?:ER|RE)S?'
           r'|MILLIMET(?:ER|RE)S?)')
_TIME = r'(?:S|SECS?|SECONDS?)'
#: An acceleration unit other than g anywhere on line 3: ``CM/SEC/SEC``, ``cm/s^2``,
#: ``m/s2``, ``m s-2``, ``gal``, ``mg``.
_OTHER_UNIT_RE = re.compile(
    r'(?<![A-Z0-9])(?:' + _LENGTH + r'\s*/\s*' + _TIME
    + r'(?:\s*/\s*' + _TIME + r'|\s*(?:\^|\*\*)?\s*2|²)?'
    + r'|' + _LENGTH + r'\s*[-*.]?\s*' + _TIME + r'\s*(?:\^|\*\*)?\s*-\s*2'
    + r'|GALS?|MILLI-?G|MG)(?![A-Z0-9])', re.IGNORECASE)
_CSV_REAL_RE = re.compile(r'[+-]?(?:\d+\.?\d*|\.\d+)(?:[Ee][+-]?\d+)?')


#: How many samples after a cut record :class:`GroundMotion` keeps for the reference
#: force's ground preview (``following_m_s2``): more than any compensator looks ahead (its
#: loop delay, at most 50 steps of ``predictor_loop_delay_steps``, and the preview's step).
FOLLOWING_SAMPLES = 64


@dataclass(frozen=True, eq=False)
class GroundMotion:
    """A ground-acceleration record sampled uniformly.

    Sample ``k`` is at time ``k*dt``; the record covers ``n*dt`` seconds.

    Parameters
    ----------
    dt : float > 0
        Sample period [s].
    acceleration_m_s2 : ndarray, shape (n,), n >= 1
        Ground acceleration [m/s^2]; stored as a read-only float64 copy.
    name : str
        Record name, e.g. ``'RSN1106_KOBE_KJM000'`` or ``'synthetic-default(seed=1)'``.
    source : str
        Where it came from: the file path or ``'default'``.
    following_m_s2 : tuple of float, optional
        The samples that follow the record's last one in its source, prepared as it was (at
        most ``FOLLOWING_SAMPLES``) [m/s^2]: a run cut short of its record
        (``duration_s``, ``n_steps``) previews the ground motion that goes on there, as the
        reference force's ground preview does everywhere else; empty where the record ends
        (zeros after it).

    Raises
    ------
    ParameterError
        If ``dt`` is not a finite float > 0 or the acceleration is not a non-empty, finite,
        one-dimensional array.

    Notes
    -----
    ``eq=False``: two records compare by identity (an array field has no single truth value);
    compare ``acceleration_m_s2`` with ``numpy.array_equal``.
    """

    dt: float
    acceleration_m_s2: np.ndarray
    name: str
    source: str
    following_m_s2: tuple = ()

    def __post_init__(self):
        dt = _check_float('dt', self.dt, '> 0')
        a = np.array(self.acceleration_m_s2, dtype=float)
        if a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)):
            raise ParameterError(
                f'acceleration_m_s2 of {self.name!r}: expected a finite array of shape (n,), '
                f'n >= 1, got shape {a.shape}')
        a.setflags(write=False)
        following = tuple(float(v) for v in self.following_m_s2)[:FOLLOWING_SAMPLES]
        if not all(math.isfinite(v) for v in following):
            raise ParameterError(f'following_m_s2 of {self.name!r}: expected finite values')
        object.__setattr__(self, 'dt', dt)
        object.__setattr__(self, 'acceleration_m_s2', a)
        object.__setattr__(self, 'following_m_s2', following)

    def cut(self, n: int) -> 'GroundMotion':
        """The first `n` samples (1 <= n <= :attr:`n`), the rest previewed after them
        (``following_m_s2``)."""
        a = self.acceleration_m_s2
        return GroundMotion(self.dt, a[:n], self.name, self.source,
                            tuple(a[n:n + FOLLOWING_SAMPLES].tolist())
                            + self.following_m_s2)

    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.acceleration_m_s2.size)

    @property
    def time_s(self) -> np.ndarray:
        """Sample times ``k*dt`` [s], shape (n,)."""
        return np.arange(self.n) * self.dt

    @property
    def duration_s(self) -> float:
        """Length of the record ``n*dt`` [s]."""
        return self.n * self.dt

    @property
    def peak_m_s2(self) -> float:
        """Peak ground acceleration ``max |a|`` [m/s^2]."""
        return float(np.max(np.abs(self.acceleration_m_s2)))


# -- readers ---------------------------------------------------------------------------------

def _read_lines(path) -> list[str]:
    """The lines of a text file, any line ending; ``InputError`` if it cannot be read."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise InputError(f'{path}: no such file') from None
    except IsADirectoryError:
        raise InputError(f'{path}: is a directory, expected a file') from None
    except OSError as exc:
        raise InputError(f'{path}: cannot read ({exc.strerror})') from None
    if b'\x00' in data:
        lineno = data[:data.index(b'\x00')].count(b'\n') + 1
        raise InputError(f'{path}: line {lineno}: binary content (a NUL byte), expected a text '
                         'file')
    return data.decode('utf-8', errors='replace').splitlines()


def _excerpt(text: str, limit: int = 40) -> str:
    """``repr(text)``, cut to its first `limit` characters (``'...'`` after) so that a binary
    file's bytes do not fill an error message."""
    return repr(text) if len(text) <= limit else repr(text[:limit]) + '...'


def _units_of(line: str) -> str | None:
    """The unit other than g that a ``.AT2`` units line (line 3) names, or None.

    ``UNITS OF <u>`` or ``UNITS: <u>`` with ``<u>`` not ``G`` gives ``<u>``; otherwise an
    acceleration unit other than g anywhere on the line (:data:`_OTHER_UNIT_RE`: ``IN
    CM/SEC/SEC``, ``gal``) gives that. A line that names g, or no unit at all, gives None
    (values in g, PEER's format).
    """
    stated = _UNITS_RE.search(line)
    if stated and stated.group('unit').upper() != 'G':
        return stated.group('unit')
    other = _OTHER_UNIT_RE.search(line)
    return other.group(0) if other else None


def _check_record_dt(path, where: str, dt: float) -> None:
    """``InputError`` if a record file's sample period `dt` [s] exceeds
    :data:`MAX_RECORD_DT_S`."""
    if dt > MAX_RECORD_DT_S:
        raise InputError(f'{path}: {where}: expected a sample period DT <= {MAX_RECORD_DT_S} s '
                         f'(earthquake records: 0.001-0.04 s), got {dt!r} s (a time unit other '
                         'than seconds?)')


def _fortran_float(token: str) -> float:
    return float(token.replace('D', 'E').replace('d', 'e'))


def read_at2(path) -> GroundMotion:
    """Read a PEER NGA ``.AT2`` acceleration record (values in g) into SI units.

    Layout: four header lines (title; event, date, station, component; units; ``NPTS``/``DT``),
    then ``NPTS`` values in g, any number per line (PEER writes five). Accepted variants of
    line 4: ``NPTS=   7500, DT=   .0200 SEC,`` (standard), blanks around ``=`` and ``,``
    (``NPTS =   7500 , DT =   .020 SEC ,``), a missing trailing comma, lower case, and the
    older layout ``7500   0.0200`` (NPTS then DT) possibly followed by text. Values may use
    Fortran exponents ``E`` or ``D``; CRLF line endings are accepted.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.AT2`` file.

    Returns
    -------
    GroundMotion
        ``dt = DT`` [s], acceleration ``= value * G`` [m/s^2], ``name`` the file stem,
        ``source = str(path)``.

    Raises
    ------
    InputError
        One-line message starting with the path and naming the line: missing or unreadable
        file, fewer than four header lines, a units line that is not g, a malformed
        ``NPTS``/``DT`` line, ``NPTS <= 0`` or ``DT <= 0``, a non-numeric value, or a number of
        values other than ``NPTS`` (the parser is strict: a truncated record is an error).

    References
    ----------
    PEER NGA-West2 ground motion database, https://ngawest2.berkeley.edu/ (file format of the
    ``.AT2`` time series); T. D. Ancheta et al. (2014), NGA-West2 database, Earthquake
    Spectra 30(3), 989-1005.
    """
    lines = _read_lines(path)
    if not lines or not any(line.strip() for line in lines):
        raise InputError(f'{path}: line 1: empty file, expected a PEER .AT2 record')
    if len(lines) < 4:
        raise InputError(f'{path}: line {len(lines) + 1}: expected 4 header lines, '
                         f'the file ends after {len(lines)}')
    unit = _units_of(lines[2])
    if unit is not None:
        raise InputError(f'{path}: line 3: expected units of G, got {_excerpt(unit)} (seft '
                         'reads .AT2 values in g: convert them, or write a CSV in m/s^2)')
    header = lines[3]
    match = _NPTS_DT_RE.match(header) or _OLD_NPTS_DT_RE.match(header)
    if match is None:
        raise InputError(f"{path}: line 4: expected 'NPTS=<int>, DT=<float> SEC', "
                         f'got {_excerpt(header.strip())}')
    word = _DT_WORD_RE.match(header, match.end('dt'))
    dt_unit = word.group('word').upper() if word else None
    refused = _OTHER_TIME_UNITS if match.re is _OLD_NPTS_DT_RE else None
    if dt_unit is not None and dt_unit not in _SECONDS and (refused is None
                                                            or dt_unit in refused):
        raise InputError(f"{path}: line 4: expected 'NPTS=<int>, DT=<float> SEC', got DT in "
                         f"{_excerpt(word.group('word'))} (seft reads DT in seconds)")
    npts = int(match.group('npts'))
    dt = _fortran_float(match.group('dt'))
    if npts <= 0:
        raise InputError(f'{path}: line 4: expected NPTS > 0, got NPTS={npts}')
    if not (math.isfinite(dt) and dt > 0):
        raise InputError(f"{path}: line 4: expected DT > 0, got DT={match.group('dt')}")
    _check_record_dt(path, 'line 4', dt)

    values = []
    extra_line = None
    counts = []                        # (line, values on it) of the data lines
    for lineno, line in enumerate(lines[4:], start=5):
        tokens = line.split()
        if tokens:
            counts.append((lineno, len(tokens)))
        for token in tokens:
            if not _REAL_RE.fullmatch(token):
                raise InputError(f'{path}: line {lineno}: expected a number, '
                                 f'got {_excerpt(token)}')
            if len(values) == npts and extra_line is None:
                extra_line = lineno
            values.append(_fortran_float(token))
    odd = _odd_line(counts)
    if len(values) < npts:
        where = (f'line {odd[0]} holds {odd[1]} values where the others hold {odd[2]}'
                 if odd else None)
        raise InputError(f'{path}: line {len(lines)}: truncated: expected NPTS={npts} values, '
                         f'found {len(values)}' + (f' ({where})' if where else ''))
    if extra_line is not None:
        if odd is not None:
            raise InputError(f'{path}: line {odd[0]}: expected NPTS={npts} values, found '
                             f'{len(values)}: this line holds {odd[1]} values where the others '
                             f'hold {odd[2]}')
        raise InputError(f'{path}: line {extra_line}: expected NPTS={npts} values, found '
                         f'{len(values)} (the extra values start on this line)')
    accel = np.asarray(values) * G
    if not np.all(np.isfinite(accel)):
        raise InputError(f'{path}: a value overflows float64')
    return GroundMotion(dt, accel, Path(path).stem, str(path))


def _odd_line(counts: list) -> tuple | None:
    """``(line, its count, the usual count)`` of the first data line of a PEER file (a fixed
    number of values a line, the last line fewer) whose count is not the others', or None
    when they agree: where a value was added or lost (a stray value on line 8 was named at
    the file's end, line 1504)."""
    body = [n for _, n in counts[:-1]]
    if len(body) < 2:
        return None
    usual = max(set(body), key=body.count)
    for lineno, n in counts[:-1]:
        if n != usual:
            return lineno, n, usual
    last_line, last = counts[-1]
    return (last_line, last, usual) if last > usual else None


def read_csv(path) -> GroundMotion:
    """Read a two-column CSV record: time [s], ground acceleration [m/s^2].

    Columns are separated by a comma or by blanks; ``#`` starts a comment; blank lines are
    skipped; the first data line may be a header (no numeric field). Time must increase
    strictly with a uniform step: every step must equal the median step, and the mean step
    ``(t[-1] - t[0]) / (n - 1)``, within ``1e-6`` of it. The time origin is dropped (sample
    ``k`` of the result is at ``k*dt``).

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file.

    Returns
    -------
    GroundMotion
        ``dt`` the mean time step [s], the acceleration column [m/s^2], ``name`` the file
        stem, ``source = str(path)``.

    Raises
    ------
    InputError
        One-line message starting with the path and naming the line: missing or unreadable
        file, a row without exactly two numeric fields, fewer than two rows, time not strictly
        increasing, or a non-uniform time step.
    """
    lines = _read_lines(path)
    times, accels, linenos = [], [], []
    header_allowed = True
    for lineno, raw in enumerate(lines, start=1):
        line = raw.split('#', 1)[0].strip()
        if not line:
            continue
        fields = [f.strip() for f in line.split(',')] if ',' in line else line.split()
        numeric = [bool(_CSV_REAL_RE.fullmatch(f)) for f in fields]
        # a header has no field that starts with a number ('0.0;0.1' is a row, not a header)
        if header_allowed and not any(_CSV_REAL_RE.match(f) for f in fields):
            header_allowed = False
            continue
        header_allowed = False
        if len(fields) != 2:
            # a decimal comma ('0,01;0,028' or '0,01<tab>0,028') splits each number in two
            # (a new user's European CSV was told only the column count, session 36)
            decimal_comma = bool(re.search(r'\d,\d', line)) and (';' in line or '\t' in line
                                                                or ' ' in line)
            hint = (' (columns are separated by a comma or blanks; numbers take a decimal '
                    "point: a decimal comma, as in '0,01', splits each into two)"
                    if decimal_comma else
                    ' (columns are separated by a comma or blanks)' if ';' in line else '')
            raise InputError(f'{path}: line {lineno}: expected 2 columns (time [s], '
                             f'acceleration [m/s^2]), found {len(fields)}{hint}')
        if not all(numeric):
            bad = fields[numeric.index(False)]
            raise InputError(f'{path}: line {lineno}: expected a number, got {bad!r}')
        times.append(float(fields[0]))
        accels.append(float(fields[1]))
        linenos.append(lineno)
    if len(times) < 2:
        raise InputError(f'{path}: line {len(lines) + 1}: expected at least 2 rows of '
                         f'time, acceleration, found {len(times)}')
    t = np.asarray(times)
    a = np.asarray(accels)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(a))):
        bad = int(np.flatnonzero(~(np.isfinite(t) & np.isfinite(a)))[0])
        raise InputError(f'{path}: line {linenos[bad]}: value overflows float64')
    steps = np.diff(t)
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise InputError(f'{path}: line {linenos[k]}: time not strictly increasing '
                         f'(t={float(t[k])!r} after t={float(t[k - 1])!r})')
    dt = float((t[-1] - t[0]) / (len(t) - 1))
    _check_record_dt(path, f'line {linenos[1]}', dt)
    # each step against the file's median step (one dropped row moves the mean, not the
    # median: the line named is the gap's, not the first line's)
    usual = float(np.median(steps))
    off = np.abs(steps - usual) > 1e-6 * usual
    if not np.any(off):
        off = np.abs(steps - dt) > 1e-6 * dt
    if np.any(off):
        k = int(np.flatnonzero(off)[0]) + 1
        raise InputError(f'{path}: line {linenos[k]}: non-uniform time step: '
                         f'{float(steps[k - 1]):.9g} s where the file steps by {usual:.9g} s '
                         '(relative tolerance 1e-6)')
    return GroundMotion(dt, a, Path(path).stem, str(path))


# -- the embedded default record -------------------------------------------------------------

#: Kanai-Tajimi ground filter: predominant frequency [rad/s] and damping ratio.
_KT_OMEGA_G = 2.0 * np.pi * 2.5
_KT_ZETA_G = 0.6
#: Clough-Penzien high-pass: corner frequency [rad/s] (0.5 Hz, a fifth of omega_g) and damping.
_CP_OMEGA_F = 0.2 * _KT_OMEGA_G
_CP_ZETA_F = 0.6
#: Jennings envelope: end of the quadratic rise and of the plateau as fractions of the
#: duration, and the decay exponent reached at the end (envelope exp(-4) = 1.8 % there).
_ENV_RISE, _ENV_PLATEAU, _ENV_DECAY = 0.1, 0.5, 4.0
#: Acausal band-pass (order, corners [Hz]) applied to the enveloped noise.
_BP_ORDER, _BP_LOW_HZ, _BP_HIGH_HZ = 4, 0.1, 20.0
#: Peak of the default record [g].
_PEAK_G = 0.5


def _jennings_envelope(t: np.ndarray, duration_s: float) -> np.ndarray:
    t1, t2 = _ENV_RISE * duration_s, _ENV_PLATEAU * duration_s
    c = _ENV_DECAY / (duration_s - t2)
    return np.where(t < t1, (t / t1) ** 2, np.where(t <= t2, 1.0, np.exp(-c * (t - t2))))


def _end_velocity_displacement(a: np.ndarray, dt: float) -> tuple[float, float]:
    """Velocity and displacement at the end of ``a`` (trapezoid rule, at rest at t=0)."""
    v = cumulative_trapezoid(a, dx=dt, initial=0.0)
    d = cumulative_trapezoid(v, dx=dt, initial=0.0)
    return float(v[-1]), float(d[-1])


def synthetic_default(*, duration_s: float = 20.0, dt: float = 0.01,
                      seed: int = 1) -> GroundMotion:
    """The embedded default input: an enveloped Kanai-Tajimi/Clough-Penzien accelerogram.

    A stationary Gaussian white noise ``w[k]`` (``numpy.random.Generator(PCG64(seed))``,
    standard normal, so the record is the same on every machine) is filtered by the
    Clough-Penzien ground filter, multiplied by a Jennings envelope, band-passed, baseline
    corrected and normalized to a peak of 0.5 g.

    Parameters
    ----------
    duration_s : float >= 100*dt
        Length of the record [s]; ``n = round(duration_s/dt)`` samples.
    dt : float, 0 < dt <= 0.02
        Sample period [s] (the 20 Hz band edge must lie below the Nyquist frequency).
    seed : int >= 0
        Seed of the PCG64 generator.

    Returns
    -------
    GroundMotion
        ``name = 'synthetic-default(seed=<seed>)'`` (with the duration and dt when they are
        not the defaults), ``source = 'default'``, peak ``0.5*G`` [m/s^2].

    Raises
    ------
    ParameterError
        If a parameter is outside its range.

    Notes
    -----
    1. Kanai-Tajimi ground filter (Kanai 1957, Tajimi 1960) in series with the
       Clough-Penzien high-pass (Clough & Penzien 1975),

       ::

           H(s) = (2 zeta_g omega_g s + omega_g^2) / (s^2 + 2 zeta_g omega_g s + omega_g^2)
                  * s^2 / (s^2 + 2 zeta_f omega_f s + omega_f^2)

       with ``omega_g = 2*pi*2.5 rad/s`` (15.7 rad/s) and ``zeta_g = 0.6``, Tajimi's values for
       firm ground (15.6 rad/s, 0.6), and ``omega_f = 0.2*omega_g`` (0.5 Hz, the lower edge of
       the band of interest), ``zeta_f = zeta_g`` (Der Kiureghian & Neuenhofer 1992 use
       ``omega_f = 0.1*omega_g``, ``zeta_f = 0.6``; the higher corner here keeps at least
       93 % of the power in 0.5-15 Hz over seeds 1-20, against 88 %). The Clough-Penzien
       factor removes the infinite low-frequency displacement variance of the Kanai-Tajimi
       model. ``H`` is discretized with the bilinear transform at ``dt``
       (``scipy.signal.cont2discrete``; 3 % frequency warping at 10 Hz for dt = 0.01 s) and
       applied with ``scipy.signal.lfilter``.
    2. Envelope (Jennings, Housner & Tsai 1968):
       ``e(t) = (t/t1)^2`` for ``t < t1``, ``1`` for ``t1 <= t <= t2``,
       ``exp(-c (t - t2))`` after, with ``t1 = 0.1 D``, ``t2 = 0.5 D`` and ``c = 4/(D - t2)``
       for the duration ``D`` (default: 2 s rise, 8 s strong motion, decay to
       ``exp(-4) = 1.8 %`` at 20 s; ``c = 0.4 1/s``).
    3. Band-pass: fourth-order Butterworth 0.1-20 Hz applied forward and backward
       (``scipy.signal.sosfiltfilt``, zero phase) on the record padded with ``n`` zeros on
       each side, as in PEER's acausal record processing (Boore & Bommer 2005). It removes
       the long-period drift and the Kanai-Tajimi ``1/omega^2`` power tail above 20 Hz.
    4. Baseline correction: subtract ``e(t) (c0 + c1 t)`` with ``c0, c1`` solved so that the
       trapezoid-rule velocity and displacement at the end are zero (the correction is
       shaped by the envelope so the record still starts at rest).
    5. Scale to ``max|a| = 0.5 g``; :func:`prepare` rescales it for a run.

    Measured for the defaults (seed 1; ``scipy.signal.welch``, 512-sample segments): 2000
    samples, 97 % of the power between 0.5 and 15 Hz and 60 % between 2 and 10 Hz, spectral
    peak near 2.7 Hz; peak ground velocity 0.52 m/s, peak displacement 0.14 m, strongest
    sample at 7.04 s. At time scale 0.5 every frequency doubles (band 1-30 Hz).

    References
    ----------
    K. Kanai (1957), Semi-empirical formula for the seismic characteristics of the ground,
    Bull. Earthquake Res. Inst. Univ. Tokyo 35, 309-325.
    H. Tajimi (1960), A statistical method of determining the maximum response of a building
    structure during an earthquake, Proc. 2nd WCEE, Tokyo, vol. 2, 781-797.
    R. W. Clough and J. Penzien (1975), Dynamics of Structures, McGraw-Hill.
    P. C. Jennings, G. W. Housner and N. C. Tsai (1968), Simulated earthquake motions,
    EERL report, California Institute of Technology.
    A. Der Kiureghian and A. Neuenhofer (1992), Response spectrum method for multi-support
    seismic excitations, Earthquake Eng. Struct. Dyn. 21(8), 713-740.
    D. M. Boore and J. J. Bommer (2005), Processing of strong-motion accelerograms: needs,
    options and consequences, Soil Dyn. Earthquake Eng. 25(2), 93-115.
    """
    dt = _check_float('dt', dt, '> 0')
    if dt > 0.02:
        raise ParameterError(f'parameter dt={dt!r}: expected float, 0 < dt <= 0.02')
    duration_s = _check_float('duration_s', duration_s, '> 0')
    if duration_s < 100 * dt:
        raise ParameterError(f'parameter duration_s={duration_s!r}: expected float '
                             f'>= 100*dt = {100 * dt!r}')
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ParameterError(f'parameter seed={seed!r}: expected int >= 0')

    n = int(round(duration_s / dt))
    t = np.arange(n) * dt
    rng = np.random.Generator(np.random.PCG64(int(seed)))
    noise = rng.standard_normal(n)

    wg, zg, wf, zf = _KT_OMEGA_G, _KT_ZETA_G, _CP_OMEGA_F, _CP_ZETA_F
    num = np.polymul([2.0 * zg * wg, wg ** 2], [1.0, 0.0, 0.0])
    den = np.polymul([1.0, 2.0 * zg * wg, wg ** 2], [1.0, 2.0 * zf * wf, wf ** 2])
    bz, az, _ = signal.cont2discrete((num, den), dt, method='bilinear')
    a = signal.lfilter(np.ravel(bz), np.ravel(az), noise)

    envelope = _jennings_envelope(t, n * dt)
    a = a * envelope

    sos = signal.butter(_BP_ORDER, [_BP_LOW_HZ, _BP_HIGH_HZ], btype='bandpass', fs=1.0 / dt,
                        output='sos')
    padded = np.concatenate([np.zeros(n), a, np.zeros(n)])
    a = signal.sosfiltfilt(sos, padded, padtype=None)[n:2 * n]

    basis = (envelope, envelope * t)
    ends = np.array([_end_velocity_displacement(b, dt) for b in basis]).T  # rows: v, d
    coef = np.linalg.solve(ends, _end_velocity_displacement(a, dt))
    a = a - coef[0] * basis[0] - coef[1] * basis[1]

    a = a * (_PEAK_G * G / np.max(np.abs(a)))
    if duration_s == 20.0 and dt == 0.01:
        name = f'synthetic-default(seed={seed})'
    else:
        name = f'synthetic-default(seed={seed}, duration_s={n * dt:g}, dt={dt:g})'
    return GroundMotion(dt, a, name, 'default')


def load_record(source) -> GroundMotion:
    """Load the record named by the ``record`` parameter.

    Parameters
    ----------
    source : str or os.PathLike
        ``'default'`` for :func:`synthetic_default` with its defaults, else a path ending in
        ``.at2`` (any case; :func:`read_at2`) or ``.csv`` (any case; :func:`read_csv`).

    Returns
    -------
    GroundMotion

    Raises
    ------
    InputError
        If the suffix is neither, or the file is missing or malformed.
    """
    if isinstance(source, str) and source == 'default':
        return synthetic_default()
    suffix = Path(os.fspath(source)).suffix.lower() if str(source) else ''
    if suffix == '.at2':
        return read_at2(source)
    if suffix == '.csv':
        return read_csv(source)
    raise InputError(f"{source}: unknown record format {suffix!r}: expected 'default', "
                     'a PEER .AT2 file or a .csv file')


# -- preparation for a run -------------------------------------------------------------------

def _check_float(name: str, value, rng: str) -> float:
    """``float(value)`` if finite and ``> 0`` / ``>= 0`` (``rng``), else ``ParameterError``."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        x = math.nan
    ok = math.isfinite(x) and (x > 0 if rng == '> 0' else x >= 0)
    if isinstance(value, bool) or not ok:
        raise ParameterError(f'parameter {name}={value!r}: expected float {rng}')
    return x


#: The resampling methods of :func:`prepare` (parameter ``record_resampling``, with 'auto').
RESAMPLING_METHODS = ('linear', 'band_limited')


def _resample_band_limited(a: np.ndarray, ratio: float, n: int) -> np.ndarray:
    """``a`` resampled by ``ratio`` (old period / new period) with ``scipy.signal.resample_poly``,
    held at its last value (or cut) to ``n`` samples (:func:`prepare`, step 2)."""
    fraction = Fraction(ratio).limit_denominator(1000)
    out = signal.resample_poly(a, fraction.numerator, fraction.denominator)
    if out.shape[0] < n:
        out = np.concatenate([out, np.full(n - out.shape[0], out[-1])])
    return out[:n]


def prepare(record: GroundMotion, *, dt: float, mass_kg: float, amplitude_N: float = 0.0,
            scale_factor: float = 1.0, time_scale: float = 1.0,
            duration_s: float = 0.0, resampling: str = 'linear') -> GroundMotion:
    """Make a record ready for a run: time scale, resample to ``dt``, truncate, scale.

    1. Time scaling: the record's sample period becomes ``record.dt * time_scale`` (0.5 halves
       it and doubles every frequency, as the reference study's time scale factor 0.5).
    2. Resampling to the control period ``dt``, by one of two methods (``resampling``):

       - ``'linear'``: linear interpolation (``numpy.interp``) at ``k*dt``,
         ``k = 0 .. round(n*record.dt*time_scale/dt) - 1``; past the last sample the last
         value is held (at most one record step). Each new sample is a convex combination of
         two neighbours, so it never exceeds the record's peak, and its error on a sine of
         angular frequency ``omega`` is at most ``(omega*h)^2/8`` of the amplitude, ``h`` the
         scaled record step (4.9e-4 for 1 Hz and 1.2 % for 5 Hz at h = 0.01 s). But it
         leaves *images*: content at ``f`` reappears at ``j/h -+ f`` with the kernel's gain
         there, ``sinc^2(f_image h)`` (about 14 % of a 30 Hz component at 70 Hz,
         h = 0.01 s). A one-DOF structure's relative acceleration follows ``-xg''`` above its
         natural frequency, so the reference holds these images and no force loop tracks
         them: on Kobe KJMA 000 (h = 0.01 s) with a 50 Hz specimen at dt = 1 ms they were
         10 of the acceleration's 12 % NRMS error. Downsampling picks interpolated samples
         without an anti-alias filter.
       - ``'band_limited'``: polyphase resampling by the ratio ``h/dt`` as a fraction
         (``scipy.signal.resample_poly``, its Kaiser-windowed FIR; Crochiere and Rabiner,
         *Multirate Digital Signal Processing*, 1983, Ch. 2): nothing of the record above
         its Nyquist frequency ``1/(2h)`` (or the run's, downsampling) is kept or made, the
         passband is flat. The filter (20 record steps long) takes the ground at rest before
         and after the record, so a record that does not start or end at rest gets a
         transient of 10 record steps at that end. The ratio
         is a fraction of denominator 1000 or less: exact for the usual record and control
         periods (records at 0.005-0.02 s, time scales 0.25-1, dt 0.5-2 ms); otherwise the
         nearest such fraction, which stretches the record's time axis by at most 5e-4
         when upsampling. A rectangular pulse overshoots by its Gibbs ripple (14 % at
         2-20x upsampling), so with ``scale_factor`` the peak can exceed the record's;
         ``amplitude_N`` scales the prepared peak.

       Both give the same input to the test and to the reference analysis.
    3. Truncation to ``round(duration_s/dt)`` samples if ``duration_s > 0`` and the record
       is longer (a longer ``duration_s`` keeps the whole record).
    4. Amplitude: if ``amplitude_N > 0``, scale so that ``max|mass_kg * a| == amplitude_N``
       (to rounding); else multiply by ``scale_factor``.

    Parameters
    ----------
    record : GroundMotion
        The record as read.
    dt : float > 0
        Control period [s] (e.g. 0.002).
    mass_kg : float > 0
        Mass ``m`` whose inertial force ``m*a`` the amplitude refers to [kg].
    amplitude_N : float >= 0
        Target peak of ``m*a`` [N] (reference study: 1000 N); 0 uses ``scale_factor``.
    scale_factor : float > 0
        Plain amplitude factor, used when ``amplitude_N == 0``.
    time_scale : float > 0
        Factor on the record's time step.
    duration_s : float >= 0
        Length of the run after time scaling [s]; 0 keeps the whole record.
    resampling : {'linear', 'band_limited'}
        How the record is resampled to ``dt`` (step 2).

    Returns
    -------
    GroundMotion
        New record with ``dt`` the control period, same ``name`` and ``source``.

    Raises
    ------
    ParameterError
        If a parameter is outside its range, or ``0 < duration_s < dt/2`` (no sample left).
    InputError
        If the (truncated) record is all zeros (with ``amplitude_N`` or ``scale_factor``:
        a run without ground motion measures nothing).

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing (time scale factor 0.5,
    amplitude 1000 N).
    """
    return _prepare(record, dt=dt, mass_kg=mass_kg, amplitude_N=amplitude_N,
                    scale_factor=scale_factor, time_scale=time_scale, duration_s=duration_s,
                    resampling=resampling)[0]


def _prepare(record: GroundMotion, *, dt, mass_kg, amplitude_N, scale_factor, time_scale,
             duration_s, resampling) -> tuple[GroundMotion, float]:
    """:func:`prepare`'s record and the factor it multiplied the record by (step 4)."""
    if resampling not in RESAMPLING_METHODS:
        raise ParameterError(f'parameter record_resampling={resampling!r}: expected one of '
                             + ', '.join(repr(m) for m in RESAMPLING_METHODS))
    dt = _check_float('dt', dt, '> 0')
    mass_kg = _check_float('mass_kg', mass_kg, '> 0')
    amplitude_N = _check_float('amplitude_N', amplitude_N, '>= 0')
    scale_factor = _check_float('scale_factor', scale_factor, '> 0')
    time_scale = _check_float('time_scale', time_scale, '> 0')
    duration_s = _check_float('duration_s', duration_s, '>= 0')

    step = record.dt * time_scale
    a = np.asarray(record.acceleration_m_s2, dtype=float)
    n = max(1, int(round(record.n * step / dt)))
    if abs(step - dt) > 1e-9 * dt:
        if resampling == 'band_limited':
            a = _resample_band_limited(a, step / dt, n)
        else:
            a = np.interp(np.arange(n) * dt, np.arange(record.n) * step, a)
    if duration_s > 0:
        keep = int(round(duration_s / dt))
        if keep < 1:
            raise ParameterError(f'parameter duration_s={duration_s!r}: expected 0 (whole '
                                 f'record) or float >= dt={dt!r}')
        following = a[keep:keep + FOLLOWING_SAMPLES]
        a = a[:keep]
    else:
        following = a[:0]
    if not np.any(a):
        within = f' in its first {duration_s:g} s' if duration_s > 0 else ''
        need = (f'cannot scale it to amplitude_N={amplitude_N!r}' if amplitude_N > 0 else
                'expected a record with a non-zero sample')
        raise InputError(f'{record.source}: record {record.name!r} is all zeros{within}; '
                         f'{need}')
    if amplitude_N > 0:
        peak_N = float(np.max(np.abs(mass_kg * a)))
        factor = amplitude_N / peak_N
        a = a * factor
        following = following * factor
    else:
        factor = scale_factor
        a = a * scale_factor
        following = following * scale_factor
    return GroundMotion(dt, a, record.name, record.source, tuple(following.tolist())), factor


def resampling_method(params, record: GroundMotion) -> str:
    """The resampling of :func:`prepare` for a run: parameter ``record_resampling``, with
    ``'auto'`` resolved to ``'linear'`` for the embedded default (``record.source ==
    'default'``) and ``'band_limited'`` for a record read from a file.

    Raises
    ------
    ParameterError
        ``record_resampling`` is none of 'auto', 'linear', 'band_limited'.
    """
    method = params.get('record_resampling', 'auto')
    if method == 'auto':
        return 'linear' if record.source == 'default' else 'band_limited'
    if method not in RESAMPLING_METHODS:
        raise ParameterError(f'parameter record_resampling={method!r}: expected one of '
                             "'auto', " + ', '.join(repr(m) for m in RESAMPLING_METHODS))
    return method


def prepared_record(params) -> GroundMotion:
    """Load and prepare the run's ground motion (scaling, time scale, resampling, duration).

    With an excitation (parameter ``excitation`` other than 'none'), the record is not
    played: the ground motion is :func:`seft_ros.core.excitation.excitation_record`.
    ``record_resampling: auto`` (the default) resamples the embedded default linearly (the
    reference study's test, bit for bit as it always ran: its images lie above 160 Hz at
    5.5 % or less of a 40 Hz component, h = 5 ms) and a record read from a file
    band-limited (:func:`prepare`, step 2).

    Raises
    ------
    InputError, ParameterError
        Bad record file or parameter.
    """
    if identification_run(params):
        from seft_ros.core.excitation import excitation_record
        gm = excitation_record(params)
        n = int(params.get('n_steps', 0) or 0)
        return GroundMotion(gm.dt, gm.acceleration_m_s2[:n], gm.name, gm.source) if n else gm
    return _load_and_prepare(params)[1]


def _load_and_prepare(params) -> tuple[GroundMotion, GroundMotion, float]:
    """The record as read, as prepared (cut to ``n_steps``) and the factor of
    :func:`prepare` (step 4), for :func:`prepared_record` and :func:`record_read`."""
    record = load_record(params['record'])
    gm, factor = _prepare(record, dt=float(params['dt']), mass_kg=float(params['mass_kg']),
                          amplitude_N=float(params['amplitude_N']),
                          scale_factor=float(params['scale_factor']),
                          time_scale=float(params['time_scale']),
                          duration_s=float(params['duration_s']),
                          resampling=resampling_method(params, record))
    n = int(params.get('n_steps', 0) or 0)
    if n:
        if n > gm.acceleration_m_s2.shape[0]:
            raise ParameterError(
                f'parameter n_steps={n}: expected <= {gm.acceleration_m_s2.shape[0]} '
                '(the prepared record length)')
        gm = gm.cut(n)
    return record, gm, factor


def record_read(params) -> dict | None:
    """What a run reads from its record file and how it prepares it, for the console and
    ``summary.json`` (None for the embedded default or an excitation run).

    Returns
    -------
    dict or None
        ``{'file', 'npts', 'dt_s', 'duration_s', 'pga_g', 'pga_at_s'}``: the file as read
        (peak ground acceleration ``max|a|/G`` and the time of its first occurrence), and the
        run's input: ``{'time_scale', 'scale', 'scaled_by', 'run_samples', 'run_dt_s',
        'run_duration_s', 'run_peak_g'}``, ``scale`` the factor the resampled record was
        multiplied by, ``scaled_by`` ``'amplitude_N'`` (to the peak ``amplitude_N`` [N] of
        ``mass_kg * a``, with the keys ``'amplitude_N'`` and ``'mass_kg'``: the top-level
        ``mass_kg``, the study's specimen mass unless set, also for a structure) or
        ``'scale_factor'``.

    Raises
    ------
    InputError, ParameterError
        As :func:`prepared_record`.
    """
    if identification_run(params) or params.get('record') == 'default':
        return None
    record, gm, factor = _load_and_prepare(params)
    a = record.acceleration_m_s2
    k = int(np.argmax(np.abs(a)))
    info = {'file': str(record.source), 'npts': record.n, 'dt_s': record.dt,
            'duration_s': record.duration_s, 'pga_g': float(abs(a[k]) / G),
            'pga_at_s': k * record.dt, 'time_scale': float(params['time_scale']),
            'scale': factor}
    amplitude = float(params['amplitude_N'])
    if amplitude > 0:
        info.update(scaled_by='amplitude_N', amplitude_N=amplitude,
                    mass_kg=float(params['mass_kg']))
    else:
        info['scaled_by'] = 'scale_factor'
    info.update(run_samples=gm.n, run_dt_s=gm.dt, run_duration_s=gm.duration_s,
                run_peak_g=gm.peak_m_s2 / G,
                run_start_g=float(gm.acceleration_m_s2[0]) / G if gm.n else 0.0)
    asked = float(params.get('duration_s', 0.0) or 0.0)
    if asked > gm.duration_s + gm.dt / 2:
        info['asked_duration_s'] = asked          # longer than the record: its whole is run
    return info


#: A record whose first sample is more than this part of its peak starts with a step [-]:
#: the test starts at rest, so the step is a jolt the loop and the compensators answer
#: (measured, a new user's window of El Centro 180 starting at 19 % of its peak: `model`
#: 6.5 % NRMS x, the same window tapered 0.27 %). The PEER records read here start within
#: 0.4 % of their peak (El Centro 180 0.36 %, Kobe KJMA 0.02 %; the embedded one 0.08 %).
START_STEP_FRACTION = 0.01


#: A run whose part of its record peaks below this part of the record's PGA, scaled by
#: ``amplitude_N`` to its own peak, is warned [-]: its samples are the record's quiet part
#: scaled up (a new user's first 2 s of Kobe KJMA 000, its lead-in before the event, came to
#: 2 g scaled x2101, the recorder's noise and all).
QUIET_PART_FRACTION = 0.1


def record_quiet_warning(info: dict) -> str:
    """The warning of a run that scales a quiet part of its record (a cut of its lead-in)
    to ``amplitude_N`` (:data:`QUIET_PART_FRACTION`), or '' (`info`: :func:`record_read`'s)."""
    if info.get('scaled_by') != 'amplitude_N' or not info.get('scale'):
        return ''
    played_g = info['run_peak_g'] / info['scale']        # the played part, as recorded
    if not info['pga_g'] > 0 or played_g >= QUIET_PART_FRACTION * info['pga_g']:
        return ''
    return (f"record {info['file']}: the run's part peaks at {played_g:.3g} g, "
            f"{100 * played_g / info['pga_g']:.2g} % of the record's PGA "
            f"({info['pga_g']:.4g} g at {info['pga_at_s']:g} s), and amplitude_N scales it "
            f"x{info['scale']:.4g}: a quiet part of the record (its lead-in?) scaled up, "
            "noise and all; play the record's strong motion, or scale by scale_factor")


def record_warnings(info: dict) -> list[str]:
    """The warnings of what a run read from its record file (:func:`record_start_warning`,
    :func:`record_quiet_warning`), for the console before the run and for its summary and
    report after it (a new user's record that starts mid-motion was warned before the run
    only; session 36)."""
    return [w for w in (record_start_warning(info), record_quiet_warning(info)) if w]


def record_start_warning(info: dict) -> str:
    """The warning of a record that starts with a step (:data:`START_STEP_FRACTION`), or
    '' (`info`: :func:`record_read`'s)."""
    start, peak = abs(info.get('run_start_g', 0.0)), info.get('run_peak_g', 0.0)
    if not peak > 0 or start <= START_STEP_FRACTION * peak:
        return ''
    return (f"record {info['file']} starts at {info['run_start_g']:.3g} g, "
            f'{100 * start / peak:.0f} % of its peak: the test starts at rest, so its first '
            'sample is a step the loop answers with a jolt (its error shows in every signal); '
            'cut the record where the ground is at rest, or taper its start')


def record_read_line(info: dict) -> str:
    """One line of :func:`record_read`'s figures: ``record X.AT2: 5372 samples at 0.01 s
    (53.72 s), PGA 0.2808 g at 2.18 s; run: time scale 0.5, 26.86 s at dt 0.002 s, scaled
    x3.63 to amplitude_N=1000 N over mass_kg=52.7 kg, peak 1.019 g``."""
    how = (f"to amplitude_N={info['amplitude_N']:g} N over mass_kg={info['mass_kg']:g} kg"
           if info['scaled_by'] == 'amplitude_N' else '(scale_factor)')
    whole = (f" (the whole record: duration_s {info['asked_duration_s']:g} s asked)"
             if 'asked_duration_s' in info else '')
    return (f"record {info['file']}: {info['npts']} samples at {info['dt_s']:g} s "
            f"({info['duration_s']:g} s), PGA {info['pga_g']:.4g} g at {info['pga_at_s']:g} s; "
            f"run: time scale {info['time_scale']:g}, {info['run_duration_s']:g} s{whole} at "
            f"dt {info['run_dt_s']:g} s, scaled x{info['scale']:.4g} {how}, "
            f"peak {info['run_peak_g']:.4g} g")
