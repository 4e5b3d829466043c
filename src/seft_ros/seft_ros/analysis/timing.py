"""Timing of a real-time run, from the per-node timing records of its bag.

Every node keeps, in real-time mode, one record per step, in the bag on ``/seft/timing/<node>``
(``seft_msgs_py.signals.TIMING_FIELDS``): period jitter, compute time, age of the oldest
input, missed deadline, stale input and, for the rig, the loop latency (sample at the rig to
the command computed from it back at the rig). This module reads them (rosbags, no rclpy),
summarizes them as percentiles and fractions, and plots their distributions, after the
latency and overrun statistics the ``pendulum_control`` demo of ros2/demos keeps as data.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py import signals
from seft_msgs_py.errors import InputError

__all__ = ['NodeTiming', 'read_timing', 'timing_row', 'node_timings', 'timing_summary',
           'timing_until',
           'timing_figure', 'timing_table', 'percentiles_ms', 'TIMING_PUBLISHER',
           'link_summary', 'PLAYOUT_MISS_FRACTION', 'link_markdown']

_FIELDS = signals.TIMING_FIELDS
#: Timing topic -> the node that publishes it.
TIMING_PUBLISHER = {s.name: s.publisher for s in signals.TIMING}


@dataclass
class NodeTiming:
    """The timing records of one node, sorted by step.

    Attributes
    ----------
    node : str
    step : ndarray of int, shape (n,)
        Step index of each record.
    period_jitter_s, compute_s, input_age_s, loop_latency_s : ndarray, shape (n,)
        [s]; nan where not defined (the first activation; loop latency on nodes other than
        the rig, or a command that never arrived).
    missed_deadline, stale : ndarray of bool, shape (n,)
    """

    node: str
    step: np.ndarray
    period_jitter_s: np.ndarray
    compute_s: np.ndarray
    input_age_s: np.ndarray
    missed_deadline: np.ndarray
    stale: np.ndarray
    loop_latency_s: np.ndarray

    @property
    def n(self) -> int:
        """Number of records."""
        return int(self.step.shape[0])


def timing_row(msg) -> tuple[int, list[float]]:
    """``(stamp [ns], [field values in TIMING_FIELDS order])`` of one timing record (a
    deserialized ``sensor_msgs/JointState``; a field it lacks is nan)."""
    values = dict(zip(msg.name, msg.position))
    stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    return stamp, [values.get(f, np.nan) for f in _FIELDS]


def node_timings(rows: dict[str, list], dt: float) -> dict[str, NodeTiming]:
    """The :class:`NodeTiming` of each node from its :func:`timing_row` rows.

    Parameters
    ----------
    rows : dict of str -> list of (int, list of float)
        Per node, ``(stamp [ns], field values)``.
    dt : float > 0
        Control period [s] (turns stamps into steps).
    """
    dt_ns = int(round(dt * 1e9))
    out = {}
    for node, r in rows.items():
        a = np.array([[round(stamp / dt_ns)] + values for stamp, values in r], dtype=float)
        a = a[np.argsort(a[:, 0], kind='stable')]
        out[node] = NodeTiming(node, a[:, 0].astype(int), a[:, 1], a[:, 2], a[:, 3],
                               a[:, 4] > 0.5, a[:, 5] > 0.5, a[:, 6])
    return out


def read_timing(path, dt: float) -> dict[str, NodeTiming]:
    """Read the timing records of the bag at `path` ({} for a lockstep bag).

    Parameters
    ----------
    path : path-like
        A seft bag.
    dt : float > 0
        Control period [s] (turns stamps into steps).

    Raises
    ------
    InputError
        The bag cannot be read.
    """
    typestore = get_typestore(Stores.ROS2_JAZZY)
    rows: dict[str, list] = {}
    try:
        with Reader(Path(path)) as reader:
            conns = [c for c in reader.connections if c.topic in TIMING_PUBLISHER]
            for conn, _, raw in reader.messages(connections=conns):
                rows.setdefault(TIMING_PUBLISHER[conn.topic], []).append(
                    timing_row(typestore.deserialize_cdr(raw, conn.msgtype)))
    except Exception as exc:  # rosbags raises several types for a damaged bag
        raise InputError(f'{path}: cannot read the timing records: {exc}') from None
    return node_timings(rows, dt)


def percentiles_ms(values) -> dict:
    """``{"p50", "p99", "max"}`` of the finite `values` [s] in ms (None if there are none)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return {'p50': None, 'p99': None, 'max': None}
    p50, p99 = np.percentile(v, [50, 99])
    return {'p50': round(float(p50) * 1e3, 4), 'p99': round(float(p99) * 1e3, 4),
            'max': round(float(v.max()) * 1e3, 4)}


def timing_until(t: NodeTiming, step: int | None) -> NodeTiming:
    """The records of `t` of the steps before `step` (all of them for None)."""
    if step is None:
        return t
    keep = t.step < step
    return NodeTiming(t.node, t.step[keep], t.period_jitter_s[keep], t.compute_s[keep],
                      t.input_age_s[keep], t.missed_deadline[keep], t.stale[keep],
                      t.loop_latency_s[keep])


def timing_summary(timing: dict[str, NodeTiming],
                   until_step: int | None = None) -> dict | None:
    """The ``"timing"`` block of ``summary.json`` (None without timing records).

    Parameters
    ----------
    timing : dict of str -> NodeTiming
        Each node's records.
    until_step : int, optional
        Only the records of the steps before it: an aborted run's abort step
        (``abort_at_s / dt``). After it a real-time rig samples its safe-state ramp, with no
        command coming (its controller has stopped): those ticks are not the test's, and
        counted they made an interrupted run's 124 ramp ticks 'lost commands' and 10.9 %
        of its ticks 'stale'.

    Returns
    -------
    dict
        ``loop_latency_ms`` and ``period_jitter_ms`` ({p50, p99, max} of the rig's loop latency
        and absolute period jitter; with several rigs, over the records of every rig),
        ``missed_deadline_fraction`` (rig ticks whose sample was
        taken a period or more late), ``stale_command_fraction`` (rig ticks at which the
        command computed from the previous sample had not arrived), ``lost_commands`` (samples
        whose command never arrived), and ``nodes``: per node ``records``, ``compute_ms``,
        ``input_age_ms``, ``period_jitter_ms``, ``missed_deadline_fraction`` and
        ``stale_fraction``. Fractions are in 0..1.
    """
    timing = {name: timing_until(t, until_step) for name, t in timing.items()}
    rigs = [t for name, t in sorted(timing.items()) if _is_rig(name) and t.n]
    if not rigs:
        return None

    def joined(attr, skip_first=False):
        return np.concatenate([getattr(t, attr)[1 if skip_first else 0:] for t in rigs])
    nodes = {}
    for name, t in sorted(timing.items()):
        if not t.n:
            continue
        nodes[name] = {
            'records': t.n,
            'compute_ms': percentiles_ms(t.compute_s),
            'input_age_ms': percentiles_ms(t.input_age_s),
            'period_jitter_ms': percentiles_ms(np.abs(t.period_jitter_s)),
            'missed_deadline_fraction': round(float(np.mean(t.missed_deadline)), 6),
            'stale_fraction': round(float(np.mean(t.stale)), 6),
        }
    # the rig waits for the commands of its last samples after its last tick (DRAIN_MIN_S)
    latency = joined('loop_latency_s')
    stale = joined('stale', skip_first=True)
    return {
        'loop_latency_ms': percentiles_ms(latency),
        'period_jitter_ms': percentiles_ms(np.abs(joined('period_jitter_s'))),
        'missed_deadline_fraction': round(float(np.mean(joined('missed_deadline'))), 6),
        'stale_command_fraction': round(float(np.mean(stale)) if stale.size else 0.0, 6),
        'lost_commands': int(np.sum(~np.isfinite(latency))),
        'nodes': nodes,
    }


def _is_rig(node: str) -> bool:
    """Whether `node` is a rig (the study's ``rig``, or ``<rig>/rig`` of a structure)."""
    return node == 'rig' or node.endswith('/rig')


def timing_table(summary: dict) -> str:
    """A Markdown table of a run's timing summary (one row per node)."""
    def fmt(d):
        if d['p50'] is None:
            return '–'
        return f"{d['p50']:.2f} / {d['p99']:.2f} / {d['max']:.2f}"
    lines = [
        f"Loop latency (ms, p50 / p99 / max): {fmt(summary['loop_latency_ms'])}; rig period "
        f"jitter: {fmt(summary['period_jitter_ms'])}; missed deadlines "
        f"{100 * summary['missed_deadline_fraction']:.2f} %, stale commands "
        f"{100 * summary['stale_command_fraction']:.2f} %, lost commands "
        f"{summary['lost_commands']}.",
        '',
        '| node | records | compute ms (p50 / p99 / max) | input age ms | period jitter ms '
        '| missed | stale |',
        '|---|---|---|---|---|---|---|',
    ]
    for name, n in summary['nodes'].items():
        lines.append(f"| {name} | {n['records']} | {fmt(n['compute_ms'])} | "
                     f"{fmt(n['input_age_ms'])} | {fmt(n['period_jitter_ms'])} | "
                     f"{100 * n['missed_deadline_fraction']:.2f} % | "
                     f"{100 * n['stale_fraction']:.2f} % |")
    return '\n'.join(lines)


def timing_figure(timing: dict[str, NodeTiming], path, *, title: str = '') -> Path:
    """Histograms of loop latency, period jitter, compute time and input age; PNG at `path`.

    Returns
    -------
    Path
        The written file.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg  # only for the figure
    from matplotlib.figure import Figure
    fig = Figure(figsize=(12, 7), layout='constrained')
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2)
    panels = (
        (axes[0, 0], 'loop latency at the rig [ms]', lambda t: t.loop_latency_s, _is_rig),
        (axes[0, 1], 'period jitter [ms]', lambda t: t.period_jitter_s, None),
        (axes[1, 0], 'compute time per step [ms]', lambda t: t.compute_s, None),
        (axes[1, 1], 'age of the oldest input [ms]', lambda t: t.input_age_s, None),
    )
    for ax, label, get, only in panels:
        for name, t in sorted(timing.items()):
            if only and not only(name):
                continue
            v = get(t) * 1e3
            v = v[np.isfinite(v)]
            if v.size == 0:
                continue
            p50, p99 = np.percentile(v, [50, 99])
            ax.hist(v, bins=80, histtype='step', log=True,
                    label=f'{name} (p50 {p50:.2f}, p99 {p99:.2f})')
        ax.set_xlabel(label)
        ax.set_ylabel('steps')
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    path = Path(path)
    fig.savefig(path, dpi=90)
    return path


#: A run whose commands missed their playout step (``network_delay_s``) more often than this
#: fraction says so in its summary and report: the playout delay is too short for the link.
PLAYOUT_MISS_FRACTION = 0.01


def link_summary(link: dict | None, timing: dict | None) -> dict | None:
    """The ``"link"`` block of ``summary.json`` of a run over several hosts (None on one host).

    Parameters
    ----------
    link : dict or None
        The last ``/seft/link`` figures of the bag (``seft_ros.cli.link``): per host the
        round trip (p50/p99/max [ms]) and the clock offset [ms] to the reference host, the
        emulation, the playout delay and the preview chosen.
    timing : dict or None
        The run's :func:`timing_summary`.

    Returns
    -------
    dict
        ``{'reference', 'emulation', 'hosts': {host: {'round_trip_ms', 'offset_ms',
        'samples'}}, 'network_delay_s', 'preview_steps', 'playout',
        'decided_round_trip_p99_ms', 'playout_missed_fraction', 'warning'}``: the round trip
        the playout delay was sized from (the start-up measurement; ``hosts`` holds the whole
        run's), the fraction of steps whose controller had not received the reference
        force of its playout step (the force servo controllers' stale fraction, the largest),
        and, above :data:`PLAYOUT_MISS_FRACTION`, a warning line.
    """
    if not link:
        return None
    out = {'reference': link.get('reference'), 'emulation': link.get('emulation', 'none'),
           'hosts': {h: {k: v.get(k) for k in ('round_trip_ms', 'offset_ms', 'samples')}
                     for h, v in (link.get('links') or {}).items()},
           'network_delay_s': link.get('network_delay_s'),
           'preview_steps': link.get('preview_steps'), 'playout': link.get('playout'),
           'decided_round_trip_p99_ms': link.get('decided_round_trip_p99_ms')}
    nodes = (timing or {}).get('nodes') or {}
    stale = [v['stale_fraction'] for n, v in nodes.items()
             if n.rpartition('/')[2] == 'force_servo_controller']
    if stale and link.get('network_delay_s'):
        missed = max(stale)
        out['playout_missed_fraction'] = missed
        if missed > PLAYOUT_MISS_FRACTION:
            out['warning'] = (f'{100 * missed:.1f} % of the reference forces missed their '
                              f'playout step (more than {100 * PLAYOUT_MISS_FRACTION:g} %): '
                              'network_delay_s is short for this link')
    return out


def link_markdown(link: dict | None) -> list[str]:
    """Report lines of a :func:`link_summary` (none on one host)."""
    if not link:
        return []
    lines = [f'Links measured by the reference host {link.get("reference")} '
             f'(emulation: {link.get("emulation")}; playout {link.get("playout")}, '
             f'network_delay_s {link.get("network_delay_s")}, preview_steps '
             f'{link.get("preview_steps")}):', '',
             '| host | round trip ms (p50 / p99 / max) | clock offset ms | pings |',
             '|---|---|---|---|']
    for host, v in link['hosts'].items():
        rtt = v.get('round_trip_ms') or {}
        lines.append(f'| {host} | {rtt.get("p50", float("nan")):.2f} / '
                     f'{rtt.get("p99", float("nan")):.2f} / {rtt.get("max", float("nan")):.2f}'
                     f' | {v.get("offset_ms", float("nan")):+.3f} | {v.get("samples")} |')
    lines.append('')
    if link.get('warning'):
        lines += [f'**Warning:** {link["warning"]}.', '']
    return lines
