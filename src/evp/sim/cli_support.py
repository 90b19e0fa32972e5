"""Turning ``evp sim`` flags and an optional YAML file into :class:`SimOptions`."""

from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError

from evp.config import read_settings_yaml, validation_message
from evp.errors import ConfigError
from evp.sim.scenarios import SimOptions


def _outage(text: str) -> tuple[float, float]:
    try:
        start, duration = (float(v) for v in text.split(":"))
    except ValueError:
        raise ConfigError(f"--gps-outage wants START:DURATION in seconds, got {text!r}") from None
    return start, duration


def options_from_cli(
    config: Path | None,
    *,
    gps_clock_offset_s: float,
    spoof_start_s: float | None,
    spoof_mode: str,
    spoof_rate_m_s: float,
    spoof_jump_m: float,
    outages: list[str],
    duration: float | None,
    **flags,
) -> SimOptions:
    """Flags override the YAML file, which overrides the defaults."""
    data: dict = {}
    if config is not None:
        data = read_settings_yaml(config)
    data.update({k: v for k, v in flags.items() if v is not None})
    data["duration_s"] = duration if duration is not None else data.get("duration_s")
    gps = dict(data.get("gps", {}))
    gps.update(
        clock_offset_s=gps_clock_offset_s or gps.get("clock_offset_s", 0.0), spoof_mode=spoof_mode, spoof_rate_m_s=spoof_rate_m_s, spoof_jump_m=spoof_jump_m
    )
    if spoof_start_s is not None:
        gps["spoof_start_s"] = spoof_start_s
    if outages:
        gps["outages"] = [_outage(o) for o in outages]
    data["gps"] = gps
    try:
        return SimOptions.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"simulation option {validation_message(exc)}") from exc
