"""The position the policy sees (companion/control/policy_frame.py)."""

from __future__ import annotations

import pytest

from companion.config import CompanionConfig
from companion.control.policy_frame import policy_position
from companion.experiment.batched_eval import why_not_batched


def test_without_a_policy_frame_the_position_is_as_measured() -> None:
    assert policy_position((1.0, -2.0, -3.5), (0.0, 0.0, 0.0), None) == (1.0, -2.0, -3.5)


def test_the_pad_sits_where_the_policy_learned_it() -> None:
    # the pad on the ground here (0, 0, 0), on a 1.5 m roof 1 m north in training
    seen = policy_position((0.2, 0.3, -4.0), (0.0, 0.0, 0.0), (1.0, 0.0, -1.5))
    assert seen == pytest.approx((1.2, 0.3, -5.5))
    # standing on the pad here reads standing on the pad there
    assert policy_position((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, -1.5)) == pytest.approx((1.0, 0.0, -1.5))


def test_a_moved_frame_is_flown_by_the_session_not_the_batched_lanes() -> None:
    cfg = CompanionConfig()
    moved = cfg.model_copy(update={"session": cfg.session.model_copy(update={"policy_pad_ned_m": (0.0, 0.0, -1.5)})})
    assert "policy_pad_ned_m" in (why_not_batched(moved, None) or "")
