"""A mobile station's credential: paired once with a one-time code, then kept in a private file.

``evp stream --pair CODE`` trades the code (``POST /api/pair`` over the same TLS the stream uses,
with the same certificate pin) for this device's own credential and keeps it, readable by its
owner only; later runs read it. Never on a command line or in a URL, where other users and logs
would see it.
"""

from __future__ import annotations

import http.client
import json
import os
import socket
from pathlib import Path
from urllib.parse import urlsplit

from evp.mobile.client import StreamError, tls_context


def credential_path(url: str) -> Path:
    parts = urlsplit(url if "://" in url else f"wss://{url}")
    return Path.home() / ".config" / "evp" / "credentials" / f"{parts.hostname}_{parts.port or 443}"


def pair(url: str, code: str, device: str, cafile: str | None = None, fingerprint: str | None = None, insecure: bool = False) -> str:
    """This device's new credential for the station at ``url`` (ws(s)/http(s), as evp stream takes
    it); the station's certificate is checked as the stream checks it (:func:`tls_context`)."""
    from evp.station.tls import der_fingerprint

    parts = urlsplit(url if "://" in url else f"wss://{url}")
    secure = parts.scheme in ("wss", "https")
    port = parts.port or (443 if secure else 80)
    if secure:
        connection = http.client.HTTPSConnection(parts.hostname, port, context=tls_context(cafile, insecure or bool(fingerprint)), timeout=20)
    else:
        connection = http.client.HTTPConnection(parts.hostname, port, timeout=20)
    try:
        connection.connect()
        if secure and fingerprint:
            seen = der_fingerprint(connection.sock.getpeercert(binary_form=True))
            if seen != fingerprint.upper():
                raise StreamError(f"the station's certificate {seen} is not the pinned {fingerprint.upper()}")
        connection.request("POST", "/api/pair", json.dumps({"code": code, "device": device}), {"Content-Type": "application/json"})
        response = connection.getresponse()
        body = json.loads(response.read() or b"{}")
    except (OSError, ValueError, http.client.HTTPException) as exc:
        raise StreamError(f"pairing with {parts.hostname}:{port} failed: {exc}") from exc
    finally:
        connection.close()
    if response.status != 200 or "credential" not in body:
        raise StreamError(f"the station refused the pairing code: {body.get('error', response.status)}")
    return body["credential"]


def device_credential(url: str, code: str | None, path: Path | None, cafile: str | None = None, fingerprint: str | None = None, insecure: bool = False) -> str:
    """The credential to stream with: paired now when ``code`` is given (and kept at ``path``),
    else the one kept there; "" when there is none (a --dev-loopback station needs none)."""
    path = path or credential_path(url)
    if code:
        credential = pair(url, code, f"evp-stream {socket.gethostname()}", cafile, fingerprint, insecure)
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(descriptor, "w") as handle:
            handle.write(credential)
        return credential
    return path.read_text().strip() if path.is_file() else ""
