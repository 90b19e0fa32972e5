"""The work behind ``evp stream`` and ``evp replay`` (the CLI module only parses options)."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

from evp.errors import EvpError


def run_stream(source_spec, url, realtime, encoding, jpeg_quality, camera, max_frames, token, resume, cafile, fingerprint, out, quiet, echo) -> dict:
    from evp.mobile.client import StreamClient
    from evp.mobile.sources import open_source
    from evp.station.replay import tum_text

    if encoding not in ("auto", "jpeg", "png", "raw"):
        raise EvpError(f"--encoding {encoding!r}: choose jpeg, png, raw or auto")
    source = open_source(source_spec, camera, max_frames)
    if encoding == "auto":
        encoding = "png" if source.lossless else "jpeg"

    def show(pose) -> None:
        if not quiet:
            t = " ".join(f"{v:.4f}" for v in pose.t)
            echo(f"pose {pose.seq} t={pose.timestamp:.3f} {pose.state} xyz=({t}) quality={pose.quality}")

    client = StreamClient(url, token=token, cafile=cafile, fingerprint=fingerprint, on_pose=show, log=lambda text: echo(text, err=True))
    report = asyncio.run(client.run(source, realtime, encoding, jpeg_quality, resume))
    summary = report.summary()
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        poses = [report.poses[k] for k in sorted(report.poses)]
        (out / "poses.tum").write_text(tum_text(poses))
        (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary


def _session_reference(session: str, data: Path) -> tuple[str, Path]:
    """(session id, data folder) from an id or an .mcap path under <data>/sessions/."""
    path = Path(session)
    if path.suffix == ".mcap":
        if not path.is_file():
            raise EvpError(f"{path}: no such recording")
        return path.stem, path.resolve().parent.parent
    return session, data


def run_replay(session: str, data: Path, db: str | None, out: Path | None, all_frames: bool) -> dict:
    from rich.progress import Progress

    from evp.station.replay import compare_with_live, replay, write_replay
    from evp.station.store import SessionStore

    session_id, data = _session_reference(session, data)
    database = data / "evp.sqlite"
    if db is None and not database.is_file():
        raise EvpError(f"{data}: no station database here (evp.sqlite); give --data or --db")
    store = SessionStore(db or f"sqlite:///{database.resolve()}")
    try:
        row = store.session(session_id)
        total = row["frames_received"] if row else None
        with Progress(transient=True) as progress:
            task = progress.add_task(f"replay {session_id}", total=total or None)
            poses = replay(store, session_id, all_frames, lambda n: progress.advance(task, n))
        return write_replay(out, store, session_id, poses) if out else compare_with_live(store, session_id, poses)
    finally:
        store.close()
