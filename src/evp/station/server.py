"""The ASGI application: mobile and operator WebSockets, the operator API, the web pages.

Routes (who may use them: evp.station.access)
  /                     operator UI           /phone               phone page (mobile station)
  /ws/mobile            mobile stations       /ws/operator         operator UI live feed
  POST /api/pair        a one-time pairing code for this device's credential (open to all)
  /api/state            settings + live sessions          POST /api/configure
  /api/sessions         recorded sessions     POST /api/sessions/{id}/{start|stop|resume}
  /api/sessions/{id}/trajectory.tum | recording.mcap | events
  /mission?session={id} a marker mission's page: GET /api/sessions/{id}/mission (map, grid,
                        state, flight level), POST /api/sessions/{id}/mission/command
  POST /api/pairing     a new one-time code for a phone, with its QR code
  /api/devices          paired credentials    POST /api/devices/{id}/revoke
  /api/health           database reachable, schema version
"""

from __future__ import annotations

import asyncio
import contextlib
import io
import json
import math
import time
from importlib import resources
from pathlib import Path

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
from evp.station.access import AccessGate, login_cookie
from evp.station.auth import Identity, PairingError
from evp.station.base_station import Station
from evp.station.limits import BodyLimit
from evp.station.protocol import HEARTBEAT_TEXT, SESSION_ID, Error, Hello, ProtocolError, Welcome, decode_text, encode, is_heartbeat
from evp.station.replay import live_poses, tracked_trajectory
from evp.station.schema import health, version

HELLO_TIMEOUT_S = 10.0


def _static_dir() -> Path:
    return Path(str(resources.files("evp.station") / "static"))


async def _sender(websocket: WebSocket, outbox: asyncio.Queue) -> None:
    with contextlib.suppress(WebSocketDisconnect, RuntimeError):
        while True:
            await websocket.send_text(await outbox.get())


async def _hello(websocket: WebSocket, station: Station) -> tuple[Hello, Identity]:
    """The first message must be a valid hello from a paired device; anything else ends the
    connection with an error."""
    message = await asyncio.wait_for(websocket.receive(), HELLO_TIMEOUT_S)
    if message["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(message.get("code", 1000))
    if message.get("text") is None:
        raise ProtocolError("not_ready", "the first message must be hello (text), not binary")
    hello = decode_text(message["text"])
    if not isinstance(hello, Hello):
        raise ProtocolError("not_ready", f"the first message must be hello, not {hello.type}")
    return hello, await asyncio.to_thread(station.check_hello, hello)


async def _heartbeats(outbox: asyncio.Queue, interval_s: float) -> None:
    while True:
        await asyncio.sleep(interval_s)
        outbox.put_nowait(HEARTBEAT_TEXT)


async def mobile_endpoint(websocket: WebSocket) -> None:
    station: Station = websocket.app.state.station
    await websocket.accept()
    try:
        hello, identity = await _hello(websocket, station)
        session, resumed = station.open_session(hello, identity)
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
    limits = station.settings.station
    heartbeats = asyncio.create_task(_heartbeats(outbox, limits.heartbeat_interval_s))
    outbox.put_nowait(encode(Welcome(session_id=session.id, resumed=resumed, next_seq=session.next_seq, server=f"evp {__version__}")))
    send = outbox.put_nowait
    session.attach(send)
    taken_over = asyncio.Event()
    station.link_closers[session.id] = taken_over.set  # its owner resumed it on a new link
    session.reply(station.config_for_mobile())
    if session.worker is not None or session.camera is not None:
        session.reply(session.status())
    station.broadcast({"type": "sessions"})
    try:
        while not session.ended and not taken_over.is_set():
            message = await _receive_unless_taken_over(websocket, taken_over)
            if message is None:
                break
            if message["type"] == "websocket.disconnect":
                break
            now = time.time()
            if message.get("bytes") is not None:
                session.on_binary(message["bytes"], now)
            elif message.get("text") is not None and not is_heartbeat(message["text"]):
                session.on_text(message["text"], now)
    except WebSocketDisconnect:
        pass
    finally:
        heartbeats.cancel()
        if taken_over.is_set():  # the session lives on, on its owner's new link
            sender.cancel()
            with contextlib.suppress(RuntimeError, WebSocketDisconnect):
                await websocket.close(code=4000, reason="resumed on another link")
        else:
            await _end_link(station, session, websocket, outbox, sender, taken_over)


async def _end_link(station: Station, session, websocket: WebSocket, outbox: asyncio.Queue, sender: asyncio.Task, taken_over: asyncio.Event) -> None:
    """The link closed (or died): the session ended (bye) or is interrupted, awaiting a resume."""
    if station.link_closers.get(session.id) == taken_over.set:
        del station.link_closers[session.id]
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


async def _receive_unless_taken_over(websocket: WebSocket, taken_over: asyncio.Event) -> dict | None:
    """The next message; None when the session's owner resumed it on another link first. (A dead
    link ends in a disconnect here: uvicorn's WebSocket pings go every heartbeat_interval_s and
    a pong must come within the rest of heartbeat_timeout_s, answered by any client's WebSocket
    stack, so no client has to send anything to stay connected.)"""
    receive = asyncio.ensure_future(websocket.receive())
    interrupted = asyncio.ensure_future(taken_over.wait())
    done, _ = await asyncio.wait([receive, interrupted], return_when=asyncio.FIRST_COMPLETED)
    interrupted.cancel()
    if receive in done:
        return receive.result()
    receive.cancel()
    return None


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


async def background(request: Request) -> Response:
    """The top view's background image (``station.background_image``), when one is configured."""
    image = request.app.state.station.settings.station.background_image
    if not image:
        return JSONResponse({"error": "no background image (station.background_image)"}, status_code=404)
    return FileResponse(image, media_type="image/png" if image.lower().endswith(".png") else "image/jpeg")


async def sessions(request: Request) -> JSONResponse:
    rows = await asyncio.to_thread(request.app.state.station.store.list_sessions)
    return JSONResponse({"sessions": rows})


async def command(request: Request) -> JSONResponse:
    """start: a new map; stop: pause estimation (frames still recorded); resume: continue the map;
    velocity: drive a wheel robot."""
    station: Station = request.app.state.station
    session = station.sessions.get(request.path_params["session_id"])
    action = request.path_params["action"]
    if session is None:
        return JSONResponse({"error": "no live session with that id"}, status_code=404)
    if action == "velocity":
        return await _velocity(request, session)
    if action == "start":
        session.restart_estimator()
        session.set_estimating(True, "operator")
    elif action in ("stop", "resume"):
        session.set_estimating(action == "resume", "operator")
    else:
        return JSONResponse({"error": f"unknown action {action!r} (start, stop, resume, velocity)"}, status_code=404)
    return JSONResponse({"status": session.status().model_dump()})


async def _velocity(request: Request, session) -> JSONResponse:
    """Drive a wheel robot: ``{"linear_m_s": ..., "angular_rad_s": ...}`` (zero stops it)."""
    try:
        body = await _json_object(request)
        linear, angular = float(body["linear_m_s"]), float(body["angular_rad_s"])
        command = session.drive(linear, angular, time.time())
    except (ValueError, KeyError, TypeError) as exc:
        return JSONResponse({"error": f"velocity: {exc}"}, status_code=400)
    return JSONResponse({"sent": command.model_dump()})


def _mission_of(request: Request):
    """The live marker mission a request names, or the 404 that says why there is none."""
    session = request.app.state.station.sessions.get(request.path_params["session_id"])
    if session is None or session.mission is None:
        return None, JSONResponse(
            {"error": "no live marker mission with that session id (autopilot.vehicles names the vehicles that fly one)"}, status_code=404
        )
    return session.mission, None


async def mission_state(request: Request) -> JSONResponse:
    mission, refused = _mission_of(request)
    return refused or JSONResponse(mission.view())


async def mission_command(request: Request) -> JSONResponse:
    """An operator's command to a marker mission: 200 taken, 409 refused by the autopilot (a
    marker not in the map, a vehicle not flying), 400 not a command; each logged."""
    from evp.station.marker_mission import parse_command

    mission, refused = _mission_of(request)
    if refused:
        return refused
    try:
        order = parse_command(await _json_object(request))
    except ValueError as exc:
        return JSONResponse({"error": str(exc)}, status_code=400)
    accepted, detail = mission.command(order)
    return JSONResponse({"accepted": accepted, "detail": detail}, status_code=200 if accepted else 409)


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


def _qr_svg(text: str) -> str:
    import segno

    buffer = io.BytesIO()
    segno.make(text, error="m").save(buffer, kind="svg", scale=5, border=2)
    return buffer.getvalue().decode()


async def _json_object(request: Request) -> dict:
    try:
        body = await request.json()
    except ValueError:
        body = None
    if not isinstance(body, dict):
        raise ValueError("the body must be a JSON object")
    return body


async def pair(request: Request) -> JSONResponse:
    """A one-time code for this device's own credential (shown once; the database keeps its hash).
    An operator's login also sets the HttpOnly cookie the operator page then uses."""
    station: Station = request.app.state.station
    client = request.client.host if request.client is not None else "?"
    wait_s = station.pairing_failures.blocked(client)
    if wait_s > 0:  # unchecked and unlogged: the event log saw this client's limit once
        headers = {"Retry-After": str(math.ceil(wait_s))}
        return JSONResponse({"error": f"too many failed pairing attempts from {client}; try again in {wait_s:.0f} s"}, status_code=429, headers=headers)
    try:
        body = await _json_object(request)
        code, name = body.get("code"), body.get("device", "")
        if not isinstance(code, str) or not isinstance(name, str):
            raise ValueError("give code (and device) as strings")
        identity, credential = await asyncio.to_thread(station.credentials.pair, code[:64], name)
    except PairingError as exc:
        text = str(exc)
        if station.pairing_failures.failed(client):
            limits = station.settings.station
            text += f"; {client} made {limits.pairing_max_failures} failed attempts: refused unchecked for {limits.pairing_failure_window_s:g} s"
        station.on_event(None, station.store.log_event(None, "warning", "pairing_refused", text))
        return JSONResponse({"error": str(exc)}, status_code=403)
    except ValueError as exc:
        return JSONResponse({"error": str(exc)}, status_code=400)
    station.on_event(
        None, station.store.log_event(None, "info", "paired", f"{identity.role} {identity.name or '(unnamed)'} paired (credential {identity.credential_id})")
    )
    response = JSONResponse({"credential": credential, "credential_id": identity.credential_id, "role": identity.role})
    if identity.role == "operator":
        response.headers["Set-Cookie"] = login_cookie(credential, request.url.scheme == "https")
    return response


async def new_pairing(request: Request) -> JSONResponse:
    """A one-time code for a phone: the phone page's address with the code in its fragment (never
    sent to a server, so never in an access log), and that address as a QR code."""
    station: Station = request.app.state.station
    role = (await _json_object(request)).get("role", "mobile")
    if role not in ("mobile", "operator"):
        return JSONResponse({"error": "role: mobile or operator"}, status_code=400)
    code = await asyncio.to_thread(station.credentials.issue_code, role, station.settings.station.pairing_code_ttl_s)
    page = "phone" if role == "mobile" else ""
    url = f"{station.link.get('base_url', str(request.base_url).rstrip('/'))}/{page}#pair={code}"
    return JSONResponse({"code": code, "url": url, "qr_svg": _qr_svg(url), "expires_in_s": station.settings.station.pairing_code_ttl_s})


async def devices(request: Request) -> JSONResponse:
    return JSONResponse({"devices": await asyncio.to_thread(request.app.state.station.credentials.listing)})


async def revoke(request: Request) -> JSONResponse:
    station: Station = request.app.state.station
    credential_id = request.path_params["credential_id"]
    if not await asyncio.to_thread(station.credentials.revoke, credential_id):
        return JSONResponse({"error": "no such credential, or already revoked"}, status_code=404)
    station.on_event(None, station.store.log_event(None, "info", "revoked", f"credential {credential_id} revoked"))
    return JSONResponse({"revoked": credential_id})


async def health_check(request: Request) -> JSONResponse:
    engine = request.app.state.station.store.engine
    problem = await asyncio.to_thread(health, engine)
    schema = None if problem else await asyncio.to_thread(version, engine)
    return JSONResponse({"database": problem or "ok", "schema_version": schema}, status_code=503 if problem else 200)


def _page(name: str):
    async def page(_request: Request) -> FileResponse:
        return FileResponse(_static_dir() / name, media_type="text/html")

    return page


def create_app(station: Station) -> Starlette:
    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette):
        await station.start()
        yield
        await station.stop()

    routes = [
        Route("/", _page("operator.html")),
        Route("/phone", _page("phone.html")),
        Route("/mission", _page("mission.html")),
        Route("/api/state", state),
        Route("/api/configure", configure, methods=["POST"]),
        Route("/api/background", background),
        Route("/api/sessions", sessions),
        Route("/api/sessions/{session_id}/trajectory.tum", trajectory),
        Route("/api/sessions/{session_id}/recording.mcap", recording),
        Route("/api/sessions/{session_id}/events", session_events),
        Route("/api/sessions/{session_id}/mission", mission_state),
        Route("/api/sessions/{session_id}/mission/command", mission_command, methods=["POST"]),
        Route("/api/sessions/{session_id}/{action}", command, methods=["POST"]),
        Route("/api/pair", pair, methods=["POST"]),
        Route("/api/pairing", new_pairing, methods=["POST"]),
        Route("/api/devices", devices),
        Route("/api/devices/{credential_id}/revoke", revoke, methods=["POST"]),
        Route("/api/health", health_check),
        WebSocketRoute("/ws/mobile", mobile_endpoint),
        WebSocketRoute("/ws/operator", operator_endpoint),
        Mount("/static", StaticFiles(directory=_static_dir()), name="static"),
    ]
    limits = station.settings.station
    middleware = [
        Middleware(BodyLimit, max_bytes=limits.max_body_bytes),
        Middleware(AccessGate, identify=station.credentials.identify, open_dev=limits.dev_loopback, allowed_origins=limits.allowed_origins),
    ]
    app = Starlette(routes=routes, lifespan=lifespan, middleware=middleware)
    app.state.station = station
    return app
