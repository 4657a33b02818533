# DDS Security for the ROS 2 face: an SROS2 enclave's files checked, and Cyclone DDS's plugins set.
from __future__ import annotations

import ssl
import time
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

#: the files of an SROS2 enclave (ros2 security create_enclave), as the ROS 2 middlewares read
CERTIFICATES = ("cert.pem", "identity_ca.cert.pem", "permissions_ca.cert.pem")
SIGNED = ("governance.p7s", "permissions.p7s")
KEY = "key.pem"
#: Cyclone DDS's plugin libraries and their entry points (0.10: auth, access control, crypto)
PLUGINS = {"Authentication": ("dds_security_auth", "authentication"),
           "AccessControl": ("dds_security_ac", "access_control"),
           "Cryptographic": ("dds_security_crypto", "crypto")}
#: where Debian installs the plugins, beside libddsc
PLUGIN_DIRS = ("libddsc0debian", ".")


class SecurityError(ValueError):
    """An enclave file is missing, unreadable, not what it should be, or out of its validity."""


@dataclass(frozen=True)
class Enclave:
    """The checked files of one SROS2 enclave directory."""

    path: Path

    def file(self, name: str) -> Path:
        return self.path / name


def enclave(path: str, now: float | None = None) -> Enclave:
    """The enclave at ``path``, every file checked; a SecurityError names the first bad one."""
    root = Path(path).expanduser()
    if not root.is_dir():
        raise SecurityError(f"{root}: not a directory (an SROS2 enclave, docs/ros2.md)")
    for name in (*CERTIFICATES, KEY, *SIGNED):
        text = _read(root / name)
        if name in CERTIFICATES:
            _check_certificate(root / name, time.time() if now is None else now)
        elif name == KEY and "PRIVATE KEY-----" not in text:
            raise SecurityError(f"{root / name}: not a PEM private key")
        elif name in SIGNED and "MIME-Version" not in text and "PKCS7" not in text:
            raise SecurityError(f"{root / name}: not a signed (S/MIME) document")
    return Enclave(root)


def _read(path: Path) -> str:
    try:
        text = path.read_text(errors="replace")
    except FileNotFoundError:
        raise SecurityError(f"{path}: missing") from None
    except OSError as exc:
        raise SecurityError(f"{path}: cannot be read ({exc.strerror})") from None
    if not text.strip():
        raise SecurityError(f"{path}: empty")
    return text


def _check_certificate(path: Path, now: float) -> None:
    try:
        decoded = ssl._ssl._test_decode_cert(str(path))  # type: ignore[attr-defined]
    except (ssl.SSLError, OSError) as exc:
        raise SecurityError(f"{path}: not a PEM certificate ({exc})") from None
    not_before = ssl.cert_time_to_seconds(decoded["notBefore"])
    not_after = ssl.cert_time_to_seconds(decoded["notAfter"])
    if now > not_after:
        raise SecurityError(f"{path}: expired on {decoded['notAfter']}")
    if now < not_before:
        raise SecurityError(f"{path}: not valid before {decoded['notBefore']}")


def plugin_path(name: str, libddsc: Path | None) -> str:
    """The plugin library's file beside ``libddsc`` (Debian's layout), else its bare name
    for the dynamic loader to find."""
    if libddsc is not None:
        for folder in PLUGIN_DIRS:
            candidate = (libddsc.parent / folder / f"lib{name}.so").resolve()
            if candidate.exists():
                return str(candidate)
    return name


def cyclone_xml(found: Enclave, libddsc: Path | None) -> str:
    """Cyclone DDS's <Security> element for ``found``: identity, permissions, governance."""
    def uri(name: str) -> str:
        return f"file:{found.file(name)}"

    def library(kind: str) -> str:
        name, entry = PLUGINS[kind]
        return (f"<Library path={quoteattr(plugin_path(name, libddsc))} "
                f"initFunction='init_{entry}' finalizeFunction='finalize_{entry}'/>")

    return ("<Security><Authentication>" + library("Authentication")
            + f"<IdentityCA>{uri('identity_ca.cert.pem')}</IdentityCA>"
            + f"<IdentityCertificate>{uri('cert.pem')}</IdentityCertificate>"
            + f"<PrivateKey>{uri(KEY)}</PrivateKey></Authentication>"
            + "<AccessControl>" + library("AccessControl")
            + f"<PermissionsCA>{uri('permissions_ca.cert.pem')}</PermissionsCA>"
            + f"<Governance>{uri('governance.p7s')}</Governance>"
            + f"<Permissions>{uri('permissions.p7s')}</Permissions></AccessControl>"
            + "<Cryptographic>" + library("Cryptographic") + "</Cryptographic></Security>")
