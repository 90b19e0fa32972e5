"""evp config dump."""

import yaml

from evp.errors import ExitCode
from tests.cli.conftest import evp


def test_config_dump_is_valid_yaml(tmp_path):
    result = evp("config", "dump")
    assert result.returncode == 0
    dumped = yaml.safe_load(result.stdout)
    assert dumped["orb"]["n_features"] == 1000
    assert dumped["estimator"] == "auto" and dumped["eval"]["max_time_diff_s"] is None  # resolved per dataset by evp run
    (tmp_path / "s.yaml").write_text("orb:\n  n_features: 1500\n")
    assert yaml.safe_load(evp("config", "dump", tmp_path / "s.yaml").stdout)["orb"]["n_features"] == 1500
    missing = evp("config", "dump", tmp_path / "missing.yaml")
    assert missing.returncode == ExitCode.USAGE and "not found" in missing.stderr
