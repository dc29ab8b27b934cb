"""The collaboration human: a soft (max-entropy) grid MDP toward its current goal.

The human walks the table top on a grid of goal-sized cells, solving one soft value iteration
per goal in which the scenario's other goals are obstacles (Ziebart et al. 2009; the paper's
appendix "Human Policy"). Each tick it heads for the centre of the next cell its soft Q-values
choose, at the UserBot speed times a speed coefficient.

Two parameters are searched in one of the paper's settings (appendix "human search"): the
rationality ``tau`` (inverse softmax temperature, ``tau = 10**s`` with ``s`` in
:data:`LOG10_TAU_BOUNDS`) and the speed coefficient (:data:`SPEED_COEFF_BOUNDS`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike

from .teleop_human import user_velocity

#: Search bounds of ``log10(tau)`` in the paper's human-search setting.
LOG10_TAU_BOUNDS = (2.5, 3.5)
#: Search bounds of the human speed coefficient (0.5 is the fixed value elsewhere).
SPEED_COEFF_BOUNDS = (0.5, 2.0)
#: The robot base (x, y) in the world frame: a disk obstacle and the corner of the quadrant
#: behind it that the human cannot reach.
ROBOT_BASE_XY = (0.409, 0.338)
#: Where the human starts (and returns to after each goal).
HUMAN_START_XY = (0.91, 0.05)

#: The 8 moves (dx, dy) in the reference's order, which fixes how argmax breaks ties.
MOVES = np.array([[-1, -1], [-1, 0], [-1, 1], [0, 1], [1, 1], [1, 0], [1, -1], [0, -1]])
_MOVE_LIST = MOVES.tolist()  # the same, for plain-int arithmetic on one cell
STEP_REWARD = -0.01
OBSTACLE_REWARD = -1.0
GOAL_VALUE = 1.0


class ValueIterationError(RuntimeError):
    """Soft value iteration did not reach its tolerance; the reference fails the scenario."""


@dataclass(frozen=True, kw_only=True)
class GridSpec:
    """The human's grid: extents (m) and a square cell the size of a goal object.

    Cells are exactly ``cell`` wide and the extents must be whole multiples of it, so that
    locating a point and returning a cell's centre agree. The reference computes
    ``floor(range / cell)`` in floating point (37 x 42 here instead of 38 x 43), then locates
    points with the stretched cell ``range / dims`` (0.0514 x 0.0512 m) while centring with
    0.05 m, so far from the origin a cell's "centre" lies outside the cell. The paper says the
    cells are goal-sized so each goal sits in one cell; exact 0.05 m cells do that (two goals at
    least 0.05 apart in x or y never share a cell), so this follows the paper, not the floor.

    Raises:
        ValueError: if an extent is empty or not a whole number of cells.
    """

    x_min: float = 0.1
    x_max: float = 2.0
    y_min: float = -0.15
    y_max: float = 2.0
    cell: float = 0.05

    def __post_init__(self) -> None:
        for lo, hi in ((self.x_min, self.x_max), (self.y_min, self.y_max)):
            n = (hi - lo) / self.cell
            if hi <= lo or abs(n - round(n)) > 1e-6:
                raise ValueError(f"extent [{lo}, {hi}] must be a positive whole number of {self.cell} m cells")

    # Cached: the human locates itself on the grid every tick.
    @cached_property
    def shape(self) -> tuple[int, int]:
        """Number of cells along x and y."""
        return (
            round((self.x_max - self.x_min) / self.cell),
            round((self.y_max - self.y_min) / self.cell),
        )

    @cached_property
    def origin(self) -> np.ndarray:
        """The grid's lower-left corner ``(x_min, y_min)``."""
        return _frozen(np.array([self.x_min, self.y_min]))

    @cached_property
    def _last_cell(self) -> np.ndarray:
        return _frozen(np.array(self.shape) - 1)

    def cell_of(self, xy: ArrayLike) -> np.ndarray:
        """Integer cell ``(ix, iy)`` holding each point, clamped to the grid.

        A point exactly on a boundary goes to the upper cell (1e-6 cell of slack absorbs
        floating-point error, as pyribs does); points off the table map to the nearest edge
        cell rather than raising, since the human never leaves the table in practice.
        """
        xy = np.asarray(xy, dtype=np.float64)[..., :2]
        index = np.floor((xy - self.origin) / self.cell + 1e-6).astype(np.intp)
        return np.minimum(np.maximum(index, 0), self._last_cell)

    def centre_of(self, cells: ArrayLike) -> np.ndarray:
        """x-y of the centre of each integer cell ``(..., 2)``."""
        return self.origin + (np.asarray(cells) + 0.5) * self.cell

    def centres(self) -> np.ndarray:
        """``(nx, ny, 2)`` centres of all cells."""
        return self.centre_of(np.stack(np.indices(self.shape), axis=-1))


@dataclass(frozen=True, kw_only=True)
class ValueTable:
    """Result of :func:`soft_value_iteration` for one goal (arrays are read-only).

    Attributes:
        grid: the grid solved on.
        goal_cell: the terminal cell ``(ix, iy)``.
        obstacles: ``(nx, ny)`` obstacle mask used (the goal cell is never an obstacle).
        values: ``(nx, ny)`` soft values ``V``; ``GOAL_VALUE`` at the goal.
        q_values: ``(nx, ny, 8)`` soft ``Q = r + gamma V(next)`` for :data:`MOVES`; at the
            terminal goal cell every entry equals its value.
        best_action: ``(nx, ny)`` argmax of ``q_values`` (the deterministic human's move).
        tau: the rationality (inverse temperature) solved with.
        iterations: sweeps until convergence.
    """

    grid: GridSpec
    goal_cell: tuple[int, int]
    obstacles: np.ndarray
    values: np.ndarray
    q_values: np.ndarray
    best_action: np.ndarray
    tau: float
    iterations: int


def obstacle_mask(
    grid: GridSpec,
    *,
    other_goals_xy: ArrayLike = (),
    base_xy: Sequence[float] = ROBOT_BASE_XY,
    base_radius: float = 0.05,
) -> np.ndarray:
    """Cells the human should not enter when heading for one goal.

    Three sources, as in the reference: the robot base (cells whose centre is closer than
    ``base_radius`` to it), the quadrant behind the base the human cannot reach (centre
    ``x <= base_x`` and ``y <= base_y``), and the cells of the scenario's other goals (the human
    must not walk through a box it is not working on).

    Args:
        grid: the grid.
        other_goals_xy: ``(k, 2)`` positions of the goals other than the one being solved for.
        base_xy: robot base position; also the corner of the inaccessible quadrant.
        base_radius: radius of the base disk (m).

    Returns:
        ``(nx, ny)`` boolean mask.
    """
    centres = grid.centres()
    base = np.asarray(base_xy, dtype=np.float64)
    mask = np.linalg.norm(centres - base, axis=-1) < base_radius
    mask |= (centres[..., 0] <= base[0]) & (centres[..., 1] <= base[1])
    goals = np.asarray(other_goals_xy, dtype=np.float64).reshape(-1, 2)
    if len(goals):
        ix, iy = grid.cell_of(goals).T
        mask[ix, iy] = True
    return mask


def _transitions(obstacles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flat next-cell indices and rewards, both ``(8, nx * ny)``, for the 8 moves.

    A move off the grid stays put (reward -0.01, or -1 from inside an obstacle); entering an
    obstacle is allowed at -1; other moves cost 0.01 times their length in cells.
    """
    shape = obstacles.shape
    ix, iy = np.indices(shape)
    tx = ix[None] + MOVES[:, 0, None, None]
    ty = iy[None] + MOVES[:, 1, None, None]
    inside = (tx >= 0) & (tx < shape[0]) & (ty >= 0) & (ty < shape[1])
    tx = np.where(inside, tx, ix[None])
    ty = np.where(inside, ty, iy[None])
    move_reward = STEP_REWARD * np.linalg.norm(MOVES, axis=1)[:, None, None]
    reward = np.where(
        inside,
        np.where(obstacles[tx, ty], OBSTACLE_REWARD, move_reward),
        np.where(obstacles[None], OBSTACLE_REWARD, STEP_REWARD),
    )
    next_flat = np.ravel_multi_index((tx, ty), shape)
    return next_flat.reshape(len(MOVES), -1), reward.reshape(len(MOVES), -1)


def _soft_max(q: np.ndarray, tau: float) -> np.ndarray:
    """Log-mean-exp over moves, ``(logsumexp(tau q) - log 8) / tau``, computed stably.

    The mean (not sum) keeps V below max Q, so values cannot grow without bound.
    """
    top = q.max(axis=0)
    return top + (np.log(np.exp(tau * (q - top)).sum(axis=0)) - np.log(len(q))) / tau


def soft_value_iteration(
    grid: GridSpec,
    obstacles: np.ndarray,
    goal_cell: Sequence[int],
    *,
    tau: float = 1000.0,
    gamma: float = 0.9999,
    tol: float = 1e-3,
    max_iter: int = 5000,
) -> ValueTable:
    """Soft value iteration toward one goal cell (the reference's ``MDPHuman``, vectorised).

    ``Q(s, a) = r(s, a) + gamma V(s')`` and ``V(s) = logmeanexp_a(tau Q(s, a)) / tau``, with
    the goal cell terminal at ``V = GOAL_VALUE`` (the +1 for reaching it). Sweeps stop when the
    mean absolute change of V over non-goal cells drops below ``tol``. The returned Q is
    computed from the final V (the reference keeps the one from the sweep before).

    Args:
        grid: the grid.
        obstacles: ``(nx, ny)`` mask from :func:`obstacle_mask`; ignored at the goal cell,
            which is always terminal (as in the reference, where the goal overrides).
        goal_cell: ``(ix, iy)`` of the goal, e.g. ``grid.cell_of(goal_xy)``.
        tau: rationality (inverse softmax temperature): higher is closer to a hard max.
        gamma: discount factor.
        tol: convergence threshold on the mean absolute change of V.
        max_iter: sweeps allowed.

    Returns:
        The :class:`ValueTable`.

    Raises:
        ValueError: for a non-positive ``tau``, ``gamma`` outside (0, 1], ``max_iter < 1``, or
            a mask of the wrong shape.
        ValueIterationError: if ``tol`` is not reached within ``max_iter`` sweeps.
    """
    obstacles = np.array(obstacles, dtype=bool)
    if obstacles.shape != grid.shape:
        raise ValueError(f"obstacles must have shape {grid.shape}, got {obstacles.shape}")
    if tau <= 0 or not 0 < gamma <= 1 or max_iter < 1:
        raise ValueError(
            f"need tau > 0, 0 < gamma <= 1 and max_iter >= 1, got tau={tau}, gamma={gamma}, max_iter={max_iter}"
        )
    goal = (int(goal_cell[0]), int(goal_cell[1]))
    obstacles[goal] = False
    goal_flat = np.ravel_multi_index(goal, grid.shape)
    next_flat, reward = _transitions(obstacles)

    values = np.zeros(obstacles.size)
    values[goal_flat] = GOAL_VALUE
    for iteration in range(1, max_iter + 1):  # noqa: B007 - read after the loop: the sweeps it took
        new = _soft_max(reward + gamma * values[next_flat], tau)
        new[goal_flat] = GOAL_VALUE
        change = np.abs(new - values).sum() / (values.size - 1)
        values = new
        if change < tol:
            break
    else:
        raise ValueIterationError(
            f"soft value iteration did not converge in {max_iter} sweeps (mean |dV| = {change:.3g} >= {tol})"
        )

    q_values = reward + gamma * values[next_flat]
    q_values[:, goal_flat] = GOAL_VALUE
    q_values = q_values.T.reshape(*grid.shape, len(MOVES))
    return ValueTable(
        grid=grid,
        goal_cell=goal,
        obstacles=_frozen(obstacles),
        values=_frozen(values.reshape(grid.shape)),
        q_values=_frozen(q_values),
        best_action=_frozen(np.argmax(q_values, axis=-1)),
        tau=float(tau),
        iterations=iteration,
    )


def _frozen(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def policy_probabilities(table: ValueTable) -> np.ndarray:
    """``(nx, ny, 8)`` soft policy ``pi(a|s) = exp(tau (Q - V))``: softmax of ``tau Q``.

    The stochastic human of the reference's human-search setting samples from this; lower
    ``tau`` spreads it over more moves.
    """
    return _softmax(table.tau * table.q_values)


def _softmax(logits: np.ndarray) -> np.ndarray:
    weights = np.exp(logits - logits.max(axis=-1, keepdims=True))
    return weights / weights.sum(axis=-1, keepdims=True)


def next_target(
    table: ValueTable,
    position_xy: ArrayLike,
    goal_xy: ArrayLike,
    *,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Where the human heads this tick: the centre of the next cell, or the goal itself.

    From the cell holding ``position_xy`` take the move with the highest soft Q (the paper's
    deterministic human) or, given ``rng``, a move sampled from :func:`policy_probabilities`
    (the human-search setting; the reference's sampler was unseeded, this one is explicit).
    Entering the goal cell, or already being in it, returns the exact ``goal_xy`` so the human
    ends on the box rather than on a cell centre.

    Returns:
        ``(2,)`` target x-y.
    """
    grid = table.grid
    cell = tuple(grid.cell_of(position_xy).tolist())
    if cell == table.goal_cell:
        return np.asarray(goal_xy, dtype=np.float64)[:2].copy()
    if rng is None:
        move = table.best_action[cell]
    else:
        move = rng.choice(len(MOVES), p=_softmax(table.tau * table.q_values[cell]))
    (dx, dy), (nx, ny) = _MOVE_LIST[move], grid.shape
    nxt = (min(max(cell[0] + dx, 0), nx - 1), min(max(cell[1] + dy, 0), ny - 1))
    if nxt == table.goal_cell:
        return np.asarray(goal_xy, dtype=np.float64)[:2].copy()
    return grid.centre_of(nxt)


def human_step(position: ArrayLike, target: ArrayLike, speed_coeff: float = 0.5, dt: float = 0.025) -> np.ndarray:
    """One tick of human motion: the UserBot command toward ``target`` times ``speed_coeff``.

    The command is at most 0.25 in norm, so the human moves at most ``0.25 * speed_coeff``
    m/s (0.125 m/s at the default 0.5). A z coordinate, if given, is carried unchanged.

    Returns:
        The new position, same shape as ``position``.
    """
    new = np.array(position, dtype=np.float64)
    new[:2] += user_velocity(new, target) * speed_coeff * dt
    return new
