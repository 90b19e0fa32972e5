"""``evp experiment``: the registry, seed 001's convergence study's headline cases, and seed
002's scoring of the fused track."""

from __future__ import annotations

import numpy as np
import pytest

from evp.experiments.seed001_convergence import CASES, run_case
from tests.cli.conftest import evp
from tests.conftest import shared


def test_experiments_are_listed_and_an_unknown_one_is_a_usage_error():
    listed = evp("experiment", "list")
    assert listed.returncode == 0 and "seed001-convergence" in listed.stdout
    unknown = evp("experiment", "seed001-convergance", "--out", "/nonexistent")
    assert unknown.returncode == 2 and "seed001-convergence" in unknown.stderr


def test_a_wrong_robot_start_converges_under_3_cm_and_true_states_stay_there():
    """Seed 001's Figures 9 and 10: 40 cm of start error is gone (< 3 cm) once the surveyed
    features are seen; true initial states never leave 3 cm."""
    wrong_start = run_case("robot start off", *CASES["robot start off (Fig. 10)"])
    assert wrong_start.position_error[-1] < 0.03 and wrong_start.position_error[wrong_start.times > 5.0].max() < 0.03
    true_start = run_case("true", *CASES["true initial states (Fig. 9)"])
    assert true_start.position_error.max() < 0.03


def test_the_accelerometer_drifts_far_beyond_the_wheels():
    """Seed 001's Figure 3 on the simulated robot: double integration ends metres off, the wheels
    within decimetres."""
    from evp.experiments.seed001_dead_reckoning import METHODS, _errors, paths_for_seed

    truth, paths = paths_for_seed(1)
    end = {name: _errors(truth, *paths[name])[-1] for name in METHODS}
    assert end[METHODS[0]] > 10.0 and end[METHODS[1]] < 0.5 and end[METHODS[2]] < 0.5


def test_on_the_real_car_the_wheels_and_gyro_drift_least():
    """comma2k19's 60 s, 1 km: the accelerometer integrated twice ends tens of metres off, the CAN
    wheels with the gyro least, the wheels' own turn rate (the rear wheels' difference over an
    assumed 1.6 m track) worst."""
    from evp.experiments.seed001_dead_reckoning import COMMA_FOLDER, METHODS, _errors, comma_paths

    truth, paths = comma_paths(shared(COMMA_FOLDER))
    end = {name: _errors(truth, *paths[name])[-1] for name in METHODS}
    assert end[METHODS[0]] > 30.0 and end[METHODS[1]] < 0.5 * end[METHODS[0]] and end[METHODS[2]] > end[METHODS[1]]
    assert all(times[-1] - times[0] > 59.0 for times, _ in paths.values())


def test_seed002_scores_the_fused_track_after_the_alignment_phase_above_15_m_as_the_paper():
    from evp.experiments.seed002_flights import _fused_scores
    from evp.fusion.geodesy import EnuFrame
    from evp.fusion.gps_input import GpsTrack
    from evp.types import Trajectory

    times = np.arange(0.0, 100.0, 0.5)
    up = np.interp(times, [0, 20, 80, 100], [0, 60, 60, 0])  # climb, cruise, descent
    truth_xyz = np.column_stack([2.0 * times, np.zeros_like(times), up])
    gps = GpsTrack(EnuFrame(0.0, 0.0, 0.0), times, truth_xyz, np.full(len(times), 1.5))
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1))
    truth = Trajectory(truth_xyz, quats, times, "truth")
    error = np.where(up > 15.0, 1.0, 40.0)  # 1 m east above 15 m, 40 m below: never scored
    fused = Trajectory(truth_xyz + np.column_stack([error, np.zeros((len(times), 2))]), quats, times, "fused")
    scores = _fused_scores(fused, gps, 30.0, truth, 60.0)
    after_and_high = (times > 30.0) & (up > 15.0)
    assert scores["whole"]["count"] == after_and_high.sum() and scores["whole"]["mean"] == pytest.approx(1.0)
    assert scores["near_target"]["count"] == ((times > 30.0) & (np.abs(up - 60.0) < 2.0)).sum()
    assert scores["vs_truth_mean_m"] == pytest.approx(1.0)
    assert _fused_scores(Trajectory(truth_xyz[:1], quats[:1], times[:1], "fused"), gps, 30.0, truth, 60.0)["whole"] is None


def test_seed002_tells_the_scored_fixes_own_error_against_the_truth():
    """What a track on the truth would score against GPS: the fixes scored (after the phase, above 15 m)
    against the truth; None when no fix is scored."""
    from evp.experiments.seed002_flights import _gps_own_error
    from evp.fusion.geodesy import EnuFrame
    from evp.fusion.gps_input import GpsTrack
    from evp.types import Trajectory

    times = np.arange(0.0, 100.0, 0.5)
    up = np.interp(times, [0, 20, 80, 100], [0, 60, 60, 0])
    truth_xyz = np.column_stack([2.0 * times, np.zeros_like(times), up])
    truth = Trajectory(truth_xyz, np.tile([0.0, 0.0, 0.0, 1.0], (len(times), 1)), times, "truth")
    north = np.where((times > 30.0) & (up > 15.0), 2.0, 50.0)  # 2 m off where scored, 50 m where not
    gps = GpsTrack(EnuFrame(0.0, 0.0, 0.0), times, truth_xyz + np.column_stack([np.zeros_like(times), north, np.zeros_like(times)]), np.full(len(times), 1.5))
    assert _gps_own_error(gps, 30.0, truth) == pytest.approx(2.0)
    assert _gps_own_error(gps, 200.0, truth) is None
