"""The inner loop's penalty measures in the repair's units: it equals the repair's cost where the
repair only clips or projects, in normalised and in raw units alike."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hritest.domain import compile_spec
from hritest.spec import load_spec
from hritest.surrogate.penalty import Penalty

# A goal in metres and a wait in seconds under one bounds constraint, and a box kept inside a region.
PARAMETERS = (
    "  - {name: noise, bind: human.noise, size: 3, bounds: [-0.05, 0.05]}\n",
    "  - {name: noise, bind: human.noise, size: 3, bounds: [-0.05, 0.05]}\n"
    "  - {name: wait, bind: task.delay, bounds: [0.0, 10.0]}\n"
    "  - {name: box_x, bind: box.x, bounds: [0.0, 2.0]}\n"
    "  - {name: box_y, bind: box.y, bounds: [0.0, 0.5]}\n",
)
PLACED = (
    "constraints:\n",
    "workspace:\n"
    "  regions:\n"
    "    - {name: shelf, x: [0.5, 1.5], y: [0.1, 0.4]}\n"
    "objects:\n"
    "  - {name: box, half_size: [0.05, 0.05, 0.05], position: [1.0, 0.25, 0.9]}\n"
    "constraints:\n"
    "  - {type: inside, objects: [box], regions: [shelf]}\n",
)


def domain(toy_spec, units: str):
    path = toy_spec()
    text = path.read_text()
    for old, new in (PARAMETERS, PLACED, ("constraints:\n", f"repair: {{units: {units}}}\nconstraints:\n")):
        assert text.count(old) == 1, old
        text = text.replace(old, new, 1)
    return compile_spec(load_spec(toy_spec(text=text)))


@pytest.mark.parametrize("units", ["normalised", "raw"])
def test_the_penalty_is_the_repair_cost_of_what_clipping_and_projection_repair(toy_spec, units):
    compiled = domain(toy_spec, units)
    penalty = Penalty(compiled.repair.penalty_terms(), torch.device("cpu"))
    thetas = np.array(
        [
            [0.6, 0.05, 0.6, 0.05, 0, 0, 0, 5.0, 1.0, 0.25],  # valid
            [0.7, 0.05, 0.6, 0.05, 0, 0, 0.06, 12.0, 1.0, 0.25],  # a goal, a noise and the wait out of bounds
            [0.6, 0.05, 0.6, 0.05, 0, 0, 0, 5.0, 1.7, 0.05],  # the box off the shelf in x and y
        ]
    )
    costs = [compiled.repair(theta).cost for theta in thetas]
    assert costs[0] == 0 and costs[1] > 0 and costs[2] > 0
    assert penalty(torch.tensor(thetas, dtype=torch.float32)).tolist() == pytest.approx(costs, rel=1e-5)
