"""config/two_story.yaml's two-story shear building as an OpenSeesPy model (issue 32).

The whole structure as a structural engineer writes it: each story a zeroLength spring with
its dashpot (an Elastic material's stiffness and damping), each floor a lumped mass. Story 1
(element 1) is the specimen, tested on the rig: m = 52.7 kg, k = 2.11e5 N/m, c = 903.278 N s/m
(Nakata and Combs, Sec. 3.1). Units: N, m, kg, s.
"""

import openseespy.opensees as ops

STORY_MASSES_KG = (52.7, 52.7)
STORY_STIFFNESSES_N_PER_M = (2.11e5, 2.11e5)
STORY_DAMPING_N_S_PER_M = (903.278, 333.5)


def build(masses_kg=STORY_MASSES_KG, stiffnesses_N_per_m=STORY_STIFFNESSES_N_PER_M,
          damping_N_s_per_m=STORY_DAMPING_N_S_PER_M):
    """Build the shear building: node 0 the ground, node i floor i, element i story i."""
    ops.wipe()
    ops.model('basic', '-ndm', 1, '-ndf', 1)
    ops.node(0, 0.0)
    ops.fix(0, 1)
    for i, (m, k, c) in enumerate(zip(masses_kg, stiffnesses_N_per_m, damping_N_s_per_m),
                                  start=1):
        ops.node(i, 0.0)
        ops.mass(i, m)
        ops.uniaxialMaterial('Elastic', i, k, c)
        ops.element('zeroLength', i, i - 1, i, '-mat', i, '-dir', 1)
