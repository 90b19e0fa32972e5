"""``evp serve``, ``evp stream`` and ``evp replay``: the base station, a mobile station, and a
recorded session re-run offline."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import typer

from evp.errors import DataError, ExitCode, UsageError
from evp.io.output_paths import writable_folder

if TYPE_CHECKING:
    from evp.config import RobotSettings

app = typer.Typer()


@app.command()
def serve(
    host: str = typer.Option("0.0.0.0", "--host", help="Address to listen on (0.0.0.0: every interface)."),
    port: int = typer.Option(8443, "--port", help="TCP port for the web UI, the phone page and the WebSockets."),
    data: Path = typer.Option(Path("evp-data"), "--data", help="Data folder: database, one MCAP recording per session, TLS certificate."),
    db: str | None = typer.Option(None, "--db", help="SQLAlchemy URL (default: SQLite in the data folder), e.g. postgresql://user@host/evp."),
    mavlink: str | None = typer.Option(None, "--mavlink", help="Pose to a flight controller, e.g. udpout:127.0.0.1:14540 or /dev/ttyUSB0,57600."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (ORB, camera, SLAM, station, mavlink sections)."),
    no_tls: bool = typer.Option(False, "--no-tls", help="Plain HTTP/WebSocket (behind a TLS proxy); phones then need localhost for the camera."),
    dev_loopback: bool = typer.Option(
        False, "--dev-loopback", help="Development only: no credentials at all, listening on loopback only (station.dev_loopback)."
    ),
) -> None:
    """Run the base station: mobile stations stream to it, operators watch it in a browser.
    Each phone pairs once (a one-time QR code on the operator page); the operator logs in with
    the one-time link printed at start."""
    from evp.config import load_settings
    from evp.station.serve import serve as run_station

    settings = load_settings(config)
    if dev_loopback:
        settings.station.dev_loopback = True
    run_station(host, port, data, settings, db, mavlink, not no_tls, typer.echo)


def _station_database(data: Path, db: str | None) -> str:
    database = data / "evp.sqlite"
    if db is None and not database.is_file():
        raise UsageError(f"{data}: no station database here (evp.sqlite); give --data or --db")
    return db or f"sqlite:///{database.resolve()}"


@app.command("pairing-code")
def pairing_code(
    data: Path = typer.Option(Path("evp-data"), "--data", help="The station's data folder."),
    db: str | None = typer.Option(None, "--db", help="SQLAlchemy URL, when the station uses --db."),
    role: str = typer.Option("mobile", "--role", help="mobile (a phone or companion computer: evp stream --pair) or operator (a login)."),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (station.pairing_code_ttl_s)."),
) -> None:
    """Print a one-time pairing code (from the station computer; the station may be running)."""
    from evp.config import load_settings
    from evp.station.auth import Credentials
    from evp.station.store import SessionStore

    if role not in ("mobile", "operator"):
        raise UsageError(f"--role {role!r}: mobile or operator")
    store = SessionStore(_station_database(data, db))
    try:
        typer.echo(Credentials(store.engine).issue_code(role, load_settings(config).station.pairing_code_ttl_s))
    finally:
        store.close()


@dataclass(frozen=True)
class StreamRequest:
    """What ``evp stream`` was asked for: the source and how to send it, the station and how to
    trust it, and where the answers go. ``robot`` (RobotSettings): the wheel records go as that
    robot's encoder counts."""

    source: str
    url: str
    realtime: bool = False
    encoding: str = "auto"
    jpeg_quality: int = 90
    camera: str | None = None
    max_frames: int | None = None
    credential: str = ""
    resume: str | None = None
    cafile: str | None = None
    fingerprint: str | None = None
    insecure: bool = False
    out: Path | None = None
    quiet: bool = False
    device: str = "evp-stream"
    robot: RobotSettings | None = None


def run_stream(request: StreamRequest, echo) -> dict:
    """Stream a source to a station; the poses received are echoed (unless quiet) and written to
    ``request.out`` (poses.tum: the tracked ones; answers.jsonl: every answer with its fields and
    its frame-sent to answer-received latency; summary.json) when given. Returns the summary."""
    import asyncio

    from evp.io.trajectory import tum_text
    from evp.mobile.client import StreamClient
    from evp.mobile.sources import open_source
    from evp.station.replay import tracked_trajectory

    if request.encoding not in ("auto", "jpeg", "png", "raw"):
        raise UsageError(f"--encoding {request.encoding!r}: choose jpeg, png, raw or auto")
    source = open_source(request.source, request.camera, request.max_frames, encoder_robot=request.robot)
    encoding = request.encoding
    if encoding == "auto":
        encoding = "png" if source.lossless else "jpeg"

    def show(pose) -> None:
        if not request.quiet:
            t = " ".join(f"{v:.4f}" for v in pose.t)
            echo(f"pose {pose.seq} t={pose.timestamp:.3f} {pose.state} xyz=({t}) quality={pose.quality}")

    client = StreamClient(
        request.url,
        token=request.credential,
        device=request.device,
        cafile=request.cafile,
        fingerprint=request.fingerprint,
        insecure=request.insecure,
        on_pose=show,
        log=lambda text: echo(text, err=True),
    )
    report = asyncio.run(client.run(source, request.realtime, encoding, request.jpeg_quality, request.resume))
    summary = report.summary()
    out = request.out
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        poses = [report.poses[k] for k in sorted(report.poses)]
        (out / "poses.tum").write_text(tum_text(tracked_trajectory(poses)))
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
        lines = (json.dumps({**pose.model_dump(exclude={"type"}), "latency_ms": report.latency_ms.get(pose.seq)}) for pose in poses)
        (out / "answers.jsonl").write_text("".join(line + "\n" for line in lines))
    return summary


def _check_trust_options(cafile: str | None, fingerprint: str | None) -> None:
    """A missing --cafile or a mangled --fingerprint, said before connecting (a link error would
    blame the network, and a fingerprint that cannot match would refuse every station)."""
    import re

    if cafile is not None and not Path(cafile).is_file():
        raise UsageError(f"--cafile {cafile}: no such file; copy the station's <data>/tls/cert.pem here, or give --fingerprint from its operator page")
    if fingerprint is not None and not re.fullmatch(r"([0-9A-F]{2}:){31}[0-9A-F]{2}", fingerprint.upper()):
        raise UsageError(f"--fingerprint {fingerprint}: expected the SHA-256 fingerprint as the operator page shows it, 32 hex pairs such as AB:CD:...:EF")


@app.command()
def stream(
    source: str = typer.Argument(..., help="Dataset/recording/video path, camera:N (local camera), or an MJPEG URL (http://phone:8080/video)."),
    url: str = typer.Option(..., "--url", help="The station, e.g. wss://192.168.1.10:8443 (ws://, http(s):// also understood)."),
    realtime: bool = typer.Option(False, "--realtime", help="Pace a recording at its own rate (else as fast as the station answers)."),
    encoding: str = typer.Option("auto", "--encoding", help="jpeg, png, raw, or auto (png for image files, jpeg otherwise)."),
    jpeg_quality: int = typer.Option(90, "--jpeg-quality", min=1, max=100),
    camera: str | None = typer.Option(None, "--camera", help="Calibration file or profile name when the source has none."),
    max_frames: int | None = typer.Option(None, "--max-frames", min=1, help="Stop after this many frames."),
    pair: str | None = typer.Option(None, "--pair", help="A one-time pairing code (evp pairing-code, or the operator page): pair, keep the credential."),
    credential_file: Path | None = typer.Option(
        None, "--credential-file", help="Where this device keeps its credential (default: ~/.config/evp/credentials/<host>_<port>)."
    ),
    resume: str | None = typer.Option(None, "--resume", help="Continue this session (after a dropped link)."),
    cafile: str | None = typer.Option(None, "--cafile", help="The station's cert.pem (<data>/tls/cert.pem), to verify its self-signed certificate."),
    fingerprint: str | None = typer.Option(
        None, "--fingerprint", help="Accept only a station certificate with this SHA-256 fingerprint (shown on the operator page and at start)."
    ),
    insecure: bool = typer.Option(False, "--insecure", help="Accept any certificate (its fingerprint is printed): for tests on a trusted network only."),
    out: Path | None = typer.Option(None, "--out", help="Write the received poses here (poses.tum, answers.jsonl, summary.json)."),
    quiet: bool = typer.Option(False, "--quiet", help="Print only the summary, not each pose."),
    encoder_ticks: bool = typer.Option(
        False, "--encoder-ticks", help="Send the wheel records as a wheel robot's encoder counts (robot section of --config): a robot's simulator."
    ),
    config: Path | None = typer.Option(None, "--config", help="Settings YAML (its robot section, with --encoder-ticks)."),
    device: str = typer.Option(
        "evp-stream", "--device", help="This mobile station's name (hello.device): the station's mavlink.vehicles and autopilot.vehicles key on it."
    ),
) -> None:
    """Stream to a base station as a mobile station would; prints each pose, then a JSON summary.
    The station's certificate is verified (--cafile, --fingerprint, or a public one) unless --insecure;
    exits with 4 (link) when the station refused frames."""
    from evp.estimator import NOT_INITIALISED_HINT
    from evp.mobile.pairing import device_credential

    writable_folder(out)
    _check_trust_options(cafile, fingerprint)
    credential = device_credential(url, pair, credential_file, cafile, fingerprint, insecure)
    robot = None
    if encoder_ticks:
        from evp.config import load_settings

        robot = load_settings(config).robot
    request = StreamRequest(
        source,
        url,
        realtime=realtime,
        encoding=encoding,
        jpeg_quality=jpeg_quality,
        camera=camera,
        max_frames=max_frames,
        credential=credential,
        resume=resume,
        cafile=cafile,
        fingerprint=fingerprint,
        insecure=insecure,
        out=out,
        quiet=quiet,
        device=device,
        robot=robot,
    )
    summary = run_stream(request, typer.echo)
    typer.echo(json.dumps(summary))
    if summary["poses_received"] and not summary["poses_tracked"]:
        typer.echo(f"warning: the station tracked none of the {summary['poses_received']} frames it answered: {NOT_INITIALISED_HINT}", err=True)
    if summary["frames_refused"]:
        typer.echo(f"the station refused {summary['frames_refused']} frame(s): {'; '.join(summary['first_errors'][:2])}", err=True)
        raise typer.Exit(int(ExitCode.LINK))


def _session_reference(session: str, data: Path) -> tuple[str, Path]:
    """(session id, data folder) from an id or an .mcap path under <data>/sessions/."""
    path = Path(session)
    if path.suffix == ".mcap":
        if not path.is_file():
            raise DataError(f"{path}: no such recording")
        return path.stem, path.resolve().parent.parent
    return session, data


def run_replay(session: str, data: Path, db: str | None, out: Path | None, all_frames: bool) -> dict:
    """Re-run a recorded session; its comparison with the live poses (written to ``out`` when given)."""
    from evp.cli.progress import progress_of
    from evp.station.replay import compare_with_live, write_replay
    from evp.station.replay import replay as replay_session
    from evp.station.store import SessionStore

    session_id, data = _session_reference(session, data)
    store = SessionStore(_station_database(data, db))
    try:
        row = store.session(session_id)
        total = row["frames_received"] if row else None
        with progress_of(f"replay {session_id}", total or None) as progress:
            poses = replay_session(store, session_id, all_frames, progress.advance)
        return write_replay(out, store, session_id, poses) if out else compare_with_live(store, session_id, poses)
    finally:
        store.close()


@app.command()
def replay(
    session: str = typer.Argument(..., help="Session id (as listed by the station) or the path of its .mcap file."),
    data: Path = typer.Option(Path("evp-data"), "--data", help="The station's data folder."),
    db: str | None = typer.Option(None, "--db", help="SQLAlchemy URL, when the station used --db."),
    out: Path | None = typer.Option(None, "--out", help="Folder for trajectory.tum, trajectory_live.tum, comparison.json."),
    all_frames: bool = typer.Option(False, "--all-frames", help="Also estimate the frames the live station dropped as stale."),
) -> None:
    """Re-run a recorded session offline and compare with the poses sent live."""
    writable_folder(out)
    typer.echo(json.dumps(run_replay(session, data, db, out, all_frames), indent=2))
