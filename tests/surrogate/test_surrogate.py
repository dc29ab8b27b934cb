"""The surrogate networks, their training, the batched Jacobian, and tiny SAS / DSAS runs."""

from __future__ import annotations

import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from hritest import search as qd
from hritest.domain import compile_spec
from hritest.evaluate import evaluate
from hritest.rundir import RunDirectory
from hritest.search import archives
from hritest.search.inner import SurrogateObjective, downsample, exploit
from hritest.search.state import load_state
from hritest.spec import load_spec
from hritest.surrogate.model import Surrogate
from hritest.surrogate.networks import OccupancyNet, PredictNet

SPECS = Path(__file__).parents[2] / "specs"
CPU = torch.device("cpu")


def surrogate_for(domain, *, epochs=5, seed=0) -> Surrogate:
    return Surrogate(
        bounds=(domain.space.lower, domain.space.upper),
        channels=len(domain.grids),
        outputs=1 + len(domain.measures),
        epochs=epochs,
        batch_size=16,
        learning_rate=1e-3,
        device=CPU,
        seed=seed,
    )


@pytest.mark.parametrize(
    ("spec", "inputs", "channels", "outputs"),
    [("teleop", 9, 1, 3), ("collab", 6, 2, 3), ("collab_human", 8, 2, 3), ("collab_wait", 6, 2, 3)],
)
def test_shapes_follow_the_spec(spec, inputs, channels, outputs):
    domain = compile_spec(load_spec(SPECS / f"{spec}.yaml"))
    assert (domain.space.dim, len(domain.grids), 1 + len(domain.measures)) == (inputs, channels, outputs)
    occupancy = OccupancyNet(inputs=inputs, channels=channels).eval()
    predictor = PredictNet(inputs=inputs, channels=channels, outputs=outputs).eval()
    grids = occupancy(torch.randn(5, inputs))
    assert grids.shape == (5, channels, 32, 32)
    torch.testing.assert_close(grids.exp().sum(dim=(2, 3)), torch.ones(5, channels))
    assert predictor(torch.randn(5, inputs), grids).shape == (5, outputs)


@pytest.fixture(scope="module")
def teleop_data():
    """A small real dataset: simulated teleoperation scenarios with their occupancy grids."""
    domain = compile_spec(load_spec(SPECS / "teleop.yaml"))
    rng = np.random.default_rng(0)
    theta = rng.uniform(domain.space.lower, domain.space.upper, size=(48, domain.space.dim))
    evaluations = [evaluate(domain, t, seed=i) for i, t in enumerate(theta)]
    assert all(e.ok for e in evaluations)
    grids = np.stack([e.occupancy for e in evaluations]).astype(np.float32)
    targets = np.array([[e.search_objective / 10, *e.measures] for e in evaluations], dtype=np.float32)
    return domain, theta.astype(np.float32), grids, targets


def test_training_lowers_the_loss_on_real_data(teleop_data):
    domain, theta, grids, targets = teleop_data
    model = surrogate_for(domain, epochs=1)
    first = model.fit(theta, grids, targets)
    for _ in range(20):
        last = model.fit(theta, grids, targets)
    assert last.occupancy_loss < first.occupancy_loss
    assert last.predictor_loss < first.predictor_loss
    assert np.isfinite(model.predict(theta)).all()


def theta_only_data(n: int = 96) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """Bounds, theta and targets that are a smooth function of theta alone: what a task without
    occupancy grids gives the surrogate."""
    rng = np.random.default_rng(1)
    lower, upper = np.array([-1.0, -1.0, 0.0, 0.5]), np.array([1.0, 1.0, 0.2, 1.5])
    theta = rng.uniform(lower, upper, size=(n, 4)).astype(np.float32)
    x0, x1, x2, x3 = theta.T
    targets = np.stack([np.sin(2 * x0) + x1**2, 5 * x2 * x3, x0 - x3], axis=1).astype(np.float32)
    return (lower, upper), theta, targets


def theta_only_surrogate(bounds, *, epochs: int) -> Surrogate:
    return Surrogate(
        bounds=bounds, channels=0, outputs=3, epochs=epochs, batch_size=16, learning_rate=1e-3, device=CPU, seed=0
    )


def test_without_grids_the_predictor_alone_learns_the_targets_from_theta():
    bounds, theta, targets = theta_only_data()
    model = theta_only_surrogate(bounds, epochs=1)
    assert model.occupancy is None and model.predictor.grid is None
    first = model.fit(theta, None, targets)
    for _ in range(30):
        last = model.fit(theta, None, targets)
    assert math.isnan(first.occupancy_loss) and math.isnan(last.occupancy_loss)  # no such loss
    assert last.predictor_loss < 0.5 * first.predictor_loss
    error = np.abs(model.predict(theta) - targets).mean(axis=0)
    assert np.all(error < 0.5 * targets.std(axis=0))  # well better than predicting the mean


def test_without_grids_the_run_directorys_empty_grids_are_the_same_as_none():
    bounds, theta, targets = theta_only_data(40)
    given_none, given_empty = theta_only_surrogate(bounds, epochs=2), theta_only_surrogate(bounds, epochs=2)
    given_none.fit(theta, None, targets)
    given_empty.fit(theta, np.zeros((len(theta), 0, 32, 32), np.float32), targets)  # as Search.dataset gives
    np.testing.assert_array_equal(given_none.predict(theta), given_empty.predict(theta))


def test_the_batched_jacobian_equals_autograd_on_single_inputs(teleop_data):
    domain, theta, grids, targets = teleop_data
    model = surrogate_for(domain, epochs=2)
    model.fit(theta, grids, targets)
    objective = SurrogateObjective(domain, model)
    points = theta[:4].astype(np.float64) + 0.03  # some outside the bounds, so the penalty matters too
    obj, measures, jacobian = objective.with_jacobian(points)
    assert jacobian.shape == (4, 3, 9)
    for i, point in enumerate(points):
        x = torch.tensor(point[None], dtype=torch.float32)
        single = torch.autograd.functional.jacobian(lambda v: eager_outputs(model, objective, v)[0], x)[:, 0, :]
        np.testing.assert_allclose(jacobian[i], single.numpy(), rtol=1e-4, atol=1e-5)
    plain_obj, plain_measures = objective(points)
    np.testing.assert_allclose(obj, plain_obj, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(measures, plain_measures, rtol=1e-5, atol=1e-6)


def eager_outputs(model, objective, x):
    """The inner objective computed on the trained networks themselves, not on their refolded form."""
    predicted = model(x)
    return torch.cat([predicted[:, :1] - objective.penalty(x)[:, None], predicted[:, 1:]], dim=1)


def test_the_penalty_pulls_the_inner_objective_down_outside_the_bounds(teleop_data):
    domain, theta, _, _ = teleop_data
    objective = SurrogateObjective(domain, surrogate_for(domain))
    inside = theta[:1].astype(np.float64)
    outside = inside.copy()
    outside[0, 0] = domain.space.upper[0] + 0.5  # g0x half a metre past its bound
    assert objective.penalty(torch.tensor(inside, dtype=torch.float32)).item() == 0
    assert objective.penalty(torch.tensor(outside, dtype=torch.float32)).item() == pytest.approx(0.25, rel=1e-3)


@pytest.mark.parametrize("gradients", [False, True])
def test_the_inner_loop_fills_an_archive_and_downsampling_takes_one_per_block(teleop_data, gradients):
    domain, theta, grids, targets = teleop_data
    model = surrogate_for(domain)
    model.fit(theta, grids, targets)
    archive = exploit(domain, SurrogateObjective(domain, model), gradients=gradients, iterations=10, seed=1)
    assert archive.stats.num_elites > 0
    chosen = downsample(domain, archive, rng=np.random.default_rng(0))
    assert 0 < len(chosen) <= min(archive.stats.num_elites, 5 * 20)
    cells = {
        tuple(np.minimum(np.floor((m - np.array([0, 0])) / np.array([0.32 / 5, 0.112 / 20])), [4, 19]))
        for m in objective_measures(domain, model, chosen)
    }
    assert len(cells) == len(chosen)  # no two from the same block


def test_selection_by_gain_takes_the_surrogate_elite_that_would_add_the_most_to_the_result_archive():
    domain = compile_spec(load_spec(SPECS / "teleop.yaml"))  # objective 0-10; blocks 5 x 20 of 25 x 100 cells
    filled, empty = [0.01, 0.001], [0.05, 0.004]  # two cells of one block
    surrogate = archives.search_archive(domain, seed=0)  # objective normalised by the span, as the surrogate's
    solutions = np.array([np.full(domain.space.dim, 1.0), np.full(domain.space.dim, 2.0)])
    surrogate.add(solutions, np.array([0.9, 0.5]), np.array([filled, empty]))
    result = archives.result_archive(domain, seed=0)

    def pick(seed, *, incumbents):
        return downsample(domain, surrogate, rng=np.random.default_rng(seed), incumbents=incumbents)[0, 0]

    def incumbents(measures):
        return archives.elite_objectives(result, measures, empty=0.0)

    # Over an empty result archive, the higher prediction gains the most (9 against 5)...
    assert {pick(seed, incumbents=incumbents) for seed in range(8)} == {1.0}
    # ...but not over an incumbent of 8.5 in its cell (a gain of 0.5): the empty cell's 5 is taken.
    result.add(np.zeros((1, domain.space.dim)), np.array([8.5]), np.array([filled]), evaluation=np.array([0]))
    assert {pick(seed, incumbents=incumbents) for seed in range(8)} == {2.0}
    # The paper's selection takes either.
    assert {pick(seed, incumbents=None) for seed in range(8)} == {1.0, 2.0}


def objective_measures(domain, model, solutions):
    return SurrogateObjective(domain, model)(solutions)[1]


def tiny_run(tmp_path: Path, out: str, algorithm: str, *, workers: int = 2) -> qd.Search:
    """A 60-evaluation run of the teleoperation spec with a tiny surrogate protocol."""
    text = (
        (SPECS / "teleop.yaml")
        .read_text()
        .replace(
            "surrogate: {initial_evaluations: 100, inner_iterations: 10000, downsample_cells: [5, 20],",
            "surrogate: {initial_evaluations: 30, inner_iterations: 20, downsample_cells: [3, 5], epochs: 5,",
        )
    )
    spec = tmp_path / "teleop.yaml"
    spec.write_text(text)
    return qd.start(
        spec_file=spec,
        out=tmp_path / out,
        algorithm=algorithm,
        budget=60,
        seed=0,
        backend=qd.Backend(workers=workers, timeout=60),
        surrogate=qd.SurrogateOptions(device="cpu"),
    )


@pytest.mark.parametrize("algorithm", ["sas", "dsas"])
def test_a_tiny_run_completes_and_resumes(tmp_path, algorithm):
    found = tiny_run(tmp_path, "run", algorithm)
    records = RunDirectory.open(tmp_path / "run").evaluations()
    assert sorted(r.index for r in records) == list(range(60))
    assert found.state.proposer.outer >= 2
    accuracy = found.state.proposer.accuracy(found.domain)
    assert accuracy["held_out"] > 0 and np.isfinite(accuracy["objective_mae"])
    assert (tmp_path / "run" / "surrogate.json").is_file()
    assert json.loads((tmp_path / "run" / "run.json").read_text())["inner_iterations"] == 20  # the spec's

    # Resume after the run "was killed" right after asking a batch: rewind to an earlier checkpoint.
    run = RunDirectory.open(tmp_path / "run")
    run.save_checkpoint(replace(load_state(run), budget=80))
    again = qd.resume(run_path=tmp_path / "run", backend=qd.Backend(workers=2, timeout=60))
    assert again.state.evaluations == 80
    assert sorted(r.index for r in RunDirectory.open(tmp_path / "run").evaluations()) == list(range(80))


def test_outside_the_bounds_the_prediction_is_that_of_the_clipped_theta(teleop_data):
    domain, theta, grids, targets = teleop_data
    model = surrogate_for(domain, epochs=2)
    model.fit(theta, grids, targets)
    outside = theta[:3].astype(np.float64).copy()
    outside[:, 0] += 1.0  # g0x a metre past its upper bound
    outside[:, 5] -= 0.2  # a waypoint offset past its lower bound
    clipped = np.clip(outside, domain.space.lower, domain.space.upper)
    np.testing.assert_allclose(model.predict(outside), model.predict(clipped), rtol=1e-6)
    assert not np.allclose(model.predict(outside), model.predict(theta[:3]))


def test_targets_are_learned_standardised_and_predicted_in_their_own_units(teleop_data):
    domain, theta, grids, targets = teleop_data
    model = surrogate_for(domain, epochs=30)
    model.fit(theta, grids, targets)
    torch.testing.assert_close(model.target_mean, torch.tensor(targets.mean(axis=0)))
    predicted = model.predict(theta)
    # In the targets' units: each output's mean near the data's own, not near the standardised zero.
    assert np.all(np.abs(predicted.mean(axis=0) - targets.mean(axis=0)) < 0.5 * targets.std(axis=0))


def test_the_same_seed_gives_the_same_surrogate_run(tmp_path):
    """On one machine: the README's reproducibility holds for SAS too (training, inner loop and all)."""
    tiny_run(tmp_path, "a", "sas", workers=2)
    tiny_run(tmp_path, "b", "sas", workers=1)
    assert (tmp_path / "a" / "archive.csv").read_text() == (tmp_path / "b" / "archive.csv").read_text()
    thetas = [[r.theta for r in RunDirectory.open(tmp_path / run).evaluations()] for run in ("a", "b")]
    assert sorted(thetas[0]) == sorted(thetas[1])  # the same proposals, finished in any order


def test_a_fit_on_some_rows_trains_on_those_and_standardises_over_all(teleop_data):
    domain, theta, grids, targets = teleop_data
    model = surrogate_for(domain, epochs=2)
    fit = model.fit(theta, grids, targets, rows=np.arange(32, 48))
    assert fit.samples == 16
    torch.testing.assert_close(model.target_mean, torch.as_tensor(targets).mean(dim=0))


def optimizer_steps(optimizer: torch.optim.Optimizer) -> int:
    return int(max(state["step"] for state in optimizer.state.values()))


def test_a_fit_past_its_deadline_stops_after_one_batch_even_mid_epoch(teleop_data):
    domain, theta, grids, targets = teleop_data
    whole, late = surrogate_for(domain, epochs=3), surrogate_for(domain, epochs=3)
    whole.fit(theta, grids, targets)
    late.fit(theta, grids, targets, deadline=time.monotonic())
    # 48 samples in batches of 16: three steps an epoch, nine in all; past the deadline, one.
    assert optimizer_steps(whole.occupancy_optimizer) == optimizer_steps(whole.predictor_optimizer) == 9
    assert optimizer_steps(late.occupancy_optimizer) == optimizer_steps(late.predictor_optimizer) == 1


def test_an_inner_loop_stops_once_its_archive_stops_growing(teleop_data):
    domain, theta, grids, targets = teleop_data
    model = surrogate_for(domain)
    model.fit(theta, grids, targets)
    full, early = SurrogateObjective(domain, model), SurrogateObjective(domain, model)
    exploit(domain, full, gradients=False, iterations=300, seed=1)
    archive = exploit(domain, early, gradients=False, iterations=300, seed=1, stall=5)
    assert full.calls == 300
    assert 5 <= early.calls < 300 and archive.stats.num_elites > 0


def test_incremental_training_sees_the_new_samples_and_as_many_old_ones(tmp_path):
    text = (SPECS / "teleop.yaml").read_text()
    old = "surrogate: {initial_evaluations: 100, inner_iterations: 10000, downsample_cells: [5, 20],"
    new = "surrogate: {initial_evaluations: 30, inner_iterations: 20, downsample_cells: [3, 5], epochs: 5,"
    paper = "training: paper, inner_stall: null, time_share: 1,"
    assert paper in text
    text = text.replace(paper, "training: incremental, inner_stall: 5,")
    assert old in text
    (tmp_path / "teleop.yaml").write_text(text.replace(old, new))
    found = qd.start(
        spec_file=tmp_path / "teleop.yaml",
        out=tmp_path / "run",
        algorithm="sas",
        budget=70,
        seed=0,
        backend=qd.Backend(workers=2, timeout=60),
        surrogate=qd.SurrogateOptions(device="cpu"),
    )
    proposer = found.state.proposer
    assert len(proposer.fits) >= 2 and proposer.fits[0]["samples"] == 30  # the first round: every sample
    # Later rounds: the samples new since the last round, and as many old ones (at least a batch,
    # and at most every old one: how many the last round had depends on the batches' sizes, which
    # follow the surrogate's archive, so this does not fix it).
    trained, batch, largest = proposer.trained, proposer.surrogate.batch_size, proposer.largest
    assert trained >= 30
    for new in (10, largest):
        rows = proposer._rows(trained + new)
        assert len(rows) == new + min(trained, max(new, batch)) and len(set(rows.tolist())) == len(rows)
        assert set(range(trained, trained + new)) <= set(rows.tolist())
    # More new samples than its largest batch (others simulated them: auto's model-free arms):
    # as many as that batch, drawn from all of them; the rest are old for later rounds to replay.
    rows = proposer._rows(trained + 10 * largest)
    drawn = rows[rows >= trained]
    assert len(drawn) == largest and len(rows) == largest + min(trained, max(largest, batch))
    assert len(set(rows.tolist())) == len(rows) and drawn.max() >= trained + 5 * largest
    proposer.trained = 0
    assert proposer._rows(largest) is None and len(proposer._rows(3 * largest)) == largest
