"""The station's self-signed TLS certificate, created on first start under the data folder.

Phones need HTTPS for the camera (getUserMedia) and a stable certificate to trust once, so it is
kept across restarts; its SHA-256 fingerprint is shown in the operator UI and printed at start.
It is a leaf (not a CA: trusting it cannot vouch for any other site) for server authentication
only, valid ``VALIDITY_DAYS``; a station replaces it at start when it has less than
``RENEW_DAYS`` left, or when it is an older one made as a CA.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import socket
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

# 90 days, as public certificate authorities issue now (Let's Encrypt; browsers cap leaves at 398):
# a stolen key is useful for weeks, not years. Renewed 14 days ahead, so a fingerprint pinned by a
# phone changes at a restart the operator chooses, never mid-flight.
VALIDITY_DAYS = 90
RENEW_DAYS = 14


def local_addresses() -> list[str]:
    """This machine's IPv4 addresses that a phone on the same network could reach."""
    addresses = {"127.0.0.1"}
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.connect(("192.0.2.1", 9))  # no packet is sent; picks the outgoing interface
            addresses.add(probe.getsockname()[0])
    except OSError:
        pass
    return sorted(addresses)


def _still_good(cert_path: Path, now: datetime.datetime) -> bool:
    """A leaf certificate with more than RENEW_DAYS to run."""
    certificate = x509.load_pem_x509_certificate(cert_path.read_bytes())
    try:
        is_ca = certificate.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    except x509.ExtensionNotFound:
        is_ca = False
    return not is_ca and certificate.not_valid_after_utc - now > datetime.timedelta(days=RENEW_DAYS)


def ensure_certificate(directory: Path) -> tuple[Path, Path]:
    """(certificate, key) PEM files: the ones kept here while still good, else new ones
    (VALIDITY_DAYS, localhost + this machine's addresses)."""
    directory.mkdir(parents=True, exist_ok=True)
    directory.chmod(0o700)
    cert_path, key_path = directory / "cert.pem", directory / "key.pem"
    now = datetime.datetime.now(datetime.UTC)
    if cert_path.is_file() and key_path.is_file() and _still_good(cert_path, now):
        return cert_path, key_path
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"EVP base station {socket.gethostname()}")])
    names: list[x509.GeneralName] = [x509.DNSName("localhost"), x509.DNSName(socket.gethostname())]
    names += [x509.IPAddress(ipaddress.ip_address(a)) for a in local_addresses()]
    certificate = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=1))
        .not_valid_after(now + datetime.timedelta(days=VALIDITY_DAYS))
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .sign(key, hashes.SHA256())
    )
    key_path.unlink(missing_ok=True)
    os.close(os.open(key_path, os.O_CREAT | os.O_WRONLY, 0o600))  # never readable by others, not even for a moment
    key_path.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()))
    cert_path.write_bytes(certificate.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path


def fingerprint(cert_path: Path) -> str:
    """SHA-256 fingerprint as browsers show it (colon-separated upper-case hex)."""
    certificate = x509.load_pem_x509_certificate(cert_path.read_bytes())
    return certificate.fingerprint(hashes.SHA256()).hex(":").upper()


def der_fingerprint(der: bytes) -> str:
    """The same fingerprint of a certificate as a peer presented it (DER bytes)."""
    return x509.load_der_x509_certificate(der).fingerprint(hashes.SHA256()).hex(":").upper()
