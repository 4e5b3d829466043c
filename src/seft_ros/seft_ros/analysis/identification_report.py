"""Outputs of ``seft identify``: ``identification.json``, Bode plots and a Markdown report.

The numbers come from :mod:`seft_ros.analysis.rig_identification`; this module only writes
them (matplotlib's Agg canvas, no display).
"""

import json
import math
from pathlib import Path
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
import numpy as np
import yaml

from seft_ros.analysis.rig_identification import MIN_COHERENCE, RunIdentification

__all__ = ['write_identification', 'write_params_yaml', 'SUMMARY_KEYS']

#: The top-level figures of ``identification.json`` (the first bag that gives each).
SUMMARY_KEYS = ('zero_hz', 'resonance_hz', 'crossover_hz', 'phase_margin_deg', 'gain_margin',
                'delay_ms', 'delay_xcorr_ms')


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
    ax_c.semilogx(f, fr.coherence[1:], color='C2')
    ax_c.axhline(MIN_COHERENCE, color='0.6', lw=0.8, ls=':')
    what = ('valve command -> measured force [N/V] (paper Fig. 3a)' if ident.kind ==
            'open_loop' else 'reference -> measured force [N/N] (paper Fig. 4)')
    ax_m.set_title(f'run {index}: {what}', fontsize=10)
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
    ax_m.axhline(1.0, color='0.6', lw=0.8)
    ax_p.axhline(-180.0, color='0.6', lw=0.8)
    fc = ident.figures.get('crossover_hz')
    if fc is not None and math.isfinite(fc):
        for ax in (ax_m, ax_p):
            ax.axvline(fc, color='C0', lw=0.8, ls=':')
    ax_m.set_title(f'run {index}: loop transfer function with the configured controller '
                   '(paper Fig. 3c)', fontsize=10)
    ax_m.set_ylabel('|L|')
    ax_p.set_ylabel('phase [deg]')
    ax_p.set_xlabel('frequency [Hz]')
    for ax in (ax_m, ax_p):
        ax.grid(True, which='both', alpha=0.3)
    ax_m.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    return path


def _fmt(v, spec='.3g'):
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return '–'
    return format(v, spec)


def write_identification(idents: list[RunIdentification], out_dir, *,
                         identified: dict[str, Any] | None = None,
                         version: str = '') -> dict[str, Any]:
    """Write ``identification.json``, the Bode PNGs and ``identification.md`` to `out_dir`.

    Parameters
    ----------
    idents : list of RunIdentification
        One per bag.
    out_dir : str or Path
        Created if missing.
    identified : dict, optional
        The parameters for the compensators (``rig_identification.identified_parameters``).
    version : str
        Software version, for the report.

    Returns
    -------
    dict
        The JSON document: ``{"runs": [{"bag", "kind", "excitation", "figures", "plots"}],
        <SUMMARY_KEYS>: the first run's value of each, "parameters": identified, "version"}``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = {'version': version, 'runs': []}
    for i, ident in enumerate(idents):
        plots = [_bode(ident, out / f'bode_run_{i}.png', i).name]
        if ident.loop is not None:
            plots.append(_loop_plot(ident, out / f'loop_run_{i}.png', i).name)
        p = ident.params
        doc['runs'].append({
            'bag': ident.source, 'kind': ident.kind, 'rig_model': p.get('rig_model'),
            'excitation': {k: p.get(k) for k in (
                'excitation', 'excitation_input', 'excitation_amplitude',
                'excitation_band_low_hz', 'excitation_band_hz', 'excitation_seed',
                'duration_s')},
            'figures': ident.figures, 'plots': plots})
    for key in SUMMARY_KEYS:
        doc[key] = next((r['figures'][key] for r in doc['runs'] if key in r['figures']), None)
    doc['parameters'] = {k: v for k, v in (identified or {}).items()}
    doc = _clean(doc)
    (out / 'identification.json').write_text(json.dumps(doc, indent=2) + '\n')
    lines = ['# seft identify', '', f'seft {version}' if version else '', '',
             '| bag | kind | figure | identified | known model |', '|---|---|---|---|---|']
    for r in doc['runs']:
        figs = r['figures']
        model = figs.get('model') or {}
        for key in SUMMARY_KEYS + ('magnitude_min', 'magnitude_max'):
            if key in figs:
                lines.append(f"| {r['bag']} | {r['kind']} | {key} | {_fmt(figs[key], '.4g')} | "
                             f"{_fmt(model.get(key), '.4g')} |")
        fit = figs['fit']
        lines.append(f"| {r['bag']} | {r['kind']} | fit error (orders {fit['orders']}) | "
                     f"{_fmt(fit['fit_error'], '.2%')} | |")
    lines += ['', 'Estimates: H1 = P_xy/P_xx (Welch: ' + ', '.join(
        f'{k} {v}' for k, v in (doc['runs'][0]['figures']['estimator'].items()
                                if doc['runs'] else [])) + '); frequencies with coherence '
              f'below {MIN_COHERENCE} are left out of the fits.', '']
    if doc['parameters']:
        lines += ['Parameters for the compensators (`--params`):', '']
        lines += [f'- `{k}`: {_fmt(v, ".6g")}' for k, v in doc['parameters'].items()]
        lines.append('')
    for r in doc['runs']:
        lines += [f'![{name}]({name})' for name in r['plots']]
    (out / 'identification.md').write_text('\n'.join(lines) + '\n')
    return doc


def write_params_yaml(identified: dict[str, Any], path) -> Path:
    """Write the identified parameters as a ROS 2 parameter file (``/**: ros__parameters``).

    Keys starting with '_' (fit diagnostics) go to a comment. The file is a configuration of
    ``seft run`` / ``seft simulate`` (``CONFIG`` or ``--params FILE``) and a
    ``--params-file`` of every node.
    """
    path = Path(path)
    values = {k: float(v) for k, v in identified.items() if not k.startswith('_')}
    notes = ''.join(f'# {k[1:]}: {v:.4g}\n' for k, v in identified.items() if k.startswith('_'))
    body = {'/**': {'ros__parameters': values}}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('# seft identify: the identified delay and force-loop model\n' + notes
                    + yaml.safe_dump(body, sort_keys=True))
    return path
