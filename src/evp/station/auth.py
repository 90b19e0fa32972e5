"""Who may do what at the station: per-device credentials from one-time pairing codes.

A mobile station pairs once: the operator's page shows a QR code holding a one-time code; the
phone trades it (``POST /api/pair``) for its own credential and keeps it. The operator logs in the
same way with an operator code (``evp serve`` prints a login link, ``evp pairing-code`` makes
more). A credential is ``<id>.<secret>``: the id is public (it owns sessions, it is what logs
name), the secret is 32 random bytes of which the database keeps only the SHA-256 (a fast hash is
enough for a secret nobody can guess; passwords would need a slow one). Pairing codes are stored
hashed too and are void once used or after ``station.pairing_code_ttl_s``.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass

from sqlalchemy import insert, select, update
from sqlalchemy.engine import Engine

from evp.station.store import credentials, pairing_codes

ROLES = ("mobile", "operator")


@dataclass(frozen=True)
class Identity:
    """Who a request or a link is: ``credential_id`` "" is the development mode's anybody."""

    credential_id: str
    role: str  # mobile | operator | dev (both)
    name: str = ""

    def may(self, role: str) -> bool:
        return self.role in (role, "dev")


DEV = Identity("", "dev", "dev_loopback")


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


class PairingError(ValueError):
    """A pairing code that is unknown, used, or expired (one message for all three: no oracle)."""


class Credentials:
    """Credentials and pairing codes in the station's database (direct, synchronous: rare calls
    that must be visible at once; call from a worker thread in async code)."""

    def __init__(self, engine: Engine, clock: Callable[[], float] = time.time):
        self.engine = engine
        self.clock = clock

    def issue_code(self, role: str, ttl_s: float) -> str:
        if role not in ROLES:
            raise ValueError(f"role {role!r}: choose {' or '.join(ROLES)}")
        code = secrets.token_urlsafe(16)
        now = self.clock()
        with self.engine.begin() as connection:
            connection.execute(insert(pairing_codes), [{"code_sha256": _sha256(code), "role": role, "created_at": now, "expires_at": now + ttl_s}])
        return code

    def pair(self, code: str, name: str) -> tuple[Identity, str]:
        """Use up ``code`` (atomically: two devices racing with one code get one credential) and
        return the new identity and its credential, which is shown this once and never stored."""
        now, digest = self.clock(), _sha256(code)
        unused = (pairing_codes.c.code_sha256 == digest) & pairing_codes.c.used_at.is_(None) & (pairing_codes.c.expires_at > now)
        with self.engine.begin() as connection:
            if connection.execute(update(pairing_codes).where(unused).values(used_at=now)).rowcount != 1:
                raise PairingError("unknown, used or expired pairing code")
            role = connection.execute(select(pairing_codes.c.role).where(pairing_codes.c.code_sha256 == digest)).scalar_one()
            identity = Identity(secrets.token_hex(6), role, name[:128])
            secret = secrets.token_urlsafe(32)
            row = {"id": identity.credential_id, "role": role, "name": identity.name, "secret_sha256": _sha256(secret), "created_at": now}
            connection.execute(insert(credentials), [row])
        return identity, f"{identity.credential_id}.{secret}"

    def identify(self, credential: str) -> Identity | None:
        """The identity a credential stands for; None for anything else (revoked, malformed, wrong)."""
        credential_id, _, secret = credential.partition(".")
        if not credential_id or not secret:
            return None
        with self.engine.connect() as connection:
            row = connection.execute(select(credentials).where(credentials.c.id == credential_id)).mappings().first()
        if row is None or row["revoked_at"] is not None or not hmac.compare_digest(row["secret_sha256"], _sha256(secret)):
            return None
        return Identity(row["id"], row["role"], row["name"])

    def revoke(self, credential_id: str) -> bool:
        with self.engine.begin() as connection:
            query = update(credentials).where((credentials.c.id == credential_id) & credentials.c.revoked_at.is_(None)).values(revoked_at=self.clock())
            return connection.execute(query).rowcount == 1

    def listing(self) -> list[dict]:
        """Every credential, without its hash."""
        columns = [c for c in credentials.c if c.name != "secret_sha256"]
        with self.engine.connect() as connection:
            return [dict(r) for r in connection.execute(select(*columns).order_by(credentials.c.created_at)).mappings()]
