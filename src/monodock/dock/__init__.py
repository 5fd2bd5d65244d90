"""Docking: the eight cases and Point A (planner), the mission's state machine (controller), the dock's pose
tracked in odometry (pose_filter) and the robot interface; what runs on the robot (dock-sim is in evaluation)."""

from monodock.dock.config import DockingConfig
from monodock.dock.controller import DockingMission
from monodock.dock.extensions import ArucoChargingDock, ControlLaw, Dock, PControlLaw
from monodock.dock.interface import CameraFrame, Odometry, RobotInterface
from monodock.dock.planner import (
    CASES,
    CaseSpec,
    Manoeuvre,
    PlannerConfig,
    classify,
    plan,
    plan_for,
    plan_monodock,
    plan_papers,
    point_a,
)
from monodock.dock.run import MissionResult, run_mission
from monodock.dock.states import FailureReason, State
from monodock.dock.tracking import Observation

__all__ = [
    "CASES",
    "ArucoChargingDock",
    "CameraFrame",
    "CaseSpec",
    "ControlLaw",
    "Dock",
    "DockingConfig",
    "DockingMission",
    "FailureReason",
    "Manoeuvre",
    "MissionResult",
    "Observation",
    "Odometry",
    "PControlLaw",
    "PlannerConfig",
    "RobotInterface",
    "State",
    "classify",
    "plan",
    "plan_for",
    "plan_monodock",
    "plan_papers",
    "point_a",
    "run_mission",
]
