"""Cost of a crash-safe bag: the recorder's write path with and without bounding the loss.

Writes what the recorder writes for a lockstep run (seven scalar topics a step, serialized in
place as the recorder does) and, with ``--realtime``, the four timing records a step too,
into a rosbags MCAP bag (``--storage sqlite3`` for the other plugin), under each policy:

- ``none``: as rosbags does alone (MCAP chunks of 1 MiB; sqlite3 one transaction); a SIGKILL
  loses the whole bag;
- ``flush T``: ``seft_ros.analysis.bag_recovery.flush_bag`` every T s of samples (closes
  the pending chunk / commits): a SIGKILL loses at most T s;
- ``split T``: a new closed bag every T s of samples (a rosbag2-style split, segments in one
  directory): a SIGKILL loses at most the open segment, T s.

Prints, per policy, the median CPU time per step of the writing (``time.process_time``,
several repeats; the machine is shared: quote medians), the bag's size and the time rosbags
takes to read the closed bag back. Asserts nothing.

Usage: .venv/bin/python benchmarks/bag_flush.py [--steps 10000] [--repeat 5] [--realtime]
"""

import argparse
from pathlib import Path
import statistics
import tempfile
import time

from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from seft_msgs_py.convert import SerializedStamped
from seft_msgs_py.signals import TIMING_FIELDS
from seft_msgs_py.topics import SCALAR_TOPICS, TIMING
from seft_ros.analysis.bag_recovery import flush_bag

DT_NS = 2_000_000
STORE = get_typestore(Stores.ROS2_JAZZY)


def _open(path: Path, storage, topics):
    writer = Writer(path, version=9, storage_plugin=storage)
    writer.open()
    conns = {t.name: writer.add_connection(t.name, t.type_name, typestore=STORE) for t in topics}
    return writer, conns


def write_once(path: Path, steps: int, policy: str, period_s: float, storage,
               realtime: bool) -> float:
    """CPU seconds of writing `steps` steps under `policy`."""
    topics = list(SCALAR_TOPICS) + (list(TIMING) if realtime else [])
    serial = {t.name: SerializedStamped.scalar(t) for t in SCALAR_TOPICS}
    if realtime:
        serial.update({t.name: SerializedStamped.fields(t.msg_type, TIMING_FIELDS)
                       for t in TIMING})
    timing_values = tuple(0.001 * i for i in range(len(TIMING_FIELDS)))
    period_steps = max(1, int(round(period_s / (DT_NS * 1e-9))))
    segment = 0
    t0 = time.process_time()
    writer, conns = _open(path / f'seg{segment}' if policy == 'split' else path, storage,
                          topics)
    for k in range(steps):
        stamp = k * DT_NS
        for t in SCALAR_TOPICS:
            writer.write(conns[t.name], stamp, serial[t.name](stamp, (0.5 * k,)))
        if realtime:
            for t in TIMING:
                writer.write(conns[t.name], stamp, serial[t.name](stamp, timing_values))
        if k and k % period_steps == 0:
            if policy == 'flush':
                flush_bag(writer)
            elif policy == 'split':
                writer.close()
                segment += 1
                writer, conns = _open(path / f'seg{segment}', storage, topics)
    writer.close()
    return time.process_time() - t0


def read_s(path: Path) -> float:
    t0 = time.perf_counter()
    bags = sorted(path.glob('seg*')) or [path]
    for bag in bags:
        with Reader(bag) as reader:
            for _ in reader.messages():
                pass
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument('--steps', type=int, default=10000)
    ap.add_argument('--repeat', type=int, default=5)
    ap.add_argument('--realtime', action='store_true', help='timing records too')
    ap.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    args = ap.parse_args()
    storage = StoragePlugin.MCAP if args.storage == 'mcap' else StoragePlugin.SQLITE3
    policies = [('none', 0.0), ('flush', 1.0), ('flush', 0.5), ('flush', 0.25), ('flush', 0.1),
                ('split', 1.0), ('split', 0.5)]
    results = {p: [] for p in policies}
    sizes, reads = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            for policy, period in policies:      # interleaved: the noise hits every policy
                path = Path(tmp) / f'{policy}_{period}_{i}'
                period_s = period or 1e9
                results[(policy, period)].append(
                    write_once(path, args.steps, policy, period_s, storage, args.realtime))
                if i == 0:
                    sizes[(policy, period)] = sum(f.stat().st_size for f in path.rglob('*')
                                                  if f.is_file())
                    reads[(policy, period)] = read_s(path)
    kind = 'real-time (11' if args.realtime else 'lockstep (7'
    print(f'{args.steps} steps, {args.storage}, {kind} messages a step), median of '
          f'{args.repeat}:')
    base = statistics.median(results[('none', 0.0)]) / args.steps
    for (policy, period), cpus in results.items():
        per_step = statistics.median(cpus) / args.steps
        name = policy if policy == 'none' else f'{policy} {period:g} s'
        print(f'  {name:>11}: {1e6 * per_step:6.1f} us/step ({1e6 * (per_step - base):+5.1f}), '
              f'bag {sizes[(policy, period)] / 1e6:.2f} MB, read back '
              f'{reads[(policy, period)]:.2f} s')


if __name__ == '__main__':
    main()
