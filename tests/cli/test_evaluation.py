"""evp eval and evp convert."""

import json

import numpy as np
import yaml

from evp.cli.evaluation import evaluate_files
from evp.config import EvalSettings
from evp.errors import ExitCode
from evp.eval.report import markdown_summary
from evp.io.trajectory import read_trajectory, write_trajectory
from evp.types import Trajectory
from tests.cli.conftest import evp
from tests.conftest import SAMPLE


def test_eval_contract_json_and_report(tmp_path):
    gt = SAMPLE / "groundtruth.txt"
    truth = read_trajectory(gt)
    # a slightly noisy, scaled, shifted copy
    rng = np.random.default_rng(0)
    est = Trajectory(2.0 * truth.positions + [1, 2, 3] + rng.normal(0, 0.002, truth.positions.shape), truth.quats_xyzw, truth.timestamps)
    write_trajectory(tmp_path / "est.tum", est)
    result = evp("eval", gt, tmp_path / "est.tum", "--align", "sim3", "--json", tmp_path / "m.json", "--report", tmp_path / "report")
    assert result.returncode == 0, result.stderr
    metrics = json.loads((tmp_path / "m.json").read_text())
    for key in ("rmse", "mean", "median", "std", "min", "max", "q1", "q3", "iqr", "matched_poses"):
        assert key in metrics
    assert metrics["matched_poses"] == len(truth)
    assert metrics["rmse"] < 0.005
    assert metrics["options"]["align"] == "sim3"
    # the report's settings.yaml holds the evaluation settings that ran, the tolerance included
    written = yaml.safe_load((tmp_path / "report" / "settings.yaml").read_text())["eval"]
    assert EvalSettings(**written) == EvalSettings(align="sim3", max_time_diff_s=0.01)
    plots = ("top_view.png", "ape_over_time.png", "ape_histogram.png", "ape_boxplot.png")
    for name in plots:
        assert (tmp_path / "report" / name).stat().st_size > 1000
    # the summary's length moves with number formatting: check what it says, not its size
    report = (tmp_path / "report" / "report.md").read_text()
    assert f"matched poses: {len(truth)}" in report and "alignment: sim3" in report
    for statistic in ("rmse", "median", "iqr"):
        assert f"| {statistic} |" in report
    for name in plots:
        assert f"]({name})" in report
    none = json.loads((evp("eval", gt, tmp_path / "est.tum", "--align", "none", "--json", tmp_path / "n.json"), (tmp_path / "n.json").read_text())[1])
    assert none["rmse"] > 1.0
    bad = evp("eval", gt, tmp_path / "est.tum", "--align", "affine")
    assert bad.returncode == ExitCode.USAGE and "align" in bad.stderr
    too_few = evp("eval", gt, tmp_path / "est.tum", "--n-align", "2")
    assert too_few.returncode == ExitCode.USAGE and "n_align" in too_few.stderr


def test_eval_n_align_and_kitti_times(tmp_path):
    (tmp_path / "gt.txt").write_text("".join(f"1 0 0 {i} 0 1 0 {0.1 * i * i} 0 0 1 0\n" for i in range(10)))
    (tmp_path / "est.txt").write_text("".join(f"1 0 0 {i * 1.1} 0 1 0 {0.1 * i * i} 0 0 1 0\n" for i in range(10)))
    (tmp_path / "times.txt").write_text("".join(f"{i * 0.1}\n" for i in range(10)))
    result = evp("eval", tmp_path / "gt.txt", tmp_path / "est.txt", "--align", "se3", "--n-align", "3", "--json", tmp_path / "m.json")
    assert result.returncode == 0, result.stderr
    assert json.loads((tmp_path / "m.json").read_text())["max"] > 0.5
    assert "matched poses 10 by frame number (no times" in result.stdout  # frame numbers, not seconds
    result = evaluate_files(tmp_path / "gt.txt", tmp_path / "est.txt", EvalSettings(max_time_diff_s=0.01))
    assert result.frame_indexed and "by frame number" in markdown_summary(result, "gt", "est")
    assert not evaluate_files(
        tmp_path / "gt.txt", tmp_path / "est.txt", EvalSettings(max_time_diff_s=0.01), tmp_path / "times.txt", tmp_path / "times.txt"
    ).frame_indexed
    tum = evp("convert", tmp_path / "gt.txt", tmp_path / "gt.tum", "--to", "tum", "--times", tmp_path / "times.txt")
    assert tum.returncode == 0, tum.stderr
    mixed = evp("eval", tmp_path / "gt.tum", tmp_path / "est.txt")
    assert mixed.returncode == ExitCode.DATA and "--est-times" in mixed.stderr
    ok = evp("eval", tmp_path / "gt.tum", tmp_path / "est.txt", "--est-times", tmp_path / "times.txt", "--align", "sim3")
    assert ok.returncode == 0, ok.stderr


def test_convert_errors(tmp_path):
    (tmp_path / "gt.txt").write_text("".join(f"1 0 0 {i} 0 1 0 0 0 0 1 0\n" for i in range(5)))
    (tmp_path / "times.txt").write_text("0.0\n0.1\n")
    short = evp("convert", tmp_path / "gt.txt", tmp_path / "gt.tum", "--times", tmp_path / "times.txt")
    assert short.returncode == ExitCode.DATA and "2 times for the 5 poses" in short.stderr
    no_stamps = evp("convert", tmp_path / "gt.txt", tmp_path / "gt.tum")
    assert no_stamps.returncode == ExitCode.USAGE and "--times" in no_stamps.stderr
    bad_format = evp("convert", tmp_path / "gt.txt", tmp_path / "gt.x", "--to", "x")
    assert bad_format.returncode == ExitCode.USAGE and "--to" in bad_format.stderr
