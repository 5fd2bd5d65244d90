"""DockRobot's feedback state for each mission state, against the upstream .action's constants
(interfaces/upstream/nav2_msgs/action/DockRobot.action), without a graph."""

from __future__ import annotations

import re
from pathlib import Path

from monodock.dock.nav2 import FeedbackState
from monodock.dock.states import State, feedback_state

ACTION = Path(__file__).resolve().parents[2] / "interfaces" / "upstream" / "nav2_msgs" / "action" / "DockRobot.action"


def _constants() -> dict[str, int]:
    text = ACTION.read_text(encoding="utf-8")
    return {name: int(value) for name, value in re.findall(r"^uint16 (\w+)\s*=\s*(\d+)", text, flags=re.M)}


def test_every_working_state_has_the_nav2_feedback_state_of_what_it_does() -> None:
    upstream = _constants()
    for name in ("NAV_TO_STAGING_POSE", "INITIAL_PERCEPTION", "CONTROLLING", "WAIT_FOR_CHARGE", "RETRY"):
        assert getattr(FeedbackState, name) == upstream[name], name
    expected = {
        State.ACQUIRE: "INITIAL_PERCEPTION",
        State.CALCULATE: "INITIAL_PERCEPTION",
        State.CENTER: "INITIAL_PERCEPTION",
        State.FAR_APPROACH: "NAV_TO_STAGING_POSE",
        State.MOVING1_BACK: "CONTROLLING",
        State.MOVING1_TURN: "CONTROLLING",
        State.MOVING1_DRIVE: "CONTROLLING",
        State.MOVING2: "CONTROLLING",
        State.MOVING3: "CONTROLLING",
        State.SETTLE: "WAIT_FOR_CHARGE",
        State.CHARGE_WAIT: "WAIT_FOR_CHARGE",
        State.RECOVER: "RETRY",
        State.RESEAT: "RETRY",
        State.BACK_OFF: "RETRY",
    }
    for state, name in expected.items():
        assert feedback_state(state) == upstream[name], state
