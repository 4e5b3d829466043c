"""A 2-D three-story steel moment frame (one bay) with a brace-damper at its first floor, as an
OpenSeesPy model (issue 32; config/opensees/steel_frame.yaml).

A laboratory-scale frame: 1.0 m bay, 0.6 m stories, steel flat-bar columns (30 x 10 mm) and
beams (40 x 12 mm), each a force-based beam-column with a fibre section of Steel02 (Giuffre-
Menegotto-Pinto: E = 200 GPa, Fy = ``fy_Pa``, 1 % hardening), so the frame yields as it
would. The floors' masses are lumped at the left joints (the beams are axially stiff: a rigid
floor). Rayleigh damping of 2 % in the first and third modes (initial stiffness).

The physical specimen is the brace-damper of the first floor: element 901, a zeroLength link
in the horizontal direction between the ground (node 900) and the first floor's left joint
(node 11), the reference study's specimen (k = 2.11e5 N/m, c = 903.278 N s/m; Nakata and
Combs, Sec. 3.1), tested on the servohydraulic rig; its 52.7 kg is part of the first floor's
100 kg. Units: N, m, kg, s.

Nodes: ``10 * floor + column`` (column 1 left, 2 right; floor 0 the ground). Elements:
columns ``100 + 10 * story + column``, beams ``200 + floor``.
"""

import math

import openseespy.opensees as ops

BAY_M = 1.0
STORY_M = 0.6
FLOOR_MASSES_KG = (80.0, 70.0, 60.0)
COLUMN_MM = (40.0, 12.0)          # depth (in the frame's plane), width
BEAM_MM = (50.0, 15.0)
E_PA = 200e9
SPECIMEN_K_N_PER_M = 2.11e5
SPECIMEN_C_N_S_PER_M = 903.278


def _section(tag: int, mat: int, depth_m: float, width_m: float, fibres: int = 12) -> None:
    ops.section('Fiber', tag)
    ops.patch('rect', mat, fibres, 1, -depth_m / 2, -width_m / 2, depth_m / 2, width_m / 2)


def build(fy_Pa: float = 690e6, damping_ratio: float = 0.02, integration_points: int = 3,
          column_mm=COLUMN_MM, beam_mm=BEAM_MM, floor_masses_kg=FLOOR_MASSES_KG):
    """Build the frame with its brace-damper (module notes)."""
    ops.wipe()
    ops.model('basic', '-ndm', 2, '-ndf', 3)
    for floor in range(4):
        for col in (1, 2):
            ops.node(10 * floor + col, (col - 1) * BAY_M, floor * STORY_M)
    ops.fix(1, 1, 1, 1)
    ops.fix(2, 1, 1, 1)
    for floor, m in enumerate(floor_masses_kg, start=1):
        ops.mass(10 * floor + 1, m, 0.0, 0.0)
    ops.uniaxialMaterial('Steel02', 1, fy_Pa, E_PA, 0.01, 18.0, 0.925, 0.15)
    _section(1, 1, column_mm[0] * 1e-3, column_mm[1] * 1e-3)
    _section(2, 1, beam_mm[0] * 1e-3, beam_mm[1] * 1e-3)
    ops.geomTransf('Linear', 1)
    ops.beamIntegration('Lobatto', 1, 1, integration_points)
    ops.beamIntegration('Lobatto', 2, 2, integration_points)
    for story in (1, 2, 3):
        for col in (1, 2):
            ops.element('forceBeamColumn', 100 + 10 * story + col, 10 * (story - 1) + col,
                        10 * story + col, 1, 1)
    for floor in (1, 2, 3):
        ops.element('forceBeamColumn', 200 + floor, 10 * floor + 1, 10 * floor + 2, 1, 2)
    # the brace-damper of the first floor: the specimen
    ops.node(900, 0.0, STORY_M)
    ops.fix(900, 1, 1, 1)
    ops.uniaxialMaterial('Elastic', 9, SPECIMEN_K_N_PER_M, SPECIMEN_C_N_S_PER_M)
    ops.element('zeroLength', 901, 900, 11, '-mat', 9, '-dir', 1)
    # Rayleigh damping in the first and third modes (initial stiffness)
    w2 = ops.eigen('-fullGenLapack', 3)
    w1, w3 = math.sqrt(w2[0]), math.sqrt(w2[2])
    a0 = 2.0 * damping_ratio * w1 * w3 / (w1 + w3)
    a1 = 2.0 * damping_ratio / (w1 + w3)
    ops.rayleigh(a0, 0.0, a1, 0.0)
