"""A three-story shear frame whose computational story yields, as an OpenSeesPy model (issue 40;
config/opensees/shear_frame.yaml).

2-D (``ndm`` 2, ``ndf`` 2, the vertical DOFs fixed): each story a ``zeroLength`` link in the
horizontal direction with a ``Parallel`` material of its spring and a ``Viscous`` dashpot;
each floor a lumped mass. Story 1 (element 1) is the reference study's specimen (k = 2.11e5
N/m, c = 903.278 N s/m, 52.7 kg; Nakata and Combs, Sec. 3.1), tested on the rig; story 2 is
``Steel01`` (yield force ``fy2_N``, post-yield ratio ``b``: bilinear with kinematic
hardening; or ``Steel02`` with ``gradual=True``: Giuffre-Menegotto-Pinto, R0 18, cR1 0.925,
cR2 0.15, yielding gradually, more so after each reversal), story 3 elastic, or yielding
too with ``fy3_N`` (post-yield ratio ``b3``). Units: N, m, kg, s.

Nodes: 0 the ground, ``i`` floor i. Elements: story ``i`` is element ``i``.
"""

import openseespy.opensees as ops

FLOOR_MASSES_KG = (52.7, 52.7, 52.7)
STORY_STIFFNESSES_N_PER_M = (2.11e5, 2.11e5, 2.11e5)
STORY_DAMPING_N_S_PER_M = (903.278, 333.5, 333.5)


def build(fy2_N: float = 2500.0, b: float = 0.02, masses_kg=FLOOR_MASSES_KG,
          stiffnesses_N_per_m=STORY_STIFFNESSES_N_PER_M,
          damping_N_s_per_m=STORY_DAMPING_N_S_PER_M, fy3_N: float = 0.0, b3: float = 0.05,
          gradual: bool = False):
    """Build the frame (module notes); ``fy2_N`` 0 makes story 2 elastic, ``fy3_N`` 0 (the
    default) story 3."""
    yield_forces_N = {2: (fy2_N, b), 3: (fy3_N, b3)}
    ops.wipe()
    ops.model('basic', '-ndm', 2, '-ndf', 2)
    ops.node(0, 0.0, 0.0)
    ops.fix(0, 1, 1)
    for i, (m, k, c) in enumerate(zip(masses_kg, stiffnesses_N_per_m, damping_N_s_per_m),
                                  start=1):
        ops.node(i, 0.0, 0.0)
        ops.fix(i, 0, 1)
        ops.mass(i, m, 0.0)
        fy_N, ratio = yield_forces_N.get(i, (0.0, 0.0))
        if fy_N and gradual:
            ops.uniaxialMaterial('Steel02', 10 + i, fy_N, k, ratio, 18.0, 0.925, 0.15)
        elif fy_N:
            ops.uniaxialMaterial('Steel01', 10 + i, fy_N, k, ratio)
        else:
            ops.uniaxialMaterial('Elastic', 10 + i, k)
        ops.uniaxialMaterial('Viscous', 20 + i, c, 1.0)
        ops.uniaxialMaterial('Parallel', 30 + i, 10 + i, 20 + i)
        ops.element('zeroLength', i, i - 1, i, '-mat', 30 + i, '-dir', 1)
