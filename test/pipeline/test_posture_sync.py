"""Frames are paired with the joint angle at their acquisition time, whatever arrives first."""

from __future__ import annotations

import pytest

from eit_skin.pipeline.reference import JointAngleHistory, PostureSync

MS = 1_000_000


def test_a_frame_waits_for_the_joint_state_of_its_stamp():
    history = JointAngleHistory()
    sync = PostureSync(history, max_wait_s=0.5)
    history.add(0, 0.0)
    # frames at 10 and 20 ms arrive before the joint state that covers them
    assert sync.push(10 * MS, 0, "a") == []
    assert sync.push(20 * MS, 1 * MS, "b") == []
    assert sync.waiting == 2
    history.add(15 * MS, 1.5)  # covers a (interpolated), not b
    ready = sync.ready(2 * MS)
    assert [item for item, _ in ready] == ["a"]
    assert ready[0][1] == pytest.approx(1.0)
    history.add(30 * MS, 3.0)
    ready = sync.ready(3 * MS)
    assert [item for item, _ in ready] == ["b"] and ready[0][1] == pytest.approx(2.0)
    assert sync.late == 0 and sync.waiting == 0


def test_without_its_joint_state_a_frame_goes_on_late_with_the_held_angle_in_order():
    history = JointAngleHistory()
    sync = PostureSync(history, max_wait_s=0.5)
    history.add(0, 0.7)
    sync.push(100 * MS, 0, "a")
    sync.push(110 * MS, 400 * MS, "b")
    assert sync.ready(499 * MS) == []  # a has waited 499 ms
    ready = sync.ready(500 * MS)
    assert ready == [("a", pytest.approx(0.7))] and sync.late == 1
    ready = sync.ready(900 * MS)
    assert ready == [("b", pytest.approx(0.7))] and sync.late == 2


def test_a_covered_frame_never_overtakes_a_waiting_one():
    history = JointAngleHistory()
    sync = PostureSync(history, max_wait_s=10.0)
    history.add(5 * MS, 0.0)
    sync.push(10 * MS, 0, "late stamp")
    # an older-stamped frame of another layer is covered, but must not overtake
    assert sync.push(4 * MS, 0, "early stamp") == []
    history.add(20 * MS, 2.0)
    assert [item for item, _ in sync.ready(0)] == ["late stamp", "early stamp"]
