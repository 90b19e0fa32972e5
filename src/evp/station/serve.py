"""``evp serve``: the station on uvicorn, over TLS with its own certificate unless told otherwise."""

from __future__ import annotations

import errno
import socket
from pathlib import Path

from evp.config import Settings
from evp.errors import UsageError
from evp.io.output_paths import writable_folder
from evp.station.base_station import Station
from evp.station.protocol import MAX_IMAGE_BYTES
from evp.station.server import create_app
from evp.station.tls import ensure_certificate, fingerprint, local_addresses


def link_info(host: str, port: int, tls: bool, cert: Path | None, token: str) -> dict:
    """The addresses an operator and a phone use, and the certificate to trust."""
    scheme = "https" if tls else "http"
    reachable = host if host not in ("0.0.0.0", "::", "") else next((a for a in local_addresses() if a != "127.0.0.1"), "127.0.0.1")
    query = f"?token={token}" if token else ""
    phone_url = f"{scheme}://{reachable}:{port}/phone{query}"
    return {
        "host": host,
        "port": port,
        "tls": tls,
        "operator_url": f"{scheme}://{reachable}:{port}/{query}",
        "phone_url": phone_url,
        "mobile_ws_url": f"{'wss' if tls else 'ws'}://{reachable}:{port}/ws/mobile",
        "fingerprint_sha256": fingerprint(cert) if cert else None,
        "token_required": bool(token),
    }


def check_port(host: str, port: int) -> None:
    """A UsageError when the station could not listen on ``host:port`` (in use, a privileged port,
    an address not on this machine), found by binding it as uvicorn will (SO_REUSEADDR), before
    the banner is printed or a certificate made."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                reason = "is in use (another evp serve, or another program); choose another --port or stop that program"
            elif exc.errno in (errno.EACCES, errno.EPERM):
                reason = "needs administrator rights (ports below 1024); choose --port 8443 or another above 1023"
            else:
                reason = f"cannot be listened on ({(exc.strerror or str(exc)).lower()}); check --host"
            raise UsageError(f"--host {host} --port {port}: {reason}") from None


def serve(host: str, port: int, data_dir: Path, settings: Settings, db_url: str | None, mavlink_url: str | None, token: str, tls: bool, echo) -> None:
    import uvicorn

    check_port(host, port)
    writable_folder(data_dir, "--data")
    cert, key = ensure_certificate(data_dir / "tls") if tls else (None, None)
    station = Station(data_dir, settings, db_url, token, mavlink_url)
    station.link = link_info(host, port, tls, cert, token)
    echo(f"EVP base station: operator UI {station.link['operator_url']}  phone page {station.link['phone_url']}")
    echo(f"mobile stations connect to {station.link['mobile_ws_url']}; data in {data_dir.resolve()}")
    if cert:
        echo(f"TLS certificate {cert} (self-signed), SHA-256 {station.link['fingerprint_sha256']}")
    if not token:
        echo("no --token: any client that reaches this port may stream to the station and use the operator UI")
    config = uvicorn.Config(
        create_app(station),
        host=host,
        port=port,
        ssl_certfile=str(cert) if cert else None,
        ssl_keyfile=str(key) if key else None,
        ws_max_size=2 * MAX_IMAGE_BYTES,  # up to twice the limit still gets a specific 'oversized' error
        ws_ping_interval=5.0,
        ws_ping_timeout=10.0,
        log_level="warning",
        lifespan="on",
    )
    uvicorn.Server(config).run()
