"""The rig contract as data: derived from the topic table, the schema and the simulated rigs.

The contract's promises are checked against seft's own rigs (lockstep, from
``seft_plant_sim.rigs``): the command kind each takes, the sample at which a command stamped
``t_j`` first shows, and the page's tables against the module.
"""

from pathlib import Path
import re
import sys

import numpy as np
import pytest

from seft_msgs_py import parameters, rig_contract, signals
from seft_msgs_py.rig_contract import (
    COMMAND_KINDS,
    CONTRACT,
    PUBLISHES,
    REQUIRED_PARAMETERS,
    STATUS_KEYS,
    SUBSCRIBES,
    command_kind,
    command_latency_s,
    first_effect_step,
    is_compatible,
    reaction_limit_s,
)
from seft_plant_sim.rigs import make_rig

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / 'tools'))


def test_version_and_compatibility():
    assert re.fullmatch(r'seft-rig/\d+\.\d+', CONTRACT)
    assert CONTRACT == f'seft-rig/{rig_contract.VERSION}'
    major = rig_contract.VERSION.split('.')[0]
    assert is_compatible(CONTRACT)
    assert is_compatible(f'seft-rig/{major}.99')             # a later minor: still conforms
    assert not is_compatible(f'seft-rig/{int(major) + 1}.0')  # a later major does not
    assert not is_compatible('other-rig/1.0') and not is_compatible('') \
        and not is_compatible(None)


def test_topics_are_the_graph_topics_with_their_qos():
    """Every topic of the contract is a topic of the graph's table, with its QoS there."""
    from seft_msgs_py.topics import spec_for
    names = {r.signal.name for r in PUBLISHES + SUBSCRIBES}
    assert names == {'/seft/measurement', '/seft/record/rig', '/clock',
                     '/seft/record/rig/timing', '/seft/status', '/seft/node_parameters',
                     '/seft/valve_command', '/seft/reference_force'}
    for role in PUBLISHES + SUBSCRIBES:
        q = spec_for(role.signal).qos
        assert rig_contract.qos_of(role.signal) == (
            f'{q.reliability.name.lower()}, {q.durability.name.lower()}, keep last {q.depth}')
    assert rig_contract.qos_of(signals.MEASUREMENT) == 'reliable, transient_local, keep last 2000'
    assert rig_contract.qos_of(signals.CLOCK) == 'reliable, volatile, keep last 100'
    # the rig publishes exactly its record streams (the recorder's bag topics)
    streams = {signals.record_signal(s).name for s in signals.record_streams_of('rig')}
    assert streams <= names


def test_required_parameters_are_the_rig_nodes():
    rig = {s.name for s in parameters.specs_for_node('rig')}
    assert set(REQUIRED_PARAMETERS) <= rig
    assert len(set(REQUIRED_PARAMETERS)) == len(REQUIRED_PARAMETERS)
    # the analysis takes the specimen and the clock from the rig: the rig must publish them
    from_rig = {n for n in REQUIRED_PARAMETERS if parameters.value_source(n) == 'rig'}
    assert {'dt', 'mode', 'n_steps', 'mass_kg', 'stiffness_N_per_m', 'damping_N_s_per_m',
            'rig_model', 'watchdog_timeout_s'} <= from_rig


def test_states_are_the_nodes_states():
    from seft_msgs_py import convert
    assert rig_contract.STATES == (convert.STATE_READY, convert.STATE_RUNNING,
                                   convert.STATE_DONE, convert.STATE_ABORTED,
                                   convert.STATE_FAILED)
    keys = [k.key for k in STATUS_KEYS]
    assert len(keys) == len(set(keys)) and rig_contract.CONTRACT_KEY in keys
    for k in STATUS_KEYS:
        assert set(k.states) <= set(rig_contract.STATES), k.key


def test_the_rig_node_uses_the_contracts_constants():
    from seft_plant_sim import rig_node
    assert rig_node.SAFE_HOLD_S == rig_contract.SAFE_HOLD_S == 0.05
    assert rig_node.PROGRESS_EVERY == rig_contract.PROGRESS_EVERY
    from seft_msgs_py.topics import CLOCK_EVERY
    assert CLOCK_EVERY == signals.CLOCK_EVERY == 10


@pytest.mark.parametrize('model', ['delay', 'servohydraulic'])
def test_command_kind_is_the_simulated_rigs(model):
    p = parameters.resolve({'rig_model': model})
    assert command_kind(p) == make_rig(p).command_kind
    assert command_kind(p) == (COMMAND_KINDS[1] if model == 'delay' else COMMAND_KINDS[0])
    assert rig_contract.command_signal(command_kind(p)).name == (
        '/seft/reference_force' if model == 'delay' else '/seft/valve_command')


def _first_departure(model: str, j: int, **overrides) -> tuple[int, int]:
    """Step the lockstep rig with a command step stamped `j`; return the first sample whose
    measured force departs from rest, and the contract's first effect step."""
    p = parameters.resolve(dict(rig_model=model, **overrides))
    rig = make_rig(p)
    value = 100.0 if model == 'delay' else 0.05        # N, or V
    forces = []
    for k in range(j + 20):
        forces.append(rig.measure().force_N)
        rig.apply(value if k >= j else 0.0)
    forces.append(rig.measure().force_N)
    first = int(np.flatnonzero(np.abs(forces) > 0)[0])
    return first, first_effect_step(j, command_latency_s(p), p['dt'])


@pytest.mark.parametrize('model, overrides, delay_steps', [
    ('delay', {}, 0),                                   # tau 10 ms = 5 dt: exactly then
    ('delay', {'tau_s': 0.0071}, 0),                    # 3.55 dt: the 4th sample
    ('servohydraulic', {}, 0),                          # io 3 ms: the valve moves at 3 ms
    ('servohydraulic', {'io_latency_s': 0.004}, 1),     # 4 ms: the valve starts at sample 2
])
def test_a_command_first_shows_at_the_promised_step(model, overrides, delay_steps):
    """Never before ``j + ceil(latency / dt)``; on the servohydraulic rig a latency of whole
    periods shows one sample later (the valve starts moving just at the sample)."""
    for j in (0, 7):
        first, promised = _first_departure(model, j, **overrides)
        assert first == promised + delay_steps


def test_first_effect_step_and_reaction_limit():
    assert first_effect_step(10, 0.01, 0.002) == 15      # 0.01 / 0.002 rounds to 5, not 6
    assert first_effect_step(10, 0.0, 0.002) == 10
    assert first_effect_step(10, 0.0021, 0.002) == 12
    with pytest.raises(ValueError, match=r'command_latency_s=-0\.001: expected a float >= 0'):
        first_effect_step(0, -0.001, 0.002)
    with pytest.raises(ValueError, match=r'dt=0: expected a float > 0'):
        first_effect_step(0, 0.001, 0)
    assert reaction_limit_s(parameters.resolve()) == pytest.approx(0.02 + 0.004)


def test_the_page_holds_the_current_tables():
    import gen_rig_contract_docs
    page = (ROOT / 'docs' / 'rig_contract.md').read_text()
    assert gen_rig_contract_docs.page_with_tables(page) == page, \
        'run tools/gen_rig_contract_docs.py'
    assert CONTRACT in page


def test_the_runners_interrupt_names_its_signal_and_is_told_from_other_aborts():
    """The runner's abort on the operator's signal names it (SIGHUP and SIGTERM stop a run
    as Ctrl-C does); the bag's reader tells it from other aborts, also as bags recorded
    before the signal was named wrote it."""
    from seft_msgs_py.rig_contract import INTERRUPT_REASON, is_runner_interrupt, runner_interrupt
    assert runner_interrupt('SIGHUP') == 'interrupted (SIGHUP at the runner)'
    assert all(is_runner_interrupt(runner_interrupt(s)) for s in ('SIGINT', 'SIGTERM',
                                                                   'SIGHUP'))
    assert is_runner_interrupt(INTERRUPT_REASON)
    assert not is_runner_interrupt('unstable at t=0.784 s: high-frequency oscillation')
    assert not is_runner_interrupt('interrupted (SIGINT): rig stopped by SIGINT')
