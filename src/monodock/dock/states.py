"""The docking mission's states and failure reasons: what the robot does in each state, why a mission can fail,
and the Nav2 ``DockRobot`` error code each failure maps to."""

from __future__ import annotations

from enum import StrEnum

from monodock.dock.nav2 import FeedbackState, Nav2Code

__all__ = ["FailureReason", "State", "feedback_state"]


class State(StrEnum):
    """The mission's states: what the robot does in each and what ends it.

    Every state that is not final also ends in ``FAILED`` (``FailureReason.TIMEOUT``) when the mission has run
    longer than ``DockingConfig.watch.mission_timeout``. The values are what the mission's log and dock-sim's
    ``runs.csv`` print.
    """

    ACQUIRE = "acquire"
    """Find the dock: stand still while the first frames arrive (``first_frame_wait``), then turn on the spot at
    ``acquire_turn_rate``. Ends in ``CALCULATE`` when a frame gives the dock's pose; in ``FAILED`` when
    ``acquire`` is off (``NOT_IN_VIEW``) or after ``acquire_max_turn_deg`` of turning (``NOT_FOUND``)."""

    CENTER = "center"
    """Turn on the spot, on odometry, to face the dock, so that all three markers come into view. Ends in
    ``CALCULATE`` when the heading is within ``turn_tolerance_deg`` and the robot has stopped turning."""

    CALCULATE = "calculate"
    """Stand still (until the odometry reads still, at most ``settle_timeout``), then take the median of
    ``calculate_frames`` frames (or of those that came within ``calculate_timeout``). Ends in ``CENTER`` when the
    frames saw fewer than three markers and the dock is more than ``center_tolerance_deg`` off the heading (not
    twice in a row); in ``FAR_APPROACH`` when the robot stands farther than ``far_distance`` from the face centre or
    more than ``far_bearing_deg`` off the dock's axis (``far_approach`` on); in ``MOVING1_TURN`` with the plan (the
    case, Point A, the targets in odometry; the dock filter seeded); back in ``ACQUIRE`` when no frame came within
    ``calculate_timeout``."""

    FAR_APPROACH = "far-approach"
    """The dock is too far, or too far off its axis, for the manoeuvre: make for the staging point on the dock's axis
    (``staging_distance`` from the face) in legs, on the dock filter's coarse far-field pose, which every frame that
    sees the dock refines (and the staging point with it): turn to face the leg's end, drive at most ``far_leg``
    towards it, turn to face the dock again (so that it comes back into view). Ends in ``CALCULATE`` after each
    leg (which plans from there, or starts another leg); in ``FAILED`` (``APPROACH_STALLED``) after
    ``far_max_legs`` legs."""

    MOVING1_BACK = "moving1-back"
    """monodock's planner only: back out straight along the start heading (the camera keeps the dock in view) by
    the plan's ``back_out``, on odometry. Ends in ``MOVING1_TURN`` on arrival."""

    MOVING1_TURN = "moving1-turn"
    """Moving₁'s first part: turn on the spot, on odometry, to the heading of the straight leg to Point A (no turn
    with the papers' planner). Ends in ``MOVING1_DRIVE`` when there and still."""

    MOVING1_DRIVE = "moving1-drive"
    """Moving₁: drive straight to Point A on odometry (backwards where the plan says so), steering on the
    bearing. Ends in ``MOVING2`` on arrival (within ``arrive_tolerance``)."""

    MOVING2 = "moving2"
    """Moving₂: turn on the spot, on odometry, to face the charger square from Point A (by Θab). Ends in
    ``MOVING3`` when there and still; the lost-markers clock starts then. From ``MOVING1_TURN`` to here, every
    frame that sees the dock refines the dock filter, and Point A and the turns follow it
    (``refine_while_moving``)."""

    MOVING3 = "moving3"
    """Moving₃: straight at the face; every frame refines the dock filter, a P-controller steers the lateral and
    heading errors, the speed falls towards the face, and the blind zone is driven on the filter alone at creep
    speed. Ends in ``SETTLE`` on contact or at the face by the estimate; in ``BACK_OFF`` at the checkpoint
    (``checkpoint_gap``) when off the axis or the heading reference with retries left; in ``RECOVER`` when no
    frame updated the filter for ``lost_timeout`` outside the blind zone with retries left, else in ``FAILED``
    (``MARKERS_LOST``)."""

    RECOVER = "recover"
    """Markers lost mid-approach: stop, back off straight (along the approach) by ``recover_distance``, on
    odometry. Ends in ``CALCULATE`` on arrival (which re-acquires when no frame comes)."""

    SETTLE = "settle"
    """Stand still at the face (until the odometry reads still, at most ``settle_timeout``), then judge. Ends in
    ``DOCKED`` when the charger reports charging, or when the robot's own estimate of its pose is inside the
    tolerances and the robot cannot tell whether it charges; in ``CHARGE_WAIT`` inside the tolerances when it
    can; outside them in ``BACK_OFF`` with retries left, else in ``FAILED`` (``OUTSIDE_TOLERANCES``)."""

    CHARGE_WAIT = "charge-wait"
    """Stand on the contacts until the charger reports charging. Ends in ``DOCKED`` when it does; after
    ``charge_timeout`` in ``RESEAT`` with re-seats left, else in ``FAILED`` (``NOT_CHARGING``)."""

    RESEAT = "reseat"
    """Back off ``reseat_distance`` straight, on odometry, and drive in again, each time ``reseat_push`` farther
    than the estimate's face (contacts that did not mate are most often not pressed home): ends in ``MOVING3``."""

    BACK_OFF = "back-off"
    """A retry: reverse straight to Point A (placed again from the filter's dock pose; at most
    ``max_reverse_distance`` towards it) on odometry. Ends in ``CALCULATE`` on arrival, with the dock filter
    reset."""

    UNDOCK = "undock"
    """Undocking (``DockingMission(..., task="undock")``): back out straight from the face to the staging pose,
    Point A (``planner.standoff`` of floor before the face), on odometry. Ends in ``UNDOCKED`` on arrival."""

    DOCKED = "docked"
    """Final: at the face, charging (or inside the tolerances by the robot's own estimate when it cannot tell);
    every command is zero."""

    UNDOCKED = "undocked"
    """Final: undocked, standing at the staging pose; every command is zero."""

    FAILED = "failed"
    """Final: the mission gave up (``DockingMission.failure`` says why); every command is zero."""

    @property
    def final(self) -> bool:
        """Whether the mission has ended in this state."""
        return self in (State.DOCKED, State.UNDOCKED, State.FAILED)


class FailureReason(StrEnum):
    """Why a mission failed, one member per way it can; the nearest error code of Nav2's docking server.

    Nav2's ``nav2_msgs/action/DockRobot`` reports a failure as an error code, raised in ``opennav_docking`` as an
    exception type. Ours map onto them like this:

    ======================  ==============================================================================
    member                  Nav2 ``DockRobot`` result code (``opennav_docking_core`` exception)
    ======================  ==============================================================================
    ``NOT_IN_VIEW``         ``FAILED_TO_DETECT_DOCK`` = 904 (``FailedToDetectDock``, initial perception)
    ``NOT_FOUND``           ``FAILED_TO_DETECT_DOCK`` = 904 (``FailedToDetectDock``, initial perception)
    ``MARKERS_LOST``        ``FAILED_TO_DETECT_DOCK`` = 904 (``FailedToDetectDock``, during the approach)
    ``DOCK_LOST``           ``FAILED_TO_DETECT_DOCK`` = 904 (``FailedToDetectDock``, seen, lost, not found again)
    ``APPROACH_STALLED``    ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, the far approach made no way)
    ``OUTSIDE_TOLERANCES``  ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, all retries used)
    ``OBSTACLE_BEHIND``     ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, cannot reverse)
    ``REVERSE_LIMIT``       ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, a reverse leg too long)
    ``NOT_CHARGING``        ``FAILED_TO_CHARGE`` = 906 (``FailedToCharge``, all re-seats used)
    ``TIMEOUT``             ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``: Nav2's docking server ends its
                            approach, rotation and undocking time-outs so; it never uses ``TIMEOUT`` = 907)
    ``STAGING_TIMEOUT``     ``FAILED_TO_STAGE`` = 903 (``FailedToStage``, staging took over ``max_staging_time``)
    ``ODOMETRY_LOST``       ``FAILED_TO_CONTROL`` = 905 (``FailedToControl``, no odometry to steer by)
    ``CANCELLED``           ``NONE`` = 0 (Nav2 ends a cancelled action as CANCELED, not with an error code)
    ======================  ==============================================================================

    ``MissionResult.reason`` carries the human detail (the numbers) next to the member.
    """

    NOT_IN_VIEW = "not-in-view"
    """No markers in view at the start, and ``acquire`` is off (the robot does not turn to look)."""

    NOT_FOUND = "not-found"
    """No markers in view after turning ``acquire_max_turn_deg`` on the spot."""

    MARKERS_LOST = "markers-lost"
    """No frame updated the dock filter for ``lost_timeout`` during Moving₃, outside the blind zone."""

    DOCK_LOST = "dock-lost"
    """The dock was seen (at the start, or on the far approach), then lost, and turning ``acquire_max_turn_deg`` on
    the spot did not find it again."""

    APPROACH_STALLED = "approach-stalled"
    """The far approach used ``far_max_legs`` legs and still stood beyond ``far_distance`` or ``far_bearing_deg``."""

    OUTSIDE_TOLERANCES = "outside-tolerances"
    """At the face, the robot's own estimate of its final pose is outside the tolerances after ``max_retries``."""

    OBSTACLE_BEHIND = "obstacle-behind"
    """The rear range sensor saw something within ``rear_safety_distance`` for ``blocked_timeout`` while the robot
    had to reverse: it stopped short and gave up."""

    REVERSE_LIMIT = "reverse-limit"
    """A reverse leg would be, or became, longer than ``max_reverse_distance``."""

    NOT_CHARGING = "not-charging"
    """At the face inside the tolerances, the charger never reported charging, after ``max_reseats`` re-seats."""

    TIMEOUT = "timeout"
    """The mission ran longer than ``mission_timeout`` (or, aborted from outside, than a goal's time limit)."""

    STAGING_TIMEOUT = "staging-timeout"
    """The far approach (monodock's own way to the staging point) ran longer than a DockRobot goal's
    ``max_staging_time`` (``DockingMission.abort`` by the ROS node)."""

    ODOMETRY_LOST = "odometry-lost"
    """The robot's odometry stopped coming (``DockingMission.abort`` by whoever runs the mission, e.g. the ROS node)."""

    CANCELLED = "cancelled"
    """Cancelled from outside (``DockingMission.abort``): a second call, a cancel request, a shutdown."""

    @property
    def nav2_error_code(self) -> Nav2Code:
        """The nearest ``DockRobot.Result`` error code of Nav2's docking server (see the table above)."""
        return _NAV2_ERROR_CODE[self]


_NAV2_ERROR_CODE = {
    FailureReason.NOT_IN_VIEW: Nav2Code.FAILED_TO_DETECT_DOCK,
    FailureReason.NOT_FOUND: Nav2Code.FAILED_TO_DETECT_DOCK,
    FailureReason.MARKERS_LOST: Nav2Code.FAILED_TO_DETECT_DOCK,
    FailureReason.DOCK_LOST: Nav2Code.FAILED_TO_DETECT_DOCK,
    FailureReason.APPROACH_STALLED: Nav2Code.FAILED_TO_CONTROL,
    FailureReason.OUTSIDE_TOLERANCES: Nav2Code.FAILED_TO_CONTROL,
    FailureReason.OBSTACLE_BEHIND: Nav2Code.FAILED_TO_CONTROL,
    FailureReason.REVERSE_LIMIT: Nav2Code.FAILED_TO_CONTROL,
    FailureReason.NOT_CHARGING: Nav2Code.FAILED_TO_CHARGE,
    FailureReason.TIMEOUT: Nav2Code.FAILED_TO_CONTROL,
    FailureReason.STAGING_TIMEOUT: Nav2Code.FAILED_TO_STAGE,
    FailureReason.ODOMETRY_LOST: Nav2Code.FAILED_TO_CONTROL,
    FailureReason.CANCELLED: Nav2Code.NONE,
}


_PERCEIVING = {State.ACQUIRE, State.CENTER, State.CALCULATE}
_RETRYING = {State.RECOVER, State.RESEAT, State.BACK_OFF}
_CHARGING = {State.SETTLE, State.CHARGE_WAIT, State.DOCKED}


def feedback_state(state: State) -> FeedbackState:
    """The ``DockRobot.Feedback`` state of a mission state: what Nav2's docking server would be doing."""
    if state in _PERCEIVING:
        return FeedbackState.INITIAL_PERCEPTION
    if state is State.FAR_APPROACH:  # legs to the staging point on the dock's axis: Nav2's staging, on our own pose
        return FeedbackState.NAV_TO_STAGING_POSE
    if state in _RETRYING:
        return FeedbackState.RETRY
    if state in _CHARGING:
        return FeedbackState.WAIT_FOR_CHARGE
    return FeedbackState.CONTROLLING
