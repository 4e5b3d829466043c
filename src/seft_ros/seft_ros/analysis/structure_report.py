"""The report of structure tests: summary.json, report.md, report.html and figures, per degree
of freedom (no rclpy, no pyplot: Agg canvas on ``matplotlib.figure.Figure``).

What it holds per run (:mod:`seft_ros.analysis.structure_metrics`): per degree of freedom the
NRMS error and peak ratio of displacement, relative and floor acceleration and, at a physical
one, the interface force; the story drifts; the RTHS benchmark's criteria J1-J5 per rig; a
figure of the time histories per degree of freedom, test against reference with their
difference; in real time the timing per node.
"""

from pathlib import Path

import numpy as np

from seft_msgs_py.errors import ParameterError
from seft_ros.analysis.rundata import RunData
from seft_ros.analysis.structure_metrics import (
    StructureComparison,
    compare_structure,
    dof_signals,
    structure_summary_entry,
)

__all__ = ['write_structure_report', 'plot_structure_time_histories', 'STRUCTURE_PNG']

#: Time histories of run i, one row per degree of freedom.
STRUCTURE_PNG = 'structure_run_{index}.png'

_COLUMNS = (('displacement', 'displacement [mm]', 1e3),
            ('floor_acceleration', 'floor acceleration [m/s$^2$]', 1.0),
            ('interface_force', 'interface force [N]', 1.0))


def _pct(value) -> str:
    return '–' if value is None or not np.isfinite(value) else f'{100 * value:.2f} %'


def _num(value, spec='.3f') -> str:
    return '–' if value is None or not np.isfinite(value) else format(value, spec)


def plot_structure_time_histories(run: RunData, comparison: StructureComparison,
                                  path, *, title: str = '') -> Path:
    """Test against reference per degree of freedom: rows the DOFs, columns displacement
    [mm], floor acceleration [m/s^2] and, at a physical DOF, the interface force [N]; the
    difference test - reference in grey. PNG at `path`.

    Returns
    -------
    Path
        The written file.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from seft_ros.analysis.report import _decimate
    n = comparison.n_steps
    t = np.asarray(run.time_s, dtype=float)[:n]
    test = dof_signals(run)
    ref = comparison.reference
    refs = {'displacement': ref.displacement_m, 'floor_acceleration':
            ref.absolute_acceleration_m_s2}
    dofs = comparison.dofs
    fig = Figure(figsize=(13, 2.4 * len(dofs) + 0.8), layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(dofs), 3, squeeze=False, sharex=True)
    physical = 0
    for row, d in enumerate(dofs):
        for col, (name, label, factor) in enumerate(_COLUMNS):
            ax = axes[row, col]
            if name == 'interface_force':
                if d.rig is None:
                    ax.set_axis_off()
                    continue
                r = ref.interface_force_N[:n, physical]
            else:
                r = refs[name][:n, row]
            y = test[d.dof][name][:n]
            ax.plot(*_decimate(t, r * factor), color='k', lw=1.0, label='reference')
            ax.plot(*_decimate(t, y * factor), color='tab:red', lw=0.8, ls='--', label='test')
            diff = (y - r) * factor
            good = np.isfinite(diff)
            ax.plot(*_decimate(t[good], diff[good]), color='0.6', lw=0.6, label='difference')
            c = d.signal(name)
            ax.set_title(f'{d.dof}' + (f' (rig {d.rig})' if d.rig else ' (computational)')
                         + f': NRMS {_pct(c.nrms)}', fontsize=9)
            ax.set_ylabel(label, fontsize=8)
            ax.grid(True, alpha=0.3)
            if row == 0 and col == 0:
                ax.legend(fontsize=7, loc='upper right')
        if d.rig is not None:
            physical += 1
    for ax in axes[-1]:
        ax.set_xlabel('time [s]')
    if title:
        fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=100)
    return path


def _run_markdown(index: int, run: RunData, comparison: StructureComparison,
                  entry: dict, png: Path) -> list[str]:
    p = run.params
    state = ('stable' if run.stable else
             f'**aborted** at {_num(run.unstable_at_s)} s: {run.abort_reason}')
    lines = [f'## Run {index}: predictor {p["predictor"]}, builders '
             f'{p.get("structure_builders", "central")}, {p.get("mode", "lockstep")}', '',
             f'Record {entry["record"]}, {comparison.n_steps} steps of {p["dt"]} s; {state}.',
             '', '| dof | rig | NRMS x | NRMS ẍ | NRMS floor ẍ | NRMS force | peak x | '
             'peak floor ẍ | peak force | lag x [ms] |',
             '|---|---|---|---|---|---|---|---|---|---|']
    for d in comparison.dofs:
        f = d.interface_force
        lines.append(
            f'| {d.dof} | {d.rig or "computational"} | {_pct(d.displacement.nrms)} | '
            f'{_pct(d.acceleration.nrms)} | {_pct(d.floor_acceleration.nrms)} | '
            f'{_pct(f.nrms) if f else "–"} | {_num(d.displacement.peak_ratio)} | '
            f'{_num(d.floor_acceleration.peak_ratio)} | '
            f'{_num(f.peak_ratio) if f else "–"} | {_num(1e3 * d.displacement.lag_s, ".2f")} |')
    lines += ['', '| link (story drift) | NRMS | peak ratio | peak test [mm] | '
              'peak reference [mm] |', '|---|---|---|---|---|']
    for lk in comparison.links:
        lines.append(f'| {lk.name} | {_pct(lk.drift.nrms)} | {_num(lk.drift.peak_ratio)} | '
                     f'{_num(1e3 * lk.drift.peak_test, ".2f")} | '
                     f'{_num(1e3 * lk.drift.peak_reference, ".2f")} |')
    lines += ['', '| rig | rig model | J1 [ms] | J2 [%] | J3 [%] | J4 [%] | J5 [%] |',
              '|---|---|---|---|---|---|---|']
    for rig, info in entry['rigs'].items():
        c = info['criteria']
        lines.append(f'| {rig} | {info["rig_model"]} | '
                     + ' | '.join(_num(c.get(k), '.2f') for k in ('J1', 'J2', 'J3', 'J4', 'J5'))
                     + ' |')
    lines += ['', f'![Run {index}: time histories per degree of freedom]({png.name})', '']
    if 'opensees' in entry:
        # hook (issue 32): the model's step times and its members' hysteresis
        from seft_ros.opensees.report import opensees_markdown
        lines += opensees_markdown(index, run, entry, png.parent)
    timing = run.extra.get('timing')
    if timing:
        from seft_ros.analysis.timing import (
            link_markdown,
            link_summary,
            timing_figure,
            timing_table,
        )
        lines += [f'### Run {index}: timing (real time)', '', timing_table(timing), '']
        lines += link_markdown(link_summary(run.extra.get('link'), timing))
        data = run.extra.get('timing_data')
        if data:
            fig = timing_figure(data, png.parent / f'timing_run_{index}.png',
                                title=f'run {index}, timing')
            lines += [f'![Timing, run {index}]({fig.name})', '']
    return lines


def _structure_markdown(run: RunData) -> list[str]:
    from seft_ros.core.structure import Structure
    s = Structure.from_json(run.params['structure'])
    freqs = s.modes()[0]

    def matrix(m):
        return '<br>'.join(' '.join(f'{v:.6g}' for v in row) for row in np.asarray(m))
    lines = ['## The structure', '',
             f'Degrees of freedom {", ".join(s.dofs)}; physical: '
             + ', '.join(f'{d} on rig {r}' for d, r in s.physical.items())
             + '; natural frequencies ' + ', '.join(f'{f:.3g}' for f in freqs) + ' Hz.', '',
             '| M [kg] | K [N/m] | C [N s/m] |', '|---|---|---|',
             f'| {matrix(s.mass_kg)} | {matrix(s.stiffness_N_per_m)} | '
             f'{matrix(s.damping_N_s_per_m)} |', '']
    if any(s.rigs.values()):
        lines += ['Rig sections: ' + '; '.join(
            f'{r}: ' + ', '.join(f'{k}={v!r}' for k, v in sorted(vals.items()))
            for r, vals in s.rigs.items() if vals) + '.', '']
    return lines


def write_structure_report(runs: list[RunData], out_dir, *,
                           title: str = 'seft comparison'):
    """Compare structure runs with the whole structure's reference; write summary.json,
    report.md, report.html and the figures (module notes).

    Parameters
    ----------
    runs : list of RunData
        At least one, in report order.
    out_dir : str or Path
        Output directory (created if needed).
    title : str
        Title of the report and figures.

    Returns
    -------
    ReportPaths
        ``summary_json``, ``report_md``, ``report_html`` (the other figure fields None).

    Raises
    ------
    ParameterError
        No run, or a run without a structure.
    """
    from seft_ros.analysis.report import (
        ReportPaths,
        _write_html,
        software_versions,
        write_summary_json,
    )
    runs = list(runs)
    if not runs:
        raise ParameterError('runs: expected at least one run')
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    comparisons = [compare_structure(run) for run in runs]
    entries = [structure_summary_entry(run, c) for run, c in zip(runs, comparisons)]
    summary = write_summary_json(entries, out_dir / 'summary.json')
    lines = [f'# {title}', '',
             'A structure test against its analytical reference: the whole structure '
             "M x'' + C x' + K x = -M iota xg'' simulated from the recorded ground motion "
             '(scipy.signal.lsim). Per degree of freedom: displacement relative to the ground, '
             'relative and floor (absolute) acceleration, and at a physical degree of freedom '
             "the interface force (the rig's load cell against the force the reference "
             'specimen carries); per link, its deformation (story drift); per rig, the RTHS '
             "benchmark's criteria J1-J5. NRMS = rms(test - reference) / rms(reference) "
             "after advancing the test by its own lag; a computational degree of freedom's "
             'test values are the state the builder integrated.', '',
             '| run | predictor | stable | worst NRMS x | ' + ' | '.join(
                 f'NRMS x {d}' for d in entries[0]['structure']['dofs']) + ' |',
             '|---|---|---|---|' + '---|' * len(entries[0]['structure']['dofs'])]
    for i, entry in enumerate(entries, start=1):
        dofs = entry['structure']['dofs']
        lines.append(f'| {i} | {entry["predictor"]} | {"yes" if entry["stable"] else "**no**"}'
                     f' | {_pct(entry["nrms"]["displacement"])} | ' + ' | '.join(
                         _pct((entry['dofs'][d]['displacement'] or {}).get('nrms'))
                         for d in dofs) + ' |')
    lines.append('')
    lines += _structure_markdown(runs[0])
    for i, (run, c, entry) in enumerate(zip(runs, comparisons, entries), start=1):
        png = plot_structure_time_histories(run, c, out_dir / STRUCTURE_PNG.format(index=i),
                                            title=f'{title}: run {i} ({run.params["predictor"]})')
        lines += _run_markdown(i, run, c, entry, png)
    versions = software_versions()
    lines += ['## Software', '', ', '.join(f'{k} {v}' for k, v in versions.items()), '']
    markdown = '\n'.join(lines)
    report = out_dir / 'report.md'
    report.write_text(markdown, encoding='utf-8')
    return ReportPaths(out_dir=out_dir, summary_json=summary, report_md=report,
                       time_histories_png=None, zoom_png=None,
                       report_html=_write_html(markdown, out_dir, title))
