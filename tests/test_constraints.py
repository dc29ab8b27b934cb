"""The repair's cost: in fractions of each parameter's bounds by default, in the parameters' own units
(the paper's reference) with ``repair: {units: raw}``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hritest.domain import compile_spec, load_domain
from hritest.spec import load_spec

SPECS = Path(__file__).parent.parent / "specs"

# The toy spec with a parameter in seconds beside the goals' metres, all under one bounds constraint.
SECONDS = (
    "  - {name: noise, bind: human.noise, size: 3, bounds: [-0.05, 0.05]}\n",
    "  - {name: noise, bind: human.noise, size: 3, bounds: [-0.05, 0.05]}\n"
    "  - {name: wait, bind: task.delay, bounds: [0.0, 10.0]}\n",
)
RAW = "constraints:\n", "repair: {units: raw}\nconstraints:\n"


def toy_domain(toy_spec, *edits: tuple[str, str]):
    path = toy_spec()
    text = path.read_text()
    for old, new in edits:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return compile_spec(load_spec(toy_spec(text=text)))


def test_a_second_outside_the_bounds_costs_as_much_as_a_tenth_of_a_goals_range(toy_spec):
    # g0x 0.016 m past its 0.16 m-wide bounds, wait 1 s past its 10 s-wide ones: a tenth of each.
    theta = np.array([0.68 + 0.016, 0.05, 0.6, 0.05, 0, 0, 0, 11.0])
    normalised = toy_domain(toy_spec, SECONDS).repair(theta)
    assert normalised.cost == pytest.approx(0.1**2 + 0.1**2)
    raw = toy_domain(toy_spec, SECONDS, RAW).repair(theta)
    assert raw.cost == pytest.approx(0.016**2 + 1.0**2)  # the reference's: squared metres plus squared seconds
    np.testing.assert_array_equal(normalised.theta, raw.theta)  # clipping moves theta the same either way


def test_grouped_excesses_are_summed_in_fractions_of_their_bounds(toy_spec):
    # Both goals' x 0.016 m out (a tenth of 0.16 m each): the group's sum is squared, as the reference's.
    theta = np.array([0.68 + 0.016, 0.05, 0.52 - 0.016, 0.05, 0, 0, 0])
    assert toy_domain(toy_spec).repair(theta).cost == pytest.approx((0.1 + 0.1) ** 2)
    assert toy_domain(toy_spec, RAW).repair(theta).cost == pytest.approx((0.016 + 0.016) ** 2)


# Two boxes whose footprints are 0.02 m short of apart in x and 0.04 m in y. Their x may vary over
# 0.2 m, their y over 2 m: moving them apart in y costs 4x the metres^2 of x, but a 25th of its
# share of their ranges.
PLACED = (
    "parameters:\n  - {name: g0x, bind: task.g0x, bounds: [0.52, 0.68]}\n",
    "objects:\n"
    "  - {name: a, half_size: [0.05, 0.05, 0.05], position: [0.46, 1.0, 0.9]}\n"
    "  - {name: b, half_size: [0.05, 0.05, 0.05], position: [0.54, 1.06, 0.9]}\n"
    "parameters:\n"
    "  - {name: ax, bind: a.x, bounds: [0.4, 0.6]}\n"
    "  - {name: ay, bind: a.y, bounds: [0.0, 2.0]}\n"
    "  - {name: bx, bind: b.x, bounds: [0.4, 0.6]}\n"
    "  - {name: by, bind: b.y, bounds: [0.0, 2.0]}\n"
    "  - {name: g0x, bind: task.g0x, bounds: [0.52, 0.68]}\n",
)
APART = "  - {type: bounds, groups: [[g0x, g1x], [g0y, g1y], [noise]]}\n", "  - {type: no_overlap, objects: [a, b]}\n"
OVERLAPPING = np.array([0.46, 1.0, 0.54, 1.06, 0.6, 0.05, 0.6, 0.05, 0, 0, 0])


def moved(outcome) -> np.ndarray:
    return (outcome.theta - OVERLAPPING)[:4]


def test_the_placement_program_moves_objects_by_the_smallest_fraction_of_their_ranges(toy_spec):
    normalised = toy_domain(toy_spec, PLACED, APART).repair(OVERLAPPING)
    assert normalised.status == "repaired"
    assert moved(normalised)[[0, 2]] == pytest.approx([0, 0])  # x, with the narrow range, stays put
    assert moved(normalised)[[1, 3]] == pytest.approx([-0.02, 0.02], abs=1e-3)
    scale = np.array([0.2, 2.0, 0.2, 2.0])
    assert normalised.cost == pytest.approx(((moved(normalised) / scale) ** 2).sum(), rel=1e-9)
    assert normalised.cost == pytest.approx(2 * (0.02 / 2.0) ** 2, rel=0.02)

    raw = toy_domain(toy_spec, PLACED, APART, RAW).repair(OVERLAPPING)
    assert moved(raw)[[1, 3]] == pytest.approx([0, 0])  # in metres, the smaller move is in x
    assert moved(raw)[[0, 2]] == pytest.approx([-0.01, 0.01], abs=1e-3)
    assert raw.cost == pytest.approx((moved(raw) ** 2).sum(), rel=1e-9)


def test_the_papers_specs_keep_the_references_cost_in_metres():
    teleop = load_domain(SPECS / "teleop.yaml")
    theta = np.array([0.75, 0.05, 0.6, -0.2, 0.1, 0, 0, 0, 0])  # g0x, g1y and noise[0] out of bounds
    assert teleop.repair(theta).cost == pytest.approx(0.07**2 + 0.12**2 + 0.05**2)  # (sum e_x)^2 + ...

    collab = load_domain(SPECS / "collab.yaml")
    stacked = np.array([0.4, 0.3, 0.4, 0.3, 0.4, 0.3])  # between the regions, on one spot
    repaired = collab.repair(stacked)
    assert repaired.status == "repaired"
    assert repaired.cost == pytest.approx(((repaired.theta - stacked) ** 2).sum(), rel=1e-9)
