"""A simulated marker mission served live to the operator (seed 003's monitoring station).

The mission runs in the server's event loop, a frame at a time, paced to real time; the page
(``static/mission.html``) polls ``/api/mission`` for the map and grid as they grow, the state, the
flight level and the events, and posts the operator's commands (go to a marker, land, hold, return
to exploration, abort, a manual push) to ``/api/mission/command``, where they reach the autopilot
between two frames, as the paper's keyboard commands did. A refused command (a marker not in the
map, an unknown kind) answers 409 with the autopilot's reason.
"""

from __future__ import annotations

import asyncio
import contextlib

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import JSONResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from evp.autopilot.pilot import KINDS
from evp.sim.mission import MissionRun
from evp.station.marker_mission import parse_command, pilot_view
from evp.station.server import _page, _static_dir


def mission_state(run: MissionRun) -> dict:
    """What the page shows (``pilot_view``), with the simulated floor's marker count."""
    return pilot_view(run.pilot, run.t, run.done, len(run.centres))


async def get_state(request: Request) -> JSONResponse:
    return JSONResponse(mission_state(request.app.state.run))


async def post_command(request: Request) -> JSONResponse:
    run: MissionRun = request.app.state.run
    try:
        order = parse_command(await request.json())
    except ValueError as exc:
        return JSONResponse({"error": str(exc)}, status_code=400)
    accepted = run.pilot.command(run.t, order)
    answer = {"accepted": accepted, "detail": run.pilot.events[-1].detail if run.pilot.events else ""}
    return JSONResponse(answer, status_code=200 if accepted else 409)


async def fly_live(run: MissionRun, realtime: bool = True) -> None:
    """Step the mission, a frame per ``frame_dt`` of the loop's clock (as fast as it can when
    rendering is slower, or with ``realtime`` off), yielding to the server between frames."""
    loop = asyncio.get_running_loop()
    start = loop.time()
    while run.step():
        delay = start + run.t - loop.time() if realtime else 0.0
        await asyncio.sleep(max(0.0, delay))


def create_mission_app(run: MissionRun, realtime: bool = True, on_done=None) -> Starlette:
    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette):
        async def flight() -> None:
            await fly_live(run, realtime)
            if on_done is not None:
                on_done()

        task = asyncio.create_task(flight())
        yield
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task

    routes = [
        Route("/", _page("mission.html")),
        Route("/api/mission", get_state),
        Route("/api/mission/command", post_command, methods=["POST"]),
        Mount("/static", StaticFiles(directory=_static_dir()), name="static"),
    ]
    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.run = run
    return app


def serve_mission(run: MissionRun, host: str, port: int, linger_s: float, echo) -> None:
    """Serve the mission until it ends, then ``linger_s`` more seconds (the page shows the end)."""
    import uvicorn

    server: uvicorn.Server | None = None

    def done() -> None:
        asyncio.get_running_loop().call_later(linger_s, lambda: setattr(server, "should_exit", True))

    app = create_mission_app(run, on_done=done)
    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="warning"))
    echo(f"mission live at http://{host}:{port}/  (operator commands: {', '.join(KINDS)})")
    server.run()
