"""The spec language as pydantic models: structure and per-field checks.

Checks that need the whole spec (names that refer to other names) live in
:mod:`hritest.spec.references`, so that every message can point at the exact field.
Defaults are the paper's settings (``../shared/reference/dsas-reference-code.md`` section 5).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    StringConstraints,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from hritest.records import MAX_SEED
from hritest.sim.layout import ROBOT_BASE
from hritest.spec import expr

# Sizes beyond any episode or search that can finish: ticks per episode (a task may allocate
# arrays of this length), and solutions per batch (each one theta, all in memory at once).
MAX_TICKS = 1_000_000
MAX_BATCH = 100_000


Name = Annotated[
    str,
    StringConstraints(pattern=r"^[A-Za-z][A-Za-z0-9_]*$", max_length=64),
    Field(description="letters, digits and '_', starting with a letter; at most 64"),
]


# Numbers are strict: YAML reads true, yes and on as booleans, which pydantic would take as 1.
Number = Annotated[float, Field(strict=True)]
Count = Annotated[int, Field(strict=True)]


def _check_interval(value: tuple[float, float]) -> tuple[float, float]:
    lo, hi = value
    if not lo < hi:
        raise ValueError(f"the lower end must be below the upper end: got [{lo}, {hi}]; write [low, high]")
    return value


Interval = Annotated[tuple[Number, Number], AfterValidator(_check_interval)]
Vec2 = tuple[Number, Number]
Vec3 = tuple[Number, Number, Number]
PositiveFloat = Annotated[float, Field(gt=0, strict=True)]


def _check_half_size(value: Vec3) -> Vec3:
    if min(value) <= 0:
        raise ValueError(f"every half size must be positive, got {list(value)}")
    return value


HalfSize = Annotated[Vec3, AfterValidator(_check_half_size)]
PositiveInt = Annotated[int, Field(gt=0, strict=True)]
BatchSize = Annotated[int, Field(gt=0, le=MAX_BATCH, strict=True)]


def _finite_params(params: dict[str, Any]) -> dict[str, Any]:
    """A plugin's params hold any YAML, but no NaN or infinity: a plugin's model may well accept them.

    Every such value is reported, each at its own place (a ValidationError raised here keeps its
    locations, below the params' own), so that one ``validate`` names them all.
    """
    errors, stack = [], [((key,), value) for key, value in reversed(params.items())]
    while stack:
        path, value = stack.pop()
        if isinstance(value, float) and not math.isfinite(value):
            errors.append({"type": "finite_number", "loc": path, "input": value})
        elif isinstance(value, dict):
            stack += [((*path, key), item) for key, item in reversed(value.items())]
        elif isinstance(value, list):
            stack += [((*path, i), item) for i, item in reversed(list(enumerate(value)))]
    if errors:
        raise ValidationError.from_exception_data("params", errors)
    return params


Params = Annotated[dict[str, Any], AfterValidator(_finite_params)]


def _numeric(text: str) -> str:
    expr.parse(text)
    return text


def _condition(text: str) -> str:
    expr.parse(text, condition=True)
    return text


NumericExpr = Annotated[str, AfterValidator(_numeric)]
ConditionExpr = Annotated[str, AfterValidator(_condition)]


class Strict(BaseModel):
    """Base of every spec model: unknown keys are errors, values are immutable, numbers are finite."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class TaskSpec(Strict):
    """The interaction: a task plugin, its time limit and tick."""

    name: str = Field(description="registered task name (shared_control, collaboration) or module:Class")
    time_limit: PositiveFloat = Field(description="seconds of simulated time before the episode stops")
    dt: PositiveFloat = Field(0.025, description="simulation tick in seconds (40 Hz in the paper)")
    params: Params = Field(default_factory=dict)

    @model_validator(mode="after")
    def _ticks(self) -> TaskSpec:
        ticks = round(self.time_limit / self.dt)
        if not 1 <= ticks <= MAX_TICKS:
            raise ValueError(
                f"time_limit / dt is {ticks:,} ticks; an episode has 1 to {MAX_TICKS:,}: change the time limit "
                "or the tick"
            )
        return self


class BoxSpec(Strict):
    center: Vec3
    half_size: HalfSize


class RegionSpec(Strict):
    """A rectangle on the table in which object centres may be placed."""

    name: Name
    x: Interval
    y: Interval


class WorkspaceSpec(Strict):
    """A tabletop: the table (the only thing the built-in arm can collide with) and placement regions."""

    table: BoxSpec | None = None
    regions: list[RegionSpec] = Field(default_factory=list)


class ArmSpec(Strict):
    """The robot arm: an MJCF file (default: the built-in Mico-like 6-DoF arm) and where it stands.

    Parameters bind ``arm.x``, ``arm.y``, ``arm.z``, ``arm.yaw`` and ``arm.start`` (a group of
    one angle per joint) to move it per scenario.
    """

    model: str | None = Field(
        None,
        description="arm MJCF, relative to the spec's folder; hinge joints, a tool site and a velocity_limits numeric",
    )
    ee_site: str = Field("ee", description="the name of the arm's tool site")
    base: Vec3 = Field(ROBOT_BASE, description="where the arm file's origin stands (m)")
    yaw: Number = Field(0.0, description="rad, about world z")
    start: list[Number] | None = Field(None, description="joint angles at reset; default: the model's own")


class WorldSpec(Strict):
    """The MuJoCo world a task may simulate in: a scene model of its own and the robot arm.

    Bodies of ``model`` can be moved by parameters (``<body>.x``, ``.y``, ``.z``, ``.yaw``).
    Without a ``world`` section, a spec with a ``workspace`` gets the built-in arm, as the
    paper's domains do.
    """

    model: str | None = Field(None, description="scene MJCF, relative to the spec's folder")
    arm: ArmSpec | None = None


class ObjectSpec(Strict):
    """A placed object: a box, at a nominal position that parameters may move in x, y and z."""

    name: Name
    half_size: HalfSize
    position: Vec3


class ParameterSpec(Strict):
    """Binds ``size`` components of the scenario vector theta to one target.

    ``bind`` is ``human.<param>``, ``robot.<param>``, ``task.<param>`` (a field of that plugin's
    ``Params``), ``<object>.x|y|z``, ``arm.x|y|z|yaw|start`` or ``<body>.x|y|z|yaw`` for a named
    body of the world model; a group (``size > 1``) is passed to its target as an array.
    ``nominal`` is theta's value in the nominal scenario (``hritest check`` runs it); by default
    the spec's own value of what it binds, else the middle of the bounds.
    """

    name: Name
    bind: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_]*\.[A-Za-z][A-Za-z0-9_]*$")
    bounds: tuple[Number, Number]
    size: Count = 1
    nominal: Number | list[Number] | None = None
    description: str = ""

    # Each check names the parameter and its bounds: the message is read far from the line.
    @field_validator("bounds")
    @classmethod
    def _bounds_in_order(cls, bounds: tuple[float, float], info: ValidationInfo) -> tuple[float, float]:
        lo, hi = bounds
        if not lo < hi:
            raise ValueError(
                f"{_parameter(info)} has bounds [{lo}, {hi}]: the lower end must be below the upper end; "
                "write [low, high]"
            )
        return bounds

    @field_validator("size")
    @classmethod
    def _size_positive(cls, size: int, info: ValidationInfo) -> int:
        if size < 1:
            raise ValueError(
                f"{_parameter(info)}{_bounds(info)} has size {size}; it needs at least one component: "
                "set size to 1 or more, or remove the parameter"
            )
        return size

    @field_validator("nominal")
    @classmethod
    def _nominal_in_bounds(
        cls, nominal: float | list[float] | None, info: ValidationInfo
    ) -> float | list[float] | None:
        if nominal is None or "bounds" not in info.data or "size" not in info.data:
            return nominal
        values = [nominal] if isinstance(nominal, float | int) else nominal
        size = info.data["size"]
        if len(values) not in (1, size):
            raise ValueError(
                f"{_parameter(info)} has size {size}, but its nominal has {len(values)} values; "
                f"give one number or {size}"
            )
        lo, hi = info.data["bounds"]
        outside = [v for v in values if not lo <= v <= hi]
        if outside:
            raise ValueError(
                f"{_parameter(info)}: nominal {outside} lies outside the bounds [{lo}, {hi}]; move it inside or "
                "widen the bounds"
            )
        return nominal


def _parameter(info: ValidationInfo) -> str:
    name = info.data.get("name")
    return f"parameter {name!r}" if name is not None else "this parameter"


def _bounds(info: ValidationInfo) -> str:
    bounds = info.data.get("bounds")
    return f" (bounds [{bounds[0]}, {bounds[1]}])" if bounds is not None else ""


class InsideConstraint(Strict):
    """Each object's centre lies in at least one of the regions."""

    type: Literal["inside"]
    objects: list[str] = Field(min_length=1)
    regions: list[str] = Field(min_length=1)


class NoOverlapConstraint(Strict):
    """No two of the objects' axis-aligned footprints overlap."""

    type: Literal["no_overlap"]
    objects: list[str] = Field(min_length=2)


class MinSeparationConstraint(Strict):
    """Every pair of the objects' centres is at least ``distance`` apart."""

    type: Literal["min_separation"]
    objects: list[str] = Field(min_length=2)
    distance: PositiveFloat


class BoundsConstraint(Strict):
    """Theta stays within the parameters' bounds (repaired by clipping).

    ``groups`` lists parameter names whose out-of-bound excesses are summed before squaring,
    the teleoperation reference's repair cost; each unlisted parameter is its own group.
    """

    type: Literal["bounds"]
    groups: list[list[str]] = Field(default_factory=list)


Constraint = Annotated[
    InsideConstraint | NoOverlapConstraint | MinSeparationConstraint | BoundsConstraint,
    Field(discriminator="type"),
]


class RepairSpec(Strict):
    """How the repair measures what it moves: the cost it minimises, which the search subtracts."""

    units: Literal["normalised", "raw"] = Field(
        "normalised",
        description="normalised: each parameter's displacement as a fraction of its bounds' width, so that "
        "metres, seconds and radians add up alike; raw: in the parameters' own units, as the paper's reference "
        "(its specs say so)",
    )


class PolicySpec(Strict):
    """A robot or human policy: a registered name, ``module:Class`` or ``path/file.py:Class``."""

    policy: str
    params: Params = Field(default_factory=dict)


class ObjectiveSpec(Strict):
    """What the search maximises (higher = worse for the robot), and how repairs are penalised."""

    expr: NumericExpr
    range: Interval
    repair_weight: Number = Field(1.0, ge=0, description="search sees objective - weight * repair cost")


class MeasureSpec(Strict):
    """One axis of the archive: the failures found are spread along it."""

    name: Name
    expr: NumericExpr
    range: Interval
    cells: PositiveInt | None = Field(None, description="cells along this measure, for a grid archive")


class ArchiveSpec(Strict):
    """The archives' cells: a grid (each measure's ``cells``), or a centroidal Voronoi tessellation
    of ``cells`` cells over all measures, which three or more measures need (a grid's cells grow
    as a power of the number of measures)."""

    type: Literal["grid", "cvt"] = "grid"
    cells: Annotated[int, Field(gt=0, le=100_000, strict=True)] | None = Field(
        None, description="for a cvt archive: its number of cells (centroids)"
    )
    samples: Annotated[int, Field(gt=0, le=1_000_000, strict=True)] = Field(
        100_000, description="for a cvt archive: uniform samples k-means places the centroids with"
    )


class EmitterSettings(Strict):
    """CMA-ES emitters of CMA-MAE, SAS (CMA-MAE inner loop) and DSAS (CMA-MAEGA inner loop)."""

    emitters: Annotated[int, Field(gt=0, le=1_000, strict=True)] = 8
    batch_size: BatchSize = 37
    sigma0: PositiveFloat | None = Field(
        None, description="CMA-ES step in theta's units; default: a sixth of the bounds' typical width"
    )
    x0: list[Number] | None = Field(None, description="default: the centre of the bounds")
    learning_rate: Number = Field(0.1, gt=0, le=1, description="archive learning rate alpha")
    threshold_min: Number = 0.0
    gradient_lr: PositiveFloat = Field(1.0, description="DSAS gradient-ascent step")


class MapElitesSettings(Strict):
    batch_size: BatchSize = 20
    sigma: PositiveFloat | list[PositiveFloat] | None = Field(None, description="default: emitter.sigma0")
    x0: list[Number] | None = Field(None, description="where the first batch is sampled around; default: emitter.x0")


class RandomSettings(Strict):
    batch_size: BatchSize = 100


class SurrogateSettings(Strict):
    """Outer and inner loop of SAS / DSAS (paper Algorithm 1, appendix "Surrogate Model Details")."""

    initial_evaluations: PositiveInt = 100
    inner_iterations: PositiveInt = 10_000
    downsample_cells: list[PositiveInt] | None = Field(
        None,
        description="cells per measure of the selection archive (a cvt archive: one number, its cells); one "
        "elite per block is evaluated (see selection)",
    )
    selection: Literal["gain", "random"] = Field(
        "gain",
        description="which surrogate elite of a block is evaluated: gain, the one predicted to add the most to the "
        "result archive (its predicted objective over the elite already in the cell it predicts, or over the "
        "objective range's low end where that cell is empty); random, any one (the paper and its bundled specs)",
    )
    screen: bool = Field(
        True,
        description="simulate, of the proposals selected, those whose predicted objective gained, in the last "
        "rounds, more QD-score per second of simulation than the round as a whole, its surrogate work counted "
        "(proposals predicted low add nothing to an archive of high elites); false: simulate every one, as the "
        "paper and its bundled specs. Not with pipeline, whose surrogate work costs no wall time",
    )
    epochs: PositiveInt = 100
    batch_size: BatchSize = 64
    learning_rate: PositiveFloat = 1e-4
    training: Literal["paper", "incremental"] = Field(
        "incremental",
        description="incremental: the warm networks train on the new evaluations (at most a batch's worth, drawn "
        "at random; the others are replayed later) and as many replayed old ones (a flat cost per outer "
        "iteration); paper: each outer iteration trains `epochs` passes over every evaluation so far (its "
        "cost grows with the run: the bundled specs of the paper's experiments set it)",
    )
    inner_stall: PositiveInt | None = Field(
        50,
        description="stop an inner loop once its archive's QD-score has not grown by 1% in this many iterations "
        "(null: always run inner_iterations, as the paper and its bundled specs)",
    )
    pipeline: bool = Field(
        False,
        description="train and search the surrogate for the next batch while the current one simulates, on "
        "the evaluations told so far (one batch behind the paper's schedule), so that the workers never wait "
        "for it; for machines with cores or a GPU beyond the workers",
    )
    time_share: float = Field(
        0.2,
        gt=0,
        le=1,
        description="the most of the run's time the surrogate's training and inner loop may take: each outer "
        "iteration's are cut at time_share / (1 - time_share) times what simulating a batch takes (as large as the "
        "largest it proposed, at the last batch's seconds per scenario), so that "
        "the workers are not left idle for a surrogate that only refines its proposals (1: never cut, as the paper "
        "and its bundled specs)",
    )


class SearchSpec(Strict):
    algorithm: Literal["random", "map_elites", "cma_mae", "sas", "dsas", "auto"] = Field(
        "dsas",
        description="auto measures, during the run, which of random, map_elites, cma_mae and sas gains the most "
        "QD-score per second, and spends the time there",
    )
    budget: Annotated[int, Field(gt=0, le=1_000_000_000, strict=True)] = 10_000
    seed: Count = Field(
        0,
        description="0 to 2**63 - 1: numpy's SeedSequence takes no negative seed, and torch's generators "
        "take 64 bits, of which hritest leaves room for the offsets it adds",
    )
    emitter: EmitterSettings = Field(default_factory=EmitterSettings)
    map_elites: MapElitesSettings = Field(default_factory=MapElitesSettings)
    random: RandomSettings = Field(default_factory=RandomSettings)
    surrogate: SurrogateSettings = Field(default_factory=SurrogateSettings)

    @field_validator("seed")
    @classmethod
    def _seed_in_range(cls, seed: int) -> int:
        if not 0 <= seed <= MAX_SEED:
            got = "a negative number" if seed < 0 else "a larger one"
            raise ValueError(f"a seed is a whole number from 0 to 2**63 - 1 ({MAX_SEED}), got {got}")
        return seed


class Spec(Strict):
    """A whole hritest domain: what varies, what is simulated, what counts as a failure."""

    name: Name
    description: str = ""
    task: TaskSpec
    world: WorldSpec | None = None
    workspace: WorkspaceSpec | None = None
    objects: list[ObjectSpec] = Field(default_factory=list)
    parameters: list[ParameterSpec] = Field(min_length=1)
    constraints: list[Constraint] = Field(default_factory=list)
    repair: RepairSpec = Field(default_factory=RepairSpec)
    robot: PolicySpec
    human: PolicySpec
    objective: ObjectiveSpec
    measures: list[MeasureSpec] = Field(min_length=1)
    archive: ArchiveSpec = Field(default_factory=ArchiveSpec)
    failure: ConditionExpr
    search: SearchSpec = Field(default_factory=SearchSpec)

    # Where each value stands in the file (a hritest.spec.source.SourceMap), set by load_spec.
    _source: Any = PrivateAttr(default=None)
