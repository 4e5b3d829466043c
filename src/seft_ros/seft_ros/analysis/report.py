"""Comparison report of substructure EFT runs against the reference: JSON, Markdown, figures.

Imports no rclpy and no pyplot: figures are drawn on ``matplotlib.figure.Figure`` objects with
the Agg canvas, so the report works without a display and leaves the global backend alone.
"""

from dataclasses import dataclass
import json
import math
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.metrics import (
    HIGH_FREQUENCY_CUTOFF_HZ,
    RunComparison,
    compare_run,
    json_safe,
    summary_entry,
)
from seft_ros.analysis.reference import reference_from_run
from seft_ros.analysis.rundata import SIGNALS, RunData

__all__ = ['ReportPaths', 'write_report', 'write_summary_json', 'plot_time_histories']

#: Figure files written by :func:`write_report`.
TIME_HISTORIES_PNG = 'time_histories.png'
ZOOM_PNG = 'time_histories_zoom.png'
#: Width of the zoom window around the reference's displacement peak [s].
ZOOM_WINDOW_S = 2.0
#: Most points drawn per line (min/max decimation beyond; plotting only, never metrics).
MAX_PLOT_POINTS = 4000

_DPI = 120
_COLUMN_WIDTH_IN = 4.0
_ROW_HEIGHT_IN = 2.3

# signal -> (row label, table label, factor from SI to the displayed unit)
_DISPLAY = {
    'displacement': ('displacement [mm]', 'displacement [mm]', 1e3),
    'force': ('force [N]', 'force [N]', 1.0),
    'acceleration': ('acceleration [m/s$^2$]', 'acceleration [m/s^2]', 1.0),
}


@dataclass(frozen=True)
class ReportPaths:
    """Files written by :func:`write_report`.

    Attributes
    ----------
    out_dir : Path
        Output directory.
    summary_json : Path
        ``summary.json``: ``{"runs": [entry, ...]}`` (see ``metrics.summary_entry``).
    report_md : Path
        ``report.md``: one table per run and links to the figures.
    time_histories_png, zoom_png : Path
        Whole-record figure (as the reference study's Figure 6) and the zoom around the
        reference's displacement peak.
    """

    out_dir: Path
    summary_json: Path
    report_md: Path
    time_histories_png: Path
    zoom_png: Path

    @property
    def figures(self) -> tuple[Path, Path]:
        """The PNG figures."""
        return (self.time_histories_png, self.zoom_png)


def write_summary_json(entries: list[dict[str, Any]], path) -> Path:
    """Write ``{"runs": [entry, ...]}`` as strict JSON and return the path.

    Parameters
    ----------
    entries : list of dict
        One summary entry per run (``metrics.summary_entry``), in report order.
    path : str or Path
        Output file; its directory is created if needed.

    Returns
    -------
    Path

    Notes
    -----
    NaN and inf are written as null (``metrics.json_safe``) and the file is produced with
    ``json.dumps(..., allow_nan=False)``, so it is valid JSON for any strict parser.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({'runs': json_safe(list(entries))}, indent=2, allow_nan=False)
    path.write_text(text + '\n', encoding='utf-8')
    return path


def _decimate(t: np.ndarray, y: np.ndarray, max_points: int = MAX_PLOT_POINTS):
    """Min/max decimation for plotting: keeps every bin's extremes so peaks stay visible."""
    n = t.shape[0]
    if n <= max_points:
        return t, y
    bins = max_points // 2
    size = int(math.ceil(n / bins))
    pad = bins * size - n
    tb = np.concatenate([t, np.full(pad, t[-1])]).reshape(bins, size)
    yb = np.concatenate([y, np.full(pad, np.nan)]).reshape(bins, size)
    finite = np.isfinite(yb)
    has = finite.any(axis=1)
    lo = np.argmin(np.where(finite, yb, np.inf), axis=1)
    hi = np.argmax(np.where(finite, yb, -np.inf), axis=1)
    first = np.minimum(lo, hi)
    second = np.maximum(lo, hi)
    rows = np.arange(bins)
    td = np.stack([tb[rows, first], tb[rows, second]], axis=1).ravel()
    yd = np.stack([yb[rows, first], yb[rows, second]], axis=1)
    yd[~has] = np.nan
    return td, yd.ravel()


def _alpha_title(run: RunData, label_setup: bool) -> str:
    alpha = run.params.get('alpha')
    title = f'alpha = {alpha:g}' if isinstance(alpha, (int, float)) else 'alpha = ?'
    if label_setup:
        params = run.params
        title += f"\n{params.get('rig_model', '?')}, predictor {params.get('predictor', '?')}"
    return title


def _abort_time(run: RunData) -> float | None:
    if run.stable:
        return None
    if run.unstable_at_s is not None and math.isfinite(run.unstable_at_s):
        return float(run.unstable_at_s)
    return float(run.time_s[-1]) if run.n_steps else None


def _zoom_window(run: RunData, comparison: RunComparison) -> tuple[float, float]:
    """A ZOOM_WINDOW_S window around the reference's displacement peak, inside the run."""
    t = run.time_s
    if run.n_steps == 0:
        return 0.0, ZOOM_WINDOW_S
    x = np.abs(comparison.reference.displacement_m[:run.n_steps])
    centre = float(t[int(np.nanargmax(x))]) if np.any(np.isfinite(x)) else float(t[0])
    start = max(float(t[0]), min(centre - ZOOM_WINDOW_S / 2, float(t[-1]) - ZOOM_WINDOW_S))
    return start, start + ZOOM_WINDOW_S


def plot_time_histories(runs: list[RunData], comparisons: list[RunComparison], path, *,
                        title: str = '', zoom: bool = False) -> Path:
    """Draw test versus reference time histories, one column per run, and save a PNG.

    Rows: displacement [mm], force [N], acceleration [m/s^2] (the layout of the reference
    study's Figure 6); columns: the runs in order, titled ``alpha = <alpha>``. The abort time
    of an unstable run is marked with a vertical line and an annotation.

    Parameters
    ----------
    runs : list of RunData
        The runs (one column each).
    comparisons : list of RunComparison
        Their comparisons (same order), which carry the reference responses.
    path : str or Path
        Output PNG.
    title : str
        Figure title.
    zoom : bool
        Draw only a ``ZOOM_WINDOW_S`` window around each reference's displacement peak
        (otherwise the whole run, min/max-decimated to ``MAX_PLOT_POINTS`` per line).

    Returns
    -------
    Path

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 4, Figure 6.
    """
    path = Path(path)
    ncol = len(runs)
    setups = {(r.params.get('rig_model'), r.params.get('predictor')) for r in runs}
    alphas = [r.params.get('alpha') for r in runs]
    label_setup = len(setups) > 1 or len(set(alphas)) < len(alphas)
    fig = Figure(figsize=(_COLUMN_WIDTH_IN * ncol, _ROW_HEIGHT_IN * len(SIGNALS) + 0.8),
                 layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(SIGNALS), ncol, squeeze=False, sharex='col')
    for j, (run, comparison) in enumerate(zip(runs, comparisons)):
        n = run.n_steps
        t = np.asarray(run.time_s, dtype=float)
        window = _zoom_window(run, comparison) if zoom else None
        if window is not None:
            keep = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
        else:
            keep = slice(None)
        abort_t = _abort_time(run)
        dt = float(t[1] - t[0]) if n > 1 else 0.0
        for i, name in enumerate(SIGNALS):
            ax = axes[i, j]
            ylabel, _, factor = _DISPLAY[name]
            test = np.asarray(run.signal(name), dtype=float)[:n] * factor
            ref = comparison.reference.signal(name)[:n] * factor
            tt, yt = t[keep], test[keep]
            tr, yr = t[keep], ref[keep]
            if window is None:
                tt, yt = _decimate(tt, yt)
                tr, yr = _decimate(tr, yr)
            ax.plot(tt, yt, color='C3', lw=0.8, alpha=0.85, label='test', zorder=2)
            ax.plot(tr, yr, color='k', lw=1.0, ls='--', label='reference', zorder=3)
            ax.grid(True, lw=0.3, alpha=0.5)
            if window is not None:
                end = window[1]
                if abort_t is not None and end < abort_t <= end + dt:
                    end = abort_t  # the abort time is one step after the last sample
                ax.set_xlim(window[0], end)
            if j == 0:
                ax.set_ylabel(ylabel)
            if i == 0:
                ax.set_title(_alpha_title(run, label_setup))
            if i == len(SIGNALS) - 1:
                ax.set_xlabel('time [s]')
            if abort_t is not None and (window is None
                                        or window[0] <= abort_t <= window[1] + dt):
                ax.axvline(abort_t, color='C1', lw=1.2, ls=':')
                if i == 0:
                    ax.annotate(f'unstable\nt = {abort_t:.2f} s', xy=(abort_t, 0.97),
                                xycoords=('data', 'axes fraction'), ha='right', va='top',
                                fontsize=8, color='C1',
                                bbox={'boxstyle': 'round', 'fc': 'w', 'ec': 'C1', 'lw': 0.5})
    handles, labels = axes[0, 0].get_legend_handles_labels()
    axes[0, 0].legend(handles[::-1], labels[::-1], loc='lower left', fontsize=8)
    if title:
        fig.suptitle(title + (f' (zoom, {ZOOM_WINDOW_S:g} s around the reference peak)'
                              if zoom else ''))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI)
    return path


def _fmt(value, spec: str = '.4g', factor: float = 1.0) -> str:
    if value is None or not math.isfinite(value):
        return 'n/a'
    return format(value * factor, spec)


def _param(run: RunData, name: str, factor: float = 1.0, unit: str = '') -> str:
    value = run.params.get(name)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f'{value * factor:g}{unit}'
    return 'n/a' if value is None else str(value)


def _run_markdown(index: int, run: RunData, comparison: RunComparison) -> list[str]:
    params = run.params
    record = run.record_name or params.get('record', '')
    lines = [
        f"## Run {index}: alpha = {_param(run, 'alpha')}, rig {params.get('rig_model', 'n/a')}, "
        f"predictor {params.get('predictor', 'n/a')}",
        '',
        f"- alpha = {_param(run, 'alpha')}, rig = {params.get('rig_model', 'n/a')}, "
        f"predictor = {params.get('predictor', 'n/a')}, record = {record or 'n/a'}",
        f"- dt = {_param(run, 'dt', 1e3, ' ms')}, " + (
            f"tau = {_param(run, 'tau_s', 1e3, ' ms')}, "
            if run.params.get('rig_model') == 'delay' else
            f"I/O latency = {_param(run, 'io_latency_s', 1e3, ' ms')}, ")
        + f'{run.n_steps} samples' + (f', source {run.source}' if run.source else ''),
    ]
    if run.stable:
        lines.append('- **stable**')
    else:
        at = _abort_time(run)
        where = f' at t = {at:.3f} s' if at is not None else ''
        lines.append(f'- **aborted{where}**: {run.abort_reason or "no reason recorded"}')
    lines += [
        f'- power above {HIGH_FREQUENCY_CUTOFF_HZ:g} Hz in the force: test '
        f'{_fmt(comparison.high_frequency_force_fraction, ".2f", 100)} %, reference '
        f'{_fmt(comparison.high_frequency_force_fraction_reference, ".2f", 100)} %',
        '',
        '| signal | peak test | peak ref | peak ratio | lag [ms] | NRMS [%] |',
        '|---|---:|---:|---:|---:|---:|',
    ]
    for name in SIGNALS:
        _, label, factor = _DISPLAY[name]
        c = comparison.signal(name)
        lines.append(
            f'| {label} | {_fmt(c.peak_test, ".4g", factor)} | '
            f'{_fmt(c.peak_reference, ".4g", factor)} | {_fmt(c.peak_ratio, ".3f")} | '
            f'{_fmt(c.lag_s, ".2f", 1e3)} | {_fmt(c.nrms, ".2f", 100)} |')
    lines.append('')
    return lines


def write_report(runs: list[RunData], out_dir, *, title: str = 'seft comparison') -> ReportPaths:
    """Compare runs with the reference analysis and write summary.json, report.md and figures.

    For each run the reference (``reference.reference_from_run``) and the comparison
    (``metrics.compare_run``) are computed; then

    - ``summary.json``: ``{"runs": [entry, ...]}``, one ``metrics.summary_entry`` per run in
      the given order, strict JSON (NaN/inf as null);
    - ``report.md``: per run, the parameters that matter (alpha, rig, predictor, record, dt,
      tau), stable or aborted (time and reason) and a table
      signal | peak test | peak ref | peak ratio | lag [ms] | NRMS [%]; links to the figures;
    - ``time_histories.png``: test versus reference, rows displacement [mm], force [N],
      acceleration [m/s^2], one column per run (as the reference study's Figure 6);
    - ``time_histories_zoom.png``: the same in a 2 s window around each reference's
      displacement peak, where the lag and the high-frequency vibration are visible.

    Parameters
    ----------
    runs : list of RunData
        The runs, in report (column) order; at least one.
    out_dir : str or Path
        Output directory (created if needed; existing files are overwritten).
    title : str
        Title of the report and the figures.

    Returns
    -------
    ReportPaths

    Raises
    ------
    ParameterError
        If `runs` is empty or a run's parameters are missing or out of range.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 4 (Figure 6).
    """
    runs = list(runs)
    if not runs:
        raise ParameterError('runs: expected at least one run')
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    comparisons = [compare_run(run, reference_from_run(run)) for run in runs]
    summary = write_summary_json(
        [summary_entry(run, c) for run, c in zip(runs, comparisons)], out_dir / 'summary.json')
    figure = plot_time_histories(runs, comparisons, out_dir / TIME_HISTORIES_PNG, title=title)
    zoom = plot_time_histories(runs, comparisons, out_dir / ZOOM_PNG, title=title, zoom=True)

    lines = [
        f'# {title}',
        '',
        'Test versus the analytical reference: the whole structure '
        "(1+alpha) m x'' + c x' + k x = -(1+alpha) m xg'' (paper Eq. 2.1) simulated from "
        'the recorded ground motion. The reference force is the member force '
        "m x'' + c x' + k x (paper Eq. 2.4), compared with the load-cell force. "
        "Peaks are max |x| over the run's samples; the lag is the cross-correlation estimate "
        '(positive: the test lags); NRMS = rms(test - reference) / rms(reference) after '
        'advancing the test by its lag, over the samples both share.',
        '',
        f'![Time histories]({figure.name})',
        '',
        f'![Zoom around the reference displacement peak]({zoom.name})',
        '',
    ]
    for index, (run, comparison) in enumerate(zip(runs, comparisons), start=1):
        lines += _run_markdown(index, run, comparison)
    report = out_dir / 'report.md'
    report.write_text('\n'.join(lines), encoding='utf-8')
    return ReportPaths(out_dir=out_dir, summary_json=summary, report_md=report,
                       time_histories_png=figure, zoom_png=zoom)
