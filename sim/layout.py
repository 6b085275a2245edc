"""The numbers of the simulated lab (Sec. VI of the paper), in Baxter's ``base`` frame (metres).

Conventions: x forward (away from the robot), y to the robot's left, z up; the world
frame *is* Baxter's URDF root ``base``. Baxter's pedestal reaches z = -0.93 (the floor) and,
at table height, extends to x = 0.22 (x = 0.42 at the floor), so the table's near edge sits
at x = 0.30 (a bowl at the square's near edge stands fully on the table) with its legs inset
0.16 m to clear the pedestal's feet.

The 30-inch (0.762 m) square on the table is where the bowl and the other sensed landmarks
are sampled (paper, Sec. VI-B). Its centre is shifted to the left arm's side (y > 0). The
demonstrator checks reachability with IK and may adjust ``SQUARE_CENTER_XY`` /
``SQUARE_HALF`` here; every other module reads them from this file.

Tool geometry lives in the **gripper frame** (``left_gripper``: z out of the fingers, the
fingers close along y). Both tools are held with their "up" along gripper +y and pointing
along gripper +z; the spoon's tip is at the far (+z) end, the pitcher's spout on its -x side.
"""

from __future__ import annotations

import math

import numpy as np

# --- table ---------------------------------------------------------------------------
TABLE_TOP_Z = -0.20                      # top surface height
TABLE_CENTER_XY = (0.785, 0.35)          # centre of the table top
TABLE_HALF_XY = (0.485, 0.65)            # x in [0.30, 1.27], y in [-0.30, 1.00]
TABLE_THICKNESS = 0.03
TABLE_LEG_INSET = 0.16                   # legs this far inside the corners (near legs x in [0.435, 0.485])
FLOOR_Z = -0.926                         # bottom of Baxter's pedestal

# --- the 30-inch square where landmarks are sampled ----------------------------------
SQUARE_SIDE = 0.762                      # 30 inches
SQUARE_HALF = SQUARE_SIDE / 2.0
SQUARE_CENTER_XY = (0.82, 0.35)          # x in [0.44, 1.20], y in [-0.03, 0.73]
# The whole square is demonstrable (checked with sim.demos' attempt loop on a 4 x 4 grid of bowl
# positions at +-98 % of the half side, corners included, each attempt replayed with particles):
# powder succeeded at all 16 within 3 attempts (13 at the first); pour at all 16 within 6
# attempts (the far-left corner (1.19, 0.72) and (0.45, 0.23) need the most: left_e1 too fast
# near full extension, a stream that clips the rim). Near the body the tool faces right
# (sim.demo_paths.NEAR_TURN), otherwise the forearm hits the torso.

# --- containers (base frame of each body: centre of its bottom, on the table) --------
BOWL_RADIUS = 0.09                       # inner radius at the rim
BOWL_HEIGHT = 0.07
BOWL_WALL = 0.006
BOWL_SEGMENTS = 16
BOWL_DEFAULT_XY = (0.82, 0.35)           # centre of the square

SOURCE_HALF_XY = (0.07, 0.07)            # inner half sizes of the (box) source container
SOURCE_HEIGHT = 0.08
SOURCE_WALL = 0.006
SOURCE_DEFAULT_XY = (0.75, 0.88)         # left of the square (y > 0.73), mid-depth

# --- obstacles -----------------------------------------------------------------------
PAPER_TOWELS_RADIUS = 0.06
PAPER_TOWELS_HEIGHT = 0.28
LAMP_RADIUS = 0.14                       # shade radius
LAMP_HEIGHT = 0.18                       # shade height
LAMP_BOTTOM_ABOVE_TABLE = 0.42           # lower rim of the shade above the table top
LAMP_CORD_TOP_Z = 1.6                    # the cord runs up to the "ceiling"
VASE_RADIUS = 0.055
VASE_HEIGHT = 0.22
VASE_NECK_RADIUS = 0.03
BOOK_SIZES = ((0.24, 0.17, 0.035), (0.22, 0.15, 0.04), (0.20, 0.14, 0.03))  # full sizes, bottom up
SMALL_ITEM_SIZE = (0.16, 0.05, 0.012)    # scissors / table spoon (pour landmarks)
MARKER_RADIUS = 0.015                    # visual-only landmark markers (powder distractors)

# Default places used when a scenario asks for an object without a position.
DEFAULT_XY = {
    "paper_towels": (0.65, 0.10),
    "vase": (1.10, 0.05),
    "books": (1.05, -0.15),
    "lamp_shade": (0.85, 0.45),
    "scissors": (0.55, 0.00),
    "spoon": (1.05, 0.20),
    "marker_1": (0.55, 0.05),
    "marker_2": (1.10, 0.05),
    "marker_3": (1.10, 0.65),
    "marker_4": (0.70, 0.60),
}
MARKER_HEIGHT_ABOVE_TABLE = 0.10

# --- tools (gripper frame) -----------------------------------------------------------
# Spoon: a flat handle from z=-0.02 to 0.14, a scoop z in [0.14, 0.20] whose flat floor (top at
# y=0) spans x in [-0.03, 0.03]. Its side walls (+-x) flare outwards like the sides of a real
# spoon's bowl: SPOON_WALL_SLANT long, leaning SPOON_WALL_FLARE from the vertical, so that their
# rim is SPOON_WALL_HEIGHT above the floor. The powder stays in while the spoon is carried level
# and slides out over the lowered rim once the roll exceeds 90 deg - flare + the powder's angle
# (50 deg: the particles roll), as from a spoon, not from a box that holds it until past 90 deg.
# The back and front walls (z ends) are vertical. Tip: (0, 0, 0.20).
SPOON_HANDLE = ((0.0, 0.0, 0.06), (0.008, 0.004, 0.08))          # (centre, half extents)
SPOON_SCOOP_Z = (0.14, 0.20)
SPOON_SCOOP_HALF_X = 0.03
SPOON_FLOOR_THICKNESS = 0.004
SPOON_WALL_SLANT = 0.03
SPOON_WALL_FLARE = math.radians(40.0)
SPOON_WALL_HEIGHT = SPOON_WALL_SLANT * math.cos(SPOON_WALL_FLARE)   # rim above the floor, ~0.023
SPOON_RIM_HALF_X = SPOON_SCOOP_HALF_X + SPOON_WALL_SLANT * math.sin(SPOON_WALL_FLARE)  # ~0.049
SPOON_WALL_THICKNESS = 0.004
SPOON_TIP = (0.0, 0.0, 0.20)

# Pitcher: a handle z in [-0.02, 0.085], a cylindrical cup with axis along y through
# (x=0, z=0.135): inner radius 0.045, floor top y=-0.05, rim y=0.08. The spout points along
# gripper -x (to the right of the pointing direction when level), so that pouring is a wrist
# roll about gripper z like the spoon's dump (rolling about +z lowers the -x side): the -x wall
# is notched down to y=0.05 and a trough runs out to x=-0.08, its lip at y=0.07.
PITCHER_HANDLE = ((0.0, 0.0, 0.0325), (0.008, 0.006, 0.0525))
PITCHER_AXIS_Z = 0.135
PITCHER_RADIUS = 0.045
PITCHER_WALL = 0.005
PITCHER_FLOOR_Y = -0.05
PITCHER_RIM_Y = 0.08
PITCHER_NOTCH_Y = 0.05
PITCHER_SEGMENTS = 16
PITCHER_SPOUT_SEGMENT = 12                # the ring segment at -x (angle 270 deg from +z towards +x)
PITCHER_SPOUT_LIP = (-0.08, 0.07, 0.135)

TOOL_MASS = 0.2

# --- particles -----------------------------------------------------------------------
PARTICLES = {"powder": (40, 0.005), "pour": (60, 0.007)}          # (count, radius)
PARTICLE_MASS = 0.002

# --- robot poses ---------------------------------------------------------------------
# Left arm (left_s0, s1, e0, e1, w0, w1, w2): the tool level (its up = world +z), pointing
# forward (yaw 0.3 rad), gripper at z = 0.02 (0.22 m above the table top), tool centre over the
# source container. Found with IK (most margin to the joint limits), collision-free with both tools.
HOME_Q = np.array([0.495, -0.161, -0.056, 1.605, -2.161, 1.453, -1.645])
# Rethink's "tuck" pose of the right arm (baxter_tools tuck_arms.py): folded against the torso.
RIGHT_ARM_TUCK = {"right_s0": 1.0, "right_s1": -2.07, "right_e0": -3.0, "right_e1": 2.55,
                  "right_w0": 0.0, "right_w1": 0.01, "right_w2": 0.0}
HEAD_PAN = 0.0
GRIPPER_FINGERS = 0.01                   # prismatic finger joints (m), closed on the handle

# --- simulation ----------------------------------------------------------------------
SIM_DT = 1.0 / 240.0
GRAVITY = -9.81

# Where the snapshot camera looks from (GUI and PNG).
CAMERA = {"target": (0.75, 0.35, -0.10), "distance": 2.2, "yaw": 130.0, "pitch": -30.0}
