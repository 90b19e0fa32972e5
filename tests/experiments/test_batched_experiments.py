"""Batched experiments: report.md and results.json written whatever the figures, a failed job
listed with its error, the names listed one a line."""

import json

from evp.batch.executors import LocalProcesses
from evp.experiments import EXPERIMENTS
from evp.experiments.batched import run_experiment
from tests.batch import toy_experiment
from tests.cli.conftest import evp


def test_a_batched_experiment_writes_its_report_and_results_with_the_failures(tmp_path):
    report = run_experiment(toy_experiment, "v", tmp_path, LocalProcesses(2), quick=True, command="evp experiment toy --quick", progress=lambda line: None)
    text = report.read_text()
    assert "# Toy" in text and "square: 9" in text and "`evp experiment toy --quick`" in text and "ValueError: no data" in text
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["rows"] == [{"row": "square", "ours": {"value": 9}, "paper": {"value": 10}, "ahead": True}]
    assert "no data" in results["failed_jobs"]["broken"] and results["quick"] is True


def test_the_list_is_one_name_a_line_and_a_missing_dataset_still_gives_a_report(tmp_path):
    listed = evp("experiment", "list")
    assert listed.returncode == 0 and listed.stdout.split() == list(EXPERIMENTS)
    assert {"seed000-indoor-circle", "seed002-tables2-5", "seed002-spoofing", "seed002-toledo"} <= set(EXPERIMENTS)
    run = evp("experiment", "seed002-toledo", "--quick", "--out", str(tmp_path), cwd=tmp_path)  # no ../shared/data from there
    assert run.returncode == 0, run.stderr
    assert "The job failed" in (tmp_path / "report.md").read_text()
    assert json.loads((tmp_path / "results.json").read_text())["failed_jobs"]["toledo"]
