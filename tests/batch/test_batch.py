"""The batch engine: jobs on local processes and on a real local Dask cluster, failures reported
per job, reruns skipping finished jobs, the sweep grid and its progress lines."""

import json

import pytest

from evp.batch.executors import LocalProcesses, make_executor
from evp.batch.jobs import Job, Progress, parse_set, settings_grid
from evp.batch.runner import run_batch, summary_markdown
from evp.batch.sweep import sweep_jobs
from evp.config import Settings, with_overrides
from evp.errors import ConfigError, LinkError, UsageError

TOY = "tests.batch.toy_tasks"


def _jobs(tmp_path):
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "frames.bin").write_bytes(b"\x00garbage")
    return [
        *(Job(f"square{x}", f"{TOY}:square", {"x": x}) for x in range(3)),
        Job("fails", f"{TOY}:fail", {"message": "bad settings"}),
        *sweep_jobs([tmp_path / "missing", corrupt], []),
    ]


def test_local_batch_reports_each_failure_and_a_rerun_skips_the_finished_jobs(tmp_path):
    out = tmp_path / "out"
    jobs = [*_jobs(tmp_path), Job("dies", f"{TOY}:die", {})]
    lines = []
    result = run_batch(jobs, out, LocalProcesses(2), lines.append)
    outcomes = result.outcomes
    assert [outcomes[f"square{x}"].record["square"] for x in range(3)] == [0, 1, 4]
    assert "ValueError: bad settings" in outcomes["fails"].error
    assert "missing" in outcomes["missing.defaults"].error and not outcomes["missing.defaults"].ok
    assert not outcomes["corrupt.defaults"].ok and outcomes["corrupt.defaults"].error
    assert "worker process died (exit code 3)" in outcomes["dies"].error
    rows = json.loads((out / "results.json").read_text())
    assert [row["status"] for row in rows] == ["ok"] * 3 + ["failed"] * 4
    assert (out / "jobs" / "square2.json").is_file() and "slowest jobs" in (out / "batch.md").read_text()
    assert any("FAILED" in line for line in lines) and any("finished" in line for line in lines)

    again = run_batch(jobs, out, LocalProcesses(2))
    assert [again.outcomes[f"square{x}"].reused for x in range(3)] == [True] * 3
    assert not again.outcomes["fails"].reused  # failed jobs run again
    assert "3 ok (3 reused" in summary_markdown(again)


def test_a_changed_job_is_not_read_back(tmp_path):
    run_batch([Job("a", f"{TOY}:square", {"x": 2})], tmp_path, LocalProcesses(1))
    result = run_batch([Job("a", f"{TOY}:square", {"x": 3})], tmp_path, LocalProcesses(1))
    assert not result.outcomes["a"].reused and result.outcomes["a"].record["square"] == 9


def test_a_sweep_on_a_local_dask_cluster_survives_a_dying_worker(tmp_path):
    dask = pytest.importorskip("dask")
    distributed = pytest.importorskip("distributed")
    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            executor = make_executor(None, cluster.scheduler_address)
            assert executor.capacity == 2
            jobs = [*_jobs(tmp_path), Job("dies", f"{TOY}:die", {}), Job("after", f"{TOY}:square", {"x": 7, "sleep_s": 0.2})]
            result = run_batch(jobs, tmp_path / "out", executor)
    outcomes = result.outcomes
    assert [outcomes[f"square{x}"].record["square"] for x in range(3)] == [0, 1, 4]
    assert outcomes["after"].record["square"] == 49
    assert "worker died" in outcomes["dies"].error
    assert "ValueError: bad settings" in outcomes["fails"].error
    assert not outcomes["missing.defaults"].ok and not outcomes["corrupt.defaults"].ok
    assert "Dask scheduler" in result.executor


def test_an_unreachable_scheduler_is_a_link_error():
    pytest.importorskip("distributed")
    from evp.batch.executors import DaskCluster

    with pytest.raises(LinkError, match="could not reach the Dask scheduler at tcp://127.0.0.1:9"):
        DaskCluster("tcp://127.0.0.1:9", connect_timeout_s=1.0)


def test_the_grid_expands_every_combination_with_typed_values(tmp_path):
    assert parse_set("orb.n_features=500,1000") == ("orb.n_features", [500, 1000])
    assert parse_set("align.ransac_thresholds_m=[1, 2]") == ("align.ransac_thresholds_m", [[1, 2]])
    grid = settings_grid(["orb.n_features=500,1000", "slam.loop_closing=true,false"])
    assert len(grid) == 4 and {"orb.n_features": 1000, "slam.loop_closing": False} in grid
    keys = [job.key for job in sweep_jobs([tmp_path / "a" / "mav0", tmp_path / "b" / "mav0"], ["orb.n_features=500,1000"])]
    assert keys == ["a-mav0.orb.n_features=500", "a-mav0.orb.n_features=1000", "b-mav0.orb.n_features=500", "b-mav0.orb.n_features=1000"]
    for bad in ("orb.n_features", "=1", "orb.n_features="):
        with pytest.raises(UsageError, match="section.field=value"):
            parse_set(bad)
    with pytest.raises(UsageError, match="twice"):
        settings_grid(["orb.n_features=1", "orb.n_features=2"])


def test_overrides_are_validated_with_a_suggestion():
    assert with_overrides(Settings(), {"orb.n_features": 500}).orb.n_features == 500
    with pytest.raises(ConfigError, match="did you mean orb.n_features"):
        with_overrides(Settings(), {"orb.n_feature": 500})
    with pytest.raises(ConfigError, match="orb.n_features"):
        with_overrides(Settings(), {"orb.n_features": 10})


def test_the_progress_line_counts_and_estimates_the_time_left():
    progress = Progress(total=10, done=3, failed=1, running=2, elapsed_s=65.0, mean_job_s=20.0, workers=2, running_elapsed_s=15.0)
    assert progress.waiting == 4
    assert progress.time_left_s() == pytest.approx((20.0 * (4 + 2) - 15.0) / 2)
    assert progress.line() == "4/10 finished (3 ok, 1 failed), 2 running, 4 waiting, 1m05s elapsed, ~52s left"
    overdue = Progress(total=2, done=1, failed=0, running=1, elapsed_s=90.0, mean_job_s=20.0, workers=1, running_elapsed_s=70.0)
    assert overdue.time_left_s() == 0.0
    assert "time left unknown" in Progress(3, 0, 0, 2, 1.0, None, 2).line()


def test_workers_and_cluster_exclude_each_other():
    with pytest.raises(UsageError, match="not both"):
        make_executor(2, "tcp://127.0.0.1:8786")
