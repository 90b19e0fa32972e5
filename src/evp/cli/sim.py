"""``evp sim``: a synthetic dataset with exact ground truth.

The simulation options have one source, :class:`evp.sim.scenarios.SimOptions`: a ``--config``
YAML overrides its defaults, and an option overrides the YAML only when it is typed (every option
defaults to None, meaning "not given").
"""

from __future__ import annotations

from pathlib import Path

import typer

from evp.errors import ConfigError, UsageError
from evp.io.output_paths import writable_folder

app = typer.Typer()


def _outage(text: str) -> tuple[float, float]:
    try:
        start, duration = (float(v) for v in text.split(":"))
    except ValueError:
        raise UsageError(f"--gps-outage wants START:DURATION in seconds, got {text!r}") from None
    return start, duration


def sim_options(config: Path | None, typed: dict, typed_gps: dict):
    """:class:`SimOptions` from the defaults, then the YAML file, then the options typed (those
    not None), in that order; ``typed_gps`` go to the ``gps`` section."""
    from pydantic import ValidationError

    from evp.config import read_settings_yaml, validation_message
    from evp.sim.scenarios import SimOptions

    data: dict = read_settings_yaml(config) if config is not None else {}
    data.update({name: value for name, value in typed.items() if value is not None})
    gps = {name: value for name, value in typed_gps.items() if value is not None}
    if gps:
        data["gps"] = {**data.get("gps", {}), **gps}
    try:
        return SimOptions.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"simulation option {validation_message(exc, SimOptions)}") from exc


@app.command()
def sim(
    scenario: str | None = typer.Argument(None, help="Scenario name (see --list)."),
    out: Path | None = typer.Option(None, "--out", help="Folder to write the dataset to."),
    list_scenarios: bool = typer.Option(False, "--list", help="Print the scenario names, one per line."),
    duration: float | None = typer.Option(None, "--duration", help="Seconds (default: the scenario's)."),
    seed: int | None = typer.Option(None, "--seed", help="Random seed (noise, textures, paths)."),
    fps: float | None = typer.Option(None, "--fps", help="Camera frame rate."),
    camera: str | None = typer.Option(
        None, "--camera", help="Camera profile (evp camera list): nexus5x_640x380, global_shutter_752x480, phone_1280x720, car_1241x376 or car_640x194."
    ),
    lens: str | None = typer.Option(None, "--lens", help="pinhole (the camera preset's lens) or fisheye (equidistant, at the preset's resolution)."),
    fisheye_fov: float | None = typer.Option(None, "--fisheye-fov", help="Fisheye diagonal field of view, 120-180 degrees (corner to corner; 150 by default)."),
    texture: str | None = typer.Option(None, "--texture", help="rich, low, floor, wall, or image file(s) separated by commas."),
    altitude: float | None = typer.Option(None, "--altitude", help="Flight altitude / camera height (m)."),
    speed: float | None = typer.Option(None, "--speed", help="Cruise speed (m/s)."),
    pattern: str | None = typer.Option(None, "--pattern", help="Drone path: lawnmower, loops or free."),
    gimbal: bool | None = typer.Option(None, "--gimbal", help="Camera held level by a gimbal."),
    relief: bool | None = typer.Option(None, "--relief/--flat", help="Buildings and trees on the ground."),
    rolling_shutter: float | None = typer.Option(None, "--rolling-shutter", help="Row readout time (s); 0 = global shutter."),
    drop: float | None = typer.Option(None, "--drop", help="Probability of dropping a frame."),
    noise: float | None = typer.Option(None, "--noise", help="Image read noise (grey levels)."),
    image_format: str | None = typer.Option(None, "--image-format", help="jpg (quality 95, as a phone streams) or png (lossless)."),
    gps_offset: float | None = typer.Option(None, "--gps-clock-offset", help="GPS clock minus camera clock (s)."),
    spoof_start: float | None = typer.Option(None, "--spoof-start", help="Seconds into the run when GPS spoofing starts."),
    spoof_mode: str | None = typer.Option(None, "--spoof-mode", help="pull (gradual) or jump."),
    spoof_rate: float | None = typer.Option(None, "--spoof-rate", help="Pull-off speed (m/s)."),
    spoof_jump: float | None = typer.Option(None, "--spoof-jump", help="Jump size (m)."),
    outage: list[str] = typer.Option([], "--gps-outage", help="Jamming window START:DURATION in seconds (repeatable)."),
    config: Path | None = typer.Option(None, "--config", help="YAML with any SimOptions field (sensor noise models...); options typed override it."),
    workers: int = typer.Option(2, "--workers", min=1, help="Processes rendering images."),
) -> None:
    """Generate a synthetic dataset with exact ground truth (EuRoC-like folder, see docs/simulator.md)."""
    from evp.sim.scenarios import SCENARIOS

    if list_scenarios:
        typer.echo("\n".join(SCENARIOS))
        return
    if scenario is None or out is None:
        raise UsageError("give a scenario and --out DIR (or --list)")
    writable_folder(out)
    from evp.cli.progress import progress_of
    from evp.sim.generate import generate

    typed = dict(duration_s=duration, seed=seed, fps=fps, camera=camera, texture=texture, altitude_m=altitude, speed_m_s=speed, pattern=pattern)
    typed.update(lens=lens, fisheye_fov_deg=fisheye_fov)
    typed.update(gimbal=gimbal, relief=relief, rolling_shutter_s=rolling_shutter, drop_probability=drop, noise_sigma=noise, image_format=image_format)
    typed_gps = dict(clock_offset_s=gps_offset, spoof_start_s=spoof_start, spoof_mode=spoof_mode, spoof_rate_m_s=spoof_rate, spoof_jump_m=spoof_jump)
    typed_gps["outages"] = [_outage(o) for o in outage] or None
    options = sim_options(config, typed, typed_gps)
    with progress_of(scenario, None) as progress:
        result = generate(scenario, options, out, workers, progress.advance, lambda total: setattr(progress, "total", total))
    typer.echo(
        f"{scenario}: {result.frames} frames ({len(result.dropped)} dropped), {result.scenario.motion.duration:.1f} s, sensors {', '.join(result.scenario.sensors)} -> {out}"
    )
