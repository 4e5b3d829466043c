"""Cost of one rig step: microseconds per ``apply()`` of each simulated rig.

Was a test assertion (``apply()`` under 10 us on the servohydraulic rig); timing depends on
the machine and its load, so it is measured here and tests assert no timing. Best of 5
repeats of 20,000 steps, with the load printed. Prints figures; asserts nothing.

Usage: .venv/bin/python benchmarks/rig_step.py
"""

import os
import time

from seft_msgs_py import parameters
from seft_plant_sim.rigs import make_rig


def per_step_us(rig, n: int = 20000, repeat: int = 5) -> float:
    best = float('inf')
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(n):
            rig.apply(0.01)
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def main() -> None:
    print(f'load average {os.getloadavg()[0]:.2f}')
    for rig_model in ('servohydraulic', 'delay'):
        rig = make_rig(parameters.resolve({'rig_model': rig_model}))
        print(f'{rig_model:15s} apply(): {per_step_us(rig):.2f} us per step (best of 5)')


if __name__ == '__main__':
    main()
