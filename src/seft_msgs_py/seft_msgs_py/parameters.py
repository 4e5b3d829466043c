"""The one parameter schema of a seft experiment.

Every node declares its ROS parameters from this table (name, default, unit, range,
description), the command-line runner validates a configuration against it, and the docs
table is generated from it. Values are SI floats (REP-103); the unit is in the name or in the
``unit`` field.

Imports no rclpy: the nodes turn a :class:`ParamSpec` into a ``ParameterDescriptor``.
"""

from dataclasses import dataclass, field
import math
from types import MappingProxyType
from typing import Any, Iterable, Mapping

from seft_msgs_py.errors import ParameterError

__all__ = [
    'ParamSpec', 'SCHEMA', 'NODES', 'spec', 'unknown_parameter', 'specs_for_node', 'defaults',
    'validate_value', 'from_text',
    'resolve', 'graph_nodes', 'PER_NODE', 'shared_mismatches', 'VALUE_SOURCE', 'value_source',
    'VALVE_RIG_MODELS', 'valve_commanded', 'identification_run', 'MAPPING_PARAMETERS',
    'mapping_value', 'rig_plant_parameter',
]

#: The node names of the graph, as used in ``ParamSpec.nodes``.
NODES = (
    'ground_motion_publisher', 'reference_force_builder', 'force_servo_controller', 'rig',
    'recorder',
)

_ALL = NODES
#: The nodes of a structure's rig that take the rig's own parameters (its ``rigs`` section).
RIG_SCOPED_NODES = ('force_servo_controller', 'rig')


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of the experiment.

    Attributes
    ----------
    name : str
        ROS parameter name (flat, snake case, unit suffix where it has one).
    default : bool, int, float or str
        Default value; its Python type is the parameter's type.
    unit : str
        SI unit ('' for dimensionless or text).
    description : str
        One sentence for the ``ParameterDescriptor`` and the docs.
    minimum, maximum : float or None
        Inclusive range for numbers (``None``: unbounded).
    exclusive_minimum : bool
        The minimum itself is not allowed (``mass_kg > 0``).
    choices : tuple of str
        Allowed values for a text parameter (empty: any text).
    nodes : tuple of str
        The nodes that declare it.
    """

    name: str
    default: Any
    unit: str
    description: str
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    choices: tuple = ()
    nodes: tuple = field(default=_ALL)

    @property
    def type_name(self) -> str:
        """'bool', 'int', 'float' or 'str'."""
        return type(self.default).__name__

    def expected(self) -> str:
        """Human-readable description of the allowed values, for error messages."""
        if self.choices:
            return 'one of ' + ', '.join(repr(c) for c in self.choices)
        parts = [self.type_name]
        if self.minimum is not None:
            parts.append(('> ' if self.exclusive_minimum else '>= ') + f'{self.minimum:g}')
        if self.maximum is not None:
            parts.append(f'<= {self.maximum:g}')
        return ' '.join(parts)


_GM = ('ground_motion_publisher',)
_RFB = ('reference_force_builder',)
_CTRL = ('force_servo_controller',)
_RIG = ('rig',)
_SPECIMEN = ('reference_force_builder', 'force_servo_controller', 'rig', 'recorder')
_EXC = ('ground_motion_publisher', 'force_servo_controller', 'recorder')

SCHEMA: tuple[ParamSpec, ...] = (
    # -- experiment -------------------------------------------------------------------------
    ParamSpec('dt', 0.002, 's', 'Control (sample) period of every node.', 1e-5, 1.0, True),
    ParamSpec('alpha', 0.0, '', 'Mass ratio alpha = computational mass / specimen mass '
              '(paper Eq. 2.1).', 0.0, 100.0),
    ParamSpec('mass_kg', 52.7, 'kg', 'Specimen (load-resisting member) mass m.', 0.0, None,
              True, nodes=_SPECIMEN + _GM),
    ParamSpec('stiffness_N_per_m', 2.11e5, 'N/m', 'Specimen stiffness k.', 0.0, None, True,
              nodes=_SPECIMEN),
    ParamSpec('damping_N_s_per_m', 17.14 * 52.7, 'N s/m', 'Specimen viscous damping c '
              '(default 17.14 m: the controller denominator s^2+17.14 s+4002 is '
              '(m s^2+c s+k)/m).', 0.0, None, nodes=_SPECIMEN),
    # -- specimen model (seft_plant_sim.specimen.BoucWenSpecimen) -----------------------------
    ParamSpec('specimen_model', 'linear', '', "Specimen: 'linear' (m x'' + c x' + k x = f, "
              "paper Eq. 5.1) or 'bouc_wen' (hysteretic: k x replaced by the Bouc-Wen force "
              'f_s = a k x + (1-a) k D_y z, initial stiffness k).',
              choices=('linear', 'bouc_wen'), nodes=_RIG),
    ParamSpec('post_yield_stiffness_ratio', 0.1, '', "Bouc-Wen a = post-yield / pre-yield "
              "stiffness ('bouc_wen' specimen; 1 is linear).", 0.0, 1.0, nodes=_RIG),
    ParamSpec('yield_displacement_m', 0.004, 'm', 'Bouc-Wen yield displacement D_y (yield '
              "force k D_y = 844 N: the default input yields the 'bouc_wen' specimen).", 0.0,
              None, True, nodes=_RIG),
    ParamSpec('bouc_wen_n', 2.0, '', 'Bouc-Wen exponent n: sharpness of the elastic-plastic '
              'knee.', 1.0, 100.0, nodes=_RIG),
    ParamSpec('bouc_wen_beta', 0.5, '', 'Bouc-Wen shape parameter beta (beta + gamma > 0 and '
              'beta >= gamma; beta = gamma: unloading at the initial stiffness).', -100.0, 100.0,
              nodes=_RIG),
    ParamSpec('bouc_wen_gamma', 0.5, '', 'Bouc-Wen shape parameter gamma (z saturates at '
              '(beta + gamma)^(-1/n)).', -100.0, 100.0, nodes=_RIG),
    ParamSpec('structure', 'none', '', 'The whole structure tested on several rigs, as JSON '
              '(seft run writes it from the structure and rigs sections of a configuration, '
              "seft_ros.core.structure; 'none': the reference study's single rig with the "
              'rigid computational mass alpha m). Every node of a rig runs in the namespace '
              'named after the rig.', nodes=_ALL),
    ParamSpec('structure_builders', 'central', '', "Structure tests: 'central' (one "
              'reference-force builder, in the root namespace, commands every rig: one host, '
              "or the computation on a host of its own) or 'per_rig' (one builder per rig, in "
              "the rig's namespace beside its controller: each integrates a replica of the "
              "computational part from every rig's measurements and predicts the others' "
              'motion over the network delay; the multi-site layout, network out of the fast '
              'loop).', choices=('central', 'per_rig'), nodes=_ALL),
    ParamSpec('mode', 'lockstep', '', "How the node graph steps: 'lockstep' (every node acts "
              'on step k once its inputs for step k are in; the rig is the simulated clock and '
              "the run equals seft simulate bit for bit) or 'realtime' (the rig ticks on the "
              'wall clock every dt, the other nodes act on message arrival with the latest '
              'inputs and nobody waits).', choices=('lockstep', 'realtime'), nodes=_ALL),
    ParamSpec('realtime_priority', 50, '', 'Real-time mode: SCHED_FIFO base priority of the '
              'node processes (1-96; the rig gets +3, the controller +2, the builder and the '
              'ground-motion publisher +1, the recorder -1; 0: the normal scheduler for all). '
              'Needs root or CAP_SYS_NICE; where it is refused the '
              'node warns and keeps the normal scheduler. Per node.', 0, 96, nodes=_ALL),
    ParamSpec('n_steps', 0, '', 'Number of control steps of the run (0: the whole prepared '
              'record); set by the runner.', 0, None, nodes=_ALL),
    # -- ground motion ----------------------------------------------------------------------
    ParamSpec('record', 'default', '', "Ground-motion source: 'default' (embedded synthetic "
              'accelerogram), a PEER NGA .AT2 path (g) or a two-column time [s], '
              'acceleration [m/s^2] CSV path.', nodes=_GM + _RFB + ('recorder',)),
    ParamSpec('amplitude_N', 1000.0, 'N', 'Scale the record so that the peak of m*xg_ddot is '
              'this force (reference study: 1000 N), m the top-level mass_kg (also for a '
              'structure, whatever its specimens weigh); 0 uses scale_factor instead.', 0.0, None,
              nodes=_GM + _RFB + ('recorder',)),
    ParamSpec('scale_factor', 1.0, '', 'Plain amplitude factor on the record (used when '
              'amplitude_N is 0).', 0.0, None, True, nodes=_GM + _RFB + ('recorder',)),
    ParamSpec('time_scale', 0.5, '', 'Time scale of the record (0.5 halves its time step, as '
              'in the reference study).', 0.0, 100.0, True, nodes=_GM + _RFB + ('recorder',)),
    ParamSpec('record_resampling', 'auto', '', "How the record is resampled to dt: "
              "'band_limited' (scipy.signal.resample_poly: nothing above the record's "
              "Nyquist frequency), 'linear' (numpy.interp: images of the record's content "
              "near multiples of its sample rate, which a force loop cannot track) or 'auto' "
              "(linear for the embedded default, as the reference study's test always ran; "
              "band_limited for a record file).", choices=('auto', 'linear', 'band_limited'),
              nodes=_GM + _RFB + ('recorder',)),
    ParamSpec('duration_s', 0.0, 's', 'Length of the run after time scaling (0: the whole '
              'record; with an excitation, its length, 0: 20 s).', 0.0, None,
              nodes=_GM + _CTRL + _RFB + ('recorder',)),
    ParamSpec('preview_steps', 250, '', 'How many steps ahead of the simulated clock the ground '
              'acceleration is published (the record is known before the test: a deep preview '
              "rides out a stall of the publisher, below the loop's nodes in priority; 50 "
              'steps, 100 ms, let a 110-180 ms stall on a loaded 2-core host end real-time runs '
              'on the 50 ms watchdog).', 1, 100000, nodes=_GM),
    # -- excitation (seft_ros.core.excitation): identification runs -------------------------
    ParamSpec('excitation', 'none', '', "Identification run: 'none' (the ground-motion test), "
              "'noise' (band-limited Gaussian noise, amplitude = its standard deviation), "
              "'chirp' (logarithmic sweep over the band) or 'stepped_sine' (20 log-spaced "
              'sines of whole cycles over the band); the record is not played.',
              choices=('none', 'noise', 'chirp', 'stepped_sine'), nodes=_EXC + _RFB),
    ParamSpec('excitation_input', 'reference_force', '', "Where the excitation enters: "
              "'reference_force' (closed loop: it replaces the ground-motion term "
              '-(1+alpha) m xg_ddot of the reference force, so the bag holds it as the ground '
              "acceleration) or 'valve_command' (open loop, servohydraulic rig: the force "
              'controller is bypassed and the valve is driven directly; ground motion 0).',
              choices=('reference_force', 'valve_command'), nodes=_EXC + _RFB + _RIG),
    ParamSpec('excitation_amplitude', 0.0, 'N or V', 'Excitation amplitude, in N on the '
              'reference force, in V on the valve (noise: standard deviation; chirp, '
              'stepped sine: peak; 0: 100 N, 0.05 V).', 0.0, None, nodes=_EXC),
    ParamSpec('excitation_band_low_hz', 0.5, 'Hz', 'Lower edge of the excitation band.',
              0.0, None, True, nodes=_EXC),
    ParamSpec('excitation_band_hz', 0.0, 'Hz', 'Upper edge of the excitation band (below the '
              'Nyquist frequency 1/(2 dt), above excitation_band_low_hz; 0: 0.6 of the Nyquist '
              'frequency, 150 Hz at dt = 2 ms, 300 Hz at 1 ms: an identification needs the '
              "actuator's band excited whatever the rate).", 0.0, None, nodes=_EXC),
    ParamSpec('excitation_seed', 1, '', 'Seed of the noise excitation (runs are '
              'reproducible).', 0, None, nodes=_EXC),
    # -- reference force builder ------------------------------------------------------------
    ParamSpec('predictor', 'none', '', 'Delay compensation of the fed-back acceleration '
              "('none': measured acceleration of the previous step, paper Eq. 5.3; "
              "'polynomial': extrapolated over the delay, Horiuchi et al. 1996; 'model': "
              'hold-consistent model-based prediction after Carrion and Spencer 2007, with '
              "the force loop inverted on the servohydraulic rig; 'adaptive': 'model' with "
              'the specimen m, c, k (recursive least squares), the delay and the gain '
              "identified online, the force-loop inverse refitted to them; 'ats': the "
              'adaptive time-series compensator of Chae et al. 2013 on the force loop, with '
              "'model' for the one-step measurement lag).",
              choices=('none', 'polynomial', 'model', 'adaptive', 'ats'),
              nodes=_RFB + ('recorder',)),
    ParamSpec('ground_preview', True, '', 'Command the ground-motion part of the reference '
              "force ahead by the predictor's loop delay (the record is known before the "
              'test), so that the response does not lag the reference (no effect with '
              "predictor 'none').",
              nodes=_RFB + ('recorder',)),
    ParamSpec('polynomial_order', 2, '', "Order of the 'polynomial' predictor's "
              'extrapolation.', 1, 3, nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_mass_kg', 0.0, 'kg', "Specimen mass of the predictor's model (0: "
              'mass_kg).', 0.0, None, nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_damping_N_s_per_m', 0.0, 'N s/m', "Specimen damping of the "
              "predictor's model (0: damping_N_s_per_m).", 0.0, None,
              nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_stiffness_N_per_m', 0.0, 'N/m', "Specimen stiffness of the "
              "predictor's model (0: stiffness_N_per_m).", 0.0, None,
              nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_tau_s', 0.0, 's', "Actuator delay assumed by the predictor on the "
              "'delay' rig, the prior of 'adaptive' (0: tau_s).", 0.0, 1.0,
              nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_io_latency_s', 0.0, 's', "The servohydraulic rig's I/O latency as the "
              "compensators model its force loop (0: io_latency_s, the rig's own): a lab's "
              'declared value, which may differ from its rig (the loop delay off).', 0.0, 0.1,
              nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_restoring_force', 'model', '', "'model': the restoring force in "
              "the 'model' predictor is k x (the linear specimen, the study's); 'measured': it "
              'is the measured one, f_m - m a - c v at the latest sample, extrapolated with '
              'the tangent stiffness estimated online from its last change; '
              "'hysteretic': a Bouc-Wen model of the member anchored on the measured restoring "
              'force and identified online from the hysteresis_* guesses, integrated over the '
              "horizon (for members that yield). 'adaptive' and 'ats' take that member model "
              "for both 'measured' and 'hysteretic'.", choices=('model', 'measured', 'hysteretic'),
              nodes=_RFB + ('recorder',)),
    ParamSpec('hysteresis_post_yield_ratio', 0.1, '', "Initial guess of the member's "
              "post-yield / initial stiffness ratio for the 'hysteretic' compensator and the "
              "'tangent_loop_shaping' force controller (identified online from there).", 0.0,
              1.0, True, nodes=_RFB + _CTRL + ('recorder',)),
    ParamSpec('hysteresis_yield_displacement_m', 0.004, 'm', "Initial guess of the member's "
              "yield displacement (Bouc-Wen D_y) for the 'hysteretic' compensator and the "
              "'tangent_loop_shaping' force controller.", 0.0, 1.0, True,
              nodes=_RFB + _CTRL + ('recorder',)),
    ParamSpec('hysteresis_n', 2.0, '', "Initial guess of the sharpness n of the member's "
              "elastic-plastic transition (Bouc-Wen) for the 'hysteretic' compensator and the "
              "'tangent_loop_shaping' force controller.", 1.0, 20.0, True,
              nodes=_RFB + _CTRL + ('recorder',)),
    ParamSpec('predictor_calibration', 'none', '', "'model' on a valve-driven rig: 'poles' "
              "tunes the pole-matching law's gains on the model of the whole sampled loop "
              '(plant, force controller, force-loop inverse, law) so that the closed loop has '
              "the reference structure's poles exactly (the law assumes the inverted loop is a "
              "held, delayed force; a stiff, lightly damped specimen's (omega dt)^2 error "
              "otherwise takes much of the reference's damping); on a rig of a structure "
              "whose DOF carries computational springs or dashpots it calibrates the coupled "
              "loop instead: corrections of the interface force the compensator sees that "
              "give the whole test's loop the reference structure's modes "
              "(seft_ros.core.law_calibration.structure_calibration; an 'adaptive' rig's "
              "as the 'model' law at its plant model's specimen); 'none': the law as "
              "derived (the study's). seft design writes 'poles'.", choices=('none', 'poles'),
              nodes=_RFB),
    ParamSpec('predictor_loop_delay_steps', 10, '', "Servohydraulic rig, 'model': the force "
              'loop is inverted to a pure delay of this many steps.', 1, 50,
              nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_loop_rehearsed', False, '', 'Set by seft design on a rig of a '
              'structure: predictor_loop_delay_steps was chosen by rehearsing the structure on '
              "the rig's plant model (false: the one-DOF test's choice, seft identify's; a "
              'calibrated rig whose DOF carries computational springs or dashpots is then '
              'named before the run).', nodes=('recorder',)),
    ParamSpec('predictor_loop_taps', 48, '', "Servohydraulic rig, 'model': taps of the FIR "
              'force-loop inverse.', 1, 1000, nodes=_RFB + ('recorder',)),
    ParamSpec('predictor_loop_csi_band', 'auto', '', "The force-loop inverse and the "
              "specimen's natural frequency: 'auto' leaves the band f_n (1 +- 6 zeta) out of "
              "the fit for a specimen damped below 5 % (its control-structure-interaction "
              "zero), 'fit' fits it like the rest of the band (seft design writes 'fit' where "
              "'auto' gives no test its model can predict: the family's 32 Hz, 5 % specimens, "
              "refused or 14-17 % NRMS x with 'auto', 0.24-0.73 % with 'fit'; "
              'seft_ros.core.predictors.loop_exclude_hz).', choices=('auto', 'fit'),
              nodes=_RFB),
    ParamSpec('predictor_loop_hf_weight', 1e-3, '', "Servohydraulic rig, 'model': weight "
              'mu of the FIR force-loop inverse on its own gain above 40 Hz (the fit minimizes '
              '|W T - z^-d|^2 in the band plus mu |W|^2 above it): smaller fits the band closer '
              'and lets |W| grow above it. With predictor_loop_delay_steps 14 and '
              'predictor_loop_taps 96, 1e-4 fits within 0.2 % up to 20 Hz (the defaults: '
              '0.2-0.9 %): what structures on the rig need (docs: structures).', 1e-9, 1.0,
              nodes=_RFB),
    ParamSpec('predictor_loop_latency_s', 0.0, 's', "Real-time mode with realtime_output "
              "'on_arrival': the measured loop latency (sample to command at the rig, p50 of "
              'the timing data); the predictor then compensates the actuator delay plus '
              "loop_latency - dt (0: as lockstep). Refused with 'latched' output (the "
              'default), where a command acts at the next tick whatever its latency.', 0.0,
              1.0, nodes=_RFB + ('recorder',)),
    ParamSpec('network_delay_s', 0.0, 's', 'Real-time mode, servohydraulic rig, the '
              'reference-force builder on another host than the force servo controller: the '
              'controller applies f_r[k] at step k + round(network_delay_s / dt), a fixed '
              "delay that covers the network's round trip (the measurement there, the "
              'reference force back) and its jitter, and the predictor predicts that much '
              'further ahead. Set it to the longest round trip plus about 1 ms (0: one '
              'host).', 0.0, 1.0,
              nodes=_RFB + _CTRL + ('recorder',)),
    ParamSpec('reference_extrapolation_steps', 2, 'steps', 'Real-time mode: when the '
              'reference force of a step has not arrived as the force servo controller acts '
              '(a stale step), the controller predicts it (reference_extrapolation) over at '
              'most this many steps beyond the newest (then held); 0: hold the newest '
              '(seft_ros.core.controller.ReferencePlayout).', 0, 100,
              nodes=_CTRL),
    ParamSpec('reference_extrapolation', 'prediction', '', "Real-time mode: how a stale "
              "step's reference force is found: 'prediction' (a linear predictor of order 8 "
              'fitted to the last 0.5 s of reference forces, where it fits them better than '
              "linear extrapolation) or 'linear' (from the two newest); over at most "
              'reference_extrapolation_steps (seft_ros.core.controller.ReferencePlayout).',
              choices=('prediction', 'linear'), nodes=_CTRL),
    ParamSpec('reference_deadline_fraction', 0.5, '', 'Real-time mode: when the reference '
              'force of step k has not arrived as the measurement of k does, the force servo '
              'controller waits for it until t_k plus this fraction of dt (and at most this '
              "fraction of dt from the measurement's arrival), then predicts it "
              '(reference_extrapolation); 0: never wait. The command must still reach the '
              'rig before t_k+1.', 0.0, 0.9, nodes=_CTRL),
    ParamSpec('adaptive_window_s', 0.5, 's', "Identification window of the 'adaptive' "
              'predictor.', 0.0, 100.0, True, nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_max_delay_s', 0.03, 's', "Largest delay the 'adaptive' predictor "
              "searches (also the bound of the 'ats' coefficient a1).", 0.0, 1.0, True,
              nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_memory_s', 5.0, 's', "Memory of the 'adaptive' predictor's recursive "
              'least squares on m, c, k: forgetting factor exp(-dt / memory).', 0.0, 1000.0,
              True, nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_excitation_N', 0.0, 'N', "'adaptive' and 'ats': the estimates are "
              'held while the running RMS of the measured force (time constant '
              'adaptive_window_s) is below this level (quiet start and coda); it also weights '
              "the estimators' priors. 0: adaptive_excitation_fraction of amplitude_N (the "
              'reference study: 20 N).', 0.0, None, nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_excitation_fraction', 0.02, '', "'adaptive' and 'ats' with "
              'adaptive_excitation_N 0: the hold level as this fraction of amplitude_N (0.02 x '
              '1000 N = 20 N in the reference study; a stiff specimen tested at 174 N: 3.5 N, '
              'where 20 N held the estimates through most of the record; 0: never held).', 0.0,
              1.0, nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_specimen_excitation_ratio', 0.05, '', "'adaptive': m, c and k are "
              'identified while the running RMS of the measured force exceeds this fraction of '
              'the hold level (adaptive_excitation_N or its fraction of amplitude_N: 1 N in the '
              "reference study), and 3 x noise_force_N (the load cell's noise): their "
              "regression takes measured signals alone, not the law's commands "
              '(seft_ros.core.predictors.specimen_excitation_level_N; 1: the hold level).',
              0.0, 1.0, nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_specimen_max_rate_per_s', 5.0, '1/s', "'adaptive': m, c and k change "
              'by at most this fraction of their configured values per second '
              '(adaptive_max_rate_per_s: the delay and gain).', 0.0, 100.0, True,
              nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_frequency_prior', 'auto', '', "'adaptive' with a plant_model that "
              "carries its specimen (seft identify's): that specimen's natural frequency (the "
              "force loop's control-structure-interaction zero) constrains m and k, in their "
              'regression and in the initial law, which starts at the m, k nearest the '
              "configured ones with that frequency; 'none': not used; 'auto': used where "
              'given (seft_ros.core.predictors.FREQUENCY_PRIOR_WEIGHT).',
              choices=('auto', 'none'), nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_max_deviation', 0.5, '', "'adaptive': the estimates of m, c, k and "
              'the actuator gain stay within this fraction of the configured values (the '
              "delay within 0..adaptive_max_delay_s).", 0.0, 0.95, True,
              nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_max_rate_per_s', 1.0, '1/s', "'adaptive' and 'ats': each estimate "
              'changes by at most this fraction of its configured (initial) value per second '
              "('adaptive''s m, c and k: adaptive_specimen_max_rate_per_s).",
              0.0, 100.0, True, nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_loop', 'auto', '', "'adaptive' on the servohydraulic rig: the force "
              "loop it inverts is identified from data ('data': command vs measured force), "
              "refitted from the rig model with the identified specimen ('model'), or with the "
              "identified specimen and I/O latency ('model_latency'); 'auto': model_latency "
              "on seft's rig model, data with a plant_model (starting from the model's loop) "
              '(seft_ros.core.predictors.adaptive_loop_mode).',
              choices=('auto', 'data', 'model', 'model_latency'), nodes=_RFB + ('recorder',)),
    ParamSpec('adaptive_loop_fit', 'auto', '', "'adaptive': the force loop's delay and gain "
              "fitted online from the command and the measured force ('fit'), or held at the "
              "force-loop inverse's ('hold'); 'auto': held when the force loop is given as "
              "data (plant_model, the inverse designed for it) or its I/O latency is fitted "
              "(adaptive_loop 'model_latency'), fitted on seft's own rig model with the "
              'declared latency (seft_ros.core.predictors.adaptive_fits_loop).',
              choices=('auto', 'fit', 'hold'), nodes=_RFB + ('recorder',)),
    ParamSpec('ats_window_s', 1.0, 's', "'ats': sliding window of the least-squares fit of "
              'a0, a1, a2 (refitted every 16 steps, Chae et al. 2013).', 0.0, 100.0, True,
              nodes=_RFB + ('recorder',)),
    ParamSpec('monitor_cutoff_hz', 0.0, 'Hz', 'Online instability monitor: band split of '
              'the measured force (the unstable mode lies above it, the response below); 0: '
              "25 Hz, or twice the reference structure's natural frequency where that is higher "
              '(a stiff specimen; seft_ros.core.monitor.monitor_cutoff_hz).',
              0.0, None, nodes=_RFB),
    ParamSpec('monitor_window_s', 0.2, 's', "Time constant of the monitor's running RMS.",
              0.0, 10.0, True, nodes=_RFB),
    ParamSpec('monitor_threshold', 1.0, '', 'The run is aborted when the high-band RMS exceeds '
              'this times (low-band RMS + 5 % of the ground-motion force + monitor_floor_N); 0 '
              'disables. Disarmed in an open-loop identification run (excitation on the '
              "valve: the loop it guards is open), where the rig's stroke_limit_m and "
              'force_limit_N guard the run.', 0.0, 100.0, nodes=_RFB),
    ParamSpec('divergence_factor', 3.0, '', 'The run is aborted (unstable, diverging) when '
              "a rig's measured displacement or force exceeds this times the pre-run "
              "reference analysis's peak of it plus 6 times the channel's declared noise "
              '(noise_displacement_m, noise_force_N) plus monitor_floor_N (for the '
              'displacement monitor_floor_N / k): a growth the monitor cannot see, at the '
              "reference structure's own frequency. A yielding specimen is watched on its "
              'force only; no check without a prediction (an OpenSees model, an '
              'identification run). 0 disables (seft_ros.core.monitor.DivergenceGuard).',
              0.0, 1000.0, nodes=_RFB),
    ParamSpec('specimen_uncertainty', 0.0, '', 'How far the specimens may be from their '
              'declared stiffness, as a fraction (0.2: 0.8 to 1.2 times it; 0: not declared). '
              'The pre-run guard refuses a run whose compensation is not stable over that range '
              '(its robustness margin, printed before every run).', 0.0, 0.95, nodes=_RFB),
    ParamSpec('specimen_check', 'warn', '', "What the builder does when a rig identifies its "
              'specimen (its load-cell force against its motion, Eq. 5.1) outside the declared '
              'stiffness by more than specimen_uncertainty (0: 10 %; adaptive: at least '
              "adaptive_max_deviation): 'warn' (one line, in the report and the bag), 'abort' "
              "(stop the run safely with the reason) or 'off'.",
              choices=('warn', 'abort', 'off'), nodes=_RFB),
    ParamSpec('monitor_floor_N', 50.0, 'N', "Absolute floor of the monitor's comparison "
              '(keeps sensor noise from tripping it).', 0.0, None, nodes=_RFB),
    # -- force servo controller -------------------------------------------------------------
    ParamSpec('valve_limit_V', 10.0, 'V', 'Saturation of the servo-valve command.', 0.0, 100.0,
              True, nodes=_CTRL),
    ParamSpec('force_controller', 'loop_shaping', '', "Force controller of the servo valve "
              "(seft_ros.core.controller): 'loop_shaping' (the reference study's C_f, paper "
              "Eq. 3.1); 'integral' (C_f with integral action below force_integral_hz); "
              "'velocity_feedback' (velocity feedback compensation A/k_q of the "
              'control-structure interaction, Dimig et al. 1999, Zhao et al. 2005, with a PI '
              "force controller that cancels the oil column's leakage pole: the force loop "
              "then does not depend on the specimen's stiffness); 'tangent_loop_shaping' "
              "('specimen_loop_shaping' with its control-structure-interaction poles, this "
              "rig's own (c/m, k/m), scheduled on the member's "
              'tangent stiffness force_tangent_horizon_s ahead, from a Bouc-Wen model '
              "identified online: for members that yield); 'specimen_loop_shaping' (the "
              "study's rule for this rig's own specimen: g/(s^2 + (c/m) s + k/m), e.g. a second "
              "pier of another stiffness); 'transfer_function' (a lab's own controller, or the "
              'one seft design / seft identify --params designed: force_controller_tf).',
              choices=('loop_shaping', 'integral', 'velocity_feedback', 'tangent_loop_shaping',
                       'specimen_loop_shaping', 'transfer_function'),
              nodes=_CTRL + _RFB),
    ParamSpec('force_controller_tf', 'none', '', "'transfer_function' force controller: the "
              'force error [N] to valve command [V] as a mapping {num: [...], den: [...], dt: '
              'period [s] (absent or 0: continuous, polynomials in s, discretized by Tustin at '
              'dt, prewarped at prewarp_hz if given; else polynomials in z, descending powers, '
              "at the run's dt), prewarp_hz, method: text}; in a configuration file a YAML "
              'mapping, here its JSON.', nodes=_CTRL + _RFB),
    ParamSpec('force_tangent_horizon_s', 0.005, 's', "'tangent_loop_shaping': how far ahead "
              "of the sample the member's tangent stiffness is predicted: when the valve "
              'command acts on the flow (reference rig: I/O latency 3 ms and valve time '
              'constant 2.5 ms; 5 ms measured best).', 0.0, 0.1,
              nodes=_CTRL + _RFB),
    ParamSpec('force_integral_hz', 2.0, 'Hz', "Corner of the integral action of the 'integral' "
              'force controller.', 0.0, 100.0, True, nodes=_CTRL + _RFB),
    ParamSpec('force_crossover_hz', 12.0, 'Hz', "Crossover of the 'velocity_feedback' force "
              'loop (its gain follows from the nominal piston area, oil volume, bulk modulus, '
              'valve flow gain and leakage coefficients).', 0.0, 100.0, True,
              nodes=_CTRL + _RFB),
    ParamSpec('velocity_lead_s', 0.0, 's', "'velocity_feedback': the fed-back velocity is "
              'advanced by this time with the measured acceleration (v + T a), offsetting the '
              'I/O latency and the valve lag.', 0.0, 0.1, nodes=_CTRL + _RFB),
    ParamSpec('velocity_filter_hz', 20.0, 'Hz', "'velocity_feedback' controllers: cut-off of "
              'the 2nd-order Butterworth low-pass on the fed-back velocity (keeps the delayed '
              'velocity feedback off the ~90 Hz oil-column resonance; 0: unfiltered).', 0.0,
              200.0, nodes=_CTRL + _RFB),
    ParamSpec('saturation_window_s', 0.1, 's', 'Window of the loss-of-control interlock: the '
              'run is aborted when the valve command was saturated in more than '
              'saturation_abort_fraction of this window.', 0.0, 10.0, True, nodes=_CTRL),
    ParamSpec('saturation_abort_fraction', 0.5, '', 'Fraction of saturated samples in '
              'saturation_window_s that aborts the run (1: never).', 0.0, 1.0, True,
              nodes=_CTRL),
    # -- rig --------------------------------------------------------------------------------
    ParamSpec('rig_model', 'servohydraulic', '', "Simulated rig: 'delay' (measured force = "
              "reference force delayed by tau_s, paper Sec. 5.2), 'servohydraulic' (seft's "
              "model of the study's rig; also what a lab's valve-driven rig behind the UDP "
              "bridge is), 'state_space' (a lab's own model of its actuator and specimen, "
              "plant_model: rehearse the test on it) or 'actuator' (seft_plant_sim's family of "
              "actuators seft did not design its models for: actuator_family). Every rig but "
              "'delay' takes the valve voltage from the force servo controller.",
              choices=('delay', 'servohydraulic', 'state_space', 'actuator'), nodes=_ALL),
    ParamSpec('plant_model', 'none', '', "The force loop's plant as data: valve command [V] to "
              'measured force, displacement, velocity and acceleration with the specimen in the '
              'loop (seft_msgs_py.plant), a mapping {form: state_space | transfer_function, dt '
              '(0: continuous), io_delay_s (at most 50 steps of dt: '
              'seft_msgs_py.plant.MAX_IO_DELAY_STEPS), a/b/c or num/den, specimen, '
              'uncertainty} (written '
              "by seft identify --params, or the lab's own); in a configuration file a YAML "
              "mapping or the path of a YAML file holding one, here its JSON. 'none': the "
              "servohydraulic rig's own model. The force-controller design, the compensators' "
              'force-loop inverse, the stability guard and seft identify take it; rig_model '
              "'state_space' simulates it unless rig_plant_model is given.",
              nodes=_RIG + _CTRL + _RFB),
    ParamSpec('rig_plant_model', 'none', '', "rig_model 'state_space': the plant the simulated "
              "rig steps, as plant_model's mapping (or file), when it is not the compensators' "
              "and the guard's plant_model: the lab's own model of its actuator and specimen, "
              'kept apart from the one seft identify --params writes as plant_model, so that a '
              "rehearsal runs the identified design on the lab's plant. 'none': the rig "
              'simulates plant_model. Refused with any other rig_model.', nodes=_RIG),
    ParamSpec('actuator_family', 'valve_2nd_order', '', "rig_model 'actuator': the member of "
              "seft_plant_sim's actuator family (seft_plant_sim.actuator.FAMILY: servo-valves of "
              'second order and three stages, a leaky actuator, valve flow through an orifice, '
              'Coulomb friction, a longer pure delay) driving this specimen.',
              choices=('valve_2nd_order', 'valve_3_stage', 'leaky', 'orifice_flow',
                       'coulomb_friction', 'pure_delay'), nodes=_RIG),
    ParamSpec('actuator_spread', 0.0, '', "rig_model 'actuator': Monte-Carlo spread of the "
              "family member's parameters, a fraction (0.2: each drawn uniformly within +-20 "
              '%; 0: nominal).', 0.0, 0.9, nodes=_RIG),
    ParamSpec('actuator_seed', 1, '', "rig_model 'actuator': seed of the Monte-Carlo draw "
              '(actuator_spread).', 0, None, nodes=_RIG),
    ParamSpec('rig_calibration', 'us_customary', '', 'Servohydraulic rig: the units the '
              "reference controller C_f = 37/(s^2+17.14 s+4002) (paper Eq. 3.1) is read in. "
              "'us_customary': V/lbf (37/4.448 V/N; the valve passes 2.0 m/s at 10 V); 'si': "
              'V/N (0.45 m/s at 10 V). The valve flow gain scales with it, so the force loop '
              'is the same in both.', choices=('us_customary', 'si'),
              nodes=_RIG + _CTRL + _RFB + ('recorder',)),
    ParamSpec('tau_s', 0.01, 's', "Actuator time delay of the 'delay' rig (paper Eq. 5.2).",
              0.0, 1.0, True, nodes=_RIG),
    ParamSpec('stroke_limit_m', 0.076, 'm', 'Actuator stroke limit (+/-); beyond it the run is '
              'aborted safely.', 0.0, None, True, nodes=_RIG),
    ParamSpec('force_limit_N', 24.5e3, 'N', 'Actuator force limit (+/-); beyond it the run is '
              'aborted safely.', 0.0, None, True, nodes=_RIG),
    ParamSpec('noise_force_N', 0.0, 'N', "Standard deviation of load-cell noise (a lab's "
              "rig: declare its load cell's; 'adaptive' identifies the specimen above 3 times "
              'it).', 0.0, None, nodes=_RIG + _RFB),
    ParamSpec('noise_displacement_m', 0.0, 'm', 'Standard deviation of displacement-sensor '
              'noise.', 0.0, None, nodes=_RIG + _RFB),
    ParamSpec('noise_velocity_m_s', 0.0, 'm/s', 'Standard deviation of velocity-sensor noise.',
              0.0, None, nodes=_RIG + _RFB),
    ParamSpec('noise_acceleration_m_s2', 0.0, 'm/s^2', 'Standard deviation of accelerometer '
              'noise.', 0.0, None, nodes=_RIG + _RFB),
    ParamSpec('noise_seed', 1, '', 'Seed of the sensor-noise generator (runs are '
              'reproducible).', 0, None, nodes=_RIG),
    # -- servohydraulic rig (seft_plant_sim.servohydraulic.ServoHydraulicParams) -------------
    ParamSpec('piston_area_m2', 1.18e-3, 'm^2', 'Effective piston area A.', 0.0, None, True,
              nodes=_RIG + _CTRL),
    ParamSpec('oil_bulk_modulus_Pa', 1.0e9, 'Pa', 'Effective bulk modulus beta of the oil.',
              0.0, None, True, nodes=_RIG + _CTRL),
    ParamSpec('actuator_volume_m3', 3.35e-4, 'm^3', 'Oil volume V_t of both chambers and '
              'lines (with A and beta it sets the ~90 Hz oil-column resonance).', 0.0, None,
              True, nodes=_RIG + _CTRL),
    ParamSpec('valve_time_constant_s', 0.0025, 's', 'Time constant of the first-order '
              'servo-valve spool.', 0.0, None, True, nodes=_RIG),
    ParamSpec('valve_flow_gain_m3_per_s_V', 0.0, 'm^3/(s V)', 'Linearized valve flow gain '
              'k_q (with the controller gain it sets the ~12 Hz loop crossover; 0: that of '
              "rig_calibration, 2.358e-4 'us_customary' or 5.3e-5 'si').", 0.0, None,
              nodes=_RIG + _CTRL),
    ParamSpec('valve_pressure_coefficient_m3_per_s_Pa', 8e-12, 'm^3/(s Pa)', 'Valve '
              'flow-pressure coefficient K_c at null.', 0.0, None, nodes=_RIG + _CTRL),
    ParamSpec('leakage_coefficient_m3_per_s_Pa', 2e-12, 'm^3/(s Pa)', 'Cross-port leakage '
              'C_l past the piston seals.', 0.0, None, nodes=_RIG + _CTRL),
    ParamSpec('io_latency_s', 0.003, 's', 'Transport delay of the valve command (DAQ sample '
              'and hold, one control period of computation, D/A, valve amplifier, anti-alias '
              'group delay); it puts the uncompensated stability boundary at alpha = 1.32.',
              0.0, 1.0, nodes=_RIG),
    ParamSpec('anti_alias_cutoff_hz', 0.0, 'Hz', 'Cut-off of a 2nd-order Butterworth on the '
              'force and acceleration channels (0: off; its delay is lumped in io_latency_s).',
              0.0, None, nodes=_RIG),
    ParamSpec('accelerometer_range_m_s2', 39.2, 'm/s^2', 'Accelerometer full scale (4 g); '
              'readings saturate there, and a reading at it is flagged (0: unlimited).', 0.0,
              None, nodes=_RIG + _RFB),
    ParamSpec('force_range_N', 24.5e3, 'N', 'Load-cell full scale; readings saturate there, '
              'and a reading at it is flagged (0: unlimited).', 0.0, None, nodes=_RIG + _RFB),
    ParamSpec('displacement_range_m', 0.1, 'm', 'Displacement-transducer full scale; readings '
              'saturate there, and a reading at it is flagged (0: unlimited).', 0.0, None,
              nodes=_RIG + _RFB),
    ParamSpec('velocity_range_m_s', 2.5, 'm/s', 'Velocity-sensor full scale; readings '
              'saturate there, and a reading at it is flagged (0: unlimited).', 0.0, None,
              nodes=_RIG + _RFB),
    ParamSpec('actuator_velocity_limit_m_s', 0.0, 'm/s', 'Largest piston velocity the '
              "actuator delivers (0: the servohydraulic rig's valve flow at valve_limit_V over "
              'the piston area; not declared on the delay rig).', 0.0, None, nodes=_RIG),
    ParamSpec('watchdog_timeout_s', 0.02, 's', 'Real-time mode: when no command (valve '
              'command, or reference force on the delay rig) has arrived for this long, the rig '
              'goes to its safe state and the run ends aborted; likewise when the force servo '
              'controller has had no new reference force, or the reference-force builder no '
              'measurement or no new ground-motion sample, for this long (a lost link between '
              'hosts).', 0.0, 10.0, True,
              nodes=_RIG + _RFB + _CTRL),
    ParamSpec('safe_ramp_s', 0.2, 's', "Real-time mode: on any abort the rig's command (the "
              'actuator force on the delay rig, the valve opening on the servohydraulic rig) '
              'is ramped linearly to zero over this time, then held at zero (valve closed).',
              0.0, 10.0, True, nodes=_RIG),
    ParamSpec('realtime_output', 'latched', '', 'Real-time mode: when the rig outputs the '
              "command computed from sample k. 'latched': at the next tick t_k+1 (the lockstep "
              "timing), or on arrival if it comes later; 'on_arrival': on arrival. Either way it "
              'reaches the actuator after the hardware latency io_latency_s - dt '
              '(servohydraulic) or tau_s (delay rig); the actuator and state_space rigs hold '
              'their latency in their model and add none, so latched they run one sample '
              'behind lockstep.', choices=('latched', 'on_arrival'),
              nodes=_RIG + _RFB),
    ParamSpec('realtime_late_command', 'hold', '', 'Real-time mode: what the rig outputs '
              'when the command of a sample has not arrived by the instant it is due (a late '
              "command; realtime_output). 'hold': the newest command it has (a zero-order "
              "hold); 'predict': the late command's linear prediction from the commands "
              'received (order 8, fitted over the last 0.5 s; at most 20 ms beyond the '
              'newest, then held), until it arrives (seft_plant_sim.realtime.WallClockRig; '
              'docs: the rig contract).', choices=('hold', 'predict'),
              nodes=_RIG),
    ParamSpec('realtime_substep_s', 1e-4, 's', "Real-time mode: sub-step of the rig's plant "
              'integration between ticks (command changes are applied on this grid).', 1e-6,
              1.0, True, nodes=_RIG),
    ParamSpec('rig_interface', 'simulated', '', "What the rig node is: 'simulated' (seft's "
              "rig_model in the node) or 'udp_bridge' (real time only: a bridge to a lab's "
              'real-time controller, or seft emulate-controller, over UDP; the controller is '
              "the test's clock and rig_model says what it takes: the valve voltage "
              "('servohydraulic': the graph closes the force loop) or the force reference "
              "('delay': the controller does). docs: the rig contract).",
              choices=('simulated', 'udp_bridge'), nodes=_RIG),
    ParamSpec('udp_controller_address', '127.0.0.1:47101', '', "UDP bridge: host:port of the "
              "lab's real-time controller (seft emulate-controller binds it).", nodes=_RIG),
    ParamSpec('udp_local_port', 0, '', "UDP bridge: the rig node's own port (0: any; the "
              'controller answers the address it hears from).', 0, 65535, nodes=_RIG),
    ParamSpec('udp_heartbeat_s', 0.005, 's', 'UDP bridge: each side sends a heartbeat this '
              'often when it has nothing else to send; silence for watchdog_timeout_s brings '
              'both sides to the safe state.', 1e-4, 1.0, True, nodes=_RIG),
    ParamSpec('udp_max_bad_datagrams', 10, '', 'UDP bridge: a datagram of the wrong length, '
              'magic, version or kind is rejected with one log line; this many end the run '
              'safely.', 1, 1000000, nodes=_RIG),
    ParamSpec('wait_for_recorder', False, '', 'The rig starts stepping only once the recorder '
              'subscribes to its topics (set by seft run, so no sample precedes the recorder).',
              nodes=_RIG),
    ParamSpec('recorder_window_steps', 1000, '', 'Lockstep flow control: the rig waits while '
              'the recorder is more than this many steps behind (0: never waits; else at least '
              '100: the recorder acknowledges every 50 steps and takes the samples in batches of '
              '10).', 0, 1900, nodes=_RIG),
    # -- who may command the rig (seft_msgs_py.provenance) -----------------------------------
    ParamSpec('run_token', 'none', '', "The run's token: 16 hex digits that seft run draws at "
              'random for each run and hands to its nodes; every message that commands the rig '
              "carries the run's seal (the token, or with message_auth 'hmac' an HMAC) in "
              'header.frame_id (record batches: their first label), and a node drops and names '
              "a message without it ('none': nodes by hand, unsealed messages only).",
              nodes=_ALL),
    ParamSpec('message_auth', 'token', '', "How a message shows it is the run's: 'token' (the "
              'run token in the clear: keeps out another test on the same domain and an earlier '
              "run, not a sender that reads the domain) or 'hmac' (an HMAC-SHA256 of each "
              'message and UDP datagram with the shared key of auth_key_file: only a holder of '
              'the key can command the rig; docs: network).', choices=('token', 'hmac'),
              nodes=_ALL),
    ParamSpec('auth_key_file', 'none', '', "message_auth 'hmac': the file of the test's "
              'shared key (at least 16 bytes, e.g. 64 hex digits; the same key on every host '
              "and at the lab's controller; keep it private: it is never sent).", nodes=_ALL),
    # -- recorder ---------------------------------------------------------------------------
    ParamSpec('bag_path', 'seft_bag', '', 'Directory of the rosbag2 bag to write (must not '
              'exist yet).', nodes=('recorder',)),
    ParamSpec('bag_storage', 'mcap', '', 'rosbag2 storage plugin of the bag.',
              choices=('mcap', 'sqlite3'), nodes=('recorder',)),
    ParamSpec('wait_for_live_view', False, '', 'The recorder lets the rig start only once the '
              'live view (seft run --live, set by seft run) has matched every record stream of '
              'the run, so that it shows the run from its first sample; at most 5 s, then the '
              'run starts with a warning and the view joins late.', nodes=('recorder',)),
)

_BY_NAME = {s.name: s for s in SCHEMA}


def spec(name: str) -> ParamSpec:
    """Return the :class:`ParamSpec` called `name`.

    Raises
    ------
    ParameterError
        If no parameter has that name.
    """
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ParameterError(unknown_parameter(name)) from None


def unknown_parameter(name: str) -> str:
    """The message for a parameter name that is not in the schema, with the closest names.

    Up to two names of the schema as close as the closest one (within 0.1 of its
    ``difflib.get_close_matches`` similarity ratio, at least 0.6), or, with none, a
    pointer to the parameter reference.

    Parameters
    ----------
    name : str
        The name given.

    Returns
    -------
    str
        e.g. ``"unknown parameter 'stiffnes_N_per_m' (did you mean 'stiffness_N_per_m'?)"``.
    """
    import difflib
    close = difflib.get_close_matches(name, list(_BY_NAME), n=2, cutoff=0.6)
    if close:
        best = difflib.SequenceMatcher(None, close[0], name).ratio()
        close = [c for c in close
                 if difflib.SequenceMatcher(None, c, name).ratio() >= best - 0.1]
        return f'unknown parameter {name!r} (did you mean {" or ".join(map(repr, close))}?)'
    return f'unknown parameter {name!r} (the parameter reference lists them)'


#: The rig models driven by the valve voltage, whose force loop the force servo controller
#: closes (every one but the 'delay' rig, which takes the reference force).
VALVE_RIG_MODELS = ('servohydraulic', 'state_space', 'actuator')


def valve_commanded(rig_model) -> bool:
    """Whether a rig model takes the valve voltage (:data:`VALVE_RIG_MODELS`); a mapping of
    parameters is read for its ``rig_model``."""
    if isinstance(rig_model, Mapping):
        rig_model = rig_model.get('rig_model', 'servohydraulic')
    return rig_model in VALVE_RIG_MODELS


def identification_run(params: Mapping) -> bool:
    """Whether run parameters `params` describe an identification run (``excitation`` other
    than ``'none'``: a known signal plays instead of a ground motion,
    :mod:`seft_ros.core.excitation`), not a test: nothing of a test's (its error, its valve's
    saturation, its settings' cost) is judged of it."""
    return params.get('excitation', 'none') != 'none'


def rig_plant_parameter(params: Mapping) -> str | None:
    """The parameter holding the plant a ``state_space`` rig steps.

    Parameters
    ----------
    params : mapping
        The rig's parameters (``rig_plant_model``, ``plant_model``: JSON text, a mapping or
        'none').

    Returns
    -------
    str or None
        ``'rig_plant_model'`` when it is given (the rig's own plant, apart from the
        compensators' and the guard's ``plant_model``), else ``'plant_model'`` when that is
        given, else None.
    """
    for name in ('rig_plant_model', 'plant_model'):
        if params.get(name, 'none') not in (None, '', 'none'):
            return name
    return None


def graph_nodes(rig_model: str) -> tuple[str, ...]:
    """The data nodes of a run's graph, in start order (the rig last; the recorder apart).

    The force servo controller only on a valve-commanded rig (:data:`VALVE_RIG_MODELS`): the
    'delay' rig takes the reference force directly.
    """
    nodes = ('ground_motion_publisher', 'reference_force_builder')
    if valve_commanded(rig_model):
        nodes += ('force_servo_controller',)
    return nodes + ('rig',)


def specs_for_node(node: str) -> list[ParamSpec]:
    """Return the specs a node declares, in schema order.

    The recorder declares every parameter: it stores the whole run configuration in the bag.
    """
    if node == 'recorder':
        return list(SCHEMA)
    return [s for s in SCHEMA if node in s.nodes]


def defaults() -> dict[str, Any]:
    """Return ``{name: default}`` for every parameter."""
    return {s.name: s.default for s in SCHEMA}


def validate_value(name: str, value: Any, *, where: str = '') -> Any:
    """Check one value against the schema and return it coerced to the parameter's type.

    Integers are accepted for float parameters; nothing else is coerced.

    Parameters
    ----------
    name : str
        Parameter name.
    value : object
        Candidate value.
    where : str
        Context for the message (a file name), prefixed as ``'<where>: '``.

    Raises
    ------
    ParameterError
        Unknown name, wrong type, non-finite number, out of range or not one of the choices;
        the message names the parameter and what was expected.
    """
    prefix = f'{where}: ' if where else ''
    if name not in _BY_NAME:
        raise ParameterError(prefix + unknown_parameter(name))
    s = spec(name)
    expected = s.expected()
    bad = ParameterError(f'{prefix}parameter {name}={value!r}: expected {expected}')
    if isinstance(s.default, bool):
        if not isinstance(value, bool):
            raise bad
        return value
    if isinstance(s.default, str):
        if not isinstance(value, str) or (s.choices and value not in s.choices):
            raise bad
        if not value:
            raise ParameterError(f'{prefix}parameter {name}: expected a non-empty text')
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise bad
    if isinstance(s.default, int) and not isinstance(value, int):
        if not float(value).is_integer():
            raise bad
        value = int(value)
    if isinstance(s.default, float):
        value = float(value)
    if isinstance(value, float) and not math.isfinite(value):
        raise bad
    if s.minimum is not None:
        if value < s.minimum or (s.exclusive_minimum and value == s.minimum):
            raise bad
    if s.maximum is not None and value > s.maximum:
        raise bad
    return value


#: Text parameters whose value is a mapping in a configuration file (held as its JSON): a
#: plant model (the compensators' and the state_space rig's own) and a lab's force controller.
MAPPING_PARAMETERS = ('plant_model', 'rig_plant_model', 'force_controller_tf')

def mapping_value(value, *, where: str, expected: str) -> dict:
    """The mapping a mapping parameter holds (:data:`MAPPING_PARAMETERS`): `value` itself or
    its JSON text.

    Raises
    ------
    ParameterError
        Text that is not JSON, or not a mapping (``'<where>: ...'``, naming `expected`).
    """
    import json
    doc = value
    if isinstance(value, str):
        try:
            doc = json.loads(value)
        except json.JSONDecodeError as exc:
            raise ParameterError(f'{where}: not JSON ({exc.msg}); expected {expected}') from None
    if not isinstance(doc, Mapping):
        raise ParameterError(f'{where}: expected {expected}')
    return dict(doc)


#: Parameters that may hold a list on the command line (one run per value).
LIST_PARAMETERS = ('alpha', 'predictor', 'record')


def from_text(name: str, text: str, *, where: str = '') -> Any:
    """Read a value given as text (``--set NAME=VALUE``) by the parameter's type.

    The schema's type decides, not YAML's guessing: ``1e-12`` is a float for a float
    parameter (YAML 1.1 reads it as text), ``on`` is text for a text parameter. A bool is
    ``true`` or ``false`` (any case); an int a whole number; a float any Python float
    literal; text is taken as it is. For ``alpha``, ``predictor`` and ``record`` a list
    ``[a, b]`` gives one run per value. The value is then checked by
    :func:`validate_value`.

    Parameters
    ----------
    name : str
        Parameter name.
    text : str
        The value as typed.
    where : str
        Context for the message, prefixed as ``'<where>: '``.

    Returns
    -------
    bool, int, float, str or list
        The value in the parameter's type (a list of them for a list).

    Raises
    ------
    ParameterError
        Unknown parameter, or a text that is no value of the parameter's type or out of its
        range; the message names the parameter and what was expected.
    """
    prefix = f'{where}: ' if where else ''
    if name not in _BY_NAME:
        raise ParameterError(prefix + unknown_parameter(name))
    s = spec(name)
    text = text.strip()
    if name in LIST_PARAMETERS and text.startswith('[') and text.endswith(']'):
        items = [t.strip() for t in text[1:-1].split(',') if t.strip()]
        return [from_text(name, t, where=where) for t in items]
    bad = ParameterError(f'{prefix}parameter {name}={text!r}: expected {s.expected()}')
    if isinstance(s.default, bool):
        if text.lower() not in ('true', 'false'):
            raise bad
        value: Any = text.lower() == 'true'
    elif isinstance(s.default, int):
        try:
            value = int(text)
        except ValueError:
            raise bad from None
    elif isinstance(s.default, float):
        try:
            value = float(text)
        except ValueError:
            raise bad from None
    else:
        value = text
    return validate_value(name, value, where=where)


def resolve(overrides: Mapping[str, Any] | Iterable[tuple[str, Any]] = (), *,
            where: str = '', origin: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Return the defaults updated with validated `overrides`.

    `origin` names the source of a value (parameter name to a file or ``'command line'``)
    where it is not `where`: a bad value is named as its source's.

    Raises
    ------
    ParameterError
        As :func:`validate_value`, for the first bad override.
    """
    values = defaults()
    items = overrides.items() if isinstance(overrides, Mapping) else overrides
    origin = origin or {}
    for name, value in items:
        values[name] = validate_value(name, value, where=origin.get(name, where))
    return values


#: Parameters that are legitimately set per node and never compared between nodes
#: (``use_sim_time`` is rclpy's, not the schema's).
#: Parameters that are the test's, not a rig's: a structure's ``rigs`` section may not set
#: them, and nodes in different namespaces must agree on them (:func:`shared_mismatches`).
#: Each rig's delay compensator (``predictor`` and its parameters) is the rig's: one rig of
#: a structure may identify its specimen online while another uses its model.
TEST_PARAMETERS = frozenset({
    'dt', 'alpha', 'mode', 'n_steps', 'record', 'amplitude_N', 'scale_factor', 'time_scale',
    'record_resampling', 'duration_s', 'preview_steps', 'excitation', 'excitation_input',
    'excitation_amplitude',
    'excitation_band_low_hz', 'excitation_band_hz', 'excitation_seed',
    'predictor_loop_latency_s', 'network_delay_s', 'monitor_cutoff_hz', 'monitor_window_s',
    'monitor_threshold', 'monitor_floor_N', 'divergence_factor', 'wait_for_recorder',
    'recorder_window_steps',
    'wait_for_live_view', 'bag_path', 'bag_storage', 'structure', 'structure_builders',
    'realtime_priority', 'specimen_uncertainty', 'run_token', 'message_auth',
})


PER_NODE = frozenset({'bag_path', 'bag_storage', 'wait_for_recorder', 'recorder_window_steps',
                      'wait_for_live_view', 'use_sim_time', 'realtime_priority', 'auth_key_file'})


def _node_rank(node: str) -> tuple[int, str, str]:
    """Sort key of a node name (qualified, ``<rig>/<node>``): the graph's nodes in ``NODES``
    order (of their kind, then by rig), then others by name."""
    rig, _, kind = node.rpartition('/')
    return (NODES.index(kind), rig, '') if kind in NODES else (len(NODES), '', node)


def _comparable(name: str, value: Any) -> tuple:
    """Hashable comparison key of `value`: the schema-coerced value (so 1 and 1.0 agree for a
    float parameter), or its repr when the schema rejects it (never equal to a valid one)."""
    try:
        return ('valid', validate_value(name, value))
    except ParameterError:
        return ('invalid', type(value).__name__, repr(value))


def _shown(name: str, value: Any) -> str:
    key = _comparable(name, value)
    return repr(key[1] if key[0] == 'valid' else value)


def shared_mismatches(node_params: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """List the shared parameters on which the nodes disagree, one line per parameter.

    Every schema parameter that two or more of the given nodes declare must have one value:
    the graph computes one experiment, so the reference-force builder's alpha, say, must be
    the alpha the rig and the recorder hold. Values are compared after :func:`validate_value`
    coercion, so floats compare exactly and an int equals the float of the same value; a value
    the schema rejects differs from every other value.

    Parameters
    ----------
    node_params : mapping of str to mapping of str to object
        ``{node name: {parameter name: value}}``, the parameters each node resolved (the JSON
        of ``/seft/node_parameters``). Names outside the schema (``use_sim_time``) and the
        per-node parameters ``PER_NODE`` are ignored.

    Returns
    -------
    list of str
        In schema order, for each differing parameter the line ``'parameter <name> differs:
        <node>=<value>, ...'`` naming every node that declares it with its value (``repr`` of
        the coerced value), grouped by value: the group held by the fewest nodes first (ties:
        the group of the earlier node), nodes within a group in ``NODES`` order, other names
        alphabetically. Empty when the nodes agree.

    Raises
    ------
    ParameterError
        If a node's parameters are not a mapping.

    Examples
    --------
    >>> shared_mismatches({'reference_force_builder': {'alpha': 0.5, 'dt': 0.002},
    ...                    'rig': {'alpha': 0, 'dt': 0.002}})
    ['parameter alpha differs: reference_force_builder=0.5, rig=0.0']
    """
    nodes = sorted(node_params, key=_node_rank)
    for node in nodes:
        if not isinstance(node_params[node], Mapping):
            raise ParameterError(f'parameters of node {node!r}: expected a mapping of parameter '
                                 f'names to values, got {type(node_params[node]).__name__}')
    # a structure's rig sections set their rig's parameters: the rig and controller nodes of
    # a rig ('<rig>/rig', '<rig>/force_servo_controller') agree among themselves, and with the
    # others (another rig's, the root's, a builder in a rig's namespace, which works with the
    # whole test's parameters) on the test's parameters only
    scopes: dict[str, list[str]] = {}
    for node in nodes:
        rig, _, kind = node.rpartition('/')
        scopes.setdefault(rig if kind in RIG_SCOPED_NODES else '', []).append(node)
    lines = []
    for s in SCHEMA:
        if s.name in PER_NODE:
            continue
        groups_of = [nodes] if s.name in TEST_PARAMETERS else list(scopes.values())
        for members in groups_of:
            line = _differs(s.name, [n for n in members if s.name in node_params[n]],
                            node_params)
            if line:
                lines.append(line)
    return lines


def _differs(name: str, holders: list[str], node_params) -> str | None:
    """The line of :func:`shared_mismatches` for one parameter among `holders`, or None."""
    if len(holders) < 2:
        return None
    groups: dict[tuple, list[str]] = {}
    for n in holders:
        groups.setdefault(_comparable(name, node_params[n][name]), []).append(n)
    if len(groups) < 2:
        return None
    ordered = sorted(groups.values(), key=lambda g: (len(g), holders.index(g[0])))
    return f'parameter {name} differs: ' + ', '.join(
        f'{n}={_shown(name, node_params[n][name])}' for g in ordered for n in g)


#: The source node of the parameters that several nodes declare (see :data:`VALUE_SOURCE`).
_SHARED_SOURCE = {
    'alpha': 'reference_force_builder',     # Eq. 5.3 is computed there
    'structure': 'reference_force_builder',  # it integrates the computational part
    'structure_builders': 'reference_force_builder',   # where the builders run
    'dt': 'rig', 'mode': 'rig', 'n_steps': 'rig',  # the rig is the clock
    'mass_kg': 'rig', 'stiffness_N_per_m': 'rig', 'damping_N_s_per_m': 'rig',  # the specimen
    'rig_model': 'rig', 'rig_calibration': 'rig',
    'piston_area_m2': 'rig', 'oil_bulk_modulus_Pa': 'rig', 'actuator_volume_m3': 'rig',
    'valve_flow_gain_m3_per_s_V': 'rig', 'valve_pressure_coefficient_m3_per_s_Pa': 'rig',
    'leakage_coefficient_m3_per_s_Pa': 'rig',  # the rig's; the controller's velocity design
    'force_controller': 'force_servo_controller', 'force_integral_hz': 'force_servo_controller',
    'force_controller_tf': 'force_servo_controller', 'plant_model': 'rig',
    'force_crossover_hz': 'force_servo_controller', 'velocity_lead_s': 'force_servo_controller',
    'velocity_filter_hz': 'force_servo_controller',
    'force_tangent_horizon_s': 'force_servo_controller',
    # the member's model: the compensator's (its estimates are recorded); the tangent
    # controller starts from the same guess
    'hysteresis_post_yield_ratio': 'reference_force_builder',
    'hysteresis_yield_displacement_m': 'reference_force_builder',
    'hysteresis_n': 'reference_force_builder',
    'realtime_priority': 'rig',             # per node; the rig's is the clock's
    # the sensors' ranges: the rig's (the builder flags the readings at them)
    'force_range_N': 'rig', 'displacement_range_m': 'rig', 'velocity_range_m_s': 'rig',
    'accelerometer_range_m_s2': 'rig',
    # the load cell's noise: the rig's (the builder's specimen identification stays above it,
    # predictors.specimen_excitation_level_N)
    'noise_force_N': 'rig',
    # the displacement sensor's noise: the rig's (the builder's divergence guard allows for it)
    'noise_displacement_m': 'rig',
    # the velocity sensor's and the accelerometer's noise: the rig's (the builder's specimen
    # check takes them out of its regression, monitor.SpecimenCheck)
    'noise_velocity_m_s': 'rig', 'noise_acceleration_m_s2': 'rig',
    'watchdog_timeout_s': 'rig',            # the rig's watchdog; the others watch their inputs
    'network_delay_s': 'reference_force_builder',   # the delay its predictor compensates
    # the record's scaling: the ground-motion publisher's (the builder's estimators scale
    # their hold threshold with it, predictors.excitation_level_N)
    'amplitude_N': 'ground_motion_publisher',
    # the record: the ground-motion publisher plays it (the builder's divergence guard reads
    # the same record for the pre-run reference analysis of its peaks)
    'record': 'ground_motion_publisher', 'scale_factor': 'ground_motion_publisher',
    'time_scale': 'ground_motion_publisher', 'record_resampling': 'ground_motion_publisher',
    'realtime_output': 'rig',               # the rig outputs the commands
    # who may command the rig: the run's (every node holds the same; the rig's is recorded)
    'run_token': 'rig', 'message_auth': 'rig', 'auth_key_file': 'rig',
    # the excitation: the ground-motion publisher plays it (closed loop), the controller
    # drives the valve with it (open loop); both generate the same samples
    'duration_s': 'ground_motion_publisher', 'excitation': 'ground_motion_publisher',
    'excitation_input': 'ground_motion_publisher',
    'excitation_amplitude': 'ground_motion_publisher',
    'excitation_band_low_hz': 'ground_motion_publisher',
    'excitation_band_hz': 'ground_motion_publisher', 'excitation_seed': 'ground_motion_publisher',
}


def _source_of(s: ParamSpec) -> str:
    if s.name in _SHARED_SOURCE:
        return _SHARED_SOURCE[s.name]
    users = [n for n in s.nodes if n != 'recorder']
    # one user: that node; several (a new shared parameter missing above, which a test
    # catches): the first of them; none: the recorder's own parameter
    return users[0] if users else 'recorder'


#: ``{parameter name: node}``: the node whose value an analysis must use, the one that acts on
#: it (alpha and the predictor from the reference-force builder; the specimen, the rig model
#: and the clock (dt, mode, n_steps) from the rig; the record and its scaling from the
#: ground-motion publisher; the valve limit from the servo controller; the bag settings from
#: the recorder). Derived from ``ParamSpec.nodes`` where one node besides the recorder
#: declares a parameter, explicit where several do.
VALUE_SOURCE: Mapping[str, str] = MappingProxyType({s.name: _source_of(s) for s in SCHEMA})


def value_source(name: str) -> str:
    """Return the node whose value of parameter `name` an analysis must use.

    Parameters
    ----------
    name : str
        Schema parameter name.

    Returns
    -------
    str
        One of :data:`NODES` (see :data:`VALUE_SOURCE`).

    Raises
    ------
    ParameterError
        If no parameter has that name.
    """
    return VALUE_SOURCE[spec(name).name]
