"""Outputs of ``seft identify``: ``identification.json``, Bode plots and a Markdown report.

The numbers come from :mod:`seft_ros.analysis.rig_identification`; this module only writes
them (matplotlib's Agg canvas, no display). A structure's report and parameter file are per
rig (:func:`write_identification` with ``rig_parameters``, :func:`write_rig_params_yaml`).
"""

import json
import math
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np
import yaml

from seft_msgs_py.parameters import identification_run
from seft_ros.analysis.rig_identification import MIN_COHERENCE, RunIdentification
from seft_ros.analysis.rundata import rig_label
from seft_ros.core.force_design import KANAI_TAJIMI_GROUND

__all__ = ['write_identification', 'write_params_yaml', 'write_rig_params_yaml',
           'SUMMARY_KEYS']

#: The top-level figures of ``identification.json`` (the first bag that gives each).
SUMMARY_KEYS = ('zero_hz', 'resonance_hz', 'crossover_hz', 'crossovers', 'phase_margin_deg',
                'phase_margin_hz', 'gain_margin', 'delay_ms', 'delay_xcorr_ms')



def _excitation(p) -> dict[str, Any]:
    """The identification run's excitation settings, its band's upper edge resolved (0: a
    fraction of the Nyquist frequency)."""
    out = {k: p.get(k) for k in ('excitation', 'excitation_input', 'excitation_amplitude',
                                 'excitation_band_low_hz', 'excitation_band_hz',
                                 'excitation_seed', 'duration_s')}
    if identification_run(p) and 'dt' in p:
        from seft_ros.core.excitation import excitation_band_hz
        out['excitation_band_hz'] = excitation_band_hz(p)[1]
    return out

def _clean(value):
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(float(value)) else float(value)
    if isinstance(value, np.integer):
        return int(value)
    return value


#: The decades of magnitude a Bode plot shows below its largest curve at most: a model's
#: zero near Nyquist (the hold's) dives to 1e-14 and squeezed the measured response into
#: the top strip (a new user, session 36).
MAGNITUDE_DECADES = 5.0


def _magnitude_limits(ax, measured: np.ndarray, curves) -> None:
    """The magnitude axis from half the measured response's least (finite, positive) to
    twice the largest curve's most, within :data:`MAGNITUDE_DECADES` of the top."""
    values = [np.abs(np.asarray(h))[np.isfinite(h)] for _, h, _ in curves]
    values = [v[v > 0] for v in values]
    top = max((float(v.max()) for v in values if v.size), default=0.0)
    m = np.abs(np.asarray(measured))
    m = m[np.isfinite(m) & (m > 0)]
    if not top > 0 or not m.size:
        return
    bottom = max(0.5 * float(m.min()), 2.0 * top * 10.0 ** -MAGNITUDE_DECADES)
    ax.set_ylim(bottom, 2.0 * top)


def _bode(ident: RunIdentification, path: Path, index: int) -> Path:
    """Magnitude, phase and coherence: measurement (H1), fit and the known model."""
    fr = ident.response
    f = fr.freqs_hz[1:]
    fig = Figure(figsize=(8, 8))
    FigureCanvasAgg(fig)
    ax_m, ax_p, ax_c = fig.subplots(3, 1, sharex=True,
                                    gridspec_kw={'height_ratios': [3, 3, 1.4]})
    curves = [('measured (H1)', fr.response[1:], dict(color='0.35', lw=1.0)),
              (f'fit, orders {ident.fit.orders}', ident.fit.response(f),
               dict(color='C0', lw=1.4))]
    if ident.model_response is not None:
        curves.append(('known model', ident.model_response[1:], dict(color='C3', lw=1.2,
                                                                     ls='--')))
    for label, h, style in curves:
        ax_m.loglog(f, np.abs(h), label=label, **style)
        ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(h))), **style)
    _magnitude_limits(ax_m, fr.response[1:], curves)
    ax_c.semilogx(f, fr.coherence[1:], color='C2')
    ax_c.axhline(MIN_COHERENCE, color='0.6', lw=0.8, ls=':')
    what = ('valve command -> measured force [N/V] (paper Fig. 3a)' if ident.kind ==
            'open_loop' else 'reference -> measured force [N/N] (paper Fig. 4)')
    ax_m.set_title(f'run {index}{_of_rig(ident)}: {what}', fontsize=10)
    ax_m.set_ylabel('magnitude')
    ax_p.set_ylabel('phase [deg]')
    ax_c.set_ylabel('coherence')
    ax_c.set_ylim(0, 1.05)
    ax_c.set_xlabel('frequency [Hz]')
    for ax in (ax_m, ax_p, ax_c):
        ax.grid(True, which='both', alpha=0.3)
    ax_m.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return path


def _loop_plot(ident: RunIdentification, path: Path, index: int) -> Path:
    """The loop transfer function ``C H_fu``: measured, fit and known model (Fig. 3c)."""
    fr = ident.response
    f = fr.freqs_hz[1:]
    fig = Figure(figsize=(8, 6))
    FigureCanvasAgg(fig)
    ax_m, ax_p = fig.subplots(2, 1, sharex=True)
    curves = [('measured C H1', ident.loop[1:], dict(color='0.35', lw=1.0)),
              ('C x fit', ident.loop_fit(f), dict(color='C0', lw=1.4))]
    if ident.loop_model is not None:
        curves.append(('known model', ident.loop_model(f), dict(color='C3', lw=1.2, ls='--')))
    for label, h, style in curves:
        ax_m.loglog(f, np.abs(h), label=label, **style)
        ax_p.semilogx(f, np.degrees(np.unwrap(np.angle(h))), **style)
    _magnitude_limits(ax_m, ident.loop[1:], curves)
    ax_m.axhline(1.0, color='0.6', lw=0.8)
    ax_p.axhline(-180.0, color='0.6', lw=0.8)
    fc = ident.figures.get('crossover_hz')
    if fc is not None and math.isfinite(fc):
        for ax in (ax_m, ax_p):
            ax.axvline(fc, color='C0', lw=0.8, ls=':')
    ax_m.set_title(f'run {index}{_of_rig(ident)}: loop transfer function with the configured '
                   'controller (paper Fig. 3c)', fontsize=10)
    ax_m.set_ylabel('|L|')
    ax_p.set_ylabel('phase [deg]')
    ax_p.set_xlabel('frequency [Hz]')
    for ax in (ax_m, ax_p):
        ax.grid(True, which='both', alpha=0.3)
    ax_m.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return path


def _of_rig(ident: RunIdentification) -> str:
    """`` (rig <name>)`` for a structure's rig, nothing for the study's."""
    return f' (rig {ident.rig})' if ident.rig else ''


def _specimen_plot(ident: RunIdentification, path: Path, index: int) -> Path:
    """The restoring force ``f - m a - c v`` over the displacement, with the fitted ``k x``:
    a straight line for a linear specimen, loops for a member that yields."""
    x, restoring = ident.restoring
    fit = ident.specimen
    fig = Figure(figsize=(6.5, 5))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    ax.plot(1e3 * x, restoring, color='0.35', lw=0.5, label='measured f - m a - c v')
    span = np.array([np.min(x), np.max(x)])
    ax.plot(1e3 * span, fit.stiffness_N_per_m * span, color='C0', lw=1.4,
            label=f'k x, k = {fit.stiffness_N_per_m:.4g} N/m')
    verdict = 'linear' if fit.linear else 'NOT linear'
    ax.set_title(f'run {index}{_of_rig(ident)}: specimen ({verdict}, residual '
                 f'{100 * fit.residual:.2g} %)', fontsize=10)
    ax.set_xlabel('displacement [mm]')
    ax.set_ylabel('restoring force [N]')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return path


def _fmt(v, spec='.3g'):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return '–'
    return format(v, spec)


def write_identification(idents: list[RunIdentification], out_dir, *,
                         identified: dict[str, Any] | None = None,
                         rig_parameters: dict[str, dict[str, Any]] | None = None,
                         version: str = '') -> dict[str, Any]:
    """Write ``identification.json``, the PNGs and ``identification.md`` to `out_dir`.

    Parameters
    ----------
    idents : list of RunIdentification
        One per rig of each bag.
    out_dir : str or Path
        Created if missing.
    identified : dict, optional
        The parameters for the compensators of the study's rig
        (``rig_identification.identified_parameters``).
    rig_parameters : dict of str to dict, optional
        A structure's: each rig's parameters
        (``rig_identification.identified_rig_parameters``).
    version : str
        Software version, for the report.

    Returns
    -------
    dict
        The JSON document: ``{"runs": [{"bag", "rig", "kind", "excitation", "figures",
        "plots"}], "parameters": identified, "version"}`` and, for the study's rig, its
        figures (:data:`SUMMARY_KEYS`: the first run's value of each); for a structure,
        ``"rigs": {rig: {<SUMMARY_KEYS>, "specimen": [the fits], "parameters"}}`` instead.
        PNGs: ``bode_run_<i>.png``, ``loop_run_<i>.png`` (open loop) and
        ``specimen_run_<i>.png`` per run ``i`` (a rig of a bag).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = {'version': version, 'runs': []}
    for i, ident in enumerate(idents):
        plots = [_bode(ident, out / f'bode_run_{i}.png', i).name]
        if ident.loop is not None:
            plots.append(_loop_plot(ident, out / f'loop_run_{i}.png', i).name)
        if ident.specimen is not None and ident.restoring is not None:
            plots.append(_specimen_plot(ident, out / f'specimen_run_{i}.png', i).name)
        p = ident.params
        doc['runs'].append({
            'bag': ident.source, 'rig': ident.rig, 'kind': ident.kind,
            'rig_model': p.get('rig_model'),
            'excitation': _excitation(p),
            'figures': ident.figures, 'plots': plots})
    structure = rig_parameters is not None
    if structure:
        doc['rigs'] = {}
        for r in doc['runs']:
            entry = doc['rigs'].setdefault(r['rig'], {'specimen': []})
            for key in SUMMARY_KEYS:
                if key in r['figures'] and key not in entry:
                    entry[key] = r['figures'][key]
            if 'specimen' in r['figures']:
                entry['specimen'].append(r['figures']['specimen'])
        for rig, entry in doc['rigs'].items():
            entry['parameters'] = dict(rig_parameters.get(rig, {}))
        doc['parameters'] = {}
    else:
        for key in SUMMARY_KEYS:
            doc[key] = next((r['figures'][key] for r in doc['runs'] if key in r['figures']),
                            None)
        doc['parameters'] = {k: v for k, v in (identified or {}).items()}
    doc = _clean(doc)
    (out / 'identification.json').write_text(json.dumps(doc, indent=2) + '\n')
    (out / 'identification.md').write_text('\n'.join(_markdown(doc, version)) + '\n')
    return doc


def _markdown(doc: dict[str, Any], version: str) -> list[str]:
    """The lines of ``identification.md``."""
    structure = 'rigs' in doc
    rig_col = '| rig ' if structure else ''
    lines = ['# seft identify', '', f'seft {version}' if version else '', '',
             f'{rig_col}| bag | kind | figure | identified | known model |',
             '|---' * (6 if structure else 5) + '|']
    for r in doc['runs']:
        figs = r['figures']
        model = figs.get('model') or {}
        rig = f"| {rig_label(r['rig'])} " if structure else ''
        for key in SUMMARY_KEYS + ('magnitude_min', 'magnitude_max'):
            if key in figs:
                lines.append(f"{rig}| {r['bag']} | {r['kind']} | {key} | "
                             f"{_fmt(figs[key], '.4g')} | {_fmt(model.get(key), '.4g')} |")
        fit = figs['fit']
        lines.append(f"{rig}| {r['bag']} | {r['kind']} | fit error (orders {fit['orders']}) | "
                     f"{_fmt(fit['fit_error'], '.2%')} | |")
    lines += ['', 'Estimates: H1 = P_xy/P_xx (Welch: ' + ', '.join(
        f'{k} {v}' for k, v in (doc['runs'][0]['figures']['estimator'].items()
                                if doc['runs'] else [])) + '); frequencies with coherence '
              f'below {MIN_COHERENCE} are left out of the fits.', '']
    late = [(r['bag'], r['rig'], r['figures']['late_commands']) for r in doc['runs']
            if r['figures'].get('late_commands')]
    for bag, rig, n in late:
        lines += [f"{bag}{f' (rig {rig})' if rig else ''}: {n} valve commands reached the "
                  'rig late (real time); the fits read the command the rig applied over '
                  'each step (from their arrival times), not the one sent.', '']
    lines += _specimen_lines(doc['runs'])
    if structure:
        written = {rig: e['parameters'] for rig, e in doc['rigs'].items() if e['parameters']}
        if written:
            lines += ['Parameters of each rig for the structure test (`--params`: its `rigs` '
                      'sections):', '']
            for rig, values in written.items():
                shown = ', '.join(f'`{k}` {_shown(v)}' for k, v in values.items()
                                  if not k.startswith('_'))
                lines.append(f'- `{rig}`: {shown or "nothing"}'
                             + (f" ({values['_specimen']})" if '_specimen' in values else ''))
            lines.append('')
    elif doc['parameters']:
        lines += ['Parameters for the compensators (`--params`):', '']
        lines += [f'- `{k}`: {_shown(v)}' for k, v in doc['parameters'].items()]
        lines.append('')
    lines += _design_lines(doc['runs'])
    for r in doc['runs']:
        lines += [f'![{name}]({name})' for name in r['plots']]
    return lines


def _shown(value) -> str:
    """A parameter's value in the report (a mapping: what it is, not its numbers)."""
    if isinstance(value, dict):
        if 'form' in value:
            return f"{value.get('form')}, {value.get('source', '')} (the file holds it)"
        if 'num' in value:
            return (f"{len(value['den']) - 1}th-order transfer function in "
                    f"{'z' if value.get('dt') else 's'} (the file holds it)")
        return '(a mapping: the file holds it)'
    if isinstance(value, str):
        return value
    return _fmt(value, '.6g')


def _level(plant: dict[str, Any]) -> str:
    """The level the plant was identified at, one sentence (empty when not stated)."""
    unc = plant.get('uncertainty') or {}
    if not unc.get('peak_velocity_m_s'):
        return ''
    from seft_ros.core.stability import LEVEL_MISFIT, MAX_LEVEL_EXTRAPOLATION
    return (f" Identified up to {_fmt(unc['peak_force_N'], '.3g')} N and "
            f"{_fmt(unc['peak_velocity_m_s'], '.3g')} m/s: for a test planning more than "
            f'{MAX_LEVEL_EXTRAPOLATION:g} times either, the stability guard gives a verdict '
            f'only on a fit within {100 * LEVEL_MISFIT:g} %.')


def _design_lines(runs: list[dict[str, Any]]) -> list[str]:
    """The identified plants and the controllers designed for them."""
    lines = []
    for r in runs:
        plant, design = r['figures'].get('plant'), r['figures'].get('design')
        if not plant or not design:
            continue
        m = design['margins']
        s = design['structure']
        gm, gm_db = _fmt(m['gain_margin'], '.3g'), _fmt(m.get('gain_margin_dB'), '.3g')
        notched = ''.join(f', a resonance at {f:.4g} Hz notched' for f, _ in s['resonances'])
        miss = design['inverse_band_error']       # None: no inverse (an unstable loop)
        miss = _fmt(None if miss is None else 100 * miss, '.2g')
        verdict = 'met' if design['met'] else 'NOT met'
        notes = '' if not design['notes'] else ' (' + '; '.join(design['notes']) + ')'
        errors = ', '.join(f'{k} {100 * v:.2g} %' for k, v in plant['nrms'].items())
        predicted = design.get('predicted_error') or []
        if predicted:
            predicted = (", the study's test with `model` predicted within "
                         + ' / '.join(f'{100 * e:.2g}' for _, e in predicted)
                         + ' % at alpha ' + ' / '.join(f'{a:g}' for a, _ in predicted)
                         + f" for the {design.get('prediction_ground', KANAI_TAJIMI_GROUND)}")
        else:
            predicted = ''
        lines += [f"**The force loop of {rig_label(r['rig'])} ({r['bag']}) as data.** Order "
                  f"{plant['order']} (the Bayesian information criterion over orders 1-"
                  f"{len(plant['orders'])}), delay {plant['delay_steps']} steps; relative RMS "
                  f'error of the simulated outputs: {errors}.{_level(plant)}', '',
                  f"**The force controller designed for it** ({design['method']}): crossover "
                  f"{_fmt(m['crossover_hz'], '.3g')} Hz, phase margin "
                  f"{_fmt(m['phase_margin_deg'], '.3g')} deg, gain margin {gm} ({gm_db} dB); "
                  'the control-structure-interaction zero at '
                  f"{_fmt(s['specimen_hz'], '.4g')} Hz{notched}; force-loop inverse "
                  f"{design['loop_delay_steps']} steps, {design['loop_taps']} taps (miss "
                  f'{miss} % up to 25 Hz{predicted}); targets {verdict}{notes}.', '']
        for warning in design.get('warnings') or ():
            lines += [f'**WARNING:** {warning}.', '']
    return lines


def _specimen_lines(runs: list[dict[str, Any]]) -> list[str]:
    """The table of the specimens (f = m a + c v + k x, paper Eq. 5.1) and their verdicts."""
    rows = [r for r in runs if r['figures'].get('specimen')]
    if not rows:
        return []
    lines = ["Specimens: f = m a + c v + k x (paper Eq. 5.1) by least squares on each rig's "
             'measured force and motion (band-passed alike), standard errors from four parts '
             'of the record; "rig model" is the rig\'s configured specimen, "declared" the '
             "compensators' (`predictor_*`).", '',
             '| rig | bag | figure | identified | standard error | rig model | declared |',
             '|---|---|---|---|---|---|---|']
    names = (('mass_kg', 'm [kg]'), ('damping_N_s_per_m', 'c [N s/m]'),
             ('stiffness_N_per_m', 'k [N/m]'))
    verdicts = []
    for r in rows:
        spec = r['figures']['specimen']
        for key, label in names:
            lines.append(f"| {rig_label(r['rig'])} | {r['bag']} | {label} | "
                         f"{_fmt(spec[key], '.5g')} | {_fmt(spec['standard_errors'][key], '.2g')}"
                         f" | {_fmt(spec['model'][key], '.5g')} | "
                         f"{_fmt(spec['declared'][key], '.5g')} |")
        verdicts.append(f"- {rig_label(r['rig'])} ({r['bag']}): {spec['verdict']}")
    return lines + [''] + verdicts + ['']


def write_params_yaml(identified: dict[str, Any], path, *,
                      command: str = 'seft identify') -> Path:
    """Write the identified parameters as a ROS 2 parameter file (``/**: ros__parameters``).

    Keys starting with '_' (fit diagnostics) go to a comment. The file is a configuration of
    ``seft run`` / ``seft simulate`` (``CONFIG`` or ``--params FILE``) and a
    ``--params-file`` of every node; its first line names the `command` that wrote it.
    """
    path = Path(path)
    values = {k: _yaml_value(v) for k, v in identified.items() if not k.startswith('_')}
    notes = ''.join(f'# {k[1:]}: {_note(v)}\n' for k, v in identified.items()
                    if k.startswith('_'))
    body = {'/**': {'ros__parameters': values}}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f'# {command}: the identified force loop (plant_model), the force '
                    "controller designed for it and\n# the compensators' settings, or the "
                    'identified delay\n' + notes + yaml.safe_dump(body, sort_keys=True))
    return path


def _yaml_value(value):
    """A parameter as YAML holds it: numbers as floats (ints as ints), text and mappings
    (``plant_model``, ``force_controller_tf``) as they are."""
    if isinstance(value, bool) or isinstance(value, (str, dict)):
        return _clean(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    return float(value)


def _note(value) -> str:
    return value if isinstance(value, str) else format(value, '.4g')


def write_rig_params_yaml(rig_parameters: dict[str, dict[str, Any]], path, *,
                          command: str = 'seft identify') -> Path:
    """Write a structure's identified rigs as a parameter file of its ``rigs`` sections (its
    first line names the `command` that wrote it).

    Each rig's section has its parameters (keys starting with '_' go to a comment). The
    file is a ``--params FILE`` of ``seft run`` / ``seft simulate`` with the structure's
    configuration: its rig sections are merged into the configuration's
    (:func:`seft_ros.cli.config.layer_rigs`).

    Returns
    -------
    Path
    """
    path = Path(path)
    rigs = {}
    notes = ''
    for rig, values in rig_parameters.items():
        section = {k: _yaml_value(v) for k, v in values.items() if not k.startswith('_')}
        if section:
            rigs[rig] = section
        for k, v in values.items():
            if k.startswith('_'):
                notes += f'# {rig}: {k[1:]}: {_note(v)}\n'
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"# {command}: each rig's identified specimen (predictor_*), delay and "
                    'force-loop model\n# for the structure test: seft run CONFIG --params '
                    f"{path.name} (its rigs sections are merged into CONFIG's)\n" + notes
                    + yaml.safe_dump({'rigs': rigs}, sort_keys=True))
    return path
