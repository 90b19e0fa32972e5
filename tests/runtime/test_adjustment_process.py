"""Live mapping's bundle adjustments run in a helper process: same answers as in the thread, and
mapping survives the helper's death."""

import logging
import os
import signal

import numpy as np
import pytest

from evp.runtime.adjustment_process import AdjustmentProcess
from evp.slam.adjustment import InlineAdjustment
from evp.slam.loop_closing import GraphCorrection, LoopClosure
from tests.optim.test_bundle_adjustment import shifted_six_views
from tests.slam.test_loop_geometry import drifting_circle_graph


@pytest.fixture
def problem():
    return shifted_six_views(4)


@pytest.fixture
def helper():
    adjuster = AdjustmentProcess()
    yield adjuster
    adjuster.close()


def test_helper_process_solves_as_the_thread_does(problem, helper):
    bundle, truth = problem
    remote = helper.solve(bundle, 20)
    local = InlineAdjustment().solve(bundle, 20)
    for a, b in zip(remote, local, strict=True):
        assert np.array_equal(a, b)
    assert np.abs(remote[0] - truth).max() < 1e-6
    # a global adjustment (not interruptible) takes the same path
    assert np.array_equal(helper.solve(bundle, 20, interruptible=False)[0], local[0])


def test_a_loops_pose_graph_is_solved_in_the_helper_as_in_the_thread(helper):
    _, initial, fixed, edge_i, edge_j, measured = drifting_circle_graph()
    graph = GraphCorrection(LoopClosure(19, 0, 0.0, 100, 1.0), list(range(len(initial))), initial, fixed, edge_i, edge_j, measured)
    remote, local = helper.solve_graph(graph), InlineAdjustment().solve_graph(graph)
    for name in ("s", "R", "t"):
        assert np.array_equal(getattr(remote, name), getattr(local, name))
    assert not np.allclose(remote.t, initial.t)  # the graph moved the poses


def test_mapping_goes_on_in_the_thread_when_the_helper_dies(problem, helper, caplog):
    bundle, truth = problem
    for pid in list(helper._pool._processes):
        os.kill(pid, signal.SIGKILL)
    with caplog.at_level(logging.WARNING, logger="evp.runtime.adjustment_process"):
        poses, _, _ = helper.solve(bundle, 20)
    assert np.abs(poses - truth).max() < 1e-6
    assert "helper process died" in caplog.text
    assert np.abs(helper.solve(bundle, 20)[0] - truth).max() < 1e-6  # and from then on


def _adjust_inside_a_daemon(results) -> None:
    problem, truth = shifted_six_views(5)
    adjuster = AdjustmentProcess()
    poses, _, _ = adjuster.solve(problem, 20)
    results.put((adjuster._pool is None, float(np.abs(poses - truth).max())))


def test_without_a_helper_in_a_daemonic_process_mapping_adjusts_in_its_thread():
    """The base station runs each estimator in a daemonic process, which may not start children."""
    import multiprocessing

    context = multiprocessing.get_context("spawn")
    results = context.Queue()
    process = context.Process(target=_adjust_inside_a_daemon, args=(results,), daemon=True)
    process.start()
    no_helper, error = results.get(timeout=120)
    process.join(timeout=60)
    assert no_helper and error < 1e-6
