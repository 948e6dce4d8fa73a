"""Geometry, thresholds and observation layouts of the reference tasks (private, no MuJoCo).

The environments and the scripted policies both read these, so the policies need neither MuJoCo
nor the environment classes. Geometry mirrors ``assets/*.xml``; a test checks the two agree.
"""

from __future__ import annotations

from typing import Final

__all__ = [
    "DOOR_OPEN_ID",
    "DRAWER_OPEN_ID",
    "GRASP_ID",
    "DoorLayout",
    "DrawerLayout",
    "GraspLayout",
]

DOOR_OPEN_ID: Final = "episode_audit/DoorOpen-v0"
DRAWER_OPEN_ID: Final = "episode_audit/DrawerOpen-v0"
GRASP_ID: Final = "episode_audit/Grasp-v0"


class DoorLayout:
    """DoorOpen-v0: observation slices, geometry and thresholds."""

    EE_POS: Final = slice(0, 3)
    EE_VEL: Final = slice(3, 6)
    ANGLE: Final = 6
    ANGULAR_VELOCITY: Final = 7
    HANDLE_POS: Final = slice(8, 11)
    OBS_DIM: Final = 11

    HINGE_XY: Final = (-0.3, 0.0)
    """Hinge axis position in the horizontal plane (the axis is vertical)."""
    HANDLE_LOCAL: Final = (0.45, -0.05, 0.42)
    """Centre of the push bar in the door frame (x along the door, -y toward the agent)."""
    EE_START: Final = (0.0, -0.3, 0.42)
    EE_RADIUS: Final = 0.03
    BAR_RADIUS: Final = 0.015

    TARGET_ANGLE: Final = 1.0
    """Success needs the door opened past this angle (rad) ..."""
    REST_SPEED: Final = 0.05
    """... and turning slower than this (rad/s)."""
    OPEN_STOP: Final = 1.8
    """Upper limit of the hinge (rad)."""
    STOP_ZONE: Final = 0.03
    SLAM_SPEED: Final = 1.0
    """``door_slammed``: the door reaches its stop faster than this (rad/s) ..."""
    MAX_SPEED: Final = 4.0
    """... or turns faster than this anywhere (rad/s)."""
    COLLISION_FORCE: Final = 40.0
    """``collision``: contact force between the end effector and the wall above this (N)."""
    WORKSPACE_LOW: Final = (-0.6, -0.6, 0.1)
    WORKSPACE_HIGH: Final = (0.6, 0.6, 0.9)


class DrawerLayout:
    """DrawerOpen-v0: observation slices, geometry and thresholds."""

    EE_POS: Final = slice(0, 3)
    EE_VEL: Final = slice(3, 6)
    OPENING: Final = 6
    OPENING_VELOCITY: Final = 7
    HANDLE_POS: Final = slice(8, 11)
    OBS_DIM: Final = 11

    HANDLE_CLOSED: Final = (0.0, -0.26, 0.28)
    """Centre of the handle bar with the drawer closed; the drawer opens toward -y."""
    HANDLE_HALF_LENGTH: Final = 0.08
    HANDLE_GAP: Final = 0.06
    """Distance from the bar's axis to the drawer front, the slot the hook goes into."""
    EE_START: Final = (0.0, -0.4, 0.42)
    EE_RADIUS: Final = 0.015
    BAR_RADIUS: Final = 0.01

    TARGET_OPENING: Final = 0.2
    """Success needs the drawer pulled out past this (m) ..."""
    REST_SPEED: Final = 0.02
    """... and moving slower than this (m/s)."""
    OPEN_STOP: Final = 0.3
    STOP_ZONE: Final = 0.01
    YANK_SPEED: Final = 0.3
    """``drawer_yanked``: the drawer hits its end stop faster than this (m/s)."""
    WORKSPACE_LOW: Final = (-0.4, -0.8, 0.1)
    WORKSPACE_HIGH: Final = (0.4, -0.1, 0.7)


class GraspLayout:
    """Grasp-v0: observation slices, geometry and thresholds."""

    PALM_POS: Final = slice(0, 3)
    PALM_VEL: Final = slice(3, 6)
    FINGERS: Final = slice(6, 8)
    OBJECT_POS: Final = slice(8, 11)
    OBJECT_VEL: Final = slice(11, 14)
    OBS_DIM: Final = 14

    PALM_START: Final = (0.0, 0.0, 0.2)
    OBJECT_HALF_SIZE: Final = 0.02
    """The object is a cube of edge 0.04 m resting on the table at z = 0."""
    OBJECT_START_RANGE: Final = 0.08
    """The object starts at x, y uniform in [-0.08, 0.08]."""
    GRASP_DEPTH: Final = 0.075
    """In a good grasp the object's centre is this far below the palm (fingertips at the table)."""
    FINGER_MAX: Final = 0.05
    """Each finger's inner face is up to this far from the palm's centre line (fully open)."""

    LIFT_HEIGHT: Final = 0.12
    """Success needs the object's centre above this height (m) ..."""
    HOLD_STEPS: Final = 5
    """... held between both fingers for this many consecutive steps."""
    LIFTED_HEIGHT: Final = 0.05
    """Above this the object counts as lifted; ``dropped_object`` if it falls back ..."""
    DROPPED_HEIGHT: Final = 0.03
    """... below this afterwards."""
    WORKSPACE_LOW: Final = (-0.3, -0.3, 0.04)
    WORKSPACE_HIGH: Final = (0.3, 0.3, 0.45)
