"""A 2-D ten-story steel moment frame (one bay) with a brace-damper at its first floor, as an
OpenSeesPy model: a larger computational part for real time (issue 40;
config/opensees/ten_story.yaml).

The laboratory-scale bay of config/opensees/steel_frame.py (1.0 m bay, 0.6 m stories, 40 x 12
mm columns, 50 x 15 mm beams, E = 200 GPa) ten stories high, with elastic beam-columns; the
floors' masses lumped at the left joints (axially stiff beams: a rigid floor). 63 DOFs
(60 free). Rayleigh damping of 2 % in the first and third modes. The specimen is the
brace-damper of the first floor (element 901, the reference study's k = 2.11e5 N/m,
c = 903.278 N s/m) on the rig. Units: N, m, kg, s.

Nodes: ``10 * floor + column`` (column 1 left, 2 right; floor 0 the ground); elements:
columns ``1000 + 10 * story + column``, beams ``2000 + floor``.
"""

import math

import openseespy.opensees as ops

BAY_M = 1.0
STORY_M = 0.6
STORIES = 10
FLOOR_MASS_KG = 80.0
COLUMN_MM = (40.0, 12.0)
BEAM_MM = (50.0, 15.0)
E_PA = 200e9


def _section(mm):
    depth, width = mm[0] * 1e-3, mm[1] * 1e-3
    return depth * width, width * depth ** 3 / 12.0


def build(stories: int = STORIES, damping_ratio: float = 0.02, floor_mass_kg=FLOOR_MASS_KG):
    """Build the frame with its brace-damper (module notes)."""
    ops.wipe()
    ops.model('basic', '-ndm', 2, '-ndf', 3)
    for floor in range(stories + 1):
        for col in (1, 2):
            ops.node(10 * floor + col, (col - 1) * BAY_M, floor * STORY_M)
    ops.fix(1, 1, 1, 1)
    ops.fix(2, 1, 1, 1)
    for floor in range(1, stories + 1):
        ops.mass(10 * floor + 1, floor_mass_kg, 0.0, 0.0)
    ops.geomTransf('Linear', 1)
    area_c, inertia_c = _section(COLUMN_MM)
    area_b, inertia_b = _section(BEAM_MM)
    for story in range(1, stories + 1):
        for col in (1, 2):
            ops.element('elasticBeamColumn', 1000 + 10 * story + col, 10 * (story - 1) + col,
                        10 * story + col, area_c, E_PA, inertia_c, 1)
    for floor in range(1, stories + 1):
        ops.element('elasticBeamColumn', 2000 + floor, 10 * floor + 1, 10 * floor + 2,
                    100.0 * area_b, E_PA, inertia_b, 1)
    ops.node(900, 0.0, STORY_M)
    ops.fix(900, 1, 1, 1)
    ops.uniaxialMaterial('Elastic', 9, 2.11e5, 903.278)
    ops.element('zeroLength', 901, 900, 11, '-mat', 9, '-dir', 1)
    w2 = ops.eigen('-fullGenLapack', 3)
    w1, w3 = math.sqrt(w2[0]), math.sqrt(w2[2])
    ops.rayleigh(2.0 * damping_ratio * w1 * w3 / (w1 + w3), 0.0,
                 2.0 * damping_ratio / (w1 + w3), 0.0)
