"""The nodes' shared parameters must agree; each value has one source node for the analysis."""

import ast
import math
from pathlib import Path
import re

import pytest

from seft_msgs_py import parameters
from seft_msgs_py.errors import ParameterError
from seft_msgs_py.parameters import (
    NODES,
    PER_NODE,
    SCHEMA,
    VALUE_SOURCE,
    shared_mismatches,
    spec,
    specs_for_node,
    value_source,
)

#: The rig/controller model parameters the reference-force builder declares besides its own
#: (``seft_ros/nodes/reference_force_builder.py`` ``_MODEL_PARAMETERS``; that module imports
#: rclpy, so the list is repeated here and checked against the node's source).
RFB_MODEL_PARAMETERS = (
    'rig_model', 'tau_s', 'valve_limit_V', 'piston_area_m2', 'oil_bulk_modulus_Pa',
    'actuator_volume_m3', 'valve_time_constant_s', 'valve_flow_gain_m3_per_s_V',
    'valve_pressure_coefficient_m3_per_s_Pa', 'leakage_coefficient_m3_per_s_Pa',
    'io_latency_s', 'anti_alias_cutoff_hz', 'accelerometer_range_m_s2')


def declared(node):
    """The parameter names `node` declares (and publishes on /seft/node_parameters)."""
    names = {s.name for s in specs_for_node(node)}
    if node == 'reference_force_builder':
        names |= set(RFB_MODEL_PARAMETERS)
    return names


@pytest.fixture
def graph():
    """Every node's published parameters at the schema defaults (what a consistent run has)."""
    return {node: {name: spec(name).default for name in sorted(declared(node))}
            for node in NODES}


def test_rfb_model_parameters_match_the_node():
    """The list above is the node's (read from its source: importing it needs rclpy)."""
    source = Path(__file__).parents[2] / 'src/seft_ros/seft_ros/nodes/reference_force_builder.py'
    tree = ast.parse(source.read_text(encoding='utf-8'))
    values = [ast.literal_eval(node.value) for node in tree.body
              if isinstance(node, ast.Assign)
              and any(getattr(t, 'id', None) == '_MODEL_PARAMETERS' for t in node.targets)]
    assert values == [RFB_MODEL_PARAMETERS]


# -- shared_mismatches ------------------------------------------------------------------------

def test_agreeing_graph_has_no_mismatch(graph):
    assert shared_mismatches(graph) == []
    assert shared_mismatches({}) == []
    assert shared_mismatches({'rig': graph['rig']}) == []  # one node shares nothing


def test_alpha_on_one_node_is_one_line(graph):
    """The issue's run: -p alpha:=0.5 on the reference-force builder only."""
    graph['reference_force_builder']['alpha'] = 0.5
    assert shared_mismatches(graph) == [
        'parameter alpha differs: reference_force_builder=0.5, ground_motion_publisher=0.0, '
        'force_servo_controller=0.0, rig=0.0, recorder=0.0']


def test_groups_minority_first_and_one_line_per_parameter(graph):
    graph['rig']['alpha'] = 0.5
    graph['reference_force_builder']['alpha'] = 0.5
    graph['recorder']['alpha'] = 1.5
    graph['rig']['rig_model'] = 'delay'
    graph['rig']['mass_kg'] = 60.0
    graph['ground_motion_publisher']['mass_kg'] = 60
    lines = shared_mismatches(graph)
    assert lines == [
        # schema order: alpha, mass_kg, ..., rig_model
        # groups of two: the one of the earlier node (NODES order) first
        'parameter alpha differs: recorder=1.5, ground_motion_publisher=0.0, '
        'force_servo_controller=0.0, reference_force_builder=0.5, rig=0.5',
        'parameter mass_kg differs: ground_motion_publisher=60.0, rig=60.0, '
        'reference_force_builder=52.7, force_servo_controller=52.7, recorder=52.7',
        "parameter rig_model differs: rig='delay', ground_motion_publisher='servohydraulic', "
        "reference_force_builder='servohydraulic', force_servo_controller='servohydraulic', "
        "recorder='servohydraulic'",
    ]
    assert shared_mismatches(graph) == lines  # deterministic


def test_rigs_of_a_structure_agree_within_their_namespace_and_on_the_test():
    """Nodes of different rigs' namespaces (and of the root) compare only the test's
    parameters (a rig section sets its rig's); nodes of one namespace compare every shared
    parameter."""
    from seft_msgs_py.parameters import TEST_PARAMETERS
    base = parameters.resolve()
    nodes = {name: dict(base) for name in (
        'reference_force_builder', 'ground_motion_publisher', 'recorder', 'pier_a/rig',
        'pier_a/force_servo_controller', 'pier_b/rig', 'pier_b/force_servo_controller')}
    for name in ('pier_b/rig', 'pier_b/force_servo_controller'):
        nodes[name]['stiffness_N_per_m'] = 1.6 * 2.11e5
    assert 'stiffness_N_per_m' not in TEST_PARAMETERS and 'dt' in TEST_PARAMETERS
    assert shared_mismatches(nodes) == []
    nodes['pier_b/force_servo_controller']['stiffness_N_per_m'] = 2.11e5
    assert shared_mismatches(nodes) == [
        'parameter stiffness_N_per_m differs: pier_b/force_servo_controller=211000.0, '
        'pier_b/rig=337600.0']
    nodes['pier_b/force_servo_controller']['stiffness_N_per_m'] = 1.6 * 2.11e5
    nodes['pier_a/rig']['dt'] = 0.001
    assert shared_mismatches(nodes) == [
        'parameter dt differs: pier_a/rig=0.001, ground_motion_publisher=0.002, '
        'reference_force_builder=0.002, pier_a/force_servo_controller=0.002, '
        'pier_b/force_servo_controller=0.002, pier_b/rig=0.002, recorder=0.002']


def test_rfb_model_parameter_is_compared_with_the_rig(graph):
    graph['rig']['io_latency_s'] = 0.004
    assert shared_mismatches(graph) == [
        'parameter io_latency_s differs: rig=0.004, reference_force_builder=0.003, '
        'recorder=0.003']


def test_floats_compare_exactly(graph):
    graph['rig']['dt'] = 0.002 + 1e-20  # below half a unit in the last place: 0.002
    assert shared_mismatches(graph) == []
    graph['rig']['dt'] = math.nextafter(0.002, 1.0)  # the next double up
    assert graph['rig']['dt'] - 0.002 == pytest.approx(4.3e-19, rel=0.01)
    assert shared_mismatches(graph) == [
        'parameter dt differs: rig=0.0020000000000000005, ground_motion_publisher=0.002, '
        'reference_force_builder=0.002, force_servo_controller=0.002, recorder=0.002']


def test_int_and_float_of_one_value_agree():
    assert shared_mismatches({'rig': {'alpha': 1, 'n_steps': 500, 'mass_kg': 50},
                              'reference_force_builder': {'alpha': 1.0, 'n_steps': 500.0,
                                                          'mass_kg': 50.0}}) == []
    assert shared_mismatches({'rig': {'n_steps': 500},
                              'reference_force_builder': {'n_steps': 501.0}}) == [
        'parameter n_steps differs: reference_force_builder=501, rig=500']


def test_per_node_and_unknown_names_are_ignored(graph):
    graph['recorder'].update(bag_path='a', bag_storage='sqlite3', wait_for_recorder=True,
                             recorder_window_steps=10, use_sim_time=True, not_seft=1,
                             wait_for_live_view=True)
    graph['rig'].update(bag_path='b', wait_for_recorder=False, recorder_window_steps=1000,
                        use_sim_time=False, not_seft=2, auth_key_file='/lab/key',
                        wait_for_live_view=False)
    assert shared_mismatches(graph) == []
    assert PER_NODE == {'bag_path', 'bag_storage', 'wait_for_recorder',
                        'recorder_window_steps', 'use_sim_time', 'realtime_priority',
                        'auth_key_file', 'wait_for_live_view'}


def test_unknown_node_names_sort_after_the_graph():
    lines = shared_mismatches({'zeta': {'alpha': 0.0}, 'rig': {'alpha': 0.0},
                               'beta': {'alpha': 0.5}})
    assert lines == ['parameter alpha differs: beta=0.5, rig=0.0, zeta=0.0']


def test_invalid_value_differs_from_every_valid_one():
    assert shared_mismatches({'rig': {'alpha': 0.0}, 'recorder': {'alpha': 'zero'}}) == [
        "parameter alpha differs: rig=0.0, recorder='zero'"]
    assert shared_mismatches({'rig': {'ground_preview': 1},
                              'recorder': {'ground_preview': True}}) == [
        'parameter ground_preview differs: rig=1, recorder=True']


def test_parameters_not_a_mapping_is_an_error():
    with pytest.raises(ParameterError, match=re.escape(
            "parameters of node 'rig': expected a mapping of parameter names to values, "
            'got list')):
        shared_mismatches({'rig': ['alpha', 0.5], 'recorder': {'alpha': 0.5}})


# -- value_source ----------------------------------------------------------------------------

def test_every_parameter_has_a_source_that_declares_it():
    assert set(VALUE_SOURCE) == {s.name for s in SCHEMA}
    for s in SCHEMA:
        node = value_source(s.name)
        assert node in NODES
        assert s.name in declared(node), (s.name, node)


def test_shared_parameters_have_an_explicit_source():
    """A parameter that two nodes besides the recorder declare needs a stated source."""
    shared = {s.name for s in SCHEMA if len([n for n in s.nodes if n != 'recorder']) > 1}
    assert shared == set(parameters._SHARED_SOURCE)


@pytest.mark.parametrize('names, node', [
    (['alpha', 'predictor', 'ground_preview', 'polynomial_order', 'predictor_mass_kg',
      'predictor_damping_N_s_per_m', 'predictor_stiffness_N_per_m', 'predictor_tau_s',
      'predictor_loop_delay_steps', 'predictor_loop_taps', 'predictor_loop_latency_s',
      'predictor_loop_csi_band',
      'adaptive_window_s', 'adaptive_max_delay_s', 'adaptive_memory_s',
      'adaptive_excitation_N', 'adaptive_excitation_fraction',
      'adaptive_max_deviation', 'adaptive_max_rate_per_s',
      'adaptive_specimen_excitation_ratio', 'adaptive_specimen_max_rate_per_s',
      'adaptive_loop', 'adaptive_loop_fit', 'ats_window_s', 'monitor_cutoff_hz',
      'monitor_window_s',
      'monitor_threshold', 'monitor_floor_N', 'network_delay_s',
      'predictor_restoring_force', 'hysteresis_post_yield_ratio',
      'hysteresis_yield_displacement_m', 'hysteresis_n', 'specimen_uncertainty',
      'specimen_check', 'predictor_io_latency_s', 'divergence_factor'],
     'reference_force_builder'),
    (['mass_kg', 'stiffness_N_per_m', 'damping_N_s_per_m', 'specimen_model',
      'post_yield_stiffness_ratio', 'yield_displacement_m', 'bouc_wen_n', 'bouc_wen_beta',
      'bouc_wen_gamma', 'rig_model', 'rig_calibration', 'tau_s', 'stroke_limit_m', 'force_limit_N',
      'noise_force_N', 'noise_displacement_m', 'noise_velocity_m_s', 'noise_acceleration_m_s2',
      'noise_seed', 'piston_area_m2', 'oil_bulk_modulus_Pa', 'actuator_volume_m3',
      'valve_time_constant_s', 'valve_flow_gain_m3_per_s_V',
      'valve_pressure_coefficient_m3_per_s_Pa', 'leakage_coefficient_m3_per_s_Pa',
      'io_latency_s', 'anti_alias_cutoff_hz', 'accelerometer_range_m_s2', 'force_range_N',
      'displacement_range_m', 'velocity_range_m_s', 'actuator_velocity_limit_m_s',
      'watchdog_timeout_s', 'safe_ramp_s', 'realtime_output', 'realtime_substep_s',
      'rig_interface', 'udp_controller_address', 'udp_local_port', 'udp_heartbeat_s',
      'udp_max_bad_datagrams', 'wait_for_recorder', 'recorder_window_steps', 'dt', 'mode',
      'n_steps'], 'rig'),
    (['record', 'amplitude_N', 'scale_factor', 'time_scale', 'record_resampling', 'duration_s',
      'preview_steps'],
     'ground_motion_publisher'),
    (['excitation', 'excitation_input', 'excitation_amplitude', 'excitation_band_low_hz',
      'excitation_band_hz', 'excitation_seed'], 'ground_motion_publisher'),
    (['valve_limit_V', 'saturation_window_s', 'saturation_abort_fraction', 'force_controller',
      'force_integral_hz', 'force_crossover_hz', 'velocity_lead_s', 'velocity_filter_hz',
      'force_tangent_horizon_s', 'reference_extrapolation_steps', 'reference_extrapolation',
      'reference_deadline_fraction'], 'force_servo_controller'),
    (['bag_path', 'bag_storage'], 'recorder'),
])
def test_value_source_of_each_parameter(names, node):
    assert {name: value_source(name) for name in names} == {name: node for name in names}


def test_value_source_lists_cover_the_schema():
    # + 1: realtime_priority, per node (the rig's value is the one reported); the second 6:
    # the excitation of identification runs; the rig's 47: 38, the UDP bridge's 5 and the
    # sensor ranges and actuator velocity of issue 39; the builder's 31 with
    # specimen_uncertainty, specimen_check and predictor_io_latency_s; + 6: the force loop as
    # data (plant_model, force_controller_tf, the actuator family's 3, predictor_calibration);
    # + 3: who may command the rig (run_token, message_auth, auth_key_file); + 1: the
    # recorder's wait_for_live_view; + 1: adaptive_excitation_fraction; + 1: adaptive_loop_fit;
    # + 1: predictor_loop_rehearsed (seft design's mark); + 2: adaptive's specimen gate and
    # rate (adaptive_specimen_excitation_ratio, adaptive_specimen_max_rate_per_s); + 1:
    # predictor_loop_csi_band (seft design's choice of the inverse's band); + 1:
    # record_resampling; + 1: adaptive_frequency_prior; + 2: the controller's late reference
    # force (reference_extrapolation, reference_deadline_fraction); + 1: the rig's late
    # valve command (realtime_late_command); + 1: the builder's divergence_factor; + 1: a
    # state_space rig's own plant (rig_plant_model)
    assert len(VALUE_SOURCE) == len(SCHEMA) == (31 + 47 + 6 + 6 + 10 + 2 + 1 + 2 + 1 + 6 + 3
                                                + 1 + 1 + 1 + 1 + 2 + 1 + 1 + 1 + 2 + 1 + 1
                                                + 1)


def test_value_source_of_unknown_name_is_an_error():
    with pytest.raises(ParameterError, match=re.escape("unknown parameter 'alhpa'")):
        value_source('alhpa')
    with pytest.raises(TypeError):
        VALUE_SOURCE['alpha'] = 'rig'  # read-only


def test_graph_nodes_in_start_order():
    from seft_msgs_py.parameters import graph_nodes
    assert graph_nodes('servohydraulic') == ('ground_motion_publisher',
                                             'reference_force_builder',
                                             'force_servo_controller', 'rig')
    assert graph_nodes('delay') == ('ground_motion_publisher', 'reference_force_builder', 'rig')
