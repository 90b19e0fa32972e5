"""``evp fly``: a closed-loop autonomous mission in the simulator (seed 003's autopilot)."""

from __future__ import annotations

from pathlib import Path

import typer

from evp.errors import UsageError
from evp.io.output_paths import writable_folder

app = typer.Typer()
SCENES = ("marker-field",)


@app.command()
def fly(
    scene: str = typer.Argument(..., help="The world to fly in: marker-field (seed 003's 99 markers)."),
    out: Path = typer.Option(..., "--out", help="Folder for mission.json, trajectory.csv, map.json, events.json, timeline.csv and plots."),
    target: int | None = typer.Option(None, "--target", help="Marker to land on (explores until it is mapped); none: explore, then land at the start."),
    seed: int = typer.Option(1, "--seed", help="Seeds the wind, the trim error, the sensor noise."),
    duration: float = typer.Option(150.0, "--duration", min=1.0, help="Longest mission, seconds."),
    hover: float | None = typer.Option(None, "--hover", min=0.0, help="Hold over the start this many seconds, then land (the drift test)."),
    start: int = typer.Option(49, "--start", help="Marker the vehicle takes off from (49: the field's middle)."),
    resolution: str = typer.Option("640x480", "--resolution", help="Camera image size, WxH (4:3)."),
    no_drift_correction: bool = typer.Option(
        False, "--no-drift-correction", help="Fly without the velocity loop on marker motion (seed 003's uncorrected hover)."
    ),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (markers, autopilot sections)."),
    serve: int | None = typer.Option(None, "--serve", help="Fly in real time and serve the operator page on this port (map, state, commands)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address the operator page listens on (with --serve)."),
    linger: float = typer.Option(3.0, "--linger", min=0.0, help="Seconds the page stays up after the mission (with --serve)."),
) -> None:
    """Fly a whole mission: lift-off, exploration, navigation, edge recovery, landing."""
    from evp.config import load_settings
    from evp.eval.mission_report import write_mission
    from evp.sim.mission import MissionRun, MissionSpec
    from evp.sim.mission import fly as fly_mission

    writable_folder(out)
    if scene not in SCENES:
        raise UsageError(f"unknown scene {scene!r}; choose one of {', '.join(SCENES)}")
    try:
        width, height = (int(v) for v in resolution.lower().split("x"))
    except ValueError:
        raise UsageError(f"--resolution wants WxH, got {resolution!r}") from None
    settings = load_settings(config)
    if no_drift_correction:
        settings.autopilot.drift_correction = False
    spec = MissionSpec(seed=seed, target=target, start_marker=start, duration_s=duration, hover_s=hover, resolution=(width, height))
    last = [-10.0]

    def progress(t: float, pilot) -> None:
        if t - last[0] >= 10.0:
            last[0] = t
            typer.echo(f"t={t:5.1f} s  {pilot.state.value:<11}  {len(pilot.marker_map)} markers mapped", err=True)

    if serve is None:
        result = fly_mission(spec, settings.autopilot, settings.markers, progress)
    else:
        from evp.station.mission_live import serve_mission

        run = MissionRun(spec, settings.autopilot, settings.markers)
        serve_mission(run, host, serve, linger, lambda text: typer.echo(text, err=True))
        result = run.result()
    summary = write_mission(result, out)
    typer.echo(
        f"landed={summary['landed']} landing_error_m={summary['landing_error_m']} mapped={summary['markers_mapped']}/{summary['markers_total']} "
        f"time={summary['mission_time_s']:.1f} s left_room={summary['left_room']} frame_ms_p95={summary['frame_ms_p95']:.1f} -> {out}"
    )
