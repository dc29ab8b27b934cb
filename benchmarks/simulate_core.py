"""Times the simulation core's hot path and prints a Markdown table.

    python benchmarks/simulate_core.py            # the table
    python benchmarks/simulate_core.py --profile  # and where the time goes, from cProfile

Rows: ``World.step_twist`` per tick over 4,000 ticks of varying teleoperation-sized twists;
the same with a joint held at its limit, so every tick needs the bounded solver; a 400-tick
teleoperation episode (the reference's simulated operator driving the end effector at up to
0.05 m/s towards a goal, reading the pose every tick), with and without a self-collision check
per tick as the collaboration task makes; and the one-off costs of building a world.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time

import numpy as np

from hritest.sim import DT, Box, World, WorldLayout

TICKS = 4000
EPISODE_TICKS = 400
EPISODES = 25


def reference_layout() -> WorldLayout:
    return WorldLayout(
        table=Box(name="table", center=(0.65, -0.175, 0.845), half_size=(0.2, 0.5, 0.021)),
        regions=(
            Box(name="ws1", center=(0.595, 0.05, 0.86), half_size=(0.13, 0.18, 0.021)),
            Box(name="ws2", center=(0.22, 0.625, 0.86), half_size=(0.13, 0.18, 0.021)),
        ),
        objects=(Box(name="goal0", center=(0.6, 0.05, 0.96), half_size=(0.032,) * 3),),
        hand_start=(0.91, 0.05, 0.96),
    )


def varying_twists(n: int, seed: int = 0) -> np.ndarray:
    """Teleoperation-sized twists: up to ~0.05 m/s and ~0.1 rad/s, a new one every tick."""
    twists = np.random.default_rng(seed).normal(0.0, 1.0, (n, 6))
    return twists * [0.03, 0.03, 0.03, 0.06, 0.06, 0.06]


def per_tick_us(world: World, twists: np.ndarray, start=None) -> float:
    world.reset()
    if start is not None:
        world.set_q(start)
    times = np.empty(len(twists))
    for i, twist in enumerate(twists):
        t0 = time.perf_counter_ns()
        world.step_twist(twist)
        times[i] = time.perf_counter_ns() - t0
    return float(np.median(times)) / 1e3


def episode(world: World, *, check_collisions: bool) -> tuple[int, int]:
    """The reference's simulated operator: v = 10 (goal - ee), z zeroed, |v| <= 0.25, times 0.2.

    Returns the nanoseconds of the whole episode and of the part spent inside ``World`` calls
    (the simulation overhead; the rest is this toy operator's own numpy).
    """
    goal = np.array([0.6, 0.05, 0.96])
    clock = time.perf_counter_ns
    start = clock()
    world.reset()
    inside = clock() - start
    for _ in range(EPISODE_TICKS):
        t0 = clock()
        position = world.ee_pose()[:3, 3]
        inside += clock() - t0
        error = goal - position
        error[2] = 0.0
        velocity = 10.0 * error
        velocity *= min(1.0, 0.25 / max(np.linalg.norm(velocity), 1e-12))
        twist = np.concatenate((0.2 * velocity, np.zeros(3)))
        t0 = clock()
        world.step_twist(twist, DT)
        if check_collisions:
            world.self_collision()
        inside += clock() - t0
    return clock() - start, inside


def episode_ms(world: World, *, check_collisions: bool) -> str:
    runs = np.array([episode(world, check_collisions=check_collisions) for _ in range(EPISODES)])
    total, inside = np.median(runs, axis=0) / 1e6
    return f"{inside:.2f} ms in `World` calls, {total:.2f} ms in all (medians of {EPISODES})"


def one_off_us(call, repeats: int) -> float:
    t0 = time.perf_counter_ns()
    for _ in range(repeats):
        call()
    return (time.perf_counter_ns() - t0) / repeats / 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profile", action="store_true", help="also print a cProfile summary")
    args = parser.parse_args()

    layout = reference_layout()
    world = World(layout=layout)
    twists = varying_twists(TICKS)
    # Joint 2 parked inside its limit margin; the twists keep asking it to move, so every tick
    # falls back to the bounded least-squares solver.
    at_limit = np.array(world.q)
    at_limit[1] = world.joint_limits[1][1] - 0.01
    pinned = twists + world.jacobian()[:, 1] * 0.2

    rows = [
        ("`step_twist`, varying twists", f"{per_tick_us(world, twists):.1f} µs / tick (median)"),
        (
            "`step_twist`, joint 2 at its limit (bounded solver every tick)",
            f"{per_tick_us(world, pinned, at_limit):.1f} µs / tick (median)",
        ),
        (
            f"{EPISODE_TICKS}-tick teleoperation episode (`ee_pose` + `step_twist` per tick)",
            episode_ms(world, check_collisions=False),
        ),
        (
            f"{EPISODE_TICKS}-tick episode, plus `self_collision()` every tick",
            episode_ms(world, check_collisions=True),
        ),
        ("`self_collision()`", f"{one_off_us(world.self_collision, 10_000):.1f} µs"),
        ("`ee_pose()`", f"{one_off_us(world.ee_pose, 10_000):.1f} µs"),
        (
            "`World(layout=...)` (build the spec, compile, make data)",
            f"{one_off_us(lambda: World(layout=layout), 50) / 1e3:.2f} ms",
        ),
    ]
    print("| what | time |\n|---|---|")
    for what, value in rows:
        print(f"| {what} | {value} |")

    if args.profile:
        profiler = cProfile.Profile()
        world.reset()
        profiler.enable()
        for twist in twists:
            world.step_twist(twist)
        profiler.disable()
        print(f"\ncProfile of {TICKS} `step_twist` ticks (top 12 by own time):\n")
        pstats.Stats(profiler).sort_stats("tottime").print_stats(12)


if __name__ == "__main__":
    main()
