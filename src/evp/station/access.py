"""The web layer's gate: which requests reach the station, as whom.

- The operator API and live feed need an operator credential: the ``evp_operator`` cookie the
  login sets (HttpOnly, SameSite=Strict) or ``Authorization: Bearer`` (scripts, tests). A phone's
  credential is not enough. Never ``?token=`` in a URL: URLs end up in histories and logs.
- The pages, their static files, ``POST /api/pair`` (a pairing code for a credential) and
  ``/ws/mobile`` (the credential comes in its hello message) are open to anybody.
- Cross-site requests are refused: a WebSocket or a POST whose ``Origin`` is not the station's own
  (or one of ``station.allowed_origins``), and any POST that is not ``application/json`` (a
  cross-site form or ``text/plain`` POST cannot send that without a CORS preflight, which the
  station never grants). Clients that are not browsers send no ``Origin``.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from http.cookies import SimpleCookie

from starlette.responses import JSONResponse

from evp.station.auth import DEV, Identity

OPERATOR_COOKIE = "evp_operator"
PUBLIC_PATHS = ("/", "/phone", "/mission", "/api/pair", "/ws/mobile", "/favicon.ico")
PUBLIC_PREFIXES = ("/static/",)


def _headers(scope) -> dict[str, str]:
    return {key.decode("latin-1").lower(): value.decode("latin-1") for key, value in scope.get("headers", [])}


def own_origin(scope, headers: dict[str, str]) -> str:
    secure = scope.get("scheme") in ("https", "wss")
    return f"{'https' if secure else 'http'}://{headers.get('host', '')}"


def presented_credential(headers: dict[str, str]) -> str:
    """The credential a request carries (bearer header first, then the login cookie), or ""."""
    authorization = headers.get("authorization", "")
    if authorization.lower().startswith("bearer "):
        return authorization[7:].strip()
    cookie = SimpleCookie()
    try:
        cookie.load(headers.get("cookie", ""))
    except Exception:  # a malformed Cookie header is no credential  # noqa: BLE001
        return ""
    morsel = cookie.get(OPERATOR_COOKIE)
    return morsel.value if morsel is not None else ""


def login_cookie(credential: str, secure: bool) -> str:
    return f"{OPERATOR_COOKIE}={credential}; Path=/; HttpOnly; SameSite=Strict" + ("; Secure" if secure else "")


class AccessGate:
    """ASGI middleware; ``identify(credential) -> Identity | None`` is the station's (blocking:
    run in a thread), ``open_dev`` the explicit development mode (everybody is ``auth.DEV``)."""

    def __init__(self, app, identify: Callable[[str], Identity | None], open_dev: bool, allowed_origins: list[str]):
        self.app = app
        self.identify = identify
        self.open_dev = open_dev
        self.allowed_origins = set(allowed_origins)

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = _headers(scope)
        state_changing = scope["type"] == "websocket" or scope.get("method", "GET") not in ("GET", "HEAD", "OPTIONS")
        problem = self._cross_site(scope, headers) if state_changing else None
        if problem is None and scope["type"] == "http" and state_changing and headers.get("content-type", "").split(";")[0].strip() != "application/json":
            problem = (415, "a POST to the station must be application/json")
        public = scope["path"] in PUBLIC_PATHS or scope["path"].startswith(PUBLIC_PREFIXES)
        if problem is None and not public:  # the pages, static files, pairing and phones' link need no login
            identity = DEV if self.open_dev else await self._identify(headers)
            if identity is None or not identity.may("operator"):
                problem = (401, "the operator's credential is needed (log in with the link evp serve printed)") if identity is None else (403, "operators only")
        if problem is not None:
            await self._refuse(scope, receive, send, *problem)
            return
        await self.app(scope, receive, send)

    def _cross_site(self, scope, headers: dict[str, str]) -> tuple[int, str] | None:
        origin = headers.get("origin")
        if origin is None or origin == own_origin(scope, headers) or origin in self.allowed_origins:
            return None
        return 403, f"cross-site request from {origin!r} refused"

    async def _identify(self, headers: dict[str, str]) -> Identity | None:
        credential = presented_credential(headers)
        return await asyncio.to_thread(self.identify, credential) if credential else None

    @staticmethod
    async def _refuse(scope, receive, send, status: int, text: str) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008, "reason": text[:120]})
        else:
            await JSONResponse({"error": text}, status_code=status)(scope, receive, send)
