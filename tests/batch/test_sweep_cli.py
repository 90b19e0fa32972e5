"""``evp sweep`` as a user meets it: a real grid over a tiny rendered dataset, resumed on rerun,
and a misspelt setting refused before any job runs."""

import csv

import pytest

from evp.sim.generate import generate
from evp.sim.scenarios import SimOptions
from tests.cli.conftest import evp


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tiny") / "circle"
    generate("circle-indoor", SimOptions(duration_s=0.6, fps=10.0, seed=1), folder, workers=1)
    return folder


def test_a_grid_runs_every_combination_into_one_table_and_a_rerun_resumes(tiny, tmp_path):
    out = tmp_path / "sweep"
    grid = ["--set", "estimator=klt-vo", "--set", "vo.max_features=300,400"]  # the light VO: seconds a job
    first = evp("sweep", tiny, *grid, "--workers", "2", "--out", out)
    assert first.returncode == 0, first.stderr
    with (out / "results.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [row["job"] for row in rows] == [f"circle.estimator=klt-vo,vo.max_features={n}" for n in (300, 400)]
    assert all(row["status"] == "ok" and row["frames"] == "7" for row in rows)
    assert "finished" in first.stderr and "slowest jobs" in first.stdout
    again = evp("sweep", tiny, *grid, "--out", out)
    assert again.returncode == 0 and "2 of 2 jobs already done" in again.stderr


def test_a_misspelt_setting_is_refused_with_the_closest_name(tiny, tmp_path):
    run = evp("sweep", tiny, "--set", "orb.n_feature=300", "--out", tmp_path / "x")
    assert run.returncode == 2 and "did you mean orb.n_features" in run.stderr
    assert not (tmp_path / "x" / "jobs").exists()
    missing = evp("sweep", tmp_path / "nowhere", "--out", tmp_path / "y")
    assert missing.returncode == 3 and "nowhere" in missing.stderr
