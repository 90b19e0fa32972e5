"""``evp serve``: the station on uvicorn, over TLS with its own certificate unless told otherwise."""

from __future__ import annotations

import errno
import ipaddress
import socket
from pathlib import Path

from evp.config import Settings
from evp.errors import UsageError
from evp.io.output_paths import writable_folder
from evp.station.base_station import Station
from evp.station.limits import dead_link_aware_websocket_protocol, guarded_http_protocol, limit_logs
from evp.station.protocol import MAX_IMAGE_BYTES
from evp.station.server import create_app
from evp.station.tls import ensure_certificate, fingerprint, local_addresses


def link_info(host: str, port: int, tls: bool, cert: Path | None, dev_loopback: bool) -> dict:
    """The addresses an operator and a phone use, and the certificate to trust. No secrets: the
    pairing codes travel in URL fragments made on demand (``POST /api/pairing``)."""
    scheme = "https" if tls else "http"
    reachable = host if host not in ("0.0.0.0", "::", "") else next((a for a in local_addresses() if a != "127.0.0.1"), "127.0.0.1")
    base = f"{scheme}://{reachable}:{port}"
    return {
        "host": host,
        "port": port,
        "tls": tls,
        "base_url": base,
        "operator_url": f"{base}/",
        "phone_url": f"{base}/phone",
        "mobile_ws_url": f"{'wss' if tls else 'ws'}://{reachable}:{port}/ws/mobile",
        "fingerprint_sha256": fingerprint(cert) if cert else None,
        "access": "dev_loopback: no credentials" if dev_loopback else "per-device pairing",
    }


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


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


def serve(host: str, port: int, data_dir: Path, settings: Settings, db_url: str | None, mavlink_url: str | None, tls: bool, echo) -> None:
    import uvicorn

    limits = settings.station
    if limits.dev_loopback and not is_loopback(host):
        raise UsageError(f"--dev-loopback (no credentials) listens on loopback only, not on {host!r}: use --host 127.0.0.1")
    check_port(host, port)
    if limits.background_image and not Path(limits.background_image).is_file():
        raise UsageError(f"station.background_image {limits.background_image!r}: no such file")
    writable_folder(data_dir, "--data")
    data_dir.mkdir(parents=True, exist_ok=True)
    cert, key = ensure_certificate(data_dir / "tls") if tls else (None, None)
    station = Station(data_dir, settings, db_url, mavlink_url)
    station.link = link_info(host, port, tls, cert, limits.dev_loopback)
    echo(f"EVP base station: operator UI {station.link['operator_url']}  phone page {station.link['phone_url']}")
    echo(f"mobile stations connect to {station.link['mobile_ws_url']}; data in {data_dir.resolve()}")
    if cert:
        echo(f"TLS certificate {cert} (self-signed), SHA-256 {station.link['fingerprint_sha256']}")
    if limits.dev_loopback:
        echo("DEVELOPMENT MODE (--dev-loopback): no credentials; anything on this computer may stream to the station and operate it")
    else:
        code = station.credentials.issue_code("operator", limits.pairing_code_ttl_s)
        minutes = limits.pairing_code_ttl_s / 60
        echo(f"operator login (one use, valid {minutes:g} min; `evp pairing-code --role operator` makes another): {station.link['base_url']}/#pair={code}")
        echo("phones pair from the operator page (Pair a phone: a one-time QR code)")
    limit_logs(limits)
    config = uvicorn.Config(
        create_app(station),
        host=host,
        port=port,
        ssl_certfile=str(cert) if cert else None,
        ssl_keyfile=str(key) if key else None,
        http=guarded_http_protocol(limits),
        ws=dead_link_aware_websocket_protocol(limits.heartbeat_timeout_s),  # a dead link (no close frame) is seen within heartbeat_timeout_s
        ws_max_size=2 * MAX_IMAGE_BYTES,  # up to twice the limit still gets a specific 'oversized' error
        ws_ping_interval=limits.heartbeat_interval_s,
        ws_ping_timeout=limits.heartbeat_timeout_s - limits.heartbeat_interval_s,
        log_level="warning",
        lifespan="on",
    )
    uvicorn.Server(config).run()
