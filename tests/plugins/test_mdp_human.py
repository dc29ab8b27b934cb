"""The collaboration human: grid, obstacles, soft value iteration and the walk it produces."""

from __future__ import annotations

import numpy as np
import pytest
from hritest_plugins import mdp_human as m

GRID = m.GridSpec()
START = np.array(m.HUMAN_START_XY)
WS1 = ((0.52, 0.68), (-0.08, 0.18))
WS2 = ((0.138, 0.298), (0.496, 0.756))
BASE_AND_QUADRANT = m.obstacle_mask(GRID)


def solve(goals, index, **kwargs) -> m.ValueTable:
    goals = np.asarray(goals, dtype=float)
    obstacles = m.obstacle_mask(GRID, other_goals_xy=np.delete(goals, index, axis=0))
    return m.soft_value_iteration(GRID, obstacles, GRID.cell_of(goals[index]), **kwargs)


def walk(table, goal_xy, *, speed_coeff=0.5, max_ticks=4000, rng=None):
    """Simulates the human from START until within 1 cm of the goal; returns the positions."""
    position, path = START.copy(), [START.copy()]
    while np.linalg.norm(position - goal_xy) >= 0.01 and len(path) <= max_ticks:
        target = m.next_target(table, position, goal_xy, rng=rng)
        position = m.human_step(position, target, speed_coeff)
        path.append(position)
    return np.array(path)


def cell_path(table) -> list[tuple[int, int]]:
    """The cells the deterministic policy visits from START's cell to the goal."""
    cell, cells, last = tuple(GRID.cell_of(START)), [], np.array(GRID.shape) - 1
    while cell != table.goal_cell and len(cells) < 200:
        cells.append(cell)
        cell = tuple(np.clip(np.add(cell, m.MOVES[table.best_action[cell]]), 0, last))
    return cells + [cell]


def cells_of(path) -> set[tuple[int, int]]:
    return set(map(tuple, GRID.cell_of(path)))


# --- grid and obstacles -------------------------------------------------------------------


def test_grid_has_exact_goal_sized_cells():
    assert GRID.shape == (38, 43)
    cells = np.stack(np.indices(GRID.shape), axis=-1).reshape(-1, 2)
    np.testing.assert_array_equal(GRID.cell_of(GRID.centre_of(cells)), cells)
    # goals at least 0.05 apart in x or y (the repair's guarantee) never share a cell
    assert tuple(GRID.cell_of([0.52, 0.0])) != tuple(GRID.cell_of([0.57, 0.0]))
    with pytest.raises(ValueError, match="whole number"):
        m.GridSpec(x_max=2.01)


def test_obstacles_are_the_base_the_quadrant_behind_it_and_other_goals():
    centres = GRID.centres()
    quadrant = (centres[..., 0] <= 0.409) & (centres[..., 1] <= 0.338)
    assert np.all(BASE_AND_QUADRANT[quadrant])
    extra = BASE_AND_QUADRANT & ~quadrant  # the base disk sticks out of the quadrant
    assert sorted(map(tuple, centres[extra].round(3))) == [(0.425, 0.325), (0.425, 0.375)]
    assert not BASE_AND_QUADRANT[tuple(GRID.cell_of(START))]
    with_goals = m.obstacle_mask(GRID, other_goals_xy=[[0.6, 0.05], [0.2, 0.6]])
    assert np.argwhere(with_goals & ~BASE_AND_QUADRANT).tolist() == [[2, 15], [10, 4]]


# --- value iteration ----------------------------------------------------------------------


def test_value_iteration_converges_to_a_soft_bellman_fixed_point():
    table = solve([[0.6, 0.05], [0.2, 0.6], [0.55, 0.15]], 1)
    assert table.iterations < 100
    assert table.values[table.goal_cell] == m.GOAL_VALUE
    q = table.q_values * table.tau
    backup = (np.log(np.exp(q - q.max(-1, keepdims=True)).sum(-1)) - np.log(8)) / table.tau
    backup += table.q_values.max(-1)
    residual = np.abs(backup - table.values)
    residual[table.goal_cell] = 0.0
    assert residual.mean() < 1e-3
    # near the goal the values are sharp: one orthogonal step costs 0.01 plus the entropy term
    gx, gy = table.goal_cell
    assert table.values[gx + 1, gy] == pytest.approx(-0.01 + 0.9999, abs=3e-3)
    assert table.values[gx, gy] > table.values[gx + 1, gy] > table.values[gx + 2, gy]
    assert not table.values.flags.writeable


def test_non_convergence_raises():
    with pytest.raises(m.ValueIterationError, match="1 sweeps"):
        solve([[0.6, 0.05]], 0, max_iter=1)


def test_lower_tau_gives_a_higher_entropy_policy():
    goals = [[0.6, 0.05], [0.2, 0.6], [0.55, 0.15]]
    entropies = []
    for log10_tau in m.LOG10_TAU_BOUNDS:
        table = solve(goals, 1, tau=10.0**log10_tau)
        p = m.policy_probabilities(table)
        free = ~table.obstacles
        free[table.goal_cell] = False
        entropies.append(-(p * np.log(p + 1e-300)).sum(-1)[free].mean())
        np.testing.assert_allclose(p.sum(-1), 1.0)
    assert entropies[0] > entropies[1] + 0.1


# --- the walk -----------------------------------------------------------------------------

GOALS_TO_REACH = [
    (WS1[0][0], WS1[1][0]),
    (WS1[0][1], WS1[1][1]),
    (0.6, 0.05),
    (WS1[0][0], WS1[1][1]),
    (WS2[0][0], WS2[1][0]),
    (WS2[0][1], WS2[1][1]),
    (0.218, 0.626),
    (WS2[0][1], WS2[1][0]),
]


@pytest.mark.parametrize("goal", GOALS_TO_REACH)
def test_human_reaches_goals_in_both_workspaces_around_the_base(goal):
    goal = np.array(goal)
    table = solve([goal], 0)
    path = walk(table, goal)
    assert len(path) - 1 < 100 / 0.025
    assert np.linalg.norm(path[-1] - goal) < 0.01
    assert not any(BASE_AND_QUADRANT[c] for c in cells_of(path))
    speeds = np.linalg.norm(np.diff(path, axis=0), axis=1) / 0.025
    assert speeds.max() <= 0.125 + 1e-12


def test_human_reaches_every_goal_of_random_scenarios_without_crossing_obstacles():
    rng = np.random.default_rng(7)
    for _ in range(8):
        region = rng.integers(2, size=3)
        lows = np.array([[WS1[0][0], WS1[1][0]], [WS2[0][0], WS2[1][0]]])[region]
        highs = np.array([[WS1[0][1], WS1[1][1]], [WS2[0][1], WS2[1][1]]])[region]
        goals = rng.uniform(lows, highs)
        for i in range(3):
            table = solve(goals, i)
            assert not any(table.obstacles[c] for c in cell_path(table))  # never plans through
            path = walk(table, goals[i])
            assert np.linalg.norm(path[-1] - goals[i]) < 0.01
            assert not any(BASE_AND_QUADRANT[c] for c in cells_of(path))


def test_human_walks_around_another_goal_in_the_way():
    target, blocker = np.array([0.55, 0.05]), np.array([0.72, 0.05])  # blocker on the line
    blocked = cells_of(walk(solve([target, blocker], 0), target))
    free = cells_of(walk(solve([target], 0), target))
    blocker_cell = tuple(GRID.cell_of(blocker))
    assert blocker_cell in free  # without it the straight line crosses that cell
    assert blocker_cell not in blocked


def test_enclosed_goal_is_still_reached_through_the_cheapest_obstacle():
    goal = np.array([0.6, 0.05])
    gx, gy = GRID.cell_of(goal)
    obstacles = BASE_AND_QUADRANT.copy()
    obstacles[gx - 1 : gx + 2, gy - 1 : gy + 2] = True  # a ring around the goal cell
    table = m.soft_value_iteration(GRID, obstacles, (gx, gy))
    assert not table.obstacles[gx, gy]
    crossed = [c for c in cell_path(table) if table.obstacles[c]]
    assert len(crossed) == 1
    assert np.linalg.norm(walk(table, goal)[-1] - goal) < 0.01


def test_next_target_is_a_cell_centre_then_the_exact_goal():
    goal = np.array([0.6123, 0.0471])
    table = solve([goal], 0)
    first = m.next_target(table, START, goal)
    np.testing.assert_allclose(GRID.centre_of(GRID.cell_of(first)), first)
    next_to_goal = GRID.centre_of(GRID.cell_of(goal) + [1, 0])
    np.testing.assert_array_equal(m.next_target(table, next_to_goal, goal), goal)
    np.testing.assert_array_equal(m.next_target(table, goal + 0.001, goal), goal)


def test_stochastic_human_is_reproducible_and_still_arrives():
    goal = np.array([0.218, 0.626])
    table = solve([goal], 0, tau=10.0**2.5)
    one = walk(table, goal, rng=np.random.default_rng(3))
    again = walk(table, goal, rng=np.random.default_rng(3))
    other = walk(table, goal, rng=np.random.default_rng(4))
    np.testing.assert_array_equal(one, again)
    assert not np.array_equal(one, other)
    assert np.linalg.norm(one[-1] - goal) < 0.01


def test_human_step_speed_scales_with_the_coefficient_and_keeps_z():
    position = np.array([0.9, 0.05, 0.96])
    far = np.array([0.0, 0.05])
    for coeff in m.SPEED_COEFF_BOUNDS:
        moved = m.human_step(position, far, coeff)
        assert np.linalg.norm(moved[:2] - position[:2]) == pytest.approx(0.25 * coeff * 0.025)
        assert moved[2] == 0.96
    near = m.human_step(position[:2], position[:2] + [0.001, 0.0])
    np.testing.assert_allclose(near, position[:2] + [10 * 0.001 * 0.5 * 0.025, 0.0])
