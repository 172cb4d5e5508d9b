"""Certificates made for a test: a CA, and certificates it signs (cryptography; nothing fetched, nothing kept)."""

from __future__ import annotations

import datetime
import ipaddress
import json
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


class Authority:
    """A certificate authority written to ``folder``; :meth:`issue` writes a key and a certificate it signs."""

    def __init__(self, folder: Path, name: str = "asm-test-ca") -> None:
        self.folder = folder
        self.key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        self.cert = (
            x509.CertificateBuilder()
            .subject_name(_name(name))
            .issuer_name(_name(name))
            .public_key(self.key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .sign(self.key, hashes.SHA256())
        )
        self.path = folder / f"{name}.pem"
        self.path.write_bytes(self.cert.public_bytes(serialization.Encoding.PEM))

    def issue(self, common_name: str, addresses: tuple[str, ...] = ()) -> tuple[Path, Path]:
        """(key file, certificate file) for ``common_name``, valid for localhost, 127.0.0.1 and ``addresses``."""
        key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.UTC)
        names = [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
                 *(x509.IPAddress(ipaddress.ip_address(a)) for a in addresses)]  # fmt: skip
        cert = (
            x509.CertificateBuilder()
            .subject_name(_name(common_name))
            .issuer_name(self.cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=1))
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .sign(self.key, hashes.SHA256())
        )
        key_path, cert_path = self.folder / f"{common_name}.key", self.folder / f"{common_name}.pem"
        key_path.write_bytes(
            key.private_bytes(
                serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
            )
        )
        cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        return key_path, cert_path


TEMPLATE = Path(__file__).resolve().parent.parent / "docs" / "zenoh-secure.json5"
"""The documented secure Zenoh configuration (docs/security.md) that secure_config fills in."""


def secure_config(
    folder: Path,
    authority: Authority,
    common_name: str,
    addresses: tuple[str, ...] = (),
    operators: tuple[str, ...] = (),
) -> str:
    """The documented template, filled in for a certificate ``common_name`` issued by ``authority`` (valid for
    ``addresses`` too); ``operators``: more common names the access control allows."""
    key, cert = authority.issue(common_name, addresses)
    text = TEMPLATE.read_text().replace("ROOT_CA", str(authority.path))
    text = text.replace("PRIVATE_KEY", str(key)).replace("CERTIFICATE", str(cert))
    if operators:
        text = text.replace('cert_common_names: ["robot", "operator"]',
                            f"cert_common_names: {json.dumps(['robot', 'operator', *operators])}")  # fmt: skip
    path = folder / f"{common_name}.json5"
    path.write_text(text)
    return str(path)
