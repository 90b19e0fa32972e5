"""A fleet's estimators on a cluster (issue 36): each session's estimator as a Dask actor on a
real local cluster's worker gives the same answers as a local one; an unreachable cluster is named."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from evp.runtime.vision_process import ClusterEstimator, EstimatorServer, FrameRejected, VisionLost
from tests.conftest import SAMPLE
from tests.runtime.test_vision_process import _frames, _Scripted
from tests.station.conftest import run_stream, running_station
from tests.station.test_end_to_end import _offline_live_trajectory

distributed = pytest.importorskip("distributed")


class ScriptedServer(EstimatorServer):
    """The scripted estimator, built on the worker."""

    def __init__(self):
        super().__init__(_Scripted())


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as local:
        yield local


def test_an_estimator_on_the_cluster_answers_as_it_would_here(cluster):
    remote = ClusterEstimator(cluster.scheduler_address, ScriptedServer)
    answers = []
    for frame in _frames(7):
        try:
            answers.append(remote.feed(frame).T_world_cam[0, 3])
        except FrameRejected as exc:
            answers.append(str(exc))
    remote.finish()
    assert answers == [0, 1, 2, 3, 4, "frame 5: too dark", 6]
    assert remote.reset_counter == 1 and remote.loop_closures == ["loop at 3"]


def test_an_unreachable_cluster_is_named():
    with pytest.raises(VisionLost, match="tcp://127.0.0.1:9"):
        ClusterEstimator("tcp://127.0.0.1:9", ScriptedServer, timeout_s=2.0)


def test_the_station_places_a_sessions_estimator_on_the_cluster_with_the_same_answers(tmp_path, station_data, cluster):
    config = tmp_path / "fleet.yaml"
    config.write_text(yaml.safe_dump({"station": {"cluster": cluster.scheduler_address}}))
    with running_station(station_data, "--config", str(config)) as station:
        cafile = str(station_data / "tls" / "cert.pem")
        summary = run_stream(str(SAMPLE), "--url", station.url, "--cafile", cafile, "--quiet", "--out", str(tmp_path / "stream"))
    assert summary["frames_sent"] == 87 and summary["errors"] == 0
    streamed = np.loadtxt(tmp_path / "stream" / "poses.tum")
    offline = _offline_live_trajectory()
    assert len(streamed) == len(offline)
    assert max(np.linalg.norm(row[1:4] - offline[round(row[0], 6)]) for row in streamed) < 1e-9
