"""evp sim: defaults, then --config, then the options typed."""

import yaml

from evp.cli.sim import sim_options
from evp.errors import ConfigError, ExitCode
from tests.cli.conftest import evp

CONFIG = "noise_sigma: 5\nfps: 10\ngimbal: true\ngps:\n  spoof_rate_m_s: 2.0\n  clock_offset_s: 0.3\n"
NOTHING_TYPED = dict(duration_s=None, seed=None, fps=None, noise_sigma=None, gimbal=None, relief=None)
NO_GPS_TYPED = dict(clock_offset_s=None, spoof_start_s=None, spoof_mode=None, spoof_rate_m_s=None, spoof_jump_m=None, outages=None)


def test_config_values_are_kept_unless_an_option_is_typed(tmp_path):
    config = tmp_path / "sim.yaml"
    config.write_text(CONFIG)
    options = sim_options(config, NOTHING_TYPED, NO_GPS_TYPED)
    assert (options.noise_sigma, options.fps, options.gimbal, options.relief) == (5.0, 10.0, True, True)
    assert (options.gps.spoof_rate_m_s, options.gps.clock_offset_s, options.gps.spoof_mode) == (2.0, 0.3, "pull")
    typed = sim_options(config, {**NOTHING_TYPED, "fps": 20.0, "relief": False}, {**NO_GPS_TYPED, "spoof_rate_m_s": 3.0, "outages": [(1.0, 2.0)]})
    assert (typed.noise_sigma, typed.fps, typed.gimbal, typed.relief) == (5.0, 20.0, True, False)
    assert (typed.gps.spoof_rate_m_s, typed.gps.clock_offset_s, typed.gps.outages) == (3.0, 0.3, [(1.0, 2.0)])
    defaults = sim_options(None, NOTHING_TYPED, NO_GPS_TYPED)
    assert (defaults.noise_sigma, defaults.fps) == (2.0, 30.0)


def test_bad_config_is_a_config_error(tmp_path):
    config = tmp_path / "sim.yaml"
    config.write_text("fps: -1\n")
    try:
        sim_options(config, NOTHING_TYPED, NO_GPS_TYPED)
    except ConfigError as exc:
        assert "fps" in str(exc)
    else:
        raise AssertionError("fps -1 accepted")


def test_sim_command_runs_what_the_config_says(tmp_path):
    config = tmp_path / "sim.yaml"
    config.write_text(CONFIG)
    result = evp("sim", "circle-indoor", "--duration", 0.3, "--config", config, "--flat", "--out", tmp_path / "out", "--workers", 1)
    assert result.returncode == 0, result.stderr
    ran = yaml.safe_load((tmp_path / "out" / "sim.yaml").read_text())["options"]
    assert (ran["noise_sigma"], ran["fps"], ran["gimbal"], ran["relief"], ran["duration_s"]) == (5.0, 10.0, True, False, 0.3)
    assert ran["gps"]["spoof_rate_m_s"] == 2.0 and ran["gps"]["clock_offset_s"] == 0.3


def test_sim_usage_errors(tmp_path):
    assert evp("sim").returncode == ExitCode.USAGE
    bad = evp("sim", "drone-flight", "--out", tmp_path / "y", "--gps-outage", "soon")
    assert bad.returncode == ExitCode.USAGE and "START:DURATION" in bad.stderr
    too_short = evp("sim", "circle-indoor", "--out", tmp_path / "z", "--duration", 0.01)  # fewer than 4 motion samples
    assert too_short.returncode == ExitCode.USAGE and "duration_s" in too_short.stderr
