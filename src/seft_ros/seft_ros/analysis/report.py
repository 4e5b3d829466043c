"""Comparison report of substructure EFT runs against the reference: JSON, Markdown, figures.

One report for any runs (:func:`write_report`): the reference study's tests (one rig, the
one-DOF structure) with the study's tables and figures (Figure 6, the criteria, the predictors
compared, hysteresis), structure tests per degree of freedom (tables per DOF, link and rig,
the structure's matrices, time histories per DOF, hysteresis of a yielding rig), one
``summary.json`` layout for all (:func:`~seft_ros.analysis.metrics.summary_entry`).

Imports no rclpy and no pyplot: figures are drawn on ``matplotlib.figure.Figure`` objects with
the Agg canvas, so the report works without a display and leaves the global backend alone.
"""

from dataclasses import dataclass, field
import json
import math
from pathlib import Path
import re
import textwrap
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter
import numpy as np

from seft_msgs_py.errors import ParameterError, SeftError
from seft_msgs_py.parameters import identification_run, mapping_value, rig_plant_parameter
from seft_ros.analysis.findings import (
    bridge_entry,
    bridge_lines,
    run_flags,
    sensor_range_entry,
    sensor_range_lines,
    timing_replay_line,
    verdict,
)
from seft_ros.analysis.metrics import (
    HIGH_FREQUENCY_CUTOFF_HZ,
    UNCOMPENSATED,
    RunComparison,
    best_runs,
    compare_run,
    dof_signals,
    drift,
    is_nonlinear,
    json_safe,
    peak,
    restoring_force,
    summary_entry,
)
from seft_ros.analysis.rundata import RECORDING_CUT_SHORT, SIGNALS, RunData, rig_label
from seft_ros.analysis.timing import (
    link_markdown,
    link_summary,
    timing_figure,
    timing_table,
)
from seft_ros.core.ground_motion import record_read_line, record_warnings
from seft_ros.core.models import model_kinds, model_plugin
from seft_ros.core.structure import structure_of

__all__ = ['ReportPaths', 'write_report', 'write_summary_json', 'plot_time_histories',
           'plot_criteria_vs_alpha', 'plot_runs_compared', 'software_versions',
           'plot_predictor_comparison', 'plot_estimates', 'plot_hysteresis',
           'plot_structure_time_histories']

#: Figure files written by :func:`write_report` (single predictor).
TIME_HISTORIES_PNG = 'time_histories.png'
ZOOM_PNG = 'time_histories_zoom.png'
#: Figure files written by :func:`write_report` per predictor (several predictors).
PREDICTOR_TIME_HISTORIES_PNG = 'time_histories_{predictor}.png'
PREDICTOR_ZOOM_PNG = 'time_histories_{predictor}_zoom.png'
#: Cross-predictor figure per alpha (as the reference study's Figures 7 and 8).
PREDICTORS_PNG = 'predictors_alpha_{alpha}.png'
#: Histograms of a real-time run's timing records.
TIMING_PNG = 'timing_run_{index}.png'
#: The compensator's online estimates of a run (when it has any), one figure per run.
ESTIMATES_PNG = 'estimates_run_{index}.png'
#: Hysteresis loops and drift of the runs with a nonlinear specimen (one predictor among them).
HYSTERESIS_PNG = 'hysteresis.png'
#: The same per predictor (several predictors among the nonlinear runs).
PREDICTOR_HYSTERESIS_PNG = 'hysteresis_{predictor}.png'
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
    time_histories_png, zoom_png : Path or None
        Whole-record figure of all the study's runs (as the reference study's Figure 6) and
        the zoom around the reference's displacement peak, written when they share one
        predictor; None otherwise (see `predictor_time_histories`) and without such runs.
    predictor_time_histories : dict of str to (Path, Path)
        With several predictors: ``{predictor: (whole record, zoom)}``, the Figure-6 grid of
        that predictor's runs (``time_histories_<predictor>.png`` and ``..._zoom.png``);
        empty with a single predictor.
    predictor_comparisons : dict of (alpha, rig, record) to Path
        With several predictors: one figure per alpha, rig and record comparing the
        reference, the uncompensated and the compensated runs
        (``predictors_alpha_<alpha>[_<rig>][_<record>].png``, as the reference study's
        Figures 7-8); empty with a single predictor.
    report_html : Path or None
        ``report.html``: report.md as one self-contained HTML page (figures embedded).
    criteria_png : Path or None
        ``criteria_vs_alpha.png`` (:func:`plot_criteria_vs_alpha`) when the runs have more
        than one alpha.
    runs_png : Path or None
        ``runs_compared.png`` (:func:`plot_runs_compared`) for 2 to ``MAX_COMPARED_RUNS``
        runs of one record and dt.
    hysteresis : dict of str to Path
        ``{predictor: path}``: the hysteresis loops and drift of the study's runs with a
        nonlinear specimen (:func:`plot_hysteresis`), ``hysteresis.png`` when they share one
        predictor, else ``hysteresis_<predictor>.png``; empty without a nonlinear run.
    structure_time_histories : dict of int to Path
        ``{run number: path}``: each structure run's time histories per degree of freedom
        (``structure_run_<i>.png``, :func:`plot_structure_time_histories`).
    structure_hysteresis : dict of int to Path
        ``{run number: path}``: the hysteresis loops of each structure run with a hysteretic
        rig (``hysteresis_run_<i>.png``).
    """

    out_dir: Path
    summary_json: Path
    report_md: Path
    time_histories_png: Path | None
    zoom_png: Path | None
    predictor_time_histories: dict[str, tuple[Path, Path]] = field(default_factory=dict)
    predictor_comparisons: dict[tuple[Any, Any, Any], Path] = field(default_factory=dict)
    report_html: Path | None = None
    criteria_png: Path | None = None
    runs_png: Path | None = None
    hysteresis: dict[str, Path] = field(default_factory=dict)
    structure_time_histories: dict[int, Path] = field(default_factory=dict)
    structure_hysteresis: dict[int, Path] = field(default_factory=dict)

    @property
    def figures(self) -> tuple[Path, ...]:
        """All PNG figures, in report order."""
        out = [p for p in (self.criteria_png, self.runs_png) if p is not None]
        out += [p for p in (self.time_histories_png, self.zoom_png) if p is not None]
        for pair in self.predictor_time_histories.values():
            out += list(pair)
        out += list(self.predictor_comparisons.values())
        out += list(self.hysteresis.values())
        for number, path in self.structure_time_histories.items():
            out.append(path)
            if number in self.structure_hysteresis:
                out.append(self.structure_hysteresis[number])
        return tuple(out)


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
    """A ZOOM_WINDOW_S window around the reference's displacement peak, inside the run (a
    run shorter than the window: the run; before, a 0.6 s run's zoom spanned 0-2 s and
    stretched its whole-record panel too, session 36)."""
    t = run.time_s
    if run.n_steps == 0:
        return 0.0, ZOOM_WINDOW_S
    x = np.abs(comparison.reference.displacement_m[:run.n_steps])
    centre = float(t[int(np.nanargmax(x))]) if np.any(np.isfinite(x)) else float(t[0])
    start = max(float(t[0]), min(centre - ZOOM_WINDOW_S / 2, float(t[-1]) - ZOOM_WINDOW_S))
    return start, min(start + ZOOM_WINDOW_S, float(t[-1]))


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
    # 'tight', not 'constrained': the same grid laid out in a third of the time (a 3 x 8
    # grid: 1.9 s against 5.3-7.0 s; the main job's report spent 20 of its 27 s in these
    # figures; session 39)
    fig = Figure(figsize=(_COLUMN_WIDTH_IN * ncol, _ROW_HEIGHT_IN * len(SIGNALS) + 0.8),
                 layout='tight')
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
        _suptitle(fig, title + (f' (zoom, {ZOOM_WINDOW_S:g} s around the reference peak)'
                              if zoom else ''))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI)
    return path


#: Rows of :func:`plot_predictor_comparison` (the reference study's Figures 7-8 show the first
#: two).
_COMPARISON_ROWS = ('displacement', 'acceleration', 'force')
_COMPENSATED_COLORS = ('C0', 'C2', 'C4', 'C1', 'C5', 'C6', 'C8', 'C9')


def _predictor(run: RunData) -> str:
    value = run.params.get('predictor')
    return 'n/a' if value is None else str(value)


def _ended(run: RunData) -> str:
    """How a run that did not complete ended: its verdict, 'aborted' or 'recording cut
    short' (:func:`~seft_ros.analysis.findings.verdict`)."""
    return verdict(False, [], run.recording_cut_short)


def _abort_label(run: RunData) -> str:
    at = _abort_time(run)
    what = _ended(run)
    if at is None:
        return 'stable' if run.stable else what
    return f'{what} at {at:.3f} s'


def plot_predictor_comparison(runs: list[RunData], comparisons: list[RunComparison], path, *,
                              labels: list[str] | None = None, title: str = '') -> Path:
    """Draw the reference versus the uncompensated and the compensated runs, and save a PNG.

    Rows: displacement [mm], acceleration [m/s^2], force [N]; columns: the whole record
    (min/max-decimated, the zoom window shaded) and a ``ZOOM_WINDOW_S`` window around the
    reference's displacement peak, where the lag and the high-frequency vibration show. The
    reference is black dashed, the uncompensated run (predictor 'none') red, the compensated
    runs in other colours; an aborted run's abort time is a dotted vertical line in its colour.
    The y axes span the reference and the stable runs (at most three times the reference's
    peak), so that a diverging run does not flatten the others.

    Parameters
    ----------
    runs : list of RunData
        Runs of the same structure and record (same alpha), one line each; at least one.
    comparisons : list of RunComparison
        Their comparisons (same order); the reference is taken from the longest run.
    path : str or Path
        Output PNG.
    labels : list of str or None
        Legend label of each run (default: its predictor).
    title : str
        Figure title.

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        If `runs` is empty or the lists differ in length.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 5, Figures 7 and 8.
    """
    runs = list(runs)
    comparisons = list(comparisons)
    labels = [_predictor(r) for r in runs] if labels is None else list(labels)
    if not runs or len(comparisons) != len(runs) or len(labels) != len(runs):
        raise ParameterError('plot_predictor_comparison: expected at least one run and one '
                             'comparison and label per run')
    path = Path(path)
    longest = max(range(len(runs)), key=lambda j: runs[j].n_steps)
    ref_run, ref_comparison = runs[longest], comparisons[longest]
    n_ref = ref_run.n_steps
    t_ref = np.asarray(ref_run.time_s, dtype=float)
    window = _zoom_window(ref_run, ref_comparison)
    colors, k = [], 0
    for run in runs:
        if _predictor(run) == UNCOMPENSATED:
            colors.append('C3')
        else:
            colors.append(_COMPENSATED_COLORS[k % len(_COMPENSATED_COLORS)])
            k += 1
    fig = Figure(figsize=(11.0, _ROW_HEIGHT_IN * len(_COMPARISON_ROWS) + 1.2),
                 layout='constrained')          # its legend below the axes needs room
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(_COMPARISON_ROWS), 2, squeeze=False, sharex='col',
                        width_ratios=[1.6, 1.0])
    for i, name in enumerate(_COMPARISON_ROWS):
        ylabel, _, factor = _DISPLAY[name]
        ref = np.asarray(ref_comparison.reference.signal(name), dtype=float)[:n_ref] * factor
        ref_peak = peak(ref) if n_ref else math.nan
        peaks = [ref_peak] + [peak(np.asarray(r.signal(name), dtype=float)[:r.n_steps])
                              * factor for r in runs if r.stable and r.n_steps]
        peaks = [p for p in peaks if math.isfinite(p)]
        limit = 1.15 * max(peaks) if peaks else math.nan
        if math.isfinite(ref_peak) and ref_peak > 0:
            limit = min(limit, 3.0 * ref_peak)
        for col in range(2):
            ax = axes[i, col]
            zoom = col == 1
            for run, label, color in zip(runs, labels, colors):
                n = run.n_steps
                t = np.asarray(run.time_s, dtype=float)
                y = np.asarray(run.signal(name), dtype=float)[:n] * factor
                if zoom:
                    keep = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
                    t, y = t[keep], y[keep]
                else:
                    t, y = _decimate(t, y)
                if not run.stable:
                    label = f'{label} ({_abort_label(run)})'
                ax.plot(t, y, color=color, lw=0.8, alpha=0.9, label=label, zorder=2)
                at = _abort_time(run)
                if at is not None and (not zoom or window[0] <= at <= window[1]):
                    ax.axvline(at, color=color, lw=1.0, ls=':')
            if zoom:
                keep = (t_ref >= window[0] - 1e-9) & (t_ref <= window[1] + 1e-9)
                tr, yr = t_ref[keep], ref[keep]
            else:
                tr, yr = _decimate(t_ref, ref)
                ax.axvspan(window[0], window[1], color='0.5', alpha=0.12, lw=0)
            ax.plot(tr, yr, color='k', lw=1.1, ls='--', label='reference', zorder=3)
            if math.isfinite(limit) and limit > 0:
                ax.set_ylim(-limit, limit)
            if zoom:
                ax.set_xlim(*window)
            ax.grid(True, lw=0.3, alpha=0.5)
            if col == 0:
                ax.set_ylabel(ylabel)
            if i == 0:
                ax.set_title('whole record' if not zoom else
                             f'zoom: {ZOOM_WINDOW_S:g} s around the reference peak')
            if i == len(_COMPARISON_ROWS) - 1:
                ax.set_xlabel('time [s]')
    handles, names = axes[0, 0].get_legend_handles_labels()
    order = [len(handles) - 1] + list(range(len(handles) - 1))  # reference first
    fig.legend([handles[j] for j in order], [names[j] for j in order], loc='outside lower center',
               ncols=min(len(handles), 5), fontsize=8)
    if title:
        _suptitle(fig, title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI)
    return path


#: The line styles of the references of several alphas in one figure, in order.
_REFERENCE_STYLES = ({'color': 'k', 'ls': '--'}, {'color': '0.45', 'ls': ':'},
                     {'color': 'k', 'ls': '-.'}, {'color': '0.45', 'ls': '--'})

#: Characters of a figure's title per inch of its width (matplotlib's 'large' suptitle;
#: 'medium' takes a fifth more): a longer title is wrapped (a new user's title with the
#: default record's name ran off both edges of a 1320 px figure, session 36).
_TITLE_CHARS_PER_IN = 9.5


def _rig_contract_text(run: RunData) -> str:
    """The report's rig-contract cell: the contract the rig reported; for ``seft simulate``
    (in one process, no rig node) that there is none to report (it read 'not reported (a bag
    before it)' there, a new user, session 36); for a bag without it, that it predates it."""
    if run.extra.get('rig_contract'):
        return str(run.extra['rig_contract'])
    if run.source == 'simulate':
        return "none: seft simulate steps seft's simulated rig in process (no rig node)"
    return 'not reported (a bag before it)'


def _suptitle(fig, text: str, **kwargs) -> None:
    """``fig.suptitle(text)``, wrapped to the figure's width (:data:`_TITLE_CHARS_PER_IN`)."""
    scale = 1.2 if kwargs.get('fontsize') == 'medium' else 1.0
    width = max(40, int(fig.get_figwidth() * _TITLE_CHARS_PER_IN * scale))
    fig.suptitle('\n'.join(textwrap.fill(line, width) for line in str(text).split('\n')),
                 **kwargs)


def _fmt(value, spec: str = '.4g', factor: float = 1.0) -> str:
    if value is None or not math.isfinite(value):
        return 'n/a'
    return format(value * factor, spec)


def _param(run: RunData, name: str, factor: float = 1.0, unit: str = '') -> str:
    value = run.params.get(name)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return f'{value * factor:g}{unit}'
    return 'n/a' if value is None else str(value)


#: The key values named in a run's "parameters: ... from <node>" line: label -> parameters.
_SOURCE_LABELS = (
    ('alpha', ('alpha',)), ('predictor', ('predictor',)), ('mass', ('mass_kg',)),
    ('stiffness', ('stiffness_N_per_m',)), ('damping', ('damping_N_s_per_m',)),
    ('rig', ('rig_model',)), ('dt', ('dt',)), ('record', ('record',)),
    ('scaling', ('amplitude_N', 'scale_factor', 'time_scale', 'record_resampling')),
)


def _sources_line(run: RunData) -> str | None:
    """'parameters: alpha, predictor from reference_force_builder; mass, ... from rig; ...'
    for a run read from a bag with node parameters (None otherwise). A label whose
    parameters came from different places is split into the parameter names."""
    sources = run.extra.get('param_sources') or {}
    if not run.extra.get('node_params') or not sources:
        return None
    groups: dict[str, list[str]] = {}
    for label, names in _SOURCE_LABELS:
        found = {sources.get(n, 'n/a') for n in names}
        if len(found) == 1:
            groups.setdefault(found.pop(), []).append(label)
        else:
            for n in names:
                groups.setdefault(sources.get(n, 'n/a'), []).append(n)
    return 'parameters: ' + '; '.join(f"{', '.join(labels)} from {where}"
                                      for where, labels in groups.items())


def _mismatch_lines(run: RunData) -> list[str]:
    """A marked warning with one sub-item per parameter the run's nodes disagreed on."""
    mismatches = list(run.extra.get('parameter_mismatches') or ())
    if not mismatches:
        return []
    return ['- **WARNING: the nodes ran with different values of shared parameters** (each '
            'value above is the one of the node that used it; the run is not one consistent '
            'experiment):'] + [f'  - {line}' for line in mismatches]


def _recording_end(recording: dict) -> str:
    """How a recording cut short ended, as the report's bold label says it: 'stopped', or
    'not closed' (summary ``end`` 'crashed': the recorder killed, or still recording), 'cut or
    damaged' (``end`` 'damaged': a closed bag's file cut afterwards)."""
    return {'crashed': 'not closed', 'damaged': 'cut or damaged'}.get(
        recording.get('end'), str(recording.get('end')))


def _warning_lines(run: RunData) -> list[str]:
    """A marked line per warning the run's nodes and runner reported (a specimen not the
    declared one, a foreign publisher on the run's topics), each once, in order."""
    return [f'- **warning**: {w}' for w in dict.fromkeys(run.extra.get('warnings') or ())]


def _bridge_markdown(run: RunData) -> list[str]:
    """A rig behind the UDP bridge: its link's datagram counts, a marked warning when the
    link was not clean, and a safe state the controller did not confirm."""
    label = {'counts': '', 'warning': '**warning**: ',
             'safe state': '**safe state NOT confirmed**: '}
    return [f'- {label[kind]}{line}' for kind, line in bridge_lines(bridge_entry(run))]


def _range_markdown(run: RunData) -> list[str]:
    """The pre-run guard's predicted NRMS x, the range check's lines and the samples read at
    a sensor's range, one item each (issue 39)."""
    lines = []
    predicted = (run.extra.get('stability') or {}).get('predicted_error')
    if predicted:
        lines.append(f"- pre-run stability guard: NRMS x predicted "
                     f"{100 * predicted['displacement']:.2g} % on the loop's model "
                     f"({predicted.get('spectrum')})")
    check = run.extra.get('range_check') or {}
    for line in check.get('lines') or ():
        lines.append(f'- pre-run range check: {line}')
    for line in sensor_range_lines(sensor_range_entry(run)):
        lines.append(f'- **sensor at its range**: {line}')
    replay = run.extra.get('timing_replay')
    if replay:
        lines.append(f'- timing replay: {timing_replay_line(replay)}')
    return lines



def _preparation(params) -> str:
    """' (time scale 0.5, resampling band_limited)': how the run's record was prepared
    (:func:`seft_ros.core.ground_motion.prepare`; '' for an excitation run or a bag that
    does not say)."""
    how = params.get('record_resampling')
    if how is None or identification_run(params):
        return ''
    if how == 'auto':
        how = 'linear' if params.get('record', 'default') == 'default' else 'band_limited'
    scale = params.get('time_scale')
    return (f' (time scale {scale:g}, ' if isinstance(scale, (int, float)) else ' (') + \
        f'resampling {how})'


def _latency_text(run: RunData) -> str:
    """The rig's delay as its model has it: the delay rig's ``tau_s``, seft's servohydraulic
    rig's ``io_latency_s``, a state_space rig's plant model's ``io_delay_s`` (the report gave
    every rig ``io_latency_s``, which only seft's servohydraulic rig reads: 3 ms on a new
    user's plant of 2 ms; session 38), the family's actuator its own."""
    params = run.params
    rig = params.get('rig_model')
    if rig == 'delay':
        return f"tau = {_param(run, 'tau_s', 1e3, ' ms')}, "
    if rig == 'servohydraulic':
        return f"I/O latency = {_param(run, 'io_latency_s', 1e3, ' ms')}, "
    if rig == 'state_space':
        name = rig_plant_parameter(params)
        try:
            doc = mapping_value(params[name], where=f'parameter {name}', expected='a mapping')
            delay = float(doc.get('io_delay_s', 0.0) or 0.0)
        except (KeyError, SeftError, TypeError, ValueError):
            return "I/O latency: its plant model's, "
        return f"I/O latency = {1e3 * delay:g} ms (its plant model's io_delay_s), "
    return f"I/O latency: the {rig} rig's own, "


def _run_markdown(index: int, run: RunData, comparison: RunComparison) -> list[str]:
    params = run.params
    record = (run.record_name or params.get('record', '')) + _preparation(params)
    lines = [
        f"## Run {index}: alpha = {_param(run, 'alpha')}, rig {params.get('rig_model', 'n/a')}, "
        f"predictor {params.get('predictor', 'n/a')}",
        '',
        f"- alpha = {_param(run, 'alpha')}, rig = {params.get('rig_model', 'n/a')}, "
        f"predictor = {params.get('predictor', 'n/a')}, record = {record or 'n/a'}",
        f"- dt = {_param(run, 'dt', 1e3, ' ms')}, " + _latency_text(run)
        + f'{run.n_steps} samples' + (f', source {run.source}' if run.source else ''),
        f'- rig contract: {_rig_contract_text(run)}',
    ]
    if run.extra.get('record_read'):
        lines.append(f"- {record_read_line(run.extra['record_read'])}")
        lines += [f'- **warning**: {w}' for w in record_warnings(run.extra['record_read'])]
    sources = _sources_line(run)
    if sources is not None:
        lines.append(f'- {sources}')
    lines += _mismatch_lines(run)
    flags = run_flags(run, comparison)
    if run.stable and flags:
        lines.append('- **stable, flagged**: the run may have lost accuracy, as a lab sees it '
                     'without the reference:')
        lines += [f'  - {flag}' for flag in flags]
    elif run.stable:
        lines.append('- **stable**')
    else:
        at = _abort_time(run)
        where = f' at t = {at:.3f} s' if at is not None else ''
        lines.append(f'- **aborted{where}**: {run.abort_reason or "no reason recorded"}')
    lines += _warning_lines(run)
    lines += _bridge_markdown(run)
    recording = run.extra.get('recording') or {}
    if recording.get('end') in RECORDING_CUT_SHORT:
        lines.append(f'- **recording {_recording_end(recording)}**: {recording.get("note")}')
    elif recording.get('gap_at_step') is not None:
        lines.append(f'- **recording with a gap**: {recording.get("note")}')
    lines += _range_markdown(run)
    res = comparison.residual
    if is_nonlinear(params) and res is not None:
        lines.append(
            f"- nonlinear specimen ({params.get('specimen_model')}): residual displacement "
            f'test {_fmt(res.residual_test_m, ".2f", 1e3)} mm, reference '
            f'{_fmt(res.residual_reference_m, ".2f", 1e3)} mm; displacement NRMS '
            f'{_fmt(res.nrms, ".2f", 100)} %, {_fmt(res.nrms_residual_removed, ".2f", 100)} % '
            f'with the drift (< {res.drift_cutoff_hz:g} Hz) removed')
    lines += [
        f'- power above {comparison.high_frequency_cutoff_hz:g} Hz in the force: test '
        f'{_fmt(comparison.high_frequency_force_fraction, ".2f", 100)} %, reference '
        f'{_fmt(comparison.high_frequency_force_fraction_reference, ".2f", 100)} %',
        '',
        '| signal | peak test | peak ref | peak ratio | lag [ms] | NRMS own lag [%] '
        '| NRMS common lag [%] | NRMS as recorded [%] |',
        '|---|---:|---:|---:|---:|---:|---:|---:|',
    ]
    for name in SIGNALS:
        _, label, factor = _DISPLAY[name]
        c = comparison.signal(name)
        lines.append(
            f'| {label} | {_fmt(c.peak_test, ".4g", factor)} | '
            f'{_fmt(c.peak_reference, ".4g", factor)} | {_fmt(c.peak_ratio, ".3f")} | '
            f'{_fmt(c.lag_s, ".2f", 1e3)} | {_fmt(c.nrms, ".2f", 100)} | '
            f'{_fmt(c.nrms_common_lag, ".2f", 100)} | {_fmt(c.nrms_unshifted, ".2f", 100)} |')
    lines.append('')
    return lines


def _timing_markdown(index: int, run: RunData, out_dir: Path, title: str) -> list[str]:
    """A real-time run's timing: the summary, a table per node and the histograms."""
    timing = run.extra.get('timing')
    if not timing:
        return []
    lines = [f'### Run {index}: timing (real time, wall {_fmt(run.extra.get("wall_s"), ".1f")}'
             ' s)', '', timing_table(timing), '']
    lines += link_markdown(link_summary(run.extra.get('link'), timing))
    lost = run.extra.get('bag_lost_messages')
    if lost is not None:
        lines += [f'Messages published but not in the bag: {lost}.', '']
    data = run.extra.get('timing_data')
    if data:
        png = timing_figure(data, out_dir / TIMING_PNG.format(index=index),
                            title=f'{title}: run {index}, timing')
        lines += [f'![Timing, run {index}]({png.name})', '']
    return lines


def plot_estimates(run: RunData, path, *, title: str = '') -> Path:
    """The compensator's online estimates over time, relative to their first value.

    Parameters
    ----------
    run : RunData
        A run with ``run.estimates`` (``{name: ndarray (n,)}``).
    path : str or Path
        PNG file to write.
    title : str

    Returns
    -------
    Path
        `path`.

    Raises
    ------
    ParameterError
        If the run has no estimates.

    Notes
    -----
    One axis per estimate: ``value / first value - 1`` in percent (the first value is the
    configured model, the compensator's start), with the final value in the legend; the
    measured-force envelope below marks where the excitation is strong.
    """
    if not run.estimates:
        raise ParameterError('plot_estimates: the run has no estimates')
    names = list(run.estimates)
    t = run.time_s
    fig = Figure(figsize=(2 * _COLUMN_WIDTH_IN, _ROW_HEIGHT_IN * (len(names) + 1) * 0.7),
                 constrained_layout=True)
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(names) + 1, 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, names):
        y = np.asarray(run.estimates[name], dtype=float)
        first = y[0] if y.shape[0] else 0.0
        if first != 0.0:
            rel = 100.0 * (y / first - 1.0)
            label = f'{name}: start {first:.4g}, end {y[-1]:.4g}'
            ax.set_ylabel('change [%]')
        else:
            rel, label = y, f'{name}: end {y[-1]:.4g}'
        ax.plot(*_decimate(t, rel), lw=0.9, label=label)
        ax.legend(loc='best', fontsize='small')
        ax.grid(True, alpha=0.3)
    ax = axes[-1]
    ax.plot(*_decimate(t, run.measured_force_N), lw=0.5, color='0.4')
    ax.set_ylabel('f_m [N]')
    ax.set_xlabel('time [s]')
    ax.grid(True, alpha=0.3)
    if title:
        _suptitle(fig, title)
    path = Path(path)
    fig.savefig(path, dpi=_DPI)
    return path


def _estimates_markdown(index: int, run: RunData, out_dir: Path, title: str) -> list[str]:
    """The figure of the compensator's online estimates, if the run has them."""
    if not run.estimates or run.n_steps == 0:
        return []
    png = plot_estimates(run, out_dir / ESTIMATES_PNG.format(index=index),
                         title=f'{title}: run {index}, online estimates')
    final = ', '.join(f'{k} = {v[-1]:.5g}' for k, v in run.estimates.items())
    return [f'### Run {index}: online estimates', '', f'Final: {final}.', '',
            f'![Online estimates, run {index}]({png.name})', '']


def plot_hysteresis(runs: list[RunData], comparisons: list[RunComparison], path, *,
                    title: str = '', labels: list[str] | None = None) -> Path:
    """Draw the member's hysteresis loops and the displacement's drift, test over reference.

    One column per run. Top: restoring force [N] against displacement [mm], the test's
    (:func:`~seft_ros.analysis.metrics.restoring_force`, ``f_m - m a - c v``) in red over the
    reference's (``ReferenceResponse.restoring_force_N``, the member's ``f_s(x, z)``) in
    black. Bottom: the displacement [mm] over time, test and reference thin, their drifts
    (:func:`~seft_ros.analysis.metrics.drift`) thick, the residual displacements as
    horizontal bars over the residual's window at the end, and the displacement NRMS with and
    without the drift. An aborted run's axes span at most three times the reference's peaks.

    Parameters
    ----------
    runs : list of RunData
        The runs (one column each), at least one; their parameters give m and c.
    comparisons : list of RunComparison or RigComparison
        Their comparisons (same order): the reference responses and
        ``comparison.residual`` (drift cut-off, residual window, residuals, NRMS).
    path : str or Path
        Output PNG.
    title : str
        Figure title.
    labels : list of str, optional
        Column titles (default: each run's alpha, and its rig and predictor where they
        differ); a rig of a structure: ``run.rig_view(rig)``, labelled by its name.

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        If `runs` is empty or the lists differ in length, or a run lacks mass_kg or
        damping_N_s_per_m.
    """
    runs = list(runs)
    comparisons = list(comparisons)
    if not runs or len(runs) != len(comparisons):
        raise ParameterError(f'plot_hysteresis: {len(runs)} runs and {len(comparisons)} '
                             'comparisons; expected the same number, at least one')
    path = Path(path)
    ncol = len(runs)
    setups = {(r.params.get('rig_model'), r.params.get('predictor')) for r in runs}
    alphas = [r.params.get('alpha') for r in runs]
    label_setup = len(setups) > 1 or len(set(alphas)) < len(alphas)
    # at least 6 in wide: a single column still has room for the title
    fig = Figure(figsize=(max(_COLUMN_WIDTH_IN * ncol, 6.0), 2 * _ROW_HEIGHT_IN * 1.25 + 1.2),
                 layout='tight')                # as plot_time_histories: a third of the time
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, ncol, squeeze=False)
    for j, (run, comparison) in enumerate(zip(runs, comparisons)):
        n = run.n_steps
        ref = comparison.reference
        res = comparison.residual
        x_test = np.asarray(run.displacement_m, dtype=float)[:n] * 1e3
        x_ref = np.asarray(ref.displacement_m, dtype=float)[:n] * 1e3
        fs_test = restoring_force(run)
        fs_ref = (None if ref.restoring_force_N is None
                  else np.asarray(ref.restoring_force_N, dtype=float)[:n])
        ax = axes[0, j]
        if fs_ref is not None:
            ax.plot(x_ref, fs_ref, color='k', lw=0.9, label='reference: f_s(x, z)', zorder=2)
        ax.plot(x_test, fs_test, color='C3', lw=0.7, alpha=0.85,
                label='test: f_m - m a - c v', zorder=3)
        if not run.stable:
            for values, setter in ((x_ref, ax.set_xlim), (fs_ref, ax.set_ylim)):
                top = peak(values) if values is not None and n else math.nan
                if math.isfinite(top) and top > 0:
                    setter(-3.0 * top, 3.0 * top)
        ax.set_xlabel('displacement [mm]')
        ax.set_title((labels[j] if labels else _alpha_title(run, label_setup))
                     + ('' if run.stable else f' ({_abort_label(run)})'))
        ax.grid(True, lw=0.3, alpha=0.5)
        ax = axes[1, j]
        t = np.asarray(run.time_s, dtype=float)
        dt = float(run.params.get('dt', t[1] - t[0] if n > 1 else 0.0))
        for x, color, ls, who in ((x_test, 'C3', '-', 'test'), (x_ref, 'k', '--', 'reference')):
            ax.plot(*_decimate(t, x), color=color, lw=0.5, alpha=0.5)
            if res is not None and n > 1:
                ax.plot(t, drift(x, dt, res.drift_cutoff_hz), color=color, lw=1.8, ls=ls,
                        label=f'{who}: drift (< {res.drift_cutoff_hz:g} Hz)')
        if res is not None and n:
            start = max(float(t[0]), float(t[-1]) - res.residual_window_s)
            for value, color in ((res.residual_test_m, 'C3'), (res.residual_reference_m, 'k')):
                if value is not None and math.isfinite(value):
                    ax.hlines(value * 1e3, start, float(t[-1]), colors=color, lw=3.0,
                              alpha=0.6)
            ax.text(0.02, 0.97, f'NRMS x {_fmt(res.nrms, ".1f", 100)} %, drift removed '
                    f'{_fmt(res.nrms_residual_removed, ".1f", 100)} %\nresidual: test '
                    f'{_fmt(res.residual_test_m, ".2f", 1e3)} mm, reference '
                    f'{_fmt(res.residual_reference_m, ".2f", 1e3)} mm',
                    transform=ax.transAxes, ha='left', va='top', fontsize=7,
                    bbox={'boxstyle': 'round', 'fc': 'w', 'ec': '0.7', 'lw': 0.5})
        if not run.stable:
            top = peak(x_ref) if n else math.nan
            if math.isfinite(top) and top > 0:
                ax.set_ylim(-3.0 * top, 3.0 * top)
        ax.set_xlabel('time [s]')
        ax.grid(True, lw=0.3, alpha=0.5)
    axes[0, 0].set_ylabel('restoring force [N]')
    axes[1, 0].set_ylabel('displacement [mm]')
    for row in range(2):
        handles, names = axes[row, 0].get_legend_handles_labels()
        if handles:
            axes[row, 0].legend(handles, names, loc='lower right', fontsize=7)
    if title:
        _suptitle(fig, title, fontsize='medium')
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI)
    return path


def _nonlinear_markdown(runs: list[RunData], entries: list[dict[str, Any]],
                        comparisons: list[RunComparison], out_dir: Path,
                        title: str, numbers: list[int] | None = None
                        ) -> tuple[list[str], dict[str, Path]]:
    """The section of the runs with a nonlinear specimen: the table of peak and residual
    displacements and of the NRMS with and without the drift, and the hysteresis figures
    (one per predictor). No lines and no figure without such a run."""
    indices = [j for j, run in enumerate(runs) if is_nonlinear(run.params)
               and comparisons[j].residual is not None]
    if not indices:
        return [], {}
    res0 = comparisons[indices[0]].residual
    lines = [
        '## Nonlinear specimen: residual displacement and hysteresis',
        '',
        'The runs with a yielding member (`specimen_model` other than linear). Residual '
        '(permanent) displacement: the Hann-weighted mean of the displacement over the last '
        f'{res0.residual_window_s:g} s of the record, the offset the member comes to rest at '
        '(an oscillation still going on at the end is averaged out). Drift: the displacement '
        f'low-passed at {res0.drift_cutoff_hz:g} Hz (4th-order Butterworth, forward and '
        'backward: zero phase), well below the oscillation of the yielding member (the '
        "default member's post-yield frequency: 2.0-3.2 Hz for alpha = 1.5-0). NRMS x: "
        "rms(x - x_ref) / rms(x_ref) after removing the displacement's lag; drift removed: "
        'the same of x - drift(x) against x_ref - drift(x_ref), each signal without its own '
        'permanent offset, so that an offset the test took at one yield excursion does not '
        'count over the rest of the record.',
        '',
        '| run | alpha | rig | predictor | specimen | NRMS x [%] | NRMS x, drift removed [%] '
        '| peak x test [mm] | peak x ref [mm] | residual x test [mm] | residual x ref [mm] '
        '| status |',
        '|---:|---:|---|---|---|---:|---:|---:|---:|---:|---:|---|',
    ]
    for j in indices:
        e = entries[j]
        block = e.get('nonlinear') or {}
        peaks = block.get('peak_displacement_m') or {}
        residuals = block.get('residual_displacement_m') or {}
        lines.append(
            f"| {_number(numbers, j)} | {_alpha_text(e.get('alpha'))} | {e.get('rig') or 'n/a'} | "
            f"{_predictor(runs[j])} | {block.get('specimen_model') or 'n/a'} | "
            f"{_fmt(block.get('nrms_displacement'), '.2f', 100)} | "
            f"{_fmt(block.get('nrms_displacement_residual_removed'), '.2f', 100)} | "
            + ' | '.join(_fmt(d.get(k), '.2f', 1e3) for d in (peaks, residuals)
                         for k in ('test', 'reference'))
            + f' | {_entry_status(e)} |')
    lines.append('')
    predictors = list(dict.fromkeys(_predictor(runs[j]) for j in indices))
    order = {name: i for i, name in enumerate(_predictor_order(runs))}
    predictors.sort(key=order.__getitem__)
    figures: dict[str, Path] = {}
    for name in predictors:
        chosen = [j for j in indices if _predictor(runs[j]) == name]
        file = (HYSTERESIS_PNG if len(predictors) == 1
                else PREDICTOR_HYSTERESIS_PNG.format(predictor=_safe_name(name)))
        figures[name] = plot_hysteresis(
            [runs[j] for j in chosen], [comparisons[j] for j in chosen], out_dir / file,
            title=f'{title}: predictor {name}, hysteresis loops and drift')
        alphas = ', '.join(_alpha_text(runs[j].params.get('alpha')) for j in chosen)
        lines += [f'![Hysteresis loops and drift, predictor {name}]({file})', '',
                  f'**Hysteresis, predictor {name}, alpha = {alphas}.** Top: the restoring '
                  'force of the '
                  'member against its displacement, the test (red: load-cell force minus '
                  'the inertia and damping of the specimen, f_m - m a - c v) over the '
                  'reference (black: the restoring force of the reference analysis, '
                  'Bouc-Wen f_s(x, z)). '
                  'Bottom: the displacement of test and reference (thin) with their drifts '
                  '(thick) and, at the end, the residual displacements (bars over the '
                  'window).', '']
    return lines, figures


def _safe_name(text: Any) -> str:
    """A file-name-safe version of `text` (letters, digits, '.', '-', '_')."""
    return re.sub(r'[^A-Za-z0-9_.+-]+', '_', str(text)).strip('_') or 'na'


def _number(numbers: list[int] | None, j: int) -> int:
    """The report's number of run `j` of a list: ``numbers[j]``, or ``j + 1``."""
    return numbers[j] if numbers else j + 1


def _alpha_text(alpha: Any) -> str:
    if isinstance(alpha, (int, float)) and not isinstance(alpha, bool):
        return f'{alpha:g}'
    return 'n/a' if alpha is None else str(alpha)


def _record(run: RunData) -> str:
    return run.record_name or run.params.get('record', '') or 'n/a'


def _predictor_order(runs: list[RunData]) -> list[str]:
    """Distinct predictors, the uncompensated one first, then in order of appearance."""
    names = list(dict.fromkeys(_predictor(r) for r in runs))
    return sorted(names, key=lambda name: (name != UNCOMPENSATED, names.index(name)))


def _groups(runs: list[RunData], key) -> dict[Any, list[int]]:
    """Run indices grouped by ``key(run)``, groups in order of appearance, runs ordered by
    predictor (uncompensated first) then by index."""
    rank = {name: i for i, name in enumerate(_predictor_order(runs))}
    out: dict[Any, list[int]] = {}
    for j, run in enumerate(runs):
        out.setdefault(key(run), []).append(j)
    return {k: sorted(v, key=lambda j: (rank[_predictor(runs[j])], j)) for k, v in out.items()}


def _setup_key(run: RunData) -> tuple[Any, Any]:
    return (run.params.get('alpha'), run.params.get('rig_model'))


def _figure_key(run: RunData) -> tuple[Any, Any, str]:
    return (run.params.get('alpha'), run.params.get('rig_model'), _record(run))


def _comparison_labels(runs: list[RunData], indices: list[int],
                       numbers: list[int] | None = None) -> list[str]:
    """Legend labels: the predictor, with the run number when a predictor repeats."""
    names = [_predictor(runs[j]) for j in indices]
    return [f'{name} (run {_number(numbers, j)})' if names.count(name) > 1 else name
            for name, j in zip(names, indices)]


def _entry_status(entry: dict[str, Any]) -> str:
    """A run's status in the report's tables: its verdict (a flagged run's too, as on the
    console and in ``summary.json``), or when it was aborted."""
    if entry.get('stable'):
        return 'stable, flagged' if entry.get('flags') else 'stable'
    at = entry.get('unstable_at_s')
    what = entry.get('verdict') or verdict(False, [])      # its summary's: aborted or cut
    return f'{what} at {at:.3f} s' if isinstance(at, (int, float)) else what


def _cross_predictor_markdown(runs: list[RunData], entries: list[dict[str, Any]],
                              figures: dict[tuple[Any, Any, str], Path],
                              cutoff_hz: float, numbers: list[int] | None = None) -> list[str]:
    lines = [
        '## Comparison across predictors',
        '',
        'One table per alpha (and rig), one row per run, the uncompensated predictor '
        f"'{UNCOMPENSATED}' first. x, a, f: displacement, acceleration, force. HF force: "
        f'fraction of the power of the measured force above {cutoff_hz:g} Hz (Welch PSD), '
        "which quantifies the 'undesirable high frequency vibration' of the reference study "
        '(Sec. 4); HF ref: the same for the reference force. NRMS is computed after '
        "removing each signal's lag; lag x: the displacement lag behind the reference.",
        '',
    ]
    for (alpha, rig), indices in _groups(runs, _setup_key).items():
        lines += [f'### alpha = {_alpha_text(alpha)}, rig {rig or "n/a"}', '']
        for key, png in figures.items():
            if key[:2] == (alpha, rig):
                lines += [f'![Reference vs uncompensated vs compensated, alpha = '
                          f'{_alpha_text(alpha)}, record {key[2]}]({png.name})', '']
        lines += [
            '| run | predictor | record | NRMS x [%] | NRMS a [%] | NRMS f [%] | peak ratio x '
            '| peak ratio a | peak ratio f | HF force [%] | HF ref [%] | lag x [ms] | status |',
            '|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|',
        ]
        for j in indices:
            e = entries[j]
            nrms, ratio = e['nrms'], e['peak_ratio']
            lines.append(
                f'| {_number(numbers, j)} | {_predictor(runs[j])} | {_record(runs[j])} | '
                + ' | '.join(_fmt(nrms[s], '.2f', 100)
                             for s in ('displacement', 'acceleration', 'force')) + ' | '
                + ' | '.join(_fmt(ratio[s], '.3f')
                             for s in ('displacement', 'acceleration', 'force')) + ' | '
                + f"{_fmt(e['high_frequency_force_fraction'], '.2f', 100)} | "
                f"{_fmt(e['high_frequency_force_fraction_reference'], '.2f', 100)} | "
                f"{_fmt(e['lag_s'], '.2f', 1e3)} | {_entry_status(e)} |")
        lines.append('')
    return lines


def _best_markdown(entries: list[dict[str, Any]]) -> list[str]:
    best = best_runs(entries)
    lines = [
        '## Uncompensated vs best compensated',
        '',
        f"Per alpha and rig: the uncompensated run (predictor '{UNCOMPENSATED}') beside the "
        'stable compensated run with the smallest displacement NRMS. x: displacement; HF: '
        'fraction of the power of the measured force above the cutoff.',
        '',
        '| alpha | rig | none NRMS x [%] | none peak ratio x | none HF [%] | none status '
        '| best predictor | best NRMS x [%] | best peak ratio x | best HF [%] |',
        '|---:|---|---:|---:|---:|---|---|---:|---:|---:|',
    ]
    for key in dict.fromkeys((e.get('alpha'), e.get('rig')) for e in entries):
        chosen = best.get(key)
        plain = [e for e in entries if (e.get('alpha'), e.get('rig')) == key
                 and e.get('predictor') == UNCOMPENSATED]
        same = [e for e in plain if chosen is not None and e.get('record') == chosen['record']]
        none = (same or plain or [None])[0]

        def cells(e):
            if e is None:
                return ['n/a'] * 3
            return [_fmt(e['nrms']['displacement'], '.2f', 100),
                    _fmt(e['peak_ratio']['displacement'], '.3f'),
                    _fmt(e['high_frequency_force_fraction'], '.2f', 100)]

        row = [_alpha_text(key[0]), key[1] or 'n/a', *cells(none),
               'n/a' if none is None else _entry_status(none),
               'no stable compensated run' if chosen is None else _tied(chosen, entries),
               *cells(chosen)]
        lines.append('| ' + ' | '.join(row) + ' |')
    lines.append('')
    return lines


def _tied(chosen: dict[str, Any], entries: list[dict[str, Any]]) -> str:
    """The best run's predictor, with every other stable compensated predictor of its alpha,
    rig and record whose displacement NRMS shows the same in the table (``.2f`` of a
    percent): 'adaptive = model'. (Session 35: a new user read 'adaptive' as the better
    of two runs that tied to the digit.)"""
    shown = _fmt(chosen['nrms']['displacement'], '.2f', 100)
    key = (chosen.get('alpha'), chosen.get('rig'), chosen.get('record'))
    names = [chosen['predictor']]
    for e in entries:
        if ((e.get('alpha'), e.get('rig'), e.get('record')) == key and e.get('stable')
                and e.get('predictor') not in (None, UNCOMPENSATED, *names)
                and isinstance((e.get('nrms') or {}).get('displacement'), float)
                and _fmt(e['nrms']['displacement'], '.2f', 100) == shown):
            names.append(e['predictor'])
    return ' = '.join(names)


def _comparison_files(runs: list[RunData]) -> dict[tuple[Any, Any, str], str]:
    """File name of each cross-predictor figure, rig and record appended when they vary."""
    rigs = {r.params.get('rig_model') for r in runs}
    records = {_record(r) for r in runs}
    names: dict[tuple[Any, Any, str], str] = {}
    for key in _groups(runs, _figure_key):
        stem = PREDICTORS_PNG.format(alpha=_safe_name(_alpha_text(key[0])))[:-len('.png')]
        if len(rigs) > 1:
            stem += f'_{_safe_name(key[1])}'
        if len(records) > 1:
            stem += f'_{_safe_name(key[2])}'
        name, k = stem + '.png', 2
        while name in names.values():
            name, k = f'{stem}_{k}.png', k + 1
        names[key] = name
    return names


# -- evaluation criteria, parameters and software, sweep and run-comparison figures ----------

#: Figure of the criteria against alpha, one line per predictor (a sweep over alpha).
CRITERIA_PNG = 'criteria_vs_alpha.png'
#: Figure of runs of one record side by side: time histories and differences to the reference.
RUNS_COMPARED_PNG = 'runs_compared.png'
#: Most runs drawn in :func:`plot_runs_compared` (more are unreadable; the table has them all).
MAX_COMPARED_RUNS = 4
#: The self-contained HTML page written next to report.md.
REPORT_HTML = 'report.html'
#: Distributions whose version the report names.
_DISTRIBUTIONS = ('seft_ros', 'seft_msgs_py', 'seft_plant_sim')


def software_versions() -> dict[str, str]:
    """Versions of the seft packages, Python and, where available, ``git describe``.

    Returns
    -------
    dict of str to str
        ``{'seft_ros': '0.1.0', 'seft_msgs_py': ..., 'seft_plant_sim': ..., 'python':
        '3.11.x', 'git': 'c44bed9-dirty'}``; a package that is not installed is 'not
        installed', and 'git' is absent when the sources are not in a git work tree or git
        is missing (never an error).
    """
    from importlib import metadata
    import platform
    import subprocess

    out = {}
    for name in _DISTRIBUTIONS:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = 'not installed'
    out['python'] = platform.python_version()
    try:
        proc = subprocess.run(['git', 'describe', '--always', '--dirty', '--tags'],
                              cwd=Path(__file__).resolve().parent, capture_output=True,
                              text=True, timeout=5)
        if proc.returncode == 0 and proc.stdout.strip():
            out['git'] = proc.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    return out


def _criteria_markdown(runs: list[RunData], entries: list[dict[str, Any]],
                       comparisons: list[RunComparison],
                       numbers: list[int] | None = None) -> list[str]:
    """The table of the RTHS benchmark's criteria, one row per run."""
    from seft_ros.analysis.criteria import BENCHMARK_J1_LAG_SAMPLES

    j1_window = comparisons[0].criteria.j1_max_lag_s if comparisons[0].criteria else math.nan
    lines = [
        '## Evaluation criteria (RTHS benchmark)',
        '',
        'The criteria of the RTHS benchmark control problem (Silva, Gomez, Maghareh, Dyke and '
        'Spencer 2020, Mech. Syst. Signal Process. 135, 106381), for the force loop and the '
        "one-storey response. J1: the lag, in whole samples, that maximises the "
        'cross-correlation of the load-cell force with the reference force commanded; the '
        f'search spans 0-{_fmt(j1_window, "g", 1e3)} ms (the benchmark: 0-'
        f'{BENCHMARK_J1_LAG_SAMPLES} samples). J2 = 100 std(f_m - f_r) / std(f_r) and J3 = 100 '
        'max|f_m - f_r| / max|f_r|: force tracking. J4 = 100 std(x - x_ref) / std(x_ref) '
        'and J5 = 100 max|x - x_ref| / max|x_ref|: the displacement against the analytical '
        'reference. J2-J5 compare the signals as recorded (a lag counts as error) and use the '
        "standard deviation, as the benchmark does, not the RMS. The benchmark's J6-J9 are "
        'J4-J5 of its other storeys and do not apply to one degree of freedom. NRMS columns: '
        "rms(test - ref) / rms(ref) after removing one common lag, the displacement's (lag "
        'x), from every signal; NRMS x as recorded: without removing it. (The per-run tables '
        "also give each signal's NRMS after removing its own lag.)",
        '',
        '| run | alpha | rig | predictor | record | J1 [ms] | J2 [%] | J3 [%] | J4 [%] '
        '| J5 [%] | NRMS x [%] | NRMS a [%] | NRMS f [%] | NRMS x as recorded [%] '
        '| lag x [ms] | status |',
        '|---:|---:|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|',
    ]
    for j, (run, e) in enumerate(zip(runs, entries)):
        crit = e.get('criteria') or {}
        common = e.get('nrms_common_lag') or {}
        unshifted = e.get('nrms_unshifted') or {}
        lines.append(
            f"| {_number(numbers, j)} | {_alpha_text(e.get('alpha'))} | {e.get('rig') or 'n/a'} "
            f'| {_predictor(run)} | {_record(run)} | {_fmt(crit.get("J1"), ".1f")} | '
            + ' | '.join(_fmt(crit.get(k), '.2f') for k in ('J2', 'J3', 'J4', 'J5')) + ' | '
            + ' | '.join(_fmt(common.get(s), '.2f', 100)
                         for s in ('displacement', 'acceleration', 'force')) + ' | '
            + f"{_fmt(unshifted.get('displacement'), '.2f', 100)} | "
            f"{_fmt(e.get('lag_s'), '.2f', 1e3)} | {_entry_status(e)} |")
    lines.append('')
    return lines


def _value_text(value: Any) -> str:
    if isinstance(value, float):
        return f'{value:.6g}'
    return 'n/a' if value is None else str(value)


def _parameters_markdown(runs: list[RunData], numbers: list[int] | None = None,
                         named: bool = False) -> list[str]:
    """The runs' parameters (one table of the common values, one of those that differ) and
    the software versions; `named`: the table of common values names the runs (the study's
    among structure tests)."""
    from seft_msgs_py import parameters as schema

    def unit(name):
        try:
            u = schema.spec(name).unit
        except Exception:  # a parameter of an older or newer schema
            return ''
        return '' if u in ('', '-') else u

    names = list(dict.fromkeys(n for run in runs for n in run.params))
    texts = {n: [_value_text(run.params.get(n)) for run in runs] for n in names}
    common = [n for n in names if len(set(texts[n])) == 1]
    differ = [n for n in names if n not in common]
    versions = software_versions()
    lines = [
        '## Parameters and software',
        '',
        'Software: ' + ', '.join(f'{k} {v}' for k, v in versions.items()) + '.',
        '',
    ]
    if differ:
        lines += ['Parameters that differ between the runs:', '',
                  '| parameter | unit | '
                  + ' | '.join(f'run {_number(numbers, j)}' for j in range(len(runs)))
                  + ' |', '|---|---|' + '---:|' * len(runs)]
        lines += [f'| `{n}` | {unit(n)} | ' + ' | '.join(texts[n]) + ' |' for n in differ]
        lines.append('')
    whose = ('every run' if len(runs) > 1 else 'the run') if not named else (
        'run' + ('s ' if len(runs) > 1 else ' ')
        + ', '.join(str(_number(numbers, j)) for j in range(len(runs))))
    lines += [f'Parameters of {whose}:', '',
              '| parameter | unit | value |', '|---|---|---:|']
    lines += [f'| `{n}` | {unit(n)} | {texts[n][0]} |' for n in common]
    lines.append('')
    return lines


def plot_criteria_vs_alpha(entries: list[dict[str, Any]], path, *, title: str = '') -> Path:
    """Draw the criteria against alpha, one line per predictor (and rig and record), as PNG.

    Panels: J1 [ms], J2-J5 [%] (``criteria.CRITERIA``) and the displacement NRMS after
    removing the common lag [%]. Aborted runs are drawn with a cross (their criteria cover
    the samples before the abort). A percent axis is logarithmic when its values are > 0
    and span more than a factor of 20.

    Parameters
    ----------
    entries : list of dict
        Summary entries (``metrics.summary_entry``): ``alpha``, ``predictor``, ``rig``,
        ``record``, ``stable``, ``criteria``, ``nrms_common_lag``.
    path : str or Path
        Output PNG.
    title : str
        Figure title.

    Returns
    -------
    Path
    """
    path = Path(path)
    panels = (('J1', 'J1: force-loop delay [ms]', 1.0),
              ('J2', 'J2: force tracking, std [%]', 1.0),
              ('J3', 'J3: force tracking, peak [%]', 1.0),
              ('J4', 'J4: displacement, std [%]', 1.0),
              ('J5', 'J5: displacement, peak [%]', 1.0),
              ('nrms_x', 'NRMS x, common lag removed [%]', 100.0))

    def value(e, key):
        if key == 'nrms_x':
            v = (e.get('nrms_common_lag') or {}).get('displacement')
        else:
            v = (e.get('criteria') or {}).get(key)
        return v if isinstance(v, (int, float)) and math.isfinite(v) else None

    rigs = {e.get('rig') for e in entries}
    records = {e.get('record') for e in entries}
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for e in entries:
        groups.setdefault((e.get('predictor'), e.get('rig'), e.get('record')), []).append(e)
    rank = {p: i for i, p in enumerate(sorted(dict.fromkeys(k[0] for k in groups),
                                              key=lambda p: p != UNCOMPENSATED))}
    fig = Figure(figsize=(12.0, 6.4), layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 3).ravel()
    for ax, (key, label, factor) in zip(axes, panels):
        values = []
        for g, (group, members) in enumerate(sorted(groups.items(),
                                                    key=lambda kv: rank[kv[0][0]])):
            members = sorted((e for e in members if isinstance(e.get('alpha'), (int, float))),
                             key=lambda e: e['alpha'])
            name = str(group[0])
            if len(rigs) > 1:
                name += f', {group[1]}'
            if len(records) > 1:
                name += f', {group[2]}'
            color = f'C{g % 10}'
            xs = [e['alpha'] for e in members if value(e, key) is not None]
            ys = [factor * value(e, key) for e in members if value(e, key) is not None]
            values += ys
            ax.plot(xs, ys, color=color, marker='o', ms=4, lw=1.2, label=name)
            bad = [(e['alpha'], factor * value(e, key)) for e in members
                   if not e.get('stable') and value(e, key) is not None]
            if bad:
                ax.plot(*zip(*bad), ls='none', marker='x', ms=9, mew=2, color=color,
                        label=f'{name}: aborted')
        if key != 'J1' and values and min(values) > 0 and max(values) > 20 * min(values):
            ax.set_yscale('log')
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f'{v:g}'))
        ax.set_title(label, fontsize=9)
        ax.set_xlabel('alpha')
        ax.grid(True, which='both', lw=0.3, alpha=0.5)
    handles, names = axes[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, names, loc='outside lower center', ncols=min(len(handles), 6),
                   fontsize=8)
    _suptitle(fig, title or 'Evaluation criteria against alpha (Silva et al. 2020)')
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI)
    return path


def plot_runs_compared(runs: list[RunData], comparisons: list[RunComparison], path, *,
                       labels: list[str] | None = None, title: str = '') -> Path:
    """Runs of one record side by side: time histories and their differences to the reference.

    Rows: displacement [mm], force [N], acceleration [m/s^2]. Columns: the runs and their
    references in a ``ZOOM_WINDOW_S`` window around the first run's reference displacement
    peak; the difference test - reference over the whole record; the same difference in the
    window. The runs are aligned by sample: sample k of every run is the record's sample k
    (no lag removed), so the differences hold the lag error that J4 and J5 measure.

    Parameters
    ----------
    runs : list of RunData
        Runs of the same record and dt (two predictors, two alphas, a repeat run).
    comparisons : list of RunComparison
        Their comparisons (same order), which carry the reference responses.
    path : str or Path
        Output PNG.
    labels : list of str, optional
        Legend label per run (default ``run <j>: <predictor>, alpha = <alpha>``).
    title : str
        Figure title.

    Returns
    -------
    Path

    Raises
    ------
    ParameterError
        If `runs` and `comparisons` differ in length or are empty.
    """
    if not runs or len(runs) != len(comparisons):
        raise ParameterError(f'plot_runs_compared: {len(runs)} runs and {len(comparisons)} '
                             'comparisons; expected the same number, at least one')
    path = Path(path)
    labels = labels or [f'run {j + 1}: {_predictor(r)}, '
                        f'alpha = {_alpha_text(r.params.get("alpha"))}'
                        for j, r in enumerate(runs)]
    window = _zoom_window(runs[0], comparisons[0])
    fig = Figure(figsize=(13.0, 8.0), layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(SIGNALS), 3, sharex='col')
    drawn_refs: dict[Any, bool] = {}
    for j, (run, comparison) in enumerate(zip(runs, comparisons)):
        n = run.n_steps
        t = np.asarray(run.time_s, dtype=float)
        keep = (t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)
        color = f'C{j % 10}'
        alpha = run.params.get('alpha')
        for i, name in enumerate(SIGNALS):
            _, _, factor = _DISPLAY[name]
            test = np.asarray(run.signal(name), dtype=float)[:n] * factor
            ref = comparison.reference.signal(name)[:n] * factor
            axes[i, 0].plot(t[keep], test[keep], color=color, lw=0.9,
                            label=labels[j] if i == 0 else None)
            if (alpha, i) not in drawn_refs:
                drawn_refs[(alpha, i)] = True
                # each alpha's reference a style of its own (two black dashed references
                # could not be told apart; a new user, session 36)
                k = list(dict.fromkeys(a for a, _ in drawn_refs)).index(alpha)
                style = _REFERENCE_STYLES[k % len(_REFERENCE_STYLES)]
                axes[i, 0].plot(t[keep], ref[keep], lw=1.0, **style,
                                label=f'reference, alpha = {_alpha_text(alpha)}'
                                if i == 0 else None)
            diff = test - ref
            td, yd = _decimate(t, diff)
            axes[i, 1].plot(td, yd, color=color, lw=0.7)
            axes[i, 2].plot(t[keep], diff[keep], color=color, lw=0.9)
    for i, name in enumerate(SIGNALS):
        ylabel = _DISPLAY[name][0]
        axes[i, 0].set_ylabel(ylabel)
        axes[i, 1].set_ylabel(ylabel.replace(name, 'test - reference'))
        for ax in axes[i]:
            ax.grid(True, lw=0.3, alpha=0.5)
        axes[i, 0].set_xlim(*window)
        axes[i, 2].set_xlim(*window)
    axes[0, 0].set_title(f'time histories ({ZOOM_WINDOW_S:g} s around the reference peak)',
                         fontsize=9)
    axes[0, 1].set_title('test - reference, whole record', fontsize=9)
    axes[0, 2].set_title('test - reference, zoom', fontsize=9)
    for ax in axes[-1]:
        ax.set_xlabel('time [s]')
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc='outside lower center', ncols=min(len(handles), 4),
               fontsize=8)
    if title:
        _suptitle(fig, title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI)
    return path


def _same_record(runs: list[RunData]) -> bool:
    """Whether the runs can be drawn on one time axis: one record and one dt."""
    return len({_record(r) for r in runs}) == 1 and len({r.params.get('dt') for r in runs}) == 1


def _write_html(markdown: str, out_dir: Path, title: str) -> Path:
    from seft_ros.analysis.htmlreport import markdown_to_html

    path = out_dir / REPORT_HTML
    path.write_text(markdown_to_html(markdown, base_dir=out_dir, title=title), encoding='utf-8')
    return path


# -- structure tests: per degree of freedom ---------------------------------------------------

#: Time histories of structure run i, one row per degree of freedom.
STRUCTURE_PNG = 'structure_run_{index}.png'
#: Hysteresis loops of the hysteretic rigs of structure run i.
STRUCTURE_HYSTERESIS_PNG = 'hysteresis_run_{index}.png'

_DOF_COLUMNS = (('displacement', 'displacement [mm]', 1e3),
                ('floor_acceleration', 'floor acceleration [m/s$^2$]', 1.0),
                ('interface_force', 'interface force [N]', 1.0))


def _pct(value) -> str:
    return '–' if value is None or not np.isfinite(value) else f'{100 * value:.2f} %'


def _num(value, spec='.3f') -> str:
    return '–' if value is None or not np.isfinite(value) else format(value, spec)


def _dof_rig(rig: str | None) -> str:
    """How a DOF's rig is named in a table: its rig, ``computational`` without one."""
    return 'computational' if rig is None else rig_label(rig)


def plot_structure_time_histories(run: RunData, comparison: RunComparison, path, *,
                                  title: str = '') -> Path:
    """Test against reference per degree of freedom, and save a PNG.

    Rows: the DOFs; columns: displacement [mm], floor acceleration [m/s^2] and, at a
    physical DOF, the interface force [N] (the rig's load cell against the force the
    reference specimen carries); the difference test - reference in grey.

    Parameters
    ----------
    run : RunData
        The run.
    comparison : RunComparison
        Its comparison (:func:`~seft_ros.analysis.metrics.compare_run`), which carries the
        whole structure's reference.
    path : str or Path
        Output PNG.
    title : str
        Figure title.

    Returns
    -------
    Path
        The written file.
    """
    n = comparison.n_steps
    t = np.asarray(run.time_s, dtype=float)[:n]
    test = dof_signals(run)
    ref = comparison.structure_reference
    refs = {'displacement': ref.displacement_m,
            'floor_acceleration': ref.absolute_acceleration_m_s2}
    dofs = comparison.dofs
    fig = Figure(figsize=(13, 2.4 * len(dofs) + 0.8), layout='tight')   # plot_time_histories'
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(dofs), 3, squeeze=False, sharex=True)
    for row, d in enumerate(dofs):
        for col, (name, label, factor) in enumerate(_DOF_COLUMNS):
            ax = axes[row, col]
            if name == 'interface_force':
                if d.rig is None:
                    ax.set_axis_off()
                    continue
                r = ref.interface_force_N[:n, ref.rigs.index(d.rig)]
            else:
                r = refs[name][:n, row]
            y = test[d.dof][name][:n]
            ax.plot(*_decimate(t, r * factor), color='k', lw=1.0, label='reference')
            ax.plot(*_decimate(t, y * factor), color='tab:red', lw=0.8, ls='--', label='test')
            diff = (y - r) * factor
            good = np.isfinite(diff)
            ax.plot(*_decimate(t[good], diff[good]), color='0.6', lw=0.6, label='difference')
            c = d.signal(name)
            ax.set_title(f'{d.dof}' + (f' (rig {rig_label(d.rig)})' if d.rig is not None
                                       else ' (computational)')
                         + f': NRMS {_pct(c.nrms)}', fontsize=9)
            ax.set_ylabel(label, fontsize=8)
            ax.grid(True, alpha=0.3)
            if not run.stable and run.unstable_at_s is not None:
                ax.axvline(float(run.unstable_at_s), color='tab:red', lw=0.8, ls=':',
                           label=f'{_ended(run)} at t = {float(run.unstable_at_s):.3f} s')
            if row == 0 and col == 0:
                ax.legend(fontsize=7, loc='upper right')
    # each column's lowest drawn panel carries the time axis (the interface force's column
    # ends above a computational DOF's empty panel: it had none; a new user, session 36)
    for col in range(axes.shape[1]):
        shown = [ax for ax in axes[:, col] if ax.axison]
        if shown:
            shown[-1].tick_params(labelbottom=True)
            shown[-1].set_xlabel('time [s]')
    if title:
        aborted = (f' (aborted at t = {float(run.unstable_at_s):.3f} s)'
                   if not run.stable and run.unstable_at_s is not None else '')
        _suptitle(fig, title + aborted)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def _matrix_table(label: str, dofs, matrix) -> list[str]:
    """A matrix as a table: a row and a column per DOF (an HTML table in report.html)."""
    lines = [f'| {label} | ' + ' | '.join(dofs) + ' |', '|---|' + '---:|' * len(dofs)]
    for dof, row in zip(dofs, np.asarray(matrix, dtype=float)):
        lines.append(f'| **{dof}** | ' + ' | '.join(f'{v:.6g}' for v in row) + ' |')
    return lines + ['']


def _structures_markdown(runs: list[RunData], numbers: list[int]) -> list[str]:
    """The structure of the runs (one section per distinct structure): DOFs, rigs, natural
    frequencies, ``M``, ``K``, ``C`` as matrices and the rig sections."""
    groups: dict[str, list[int]] = {}
    for run, number in zip(runs, numbers):
        groups.setdefault(str(run.params.get('structure')), []).append(number)
    lines = []
    for text, members in groups.items():
        run = runs[numbers.index(members[0])]
        s = structure_of(run.params)
        freqs = s.modes()[0]
        heading = ('## The structure' if len(groups) == 1 else
                   '## The structure of run' + ('s ' if len(members) > 1 else ' ')
                   + ', '.join(map(str, members)))
        lines += [heading, '',
                  f'Degrees of freedom {", ".join(s.dofs)}; physical: '
                  + ', '.join(f'{d} on rig {r}' for d, r in s.physical.items())
                  + '; natural frequencies ' + ', '.join(f'{f:.3g}' for f in freqs) + ' Hz.',
                  '']
        lines += _matrix_table('M [kg]', s.dofs, s.mass_kg)
        lines += _matrix_table('K [N/m]', s.dofs, s.stiffness_N_per_m)
        lines += _matrix_table('C [N s/m]', s.dofs, s.damping_N_s_per_m)
        if any(s.rigs.values()):
            lines += ['Rig sections: ' + '; '.join(
                f'{r}: ' + ', '.join(f'{k}={v!r}' for k, v in sorted(vals.items()))
                for r, vals in s.rigs.items() if vals) + '.', '']
    return lines


def _structure_run_markdown(index: int, run: RunData, comparison: RunComparison,
                            entry: dict, png: Path,
                            hysteresis: Path | None) -> list[str]:
    """A structure run's section: outcome, the per-DOF, per-link and per-rig tables, the
    figure of the time histories and, with a hysteretic rig, its hysteresis loops."""
    p = run.params
    flags = entry.get('flags') or []
    state = ('stable' if run.stable and not flags else
             '**stable, flagged** (the run may have lost accuracy, as a lab sees it without '
             'the reference)' if run.stable else
             f'**aborted** at {_num(run.unstable_at_s)} s: {run.abort_reason}')
    lines = [f'## Run {index}: predictor {p.get("predictor", "n/a")}, builders '
             f'{p.get("structure_builders", "central")}, {p.get("mode", "lockstep")}', '',
             f'Record {entry["record"]}, {comparison.n_steps} steps of {p["dt"]} s; {state}. '
             f'Reference: {comparison.structure_reference.method}.', '']
    recording = run.extra.get('recording') or {}
    if recording.get('end') in RECORDING_CUT_SHORT:
        lines += [f'- **recording {_recording_end(recording)}**: {recording.get("note")}']
    elif recording.get('gap_at_step') is not None:
        lines += [f'- **recording with a gap**: {recording.get("note")}']
    lines += _mismatch_lines(run)
    if run.stable:
        lines += [f'- flagged: {flag}' for flag in flags]
    lines += _range_markdown(run)
    if lines[-1]:
        lines.append('')
    lines += ["NRMS [%] of each signal after removing its own lag (the summary table's and the "
              "console's), then after removing its degree of freedom's displacement lag (lag x, "
              'the common lag: a lag of its own can hide a phase error) and as recorded.', '',
              '| dof | rig | NRMS x own / as recorded | NRMS ẍ own / common / as recorded | '
              'NRMS floor ẍ own / common / as recorded | NRMS force own / common / as recorded '
              '| peak x | peak floor ẍ | peak force | lag x [ms] |',
              '|---|---|---|---|---|---|---|---|---|---|']

    def pct(*values):
        return ' / '.join('–' if v is None or not np.isfinite(v) else f'{100 * v:.2f}'
                          for v in values)

    def three(c):
        return '–' if c is None else pct(c.nrms, c.nrms_common_lag, c.nrms_unshifted)

    for d in comparison.dofs:
        f = d.interface_force
        x = d.displacement
        lines.append(
            f'| {d.dof} | {_dof_rig(d.rig)} | {pct(x.nrms, x.nrms_unshifted)} | '
            f'{three(d.acceleration)} | {three(d.floor_acceleration)} | {three(f)} | '
            f'{_num(x.peak_ratio)} | {_num(d.floor_acceleration.peak_ratio)} | '
            f'{_num(f.peak_ratio) if f else "–"} | {_num(1e3 * x.lag_s, ".2f")} |')
    lines += ['', '| link (story drift) | NRMS | peak ratio | peak test [mm] | '
              'peak reference [mm] |', '|---|---|---|---|---|']
    for lk in comparison.links:
        lines.append(f'| {lk.name} | {_pct(lk.drift.nrms)} | {_num(lk.drift.peak_ratio)} | '
                     f'{_num(1e3 * lk.drift.peak_test, ".2f")} | '
                     f'{_num(1e3 * lk.drift.peak_reference, ".2f")} |')
    lines += ['', '| rig | rig model | specimen | J1 [ms] | J2 [%] | J3 [%] | J4 [%] | '
              'J5 [%] |', '|---|---|---|---|---|---|---|---|']
    for rig, info in entry['rigs'].items():
        c = info['criteria']
        lines.append(f'| {rig_label(rig)} | {info["rig_model"]} | {info["specimen_model"]} | '
                     + ' | '.join(_num(c.get(k), '.2f') for k in ('J1', 'J2', 'J3', 'J4', 'J5'))
                     + ' |')
    lines += ['', f'![Run {index}: time histories per degree of freedom]({png.name})', '']
    if hysteresis is not None:
        for rig, info in entry['rigs'].items():
            block = info.get('nonlinear')
            if block:
                res = block['residual_displacement_m']
                lines.append(
                    f'- rig {rig_label(rig)}, nonlinear specimen ({block["specimen_model"]}): '
                    f'residual displacement test {_fmt(res["test"], ".2f", 1e3)} mm, reference '
                    f'{_fmt(res["reference"], ".2f", 1e3)} mm; displacement NRMS '
                    f'{_fmt(block["nrms_displacement"], ".2f", 100)} %, '
                    f'{_fmt(block["nrms_displacement_residual_removed"], ".2f", 100)} % with '
                    f'the drift (< {block["drift_cutoff_hz"]:g} Hz) removed')
        lines += ['', f'![Run {index}: hysteresis loops and drift of the yielding rigs]'
                  f'({hysteresis.name})', '',
                  f'**Hysteresis, run {index}.** Per hysteretic rig, top: the restoring force '
                  'of its member against its displacement, the test (red: f_m - m a - c v) '
                  'over the reference (black: the Bouc-Wen f_s(x, z) of the whole structure '
                  'integrated with the yielding member); bottom: the displacement of test and '
                  'reference (thin), their drifts (thick) and the residual displacements.', '']
    for kind in model_kinds():
        markdown = getattr(model_plugin(kind), 'markdown', None) if kind in entry else None
        if markdown is not None:
            # a plug-in model's section (OpenSees: step times, its members' hysteresis)
            lines += markdown(index, run, entry, png.parent,
                              reference=comparison.structure_reference)
    return lines


def _structure_report(runs: list[RunData], comparisons: list[RunComparison],
                      entries: list[dict[str, Any]], numbers: list[int], out_dir: Path,
                      title: str, *, heading: bool) -> tuple[list[str], dict, dict]:
    """The structure tests' part of the report: the summary table, the structures, and one
    section per run (:func:`_structure_run_markdown`, timing). Returns the lines and the
    figures ``({number: time histories}, {number: hysteresis})``."""
    dofs = list(dict.fromkeys(d for e in entries for d in e['structure']['dofs']))
    lines = ['## Structure tests', ''] if heading else []
    # the reference of a model of a plug-in kind (OpenSees) is the model's own analysis
    kinds = sorted({structure_of(r.params).model_kind for r in runs} - {None})
    matrix = any(structure_of(r.params).model_kind is None for r in runs)
    how = ([("the whole structure M x'' + C x' + K x = -M iota xg'' simulated from the "
             'recorded ground motion (first-order hold, stepped by SLICOT TF01MD; with a '
             'yielding member, scipy.integrate.solve_ivp with the Bouc-Wen member)')]
           if matrix else []) + [
        f"{'an' if k[0] in 'aeio' else 'a'} {k} model's own transient analysis of the whole "
        'model from the recorded ground motion' for k in kinds]
    lines += [f"A structure test against its analytical reference: {'; or '.join(how)}. "
              'Per degree of freedom: '
              'displacement relative to the ground, '
              'relative and floor (absolute) acceleration, and at a physical degree of freedom '
              "the interface force (the rig's load cell against the force the reference "
              'specimen carries); per link, its deformation (story drift); per rig, the RTHS '
              "benchmark's criteria J1-J5. NRMS = rms(test - reference) / rms(reference) "
              "after advancing the test by its own lag; a computational degree of freedom's "
              'test values are the state the builder integrated.', '',
              # the verdict and every signal's worst, not 'stable' and x alone: a run flagged
              # at 37-55 % of acceleration read 'yes' beside its 5.8 % of x (a new user,
              # session 39)
              '| run | predictor | verdict | worst NRMS x | a | floor a | f | '
              + ' | '.join(f'NRMS x {d}' for d in dofs) + ' |',
              '|---|---|---|---|---|---|---|' + '---|' * len(dofs)]
    for number, entry in zip(numbers, entries):
        worst = entry['worst_nrms']
        said = entry.get('verdict') or ('stable' if entry['stable'] else 'aborted')
        lines.append(f'| {number} | {entry["predictor"]} | '
                     f'{said if said == "stable" else f"**{said}**"} | '
                     + ' | '.join(_pct(worst.get(s)) for s in (
                         'displacement', 'acceleration', 'floor_acceleration',
                         'interface_force')) + ' | ' + ' | '.join(
                         _pct(((entry['dofs'].get(d) or {}).get('displacement') or {})
                              .get('nrms')) for d in dofs) + ' |')
    lines.append('')
    lines += _structures_markdown(runs, numbers)
    figures, loops = {}, {}
    for number, run, c, entry in zip(numbers, runs, comparisons, entries):
        png = plot_structure_time_histories(
            run, c, out_dir / STRUCTURE_PNG.format(index=number),
            title=f'{title}: run {number} ({run.params.get("predictor")})')
        figures[number] = png
        hysteretic = [r for r in c.rigs if is_nonlinear(run.rigs[r].params)]
        if hysteretic:
            loops[number] = plot_hysteresis(
                [run.rig_view(r) for r in hysteretic], [c.rigs[r] for r in hysteretic],
                out_dir / STRUCTURE_HYSTERESIS_PNG.format(index=number),
                title=f'{title}: run {number}, hysteresis loops and drift',
                labels=[f'rig {rig_label(r)}' for r in hysteretic])
        lines += _structure_run_markdown(number, run, c, entry, png, loops.get(number))
        lines += _timing_markdown(number, run, out_dir, title)
    return lines, figures, loops


def write_report(runs: list[RunData], out_dir, *, title: str = 'seft comparison',
                 high_frequency_cutoff_hz: float = HIGH_FREQUENCY_CUTOFF_HZ,
                 not_compared: tuple[str, ...] = ()) -> ReportPaths:
    """Compare runs with the reference analysis and write summary.json, report.md and figures.

    Any runs, the reference study's tests and structure tests alike, in one report: each
    run is compared with its whole structure's reference
    (:func:`~seft_ros.analysis.metrics.compare_run`, per rig and per degree of freedom), and
    ``summary.json`` holds one :func:`~seft_ros.analysis.metrics.summary_entry` per run in the
    given order, one layout for every run, strict JSON (NaN/inf as null). A run read from a
    bag with node parameters (``run.extra['node_params']``) has its
    ``run.extra['param_sources']`` in the entry as ``"parameter_sources"``
    (``{parameter: node}``). ``report.html`` is report.md as one self-contained HTML page,
    every figure embedded as a base64 ``data:`` URI (``htmlreport.markdown_to_html``).

    **The study's tests** (``RunData.is_study``: one rig, the one-DOF structure) get, in
    report.md after the introduction:

    - the table of the RTHS benchmark's criteria J1-J5 (``criteria``) with the NRMS after
      removing the common lag, one row per run; with several alphas
      ``criteria_vs_alpha.png`` (:func:`plot_criteria_vs_alpha`); for 2 to
      ``MAX_COMPARED_RUNS`` runs of one record ``runs_compared.png``
      (:func:`plot_runs_compared`); at the end the parameters (common and differing) and
      the software versions (:func:`software_versions`);
    - per run, the parameters that matter (alpha, rig, predictor, record, dt, tau), for a
      run read from a bag with node parameters the node each key value was taken from
      (``parameters: alpha, predictor from reference_force_builder; mass, ... from rig;
      ...``) and a marked warning listing ``run.extra['parameter_mismatches']``, the shared
      parameters on which the nodes disagreed; stable or aborted (time and reason) and a
      table signal | peak test | peak ref | peak ratio | lag [ms] | NRMS [%] (own lag) |
      NRMS common lag [%] | NRMS as recorded [%]; links to the figures;
    - one predictor: ``time_histories.png``, test versus reference, rows displacement [mm],
      force [N], acceleration [m/s^2], one column per run (as the reference study's
      Figure 6), and ``time_histories_zoom.png``, the same in a 2 s window around each
      reference's displacement peak, where the lag and the high-frequency vibration show;
    - several predictors: those two figures per predictor
      (``time_histories_<predictor>.png``, ``time_histories_<predictor>_zoom.png``), and in
      addition, in report.md, an "Uncompensated vs best compensated" table (one row per
      alpha and rig, ``metrics.best_runs``) and a cross-predictor section: per alpha and rig
      a table with a row per run (NRMS and peak ratio of displacement, acceleration and
      force, high-frequency fraction of the measured and the reference force, stable or
      aborted) and a figure ``predictors_alpha_<alpha>.png`` (``_<rig>``, ``_<record>``
      appended when they vary) of the reference versus the uncompensated and the
      compensated runs (:func:`plot_predictor_comparison`, as the reference study's
      Figures 7-8);
    - runs with a nonlinear specimen (``metrics.is_nonlinear``): their summary entries carry
      ``"nonlinear"`` (``metrics.summary_entry``); report.md has a section "Nonlinear
      specimen: residual displacement and hysteresis" with a table (displacement NRMS as it
      is and with each signal's drift removed, peak and residual displacements of test and
      reference) and, per predictor, ``hysteresis.png`` (one predictor among them) or
      ``hysteresis_<predictor>.png`` (:func:`plot_hysteresis`) with a caption; each such
      run's section names its residual displacements and both NRMS.

    **Structure tests** (the other runs; after the study's, under "Structure tests" when
    both are in the report) get a table of the worst and per-DOF displacement NRMS, the
    structure (DOFs, rigs, natural frequencies, ``M``, ``K``, ``C`` as tables) and per run
    the tables per DOF, per link (story drift) and per rig (J1-J5), the figure of the time
    histories per DOF (``structure_run_<i>.png``, :func:`plot_structure_time_histories`)
    and, with a hysteretic rig, its hysteresis loops (``hysteresis_run_<i>.png``).

    A real-time run's section has its timing (tables and ``timing_run_<i>.png``); a run with
    online estimates their figure (``estimates_run_<i>.png``). Runs are numbered in the
    given order throughout.

    Parameters
    ----------
    runs : list of RunData
        The runs, in report (column) order; at least one.
    out_dir : str or Path
        Output directory (created if needed; existing files are overwritten).
    title : str
        Title of the report and the figures.
    high_frequency_cutoff_hz : float > 0
        Cutoff of the high-frequency content of the force [Hz], below every run's Nyquist
        frequency.
    not_compared : tuple of str
        One line per run that was asked for but could not be read (``seft compare`` of a
        folder: a run without its bag, an unreadable bag), listed under the title.

    Returns
    -------
    ReportPaths

    Raises
    ------
    ParameterError
        If `runs` is empty, a run's parameters are missing or out of range, or the cutoff is
        not below a run's Nyquist frequency.

    References
    ----------
    N. Nakata and S. Combs, Substructure Effective Force Testing, Sec. 4 (Figure 6) and
    Sec. 5 (Figures 7 and 8).
    """
    runs = list(runs)
    if not runs:
        raise ParameterError('runs: expected at least one run')
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    comparisons = [compare_run(run, high_frequency_cutoff_hz=high_frequency_cutoff_hz)
                   for run in runs]
    entries = [summary_entry(run, c) for run, c in zip(runs, comparisons)]
    for run, entry in zip(runs, entries):
        if run.extra.get('node_params') and run.extra.get('param_sources'):
            entry['parameter_sources'] = dict(run.extra['param_sources'])
    summary = write_summary_json(entries, out_dir / 'summary.json')
    study = [j for j, run in enumerate(runs) if run.is_study]
    others = [j for j in range(len(runs)) if j not in study]
    lines = [f'# {title}', '']
    if not_compared:
        lines += [f'- **not compared**: {line}' for line in not_compared] + ['']
    paths: dict[str, Any] = {}
    if study:
        part, paths = _study_report([runs[j] for j in study], [comparisons[j] for j in study],
                                    [entries[j] for j in study], [j + 1 for j in study],
                                    out_dir, title, high_frequency_cutoff_hz)
        lines += part
    structure_figures: dict[int, Path] = {}
    structure_loops: dict[int, Path] = {}
    if others:
        part, structure_figures, structure_loops = _structure_report(
            [runs[j] for j in others], [comparisons[j] for j in others],
            [entries[j] for j in others], [j + 1 for j in others], out_dir, title,
            heading=bool(study))
        lines += part
    if study:
        lines += _parameters_markdown([runs[j] for j in study], [j + 1 for j in study],
                                      named=bool(others))
    else:
        versions = software_versions()
        lines += ['## Software', '', ', '.join(f'{k} {v}' for k, v in versions.items()), '']
    report = out_dir / 'report.md'
    markdown = '\n'.join(lines)
    report.write_text(markdown, encoding='utf-8')
    return ReportPaths(out_dir=out_dir, summary_json=summary, report_md=report,
                       time_histories_png=paths.get('figure'), zoom_png=paths.get('zoom'),
                       predictor_time_histories=paths.get('grids', {}),
                       predictor_comparisons=paths.get('comparisons', {}),
                       report_html=_write_html(markdown, out_dir, title),
                       criteria_png=paths.get('criteria'), runs_png=paths.get('runs'),
                       hysteresis=paths.get('hysteresis', {}),
                       structure_time_histories=structure_figures,
                       structure_hysteresis=structure_loops)


def _study_report(runs: list[RunData], comparisons: list[RunComparison],
                  entries: list[dict[str, Any]], numbers: list[int], out_dir: Path,
                  title: str, high_frequency_cutoff_hz: float) -> tuple[list[str], dict]:
    """The study's tests' part of the report (:func:`write_report`): its lines and figures
    (``{'figure', 'zoom', 'grids', 'comparisons', 'criteria', 'runs', 'hysteresis'}``)."""
    predictors = _predictor_order(runs)
    lines = [
        'Test versus the analytical reference: the whole structure '
        "(1+alpha) m x'' + c x' + k x = -(1+alpha) m xg'' (paper Eq. 2.1) simulated from "
        'the recorded ground motion. The reference force is the member force '
        "m x'' + c x' + k x (paper Eq. 2.4), compared with the load-cell force. "
        "Peaks are max |x| over the run's samples; the lag is the cross-correlation estimate "
        '(positive: the test lags); NRMS = rms(test - reference) / rms(reference) after '
        'advancing the test by its lag, over the samples both share.',
        '',
    ]
    lines += _criteria_markdown(runs, entries, comparisons, numbers)
    out: dict[str, Any] = {}
    if len({e.get('alpha') for e in entries}) > 1:
        out['criteria'] = plot_criteria_vs_alpha(entries, out_dir / CRITERIA_PNG,
                                                 title=f'{title}: criteria against alpha')
        lines += ['![Evaluation criteria against alpha, per predictor]'
                  f'({out["criteria"].name})', '']
    if 1 < len(runs) <= MAX_COMPARED_RUNS and _same_record(runs):
        labels = [f'run {number}: {_predictor(r)}, '
                  f'alpha = {_alpha_text(r.params.get("alpha"))}'
                  for number, r in zip(numbers, runs)]
        out['runs'] = plot_runs_compared(runs, comparisons, out_dir / RUNS_COMPARED_PNG,
                                         labels=labels,
                                         title=f'{title}: the runs side by side, record '
                                               f'{_record(runs[0])}')
        lines += ['The runs side by side, aligned by sample (no lag removed), with their '
                  'differences to the reference:', '',
                  f'![Runs side by side and their differences]({out["runs"].name})', '']
    if len(predictors) == 1:
        out['figure'] = plot_time_histories(runs, comparisons, out_dir / TIME_HISTORIES_PNG,
                                            title=title)
        out['zoom'] = plot_time_histories(runs, comparisons, out_dir / ZOOM_PNG, title=title,
                                          zoom=True)
        lines += [f'![Time histories]({out["figure"].name})', '',
                  f'![Zoom around the reference displacement peak]({out["zoom"].name})', '']
    else:
        files = _comparison_files(runs)
        out['comparisons'] = {}
        for key, indices in _groups(runs, _figure_key).items():
            out['comparisons'][key] = plot_predictor_comparison(
                [runs[j] for j in indices], [comparisons[j] for j in indices],
                out_dir / files[key], labels=_comparison_labels(runs, indices, numbers),
                title=f'{title}: alpha = {_alpha_text(key[0])}, rig {key[1] or "n/a"}, '
                      f'record {key[2]}: reference vs uncompensated vs compensated')
        lines += _best_markdown(entries)
        lines += _cross_predictor_markdown(runs, entries, out['comparisons'],
                                           high_frequency_cutoff_hz, numbers)
        lines += ['## Time histories per predictor', '']
        out['grids'] = {}
        for name in predictors:
            indices = [j for j, run in enumerate(runs) if _predictor(run) == name]
            sub_runs = [runs[j] for j in indices]
            sub_comparisons = [comparisons[j] for j in indices]
            stem = _safe_name(name)
            grid = plot_time_histories(
                sub_runs, sub_comparisons,
                out_dir / PREDICTOR_TIME_HISTORIES_PNG.format(predictor=stem),
                title=f'{title}: predictor {name}')
            grid_zoom = plot_time_histories(
                sub_runs, sub_comparisons, out_dir / PREDICTOR_ZOOM_PNG.format(predictor=stem),
                title=f'{title}: predictor {name}', zoom=True)
            out['grids'][name] = (grid, grid_zoom)
            lines += [f'### Predictor {name}', '', f'![Time histories, {name}]({grid.name})',
                      '', f'![Zoom around the reference displacement peak, {name}]'
                      f'({grid_zoom.name})', '']
    nonlinear_lines, out['hysteresis'] = _nonlinear_markdown(runs, entries, comparisons,
                                                             out_dir, title, numbers)
    lines += nonlinear_lines
    for index, run, comparison in zip(numbers, runs, comparisons):
        lines += _run_markdown(index, run, comparison)
        lines += _timing_markdown(index, run, out_dir, title)
        lines += _estimates_markdown(index, run, out_dir, title)
    return lines, out
