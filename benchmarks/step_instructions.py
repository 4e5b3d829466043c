"""Bytecode instructions and Python calls per step of ``seft simulate``, per function.

A step's cost on a shared, noisy host varies by 2x between sessions; what the step executes
does not. This traces :func:`~seft_ros.core.experiment.simulate` with opcode events
(``sys.settrace``, ``frame.f_trace_opcodes``) over two durations of one test and prints the
difference per step: the instructions each function executes and how often it is called (the
set-up cancels out). Compare two versions of the code with it, then confirm with
``benchmarks/simulate_throughput.py`` in the same minutes. Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/step_instructions.py [--predictor model]
[--rig servohydraulic] [--alpha 0.5]
"""

import argparse
import collections
import sys

from seft_msgs_py import parameters
from seft_ros.core.experiment import simulate


def count(params, duration_s: float) -> tuple[int, collections.Counter, collections.Counter]:
    """(steps, instructions by function, calls by function) of one traced run."""
    ops, calls = collections.Counter(), collections.Counter()

    def trace(frame, event, arg):
        code = frame.f_code
        name = f'{code.co_filename.rsplit("/", 1)[-1]}:{code.co_firstlineno}:{code.co_name}'
        if event == 'call':
            calls[name] += 1
            frame.f_trace_lines = False
            frame.f_trace_opcodes = True
        elif event == 'opcode':
            ops[name] += 1
        return trace

    run_params = dict(params, duration_s=duration_s)
    simulate(run_params)                    # imports and caches outside the count
    sys.settrace(trace)
    try:
        run = simulate(run_params)
    finally:
        sys.settrace(None)
    return run.n_steps, ops, calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--predictor', default='model', help='compensator (default model)')
    ap.add_argument('--rig', default='servohydraulic', help='rig_model (default servohydraulic)')
    ap.add_argument('--alpha', type=float, default=0.5, help='mass ratio (default 0.5)')
    args = ap.parse_args()
    params = parameters.resolve({'record': 'default', 'amplitude_N': 500.0, 'alpha': args.alpha,
                                 'rig_model': args.rig, 'predictor': args.predictor})
    n1, ops1, calls1 = count(params, 0.2)
    n2, ops2, calls2 = count(params, 1.2)
    steps = n2 - n1
    rows = []
    for name in set(ops1) | set(ops2):
        per_step = (ops2[name] - ops1[name]) / steps
        if per_step >= 0.5:
            rows.append((per_step, (calls2[name] - calls1[name]) / steps, name))
    rows.sort(reverse=True)
    print(f'{args.rig}, {args.predictor}, alpha {args.alpha:g}: per step ({steps} steps '
          'counted)')
    for per_step, per_call, name in rows:
        print(f'{per_step:8.1f} instructions {per_call:5.2f} calls  {name}')
    print(f'{sum(r[0] for r in rows):8.1f} instructions {sum(r[1] for r in rows):5.1f} calls '
          'a step in all')


if __name__ == '__main__':
    main()
