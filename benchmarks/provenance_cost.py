"""What it costs that only the run commands its rig (issue 42), against the 2 ms period.

1. **Per message** (in one process, no DDS): sealing a message where it is published and
   checking it where it is taken, as the nodes do (``SerializedStamped`` with the run's frame
   id and ``SeftNode.sealed_writer``; ``frame_id_of_raw`` and ``RunSeal.frame_ok`` after the
   reader), for the reference force (a scalar), the measurement (four fields) and a record
   batch (10 rows of 5 columns), with ``message_auth`` token and hmac, against the same
   without a seal; and a UDP datagram encoded and decoded with and without its HMAC
   trailer. Each call is timed alone (``perf_counter_ns``): p50 / p99 / max [us]. Then what a
   2 ms period of the study's graph adds: 3 stamped messages sealed and 4 checked (the
   builder's reference force, the controller's valve command, the rig's measurement; the
   controller and the builder take the measurement, the controller the reference force, the
   rig the valve command) and 1.1 record batches sealed and checked (11 streams every 10
   samples).
2. **The runner's check of the graph** (``--audit``, rclpy): one ``GraphRunner.audit``-like
   pass over the study's 16 topics with the publishers of a graph (five nodes), p50 / p99 /
   max [ms] over 200 passes; the runner makes one every 0.25 s.
3. **Real-time runs** (``--runs N``): ``seft run config/main.yaml --alpha 0.5 --predictor
   model --mode realtime --duration D`` with message_auth token and hmac, N each: the rig's
   loop latency p50 / p99 / max, stale commands, and the displacement NRMS against ``seft
   simulate``.

Usage: .venv/bin/python benchmarks/provenance_cost.py [--n 20000] [--audit]
       [--runs 2 --duration 10]
Prints figures and the load average; asserts nothing.
"""

import argparse
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SEFT = Path(sys.executable).parent / 'seft'
KEY = b'5f' * 32


def _timed(fn, n: int) -> np.ndarray:
    """Each of `n` calls of `fn` timed alone [us]."""
    out = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        t = clock()
        fn(i)
        out[i] = clock() - t
    return out * 1e-3


def _fmt(us: np.ndarray) -> str:
    return f'{np.percentile(us, 50):6.2f} {np.percentile(us, 99):6.2f} {us.max():8.1f}'


def per_message(n: int) -> None:
    from seft_msgs_py.convert import (
        FieldsReader,
        ScalarReader,
        SerializedStamped,
        frame_id_of_raw,
    )
    from seft_msgs_py.provenance import RunSeal, new_run_token
    from seft_msgs_py.signals import MEASUREMENT_FIELDS
    from seft_msgs_py.topics import MEASUREMENT, REFERENCE_FORCE
    from seft_plant_sim import udp_layout as ul

    print(f'per message, {n} calls each, us: p50 p99 max (each call timed alone)')
    print(f'{"":38s} {"seal (publish)":>24s}   {"check (take)":>24s}')
    token = new_run_token()
    period = {}
    for mode, seal in (('none', RunSeal('none')), ('token', RunSeal(token)),
                       ('hmac', RunSeal(token, KEY))):
        rows = []
        for name, spec, fields in (('reference force', REFERENCE_FORCE, None),
                                   ('measurement', MEASUREMENT, MEASUREMENT_FIELDS)):
            if fields is None:
                template = SerializedStamped.scalar(spec, seal.frame_id)
                read = ScalarReader(spec)
            else:
                template = SerializedStamped.fields(spec.msg_type, fields, seal.frame_id)
                read = FieldsReader(spec.msg_type, fields, seal.frame_id)
            width = template._block.size // 8 if template._block else len(template.offsets)
            values = tuple(float(v) for v in range(1, width + 1))
            topic = spec.name

            def publish(i, template=template, values=values, topic=topic, seal=seal):
                stamp = i * 2_000_000
                mac = (seal.seal(topic, stamp, values).encode() if seal.authenticated
                       else None)
                return template(stamp, values, mac)
            raws = [publish(i) for i in range(n)]

            def take(i, raws=raws, read=read, spec=spec, topic=topic, seal=seal, fields=fields):
                raw = raws[i]
                stamp, got = read(raw)
                got = (got,) if fields is None else got
                ok = seal.frame_ok(frame_id_of_raw(raw, spec.msg_type), topic, stamp, got)
                assert ok
            pub, chk = _timed(publish, n), _timed(take, n)
            rows.append((name, pub, chk))
        rows_data = [float(v) for v in range(50)]
        batch_pub = _timed(lambda i: seal.label_of('/seft/record/rig', rows_data), n)
        label = seal.label_of('/seft/record/rig', rows_data)
        batch_chk = _timed(lambda i: seal.label_ok(label, '/seft/record/rig', rows_data), n)
        rows.append(('record batch (10 x 5)', batch_pub, batch_chk))
        for name, pub, chk in rows:
            print(f'{mode:5s} {name:32s} {_fmt(pub)}   {_fmt(chk)}')
        p50 = {name: (np.percentile(pub, 50), np.percentile(chk, 50))
               for name, pub, chk in rows}
        ref, meas, batch = (p50['reference force'], p50['measurement'],
                            p50['record batch (10 x 5)'])
        # a period: f_r and u sealed (scalars) and the measurement; f_r, u checked once and
        # the measurement twice; 1.1 batches sealed and checked
        period[mode] = (2 * ref[0] + meas[0] + 2 * ref[1] + 2 * meas[1]
                        + 1.1 * (batch[0] + batch[1]))
    for mode in ('token', 'hmac'):
        extra = period[mode] - period['none']
        print(f"a 2 ms period of the study's graph, message_auth {mode}: {period[mode]:.1f} us "
              f'of seal and check work at p50, {extra:+.1f} us against no seal '
              f'({100 * extra / 2000:+.2f} % of the period, spread over three processes)')
    for key in (None, KEY):
        d = ul.ToController(ul.KIND_COMMAND, ul.FLAG_START, 7, 1, 5, 5, 0.5, 2_000_000, 100,
                            ul.COMMAND_VALVE)
        data = ul.encode(d, key)
        enc = _timed(lambda i: ul.encode(d, key), n)
        dec = _timed(lambda i: ul.decode_to_controller(data, key), n)
        print(f'{"udp hmac" if key else "udp":5s} {"datagram to the controller":32s} '
              f'{_fmt(enc)}   {_fmt(dec)}')


def audit(passes: int) -> None:
    import rclpy

    from seft_msgs_py import parameters
    from seft_msgs_py.graph import Graph
    from seft_msgs_py.signals import CLOCK, NODE_PARAMETERS, RUN_PARAMETERS, STATUS
    from seft_msgs_py.topics import spec_for
    rclpy.init()
    graph = Graph.from_parameters(parameters.resolve({}))
    commands = set(graph.command_topics())
    topics = sorted(commands | {r.name for r in graph.record_streams()}
                    | {CLOCK.name, STATUS.name, NODE_PARAMETERS.name, RUN_PARAMETERS.name})
    nodes = {n: rclpy.create_node(n.split('/')[-1]) for n in graph.nodes() + ('recorder',)}
    runner = rclpy.create_node('seft_runner')
    for topic in topics:
        for name in graph.publishers_of(topic):
            signal = next((s for s in graph.bag_signals() if s.name == topic), None)
            spec = spec_for(signal) if signal is not None else None
            if spec is None:
                from std_msgs.msg import Float64MultiArray
                nodes[name].create_publisher(Float64MultiArray, topic, 10)
            else:
                nodes[name].create_publisher(spec.msg_type, topic, 10)
    time.sleep(2.0)

    def one(i):
        for topic in topics:
            found = [(x.node_name, x.node_namespace, bytes(x.endpoint_gid))
                     for x in runner.get_publishers_info_by_topic(topic)]
            graph.foreign_publishers(topic, found)
    ms = _timed(one, passes) * 1e-3
    print(f"the runner's check of the graph, {len(topics)} topics, {passes} passes, ms: "
          f'p50 {np.percentile(ms, 50):.2f} p99 {np.percentile(ms, 99):.2f} max '
          f'{ms.max():.2f} (one every 0.25 s: {100 * np.percentile(ms, 50) / 250:.2f} % of a '
          "core at p50, in the runner's process)")
    rclpy.try_shutdown()


def runs(n: int, duration: float) -> None:
    from seft_ros.analysis.bag import read_run
    from seft_ros.core.experiment import simulate
    print(f'real-time runs: main.yaml, alpha 0.5, model, {duration:g} s at 500 Hz')
    print(f'{"message_auth":12s} {"p50 ms":>7s} {"p99 ms":>7s} {"max ms":>7s} {"stale %":>8s} '
          f'{"NRMS x %":>9s} {"vs simulate %":>13s}')
    with tempfile.TemporaryDirectory() as tmp:
        key = Path(tmp) / 'key'
        key.write_bytes(KEY)
        for repeat in range(n):
            for mode in ('token', 'hmac'):
                out = Path(tmp) / f'{mode}_{repeat}'
                sets = ['--set', f'message_auth={mode}', '--set', f'auth_key_file={key}']
                proc = subprocess.run([str(SEFT), 'run', str(ROOT / 'config' / 'main.yaml'),
                                       '--alpha', '0.5', '--predictor', 'model', '--mode',
                                       'realtime', '--duration', str(duration), '--out',
                                       str(out), *sets], capture_output=True, text=True)
                if proc.returncode != 0:
                    print(f'{mode:12s} failed: {proc.stderr.strip().splitlines()[-1:]}')
                    continue
                run = read_run(next(out.glob('*/bag')))
                if not run.stable:
                    print(f'{mode:12s} aborted: {run.abort_reason}')
                    continue
                sim = simulate(dict(run.params, mode='lockstep'))
                k = min(run.n_steps, sim.n_steps)
                a, b = run.displacement_m[:k], sim.displacement_m[:k]
                rig = run.extra['timing_data']['rig']
                lat = np.asarray(rig.loop_latency_s)
                print(f'{mode:12s} {1e3 * np.nanpercentile(lat, 50):7.2f} '
                      f'{1e3 * np.nanpercentile(lat, 99):7.2f} {1e3 * np.nanmax(lat):7.2f} '
                      f'{100 * float(np.mean(rig.stale[1:])):8.2f} '
                      f'{100 * _nrms_x(run):9.3f} '
                      f'{100 * float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b ** 2))):13.3f}')


def _nrms_x(run) -> float:
    """The displacement NRMS of a run against its analytical reference (seft compare's)."""
    from seft_ros.analysis.metrics import compare_run
    return compare_run(run).signal('displacement').nrms


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--n', type=int, default=20000, help='calls per message figure')
    parser.add_argument('--audit', action='store_true', help="time the runner's check")
    parser.add_argument('--runs', type=int, default=0, help='real-time runs per mode')
    parser.add_argument('--duration', type=float, default=10.0, help='their length [s]')
    args = parser.parse_args()
    print(f'load average before: {" ".join(f"{x:.2f}" for x in os.getloadavg())}')
    per_message(args.n)
    if args.audit:
        audit(200)
    if args.runs:
        runs(args.runs, args.duration)
    print(f'load average after: {" ".join(f"{x:.2f}" for x in os.getloadavg())}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
