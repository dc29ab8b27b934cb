"""Policy blending (Dragan & Srinivasa): the user's twist until the goal prediction is confident."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike


def blend_twist(
    belief: ArrayLike,
    goal_actions: ArrayLike,
    user_twist: ArrayLike,
    *,
    threshold: float = 0.4,
    mode: Literal["aggressive", "timid"] = "aggressive",
) -> np.ndarray:
    """Policy blending (Dragan & Srinivasa): follow the user until the prediction is confident.

    Confidence is the gap between the two most likely goals. At or below ``threshold`` the
    user's twist is returned unchanged. Above it the assisted twist toward the most likely goal
    (its action plus the user twist, as in :func:`assisted_twist_teleop` with all belief on
    that goal) takes over: fully ("aggressive"), or ("timid") only in x-y, mixed with the user's
    x-y by ``alpha = min(1.5 (conf - threshold), 0.6)``. The reference writes
    ``1.5 (conf - 0.4)`` capped at 0.6 for conf > 0.8; this is the same for the default
    threshold and keeps alpha continuous for others.

    Raises:
        ValueError: for an unknown ``mode``.
    """
    if mode not in ("aggressive", "timid"):
        raise ValueError(f"mode must be 'aggressive' or 'timid', got {mode!r}")
    belief = np.asarray(belief, dtype=np.float64)
    user_twist = np.asarray(user_twist, dtype=np.float64)
    top_two = np.sort(belief)[-2:]
    confidence = 1.0 if belief.size <= 1 else top_two[1] - top_two[0]
    if confidence <= threshold:
        return user_twist.copy()
    assisted = np.asarray(goal_actions, dtype=np.float64)[np.argmax(belief)] + user_twist
    if mode == "timid":
        alpha = min(1.5 * (confidence - threshold), 0.6)
        assisted[:2] = alpha * assisted[:2] + (1.0 - alpha) * user_twist[:2]
    return assisted
