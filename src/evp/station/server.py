"""The ASGI application: mobile and operator WebSockets, the operator API, the web pages.

Routes
  /                     operator UI           /phone               phone page (mobile station)
  /ws/mobile            mobile stations       /ws/operator         operator UI live feed
  /api/state            settings + live sessions          POST /api/configure
  /api/sessions         recorded sessions     POST /api/sessions/{id}/{start|stop|resume}
  /api/sessions/{id}/trajectory.tum | recording.mcap | events
  /api/qr.svg           QR code of the phone page's address
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import io
import json
import time
from importlib import resources
from pathlib import Path
from urllib.parse import parse_qs

from pydantic import ValidationError
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from evp import __version__
from evp.config import validation_message
from evp.io.trajectory import tum_text
from evp.station.base_station import Station
from evp.station.protocol import SESSION_ID, Error, Hello, ProtocolError, Welcome, decode_text, encode
from evp.station.replay import live_poses, tracked_trajectory

HELLO_TIMEOUT_S = 10.0


def _static_dir() -> Path:
    return Path(str(resources.files("evp.station") / "static"))


async def _sender(websocket: WebSocket, outbox: asyncio.Queue) -> None:
    with contextlib.suppress(WebSocketDisconnect, RuntimeError):
        while True:
            await websocket.send_text(await outbox.get())


async def _hello(websocket: WebSocket, station: Station) -> Hello:
    """The first message must be a valid hello; anything else ends the connection with an error."""
    message = await asyncio.wait_for(websocket.receive(), HELLO_TIMEOUT_S)
    if message["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(message.get("code", 1000))
    if message.get("text") is None:
        raise ProtocolError("not_ready", "the first message must be hello (text), not binary")
    hello = decode_text(message["text"])
    if not isinstance(hello, Hello):
        raise ProtocolError("not_ready", f"the first message must be hello, not {hello.type}")
    station.check_hello(hello)
    return hello


async def mobile_endpoint(websocket: WebSocket) -> None:
    station: Station = websocket.app.state.station
    await websocket.accept()
    try:
        hello = await _hello(websocket, station)
        session, resumed = station.open_session(hello)
    except (ProtocolError, TimeoutError) as exc:
        error = exc if isinstance(exc, ProtocolError) else ProtocolError("not_ready", f"no hello within {HELLO_TIMEOUT_S:.0f} s")
        station.on_event(None, station.store.log_event(None, "error", error.code, f"connection refused: {error.message}"))
        with contextlib.suppress(WebSocketDisconnect, RuntimeError):
            await websocket.send_text(encode(Error(code=error.code, message=error.message)))
            await websocket.close(code=1008)
        return
    except WebSocketDisconnect:
        return
    outbox: asyncio.Queue = asyncio.Queue()
    sender = asyncio.create_task(_sender(websocket, outbox))
    outbox.put_nowait(encode(Welcome(session_id=session.id, resumed=resumed, next_seq=session.next_seq, server=f"evp {__version__}")))
    session.attach(outbox.put_nowait)
    session.reply(station.config_for_mobile())
    if session.worker is not None or session.camera is not None:
        session.reply(session.status())
    station.broadcast({"type": "sessions"})
    try:
        while not session.ended:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
            now = time.time()
            if message.get("bytes") is not None:
                session.on_binary(message["bytes"], now)
            elif message.get("text") is not None:
                session.on_text(message["text"], now)
    except WebSocketDisconnect:
        pass
    finally:
        if session.ended:
            await station.end_session(session)  # frames in flight get their poses, still sent on this link
        session.detach(clean=session.ended)
        while not outbox.empty():  # let the last replies (poses of frames in flight) go out
            await asyncio.sleep(0.01)
            if sender.done():
                break
        sender.cancel()
        with contextlib.suppress(RuntimeError, WebSocketDisconnect):
            await websocket.close()
        station.on_status(session)


async def operator_endpoint(websocket: WebSocket) -> None:
    station: Station = websocket.app.state.station
    await websocket.accept()
    outbox: asyncio.Queue = asyncio.Queue()
    outbox.put_nowait(json.dumps(station.snapshot()))
    for event in await asyncio.to_thread(station.store.recent_events, 200):
        outbox.put_nowait(json.dumps({"type": "event", "event": event}))
    station.operators.add(outbox)
    sender = asyncio.create_task(_sender(websocket, outbox))
    try:
        while True:
            message = await websocket.receive()
            if message["type"] == "websocket.disconnect":
                break
    finally:
        station.operators.discard(outbox)
        sender.cancel()


# --- HTTP API ---------------------------------------------------------------------------------


async def state(request: Request) -> JSONResponse:
    return JSONResponse(request.app.state.station.snapshot())


async def configure(request: Request) -> JSONResponse:
    station: Station = request.app.state.station
    try:
        body = await request.json()
    except ValueError as exc:
        return JSONResponse({"error": str(exc)}, status_code=400)
    if not isinstance(body, dict):
        return JSONResponse({"error": "the body must be a JSON object"}, status_code=400)
    try:
        config = station.configure(body.get("orb"), body.get("camera"), body.get("fps"), body.get("color_space"))
    except ValidationError as exc:
        return JSONResponse({"error": validation_message(exc)}, status_code=422)
    except (ValueError, TypeError) as exc:
        return JSONResponse({"error": str(exc)}, status_code=400)
    return JSONResponse({"config": config.model_dump()})


async def sessions(request: Request) -> JSONResponse:
    rows = await asyncio.to_thread(request.app.state.station.store.list_sessions)
    return JSONResponse({"sessions": rows})


async def command(request: Request) -> JSONResponse:
    """start: a new map; stop: pause estimation (frames still recorded); resume: continue the map."""
    station: Station = request.app.state.station
    session = station.sessions.get(request.path_params["session_id"])
    action = request.path_params["action"]
    if session is None:
        return JSONResponse({"error": "no live session with that id"}, status_code=404)
    if action == "start":
        session.restart_estimator()
        session.set_estimating(True, "operator")
    elif action in ("stop", "resume"):
        session.set_estimating(action == "resume", "operator")
    else:
        return JSONResponse({"error": f"unknown action {action!r} (start, stop, resume)"}, status_code=404)
    return JSONResponse({"status": session.status().model_dump()})


def _no_such_session(session_id: str) -> JSONResponse | None:
    """A 404 for anything that is not a session id: a URL's text never reaches a file name or a header."""
    return None if SESSION_ID.fullmatch(session_id) else JSONResponse({"error": "not a session id"}, status_code=404)


async def trajectory(request: Request) -> Response:
    station: Station = request.app.state.station
    session_id = request.path_params["session_id"]
    if refused := _no_such_session(session_id):
        return refused
    poses = await asyncio.to_thread(live_poses, station.store, session_id)
    headers = {"Content-Disposition": f'attachment; filename="{session_id}.tum"'}
    return PlainTextResponse(tum_text(tracked_trajectory(poses)), headers=headers)


async def recording(request: Request) -> Response:
    station: Station = request.app.state.station
    if refused := _no_such_session(request.path_params["session_id"]):
        return refused
    row = await asyncio.to_thread(station.store.session, request.path_params["session_id"])
    if row is None or not row["mcap_path"] or not Path(row["mcap_path"]).is_file():
        return JSONResponse({"error": "no recording for that session"}, status_code=404)
    return FileResponse(row["mcap_path"], media_type="application/octet-stream", filename=f"{row['id']}.mcap")


async def session_events(request: Request) -> JSONResponse:
    rows = await asyncio.to_thread(request.app.state.station.store.rows, "events", request.path_params["session_id"])
    return JSONResponse({"events": rows})


async def qr_code(request: Request) -> Response:
    import segno

    station: Station = request.app.state.station
    buffer = io.BytesIO()
    segno.make(station.link.get("phone_url", ""), error="m").save(buffer, kind="svg", scale=5, border=2)
    return Response(buffer.getvalue(), media_type="image/svg+xml")


def _page(name: str):
    async def page(_request: Request) -> FileResponse:
        return FileResponse(_static_dir() / name, media_type="text/html")

    return page


class OperatorTokenGate:
    """With ``--token``, the operator API and live feed need it too (``?token=`` or ``X-EVP-Token``):
    they show the token (phone URL, QR code) and control the sessions. The pages themselves are public."""

    PROTECTED = ("/api/", "/ws/operator")

    def __init__(self, app, token: str):
        self.app = app
        self.token = token

    async def __call__(self, scope, receive, send) -> None:
        if self.token and scope["type"] in ("http", "websocket") and scope["path"].startswith(self.PROTECTED):
            supplied = parse_qs(scope.get("query_string", b"").decode()).get("token", [""])[0]
            supplied = supplied or dict(scope.get("headers", [])).get(b"x-evp-token", b"").decode()
            if not hmac.compare_digest(supplied.encode(), self.token.encode()):
                if scope["type"] == "websocket":
                    await send({"type": "websocket.close", "code": 1008, "reason": "missing or wrong token"})
                else:
                    await JSONResponse({"error": "missing or wrong token (?token= or X-EVP-Token)"}, status_code=401)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def create_app(station: Station) -> Starlette:
    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette):
        await station.start()
        yield
        await station.stop()

    routes = [
        Route("/", _page("operator.html")),
        Route("/phone", _page("phone.html")),
        Route("/api/state", state),
        Route("/api/configure", configure, methods=["POST"]),
        Route("/api/sessions", sessions),
        Route("/api/sessions/{session_id}/trajectory.tum", trajectory),
        Route("/api/sessions/{session_id}/recording.mcap", recording),
        Route("/api/sessions/{session_id}/events", session_events),
        Route("/api/sessions/{session_id}/{action}", command, methods=["POST"]),
        Route("/api/qr.svg", qr_code),
        WebSocketRoute("/ws/mobile", mobile_endpoint),
        WebSocketRoute("/ws/operator", operator_endpoint),
        Mount("/static", StaticFiles(directory=_static_dir()), name="static"),
    ]
    app = Starlette(routes=routes, lifespan=lifespan, middleware=[Middleware(OperatorTokenGate, token=station.token)])
    app.state.station = station
    return app
