"""The logic of the ``seft`` verbs as keyword-only functions (after ``ros2param/api``).

``run_experiments`` needs rclpy (it starts and watches the node graph); the others do not.
"""

import json
import os
from pathlib import Path
import random
import time
from typing import Any, Callable

from seft_msgs_py import parameters
from seft_msgs_py.errors import InputError, SeftError
from seft_ros.analysis.bag import read_run
from seft_ros.analysis.report import write_report
from seft_ros.analysis.rundata import RunData
from seft_ros.cli.config import expand_runs, load_config, write_params_file
from seft_ros.core.experiment import simulate

__all__ = ['build_runs', 'output_dir', 'run_experiments', 'simulate_experiments',
           'compare_bags', 'summary_table', 'Result']


class Result:
    """What a verb produced: the runs, the report directory and the summary entries."""

    def __init__(self, out_dir: Path, runs: list[RunData], summary: list[dict],
                 wall_time_s: float):
        self.out_dir = out_dir
        self.runs = runs
        self.summary = summary
        self.wall_time_s = wall_time_s


def build_runs(*, config: str | None = None, overrides: dict[str, Any] | None = None,
               alphas: list[float] | None = None) -> list[dict[str, Any]]:
    """Parameter sets of the runs: defaults < config file < overrides < alphas.

    Raises
    ------
    InputError, ParameterError
        Bad configuration file or value.
    """
    values = load_config(config) if config else {}
    values.update({k: v for k, v in (overrides or {}).items() if v is not None})
    if alphas:
        values['alpha'] = list(alphas)
    return expand_runs(values, where=config or 'command line')


def output_dir(*, out: str | None, name: str) -> Path:
    """The output directory: `out` (must be new or empty) or ``runs/<name>[-N]``.

    Raises
    ------
    InputError
        `out` exists and is not an empty directory.
    """
    if out:
        path = Path(out)
        if path.exists() and (not path.is_dir() or any(path.iterdir())):
            raise InputError(f'{path}: output directory exists and is not empty; expected a '
                             'new directory')
        path.mkdir(parents=True, exist_ok=True)
        return path
    base = Path('runs') / name
    path, i = base, 1
    while path.exists():
        i += 1
        path = base.with_name(f'{base.name}-{i}')
    path.mkdir(parents=True)
    return path


def _run_label(p: dict) -> str:
    return f'alpha_{p["alpha"]:g}_{p["rig_model"]}_{p["predictor"]}'


def _finish(out_dir: Path, runs: list[RunData], title: str, t0: float) -> Result:
    paths = write_report(runs, out_dir, title=title)
    summary = json.loads(Path(paths.summary_json).read_text())['runs']
    return Result(out_dir, runs, summary, time.monotonic() - t0)


def simulate_experiments(*, runs: list[dict], out_dir: Path,
                         progress: Callable[[str], None] = print, title: str = '') -> Result:
    """Run each parameter set in one process (no ROS) and write the report.

    Raises
    ------
    InputError, ParameterError
        Bad record or parameter.
    """
    t0 = time.monotonic()
    data = []
    for p in runs:
        label = _run_label(p)
        progress(f'[{label}] simulating')
        rd = simulate(p, progress=lambda k, n, lb=label: progress(f'[{lb}] step {k}/{n}'))
        run_dir = out_dir / label
        run_dir.mkdir(parents=True, exist_ok=True)
        write_params_file(p, run_dir / 'params.yaml')
        data.append(rd)
        progress(f'[{label}] {"stable" if rd.stable else "ABORTED: " + str(rd.abort_reason)}')
    return _finish(out_dir, data, title or 'seft simulate', t0)


def _domain_id() -> int:
    env = os.environ.get('ROS_DOMAIN_ID')
    if env:
        try:
            value = int(env)
        except ValueError:
            raise InputError(f'ROS_DOMAIN_ID={env!r}: expected an integer 0-232') from None
        return value
    return random.SystemRandom().randint(100, 199)


def run_experiments(*, runs: list[dict], out_dir: Path,
                    progress: Callable[[str], None] = print, title: str = '',
                    domain_id: int | None = None) -> Result:
    """Run each parameter set as a node graph (separate processes over DDS), record a bag
    per run, read the bags back and write the report.

    Raises
    ------
    SeftError
        A node failed or the graph stalled (message names the node and its log).
    """
    from seft_ros.cli.runner import GraphRunner  # rclpy only for this verb

    t0 = time.monotonic()
    chosen = domain_id if domain_id is not None else (
        _domain_id() if os.environ.get('ROS_DOMAIN_ID') else None)
    for _ in range(5):
        runner = GraphRunner(_domain_id() if chosen is None else chosen, progress)
        busy = runner.busy_topics()
        if not busy:
            break
        runner.close()
        if chosen is not None:
            raise SeftError(f'ROS_DOMAIN_ID={chosen} already carries seft topics '
                            f'({", ".join(busy)}): another run? Choose another --domain-id')
    else:
        raise SeftError('no free ROS domain found for the run (5 random tries)')
    data = []
    try:
        for p in runs:
            label = _run_label(p)
            outcome = runner.run(p, out_dir / label, label=f'[{label}] ')
            rd = read_run(outcome.bag_path)
            data.append(rd)
            state = 'stable' if rd.stable else f'ABORTED at {rd.unstable_at_s:.3f} s: ' \
                f'{rd.abort_reason}'
            progress(f'[{label}] {rd.n_steps} steps in {outcome.wall_time_s:.1f} s wall; '
                     f'{state}; bag {outcome.bag_path}')
    finally:
        runner.close()
    return _finish(out_dir, data, title or 'seft run', t0)


def compare_bags(*, bags: list[str], out_dir: Path, title: str = '') -> Result:
    """Read bags and write the comparison report against the analytical reference.

    Raises
    ------
    InputError
        A path is not a readable seft bag.
    """
    t0 = time.monotonic()
    data = [read_run(b) for b in bags]
    return _finish(out_dir, data, title or 'seft compare', t0)


def summary_table(summary: list[dict]) -> str:
    """A plain-text table of summary entries (one line per run)."""
    head = (f'{"alpha":>6} {"rig":>14} {"predictor":>10} {"stable":>7} {"abort_s":>8} '
            f'{"lag_ms":>7} {"nrms_x%":>8} {"nrms_a%":>8} {"nrms_f%":>8} {"peak_x":>7} '
            f'{"peak_a":>7} {"peak_f":>7}')
    lines = [head]

    def pct(v):
        return f'{100 * v:8.2f}' if v is not None else f'{"-":>8}'

    def num(v, w=7):
        return f'{v:{w}.3f}' if v is not None else f'{"-":>{w}}'

    for e in summary:
        abort = f'{e["unstable_at_s"]:8.3f}' if e['unstable_at_s'] is not None else f'{"-":>8}'
        lag = f'{1000 * e["lag_s"]:7.2f}' if e['lag_s'] is not None else f'{"-":>7}'
        lines.append(
            f'{e["alpha"]:6g} {e["rig"]:>14} {e["predictor"]:>10} {str(e["stable"]):>7} '
            f'{abort} {lag} {pct(e["nrms"]["displacement"])} {pct(e["nrms"]["acceleration"])} '
            f'{pct(e["nrms"]["force"])} {num(e["peak_ratio"]["displacement"])} '
            f'{num(e["peak_ratio"]["acceleration"])} {num(e["peak_ratio"]["force"])}')
    return '\n'.join(lines)


def parameter_names() -> list[str]:
    """Every parameter name (for ``--set`` completion and checks)."""
    return [s.name for s in parameters.SCHEMA]
