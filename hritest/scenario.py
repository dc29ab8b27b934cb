"""Theta and what it means: the layout of the scenario vector and a concrete scenario."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True, kw_only=True)
class Slot:
    """The components ``theta[start:start + size]``, bound to one target of the scenario."""

    name: str
    bind: str
    start: int
    size: int
    lower: float
    upper: float

    @property
    def target(self) -> str:
        return self.bind.split(".")[0]

    @property
    def attribute(self) -> str:
        return self.bind.split(".")[1]

    @property
    def labels(self) -> list[str]:
        return [self.name] if self.size == 1 else [f"{self.name}[{i}]" for i in range(self.size)]

    @property
    def part(self) -> slice:
        """Where the slot lies in theta: ``theta[slot.part]``."""
        return slice(self.start, self.start + self.size)


@dataclass(frozen=True, kw_only=True)
class Scenario:
    """One concrete scenario: where things are and the agents' model parameters.

    ``objects``: each placed object's centre ``(x, y, z)``, in the spec's order. ``bodies``: what
    the scenario sets on the world (``"arm"`` and named bodies of the world model), attribute ->
    value, for the bound attributes only. ``values``: every parameter by name.
    """

    objects: Mapping[str, np.ndarray]
    human: Mapping[str, Any]
    robot: Mapping[str, Any]
    task: Mapping[str, Any]
    bodies: Mapping[str, Mapping[str, float | np.ndarray]] = field(default_factory=dict)
    values: Mapping[str, float | np.ndarray] = field(default_factory=dict)


@dataclass(frozen=True, kw_only=True)
class ScenarioSpace:
    """Theta's layout: which component means what, and its bounds."""

    slots: tuple[Slot, ...]
    nominal_objects: Mapping[str, np.ndarray]
    nominal_params: Mapping[str, Mapping[str, Any]]

    @property
    def dim(self) -> int:
        return sum(slot.size for slot in self.slots)

    @property
    def lower(self) -> np.ndarray:
        return np.concatenate([np.full(s.size, s.lower) for s in self.slots])

    @property
    def upper(self) -> np.ndarray:
        return np.concatenate([np.full(s.size, s.upper) for s in self.slots])

    @property
    def labels(self) -> list[str]:
        return [label for slot in self.slots for label in slot.labels]

    def values(self, theta: np.ndarray) -> dict[str, float | np.ndarray]:
        """Parameter name -> its value (a float, or an array for a group)."""
        theta = self._check(theta)
        return {
            s.name: float(theta[s.start]) if s.size == 1 else theta[s.start : s.start + s.size].copy()
            for s in self.slots
        }

    def bind(self, theta: np.ndarray) -> Scenario:
        """The scenario that ``theta`` describes: nominal values overridden by theta's."""
        values = self.values(theta)
        objects = {name: pos.copy() for name, pos in self.nominal_objects.items()}
        params = {agent: dict(p) for agent, p in self.nominal_params.items()}
        bodies: dict[str, dict[str, float | np.ndarray]] = {}
        for slot in self.slots:
            value = values[slot.name]
            if slot.target in params:
                params[slot.target][slot.attribute] = value
            elif slot.target in objects:
                objects[slot.target]["xyz".index(slot.attribute)] = value
            else:
                bodies.setdefault(slot.target, {})[slot.attribute] = value
        return Scenario(
            objects=objects,
            human=params["human"],
            robot=params["robot"],
            task=params["task"],
            bodies=bodies,
            values=values,
        )

    def _check(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (self.dim,):
            raise ValueError(
                f"theta has shape {theta.shape}; this spec's theta has {self.dim} components ({', '.join(self.labels)})"
            )
        return theta
