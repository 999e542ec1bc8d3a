"""A run's TLS identities: a CA of its own and one key and certificate per process.

``make_certs`` writes them (``rgtbus certs SCENARIO --out DIR``)::

    DIR/<unit>.crt, DIR/<unit>.key     one pair a unit, its name the certificate's common name
    DIR/run/ca.crt, DIR/run/ca.key     the run's CA (keep ca.key off the hosts)
    DIR/run/router.crt, router.key     the router's (common name "@router")
    DIR/run/watch.crt, watch.key       a watcher's (common name "@watch")

``@`` is never in a unit's name (rgtbus.bus.base), so no unit can hold the router's or the
watcher's identity, and the directory ``run`` cannot collide with a unit's files. Keys are ECDSA
P-256 (PKCS#8 PEM, mode 0600); every leaf certificate is for both TLS server and client (each
process of a mesh is both), with a DNS name and 127.0.0.1 as subject alternative names though
zenoh is told not to check names: who a process is, is its certificate's common name under the
run's CA, and the access control (rgtbus.bus.config) holds it to it.

``check_tls`` checks one process's files before anything opens: every problem is one line
naming the file and the reason.
"""

from __future__ import annotations

import dataclasses
import datetime
import ipaddress
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from rgtbus.errors import BadInput, IOFailure
from rgtbus.extras import require

if TYPE_CHECKING:
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric.types import PrivateKeyTypes

ROUTER = "@router"  # the router's identity (common name)
WATCH = "@watch"  # a watcher's
RUN_DIR = "run"  # DIR/run/: the run-wide files
CA = "ca"
DEFAULT_DAYS = 30
_FILES = {ROUTER: "router", WATCH: "watch"}  # DIR/run/<name>.crt of each run-wide identity
_CLOCK_SKEW = datetime.timedelta(minutes=5)  # certificates are valid from a little earlier


@dataclasses.dataclass(frozen=True)
class TlsFiles:
    """One process's TLS files: the run's CA certificate, its own certificate and key, and the
    identity (common name) they prove."""

    identity: str
    ca: Path
    cert: Path
    key: Path


@dataclasses.dataclass(frozen=True)
class CertSet:
    """What ``make_certs`` wrote: the CA's files, and each identity's pair (units, then
    ``@router`` and ``@watch``)."""

    directory: Path
    ca: Path
    ca_key: Path
    pairs: dict[str, tuple[Path, Path]]


def paths(directory: str | os.PathLike[str], identity: str) -> tuple[Path, Path]:
    """Where ``identity``'s certificate and key are in a run's directory: ``DIR/<unit>.crt``
    and ``.key``, ``DIR/run/router.*`` and ``DIR/run/watch.*``."""
    d = Path(directory)
    base = d / RUN_DIR / _FILES[identity] if identity in _FILES else d / identity
    return base.with_name(base.name + ".crt"), base.with_name(base.name + ".key")


def ca_paths(directory: str | os.PathLike[str]) -> tuple[Path, Path]:
    """The run's CA certificate and key: ``DIR/run/ca.crt``, ``DIR/run/ca.key``."""
    d = Path(directory) / RUN_DIR
    return d / f"{CA}.crt", d / f"{CA}.key"


def describe(identity: str) -> str:
    """``unit 'b'``, ``the router``, ``a watcher``: an identity in words."""
    if identity == ROUTER:
        return "the router"
    if identity == WATCH:
        return "a watcher"
    return f"unit {identity!r}"


def dns_name(identity: str) -> str:
    """A DNS-safe name for ``identity`` (its certificate's subject alternative name):
    lower case, anything but letters, digits and hyphens a hyphen, under ``rgtbus.invalid``."""
    label = re.sub(r"[^a-z0-9-]", "-", identity.lower()).strip("-")[:63] or "unit"
    return f"{label}.rgtbus.invalid"


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.UTC)


def _name(common_name: str) -> x509.Name:
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "rgtbus"),
            x509.NameAttribute(NameOID.COMMON_NAME, common_name),
        ]
    )


def _key_usage(**allowed: bool) -> x509.KeyUsage:
    """A key usage extension: the usages named ``allowed``, no other."""
    from cryptography import x509

    usages = (
        "digital_signature", "content_commitment", "key_encipherment", "data_encipherment",
        "key_agreement", "key_cert_sign", "crl_sign", "encipher_only", "decipher_only",
    )  # fmt: skip
    return x509.KeyUsage(**{u: allowed.get(u, False) for u in usages})


def _ca_certificate(
    label: str, key: PrivateKeyTypes, days: float, now: datetime.datetime
) -> x509.Certificate:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec

    assert isinstance(key, ec.EllipticCurvePrivateKey)
    public = key.public_key()
    name = _name(f"rgtbus run CA {label}")
    return (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(public)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - _CLOCK_SKEW)
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(_key_usage(key_cert_sign=True, crl_sign=True), critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public), critical=False)
        .sign(key, hashes.SHA256())
    )


def _leaf_certificate(
    identity: str,
    key: PrivateKeyTypes,
    ca: x509.Certificate,
    ca_key: PrivateKeyTypes,
    days: float,
    now: datetime.datetime,
) -> x509.Certificate:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID

    assert isinstance(key, ec.EllipticCurvePrivateKey)
    assert isinstance(ca_key, ec.EllipticCurvePrivateKey)
    public = key.public_key()
    return (
        x509.CertificateBuilder()
        .subject_name(_name(identity))
        .issuer_name(ca.subject)
        .public_key(public)
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - _CLOCK_SKEW)
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(_key_usage(digital_signature=True), critical=True)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .add_extension(
            x509.SubjectAlternativeName(
                [
                    x509.DNSName(dns_name(identity)),
                    x509.IPAddress(ipaddress.ip_address("127.0.0.1")),
                ]
            ),
            critical=False,
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(public), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
            critical=False,
        )
        .sign(ca_key, hashes.SHA256())
    )


def _new_key() -> PrivateKeyTypes:
    from cryptography.hazmat.primitives.asymmetric import ec

    return ec.generate_private_key(ec.SECP256R1())


def _key_pem(key: PrivateKeyTypes) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _cert_pem(cert: x509.Certificate) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return cert.public_bytes(serialization.Encoding.PEM)


def _write(path: Path, data: bytes, mode: int) -> None:
    """``data`` into ``path``, created with ``mode`` (an existing file gets it too)."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
        try:
            os.fchmod(fd, mode)
            os.write(fd, data)
        finally:
            os.close(fd)
    except OSError as e:
        raise IOFailure(f"{path}: cannot write: {e.strerror or e}") from None


def make_certs(
    units: Sequence[str],
    out: str | os.PathLike[str],
    *,
    days: float = DEFAULT_DAYS,
    label: str = "",
    force: bool = False,
) -> CertSet:
    """A run's CA and one key and certificate per unit of ``units`` and for ``@router`` and
    ``@watch``, written under ``out`` (the layout in the module docstring), valid for ``days``
    days from now; ``label`` names the run in the CA's common name. Files already there are
    refused (one line naming the first) unless ``force``. RgtbusError for a bad unit name or
    ``days``, or a directory that cannot be written."""
    from rgtbus.bus.base import check_name

    require("cryptography", "rgtbus certs")

    if isinstance(days, bool) or not isinstance(days, int | float) or not 0 < days <= 36500:
        raise BadInput(f"--days {days!r}: must be a number of days from 1 to 36500")
    names = list(units)
    if not names:
        raise BadInput("certs: no unit to make a certificate for")
    for u in names:
        check_name("unit name", u)
    if len(set(names)) != len(names):
        raise BadInput(f"certs: a unit named twice in {names}")
    directory = Path(out)
    ca_crt, ca_key_path = ca_paths(directory)
    identities = [*names, ROUTER, WATCH]
    targets = [ca_crt, ca_key_path, *(p for i in identities for p in paths(directory, i))]
    if not force:
        for path in targets:
            if path.exists():
                raise BadInput(
                    f"{path}: exists (give --force to replace the run's certificates)"
                )
    try:
        (directory / RUN_DIR).mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise IOFailure(f"{directory}: cannot create: {e.strerror or e}") from None
    now = _now()
    ca_key = _new_key()
    ca = _ca_certificate(label or directory.name, ca_key, days, now)
    _write(ca_key_path, _key_pem(ca_key), 0o600)
    _write(ca_crt, _cert_pem(ca), 0o644)
    pairs: dict[str, tuple[Path, Path]] = {}
    for identity in identities:
        key = _new_key()
        cert = _leaf_certificate(identity, key, ca, ca_key, days, now)
        crt_path, key_path = paths(directory, identity)
        _write(key_path, _key_pem(key), 0o600)
        _write(crt_path, _cert_pem(cert), 0o644)
        pairs[identity] = (crt_path, key_path)
    return CertSet(directory, ca_crt, ca_key_path, pairs)


def _read(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise IOFailure(f"{path}: missing ({what})") from None
    except OSError as e:
        raise IOFailure(f"{path}: cannot read ({e.strerror or e})") from None


def _load_cert(path: Path, what: str) -> x509.Certificate:
    from cryptography import x509

    raw = _read(path, what)
    try:
        return x509.load_pem_x509_certificate(raw)
    except ValueError:
        raise BadInput(f"{path}: not a PEM certificate (malformed)") from None


def _common_name(cert: x509.Certificate) -> str | None:
    from cryptography.x509.oid import NameOID

    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if len(names) == 1 else None


def _is_ca(cert: x509.Certificate) -> bool:
    from cryptography import x509

    try:
        return bool(cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca)
    except x509.ExtensionNotFound:
        return False


def _check_validity(cert: x509.Certificate, path: Path, now: datetime.datetime) -> None:
    if now < cert.not_valid_before_utc:
        raise BadInput(
            f"{path}: not valid before {cert.not_valid_before_utc:%Y-%m-%d %H:%M:%S} UTC"
        )
    if now > cert.not_valid_after_utc:
        raise BadInput(f"{path}: expired on {cert.not_valid_after_utc:%Y-%m-%d %H:%M:%S} UTC")


def _signed_by(cert: x509.Certificate, ca: x509.Certificate) -> bool:
    from cryptography.exceptions import InvalidSignature

    try:
        cert.verify_directly_issued_by(ca)
    except (ValueError, TypeError, InvalidSignature):
        return False
    return True


def _check_key(key_path: Path, cert: x509.Certificate, cert_path: Path) -> None:
    from cryptography.exceptions import UnsupportedAlgorithm
    from cryptography.hazmat.primitives import serialization

    raw = _read(key_path, f"the key of {cert_path}")
    try:
        key = serialization.load_pem_private_key(raw, password=None)
    except TypeError:
        raise BadInput(
            f"{key_path}: an encrypted key (zenoh needs it unencrypted, mode 0600)"
        ) from None
    except (ValueError, UnsupportedAlgorithm):
        raise BadInput(f"{key_path}: not a PEM private key (malformed)") from None
    public = serialization.PublicFormat.SubjectPublicKeyInfo
    der = serialization.Encoding.DER
    if key.public_key().public_bytes(der, public) != cert.public_key().public_bytes(der, public):
        raise BadInput(f"{key_path} is not the key of {cert_path}")


def check_tls(directory: str | os.PathLike[str], identity: str) -> TlsFiles:
    """The TLS files of ``identity`` (a unit's name, ``@router`` or ``@watch``) in a run's
    directory (``make_certs``), checked: the directory, the run's CA certificate and the
    identity's certificate and key are there and well-formed, both certificates valid now, the
    identity's signed by the run's CA with ``identity`` as its common name, and the key its
    certificate's. Anything else: RgtbusError, one line naming the file and the reason."""
    require("cryptography", f"--tls {os.fspath(directory)}")
    d = Path(directory)
    if not d.is_dir():
        raise BadInput(
            f"{d}: no such directory of TLS identities (rgtbus certs SCENARIO --out {d} makes one)"
        )
    now = _now()
    ca_path = ca_paths(d)[0]
    ca = _load_cert(ca_path, "the run's CA certificate")
    if not _is_ca(ca):
        raise BadInput(f"{ca_path}: not a CA certificate")
    _check_validity(ca, ca_path, now)
    cert_path, key_path = paths(d, identity)
    cert = _load_cert(cert_path, f"the certificate of {describe(identity)}")
    if not _signed_by(cert, ca):
        raise BadInput(
            f"{cert_path}: not signed by the run's CA {ca_path} (a foreign certificate)"
        )
    _check_validity(cert, cert_path, now)
    if _is_ca(cert):
        raise BadInput(f"{cert_path}: a CA certificate, not a process's")
    holder = _common_name(cert)
    if holder != identity:
        said = "no single common name" if holder is None else f"the certificate of {holder!r}"
        raise BadInput(f"{cert_path} is {said}, not of {describe(identity)}")
    _check_key(key_path, cert, cert_path)
    return TlsFiles(identity, ca_path, cert_path, key_path)


def process_tls(directory: str | os.PathLike[str], units: Sequence[str]) -> TlsFiles:
    """The TLS files of a process running ``units`` (``check_tls`` of its one unit): a process
    proves one identity, so with TLS it runs exactly one unit (RgtbusError otherwise)."""
    names = list(units)
    if len(names) != 1:
        raise BadInput(
            f"--tls {os.fspath(directory)}: {len(names)} units in one process "
            f"({', '.join(names) or 'none'}): a process proves one identity (one "
            "certificate), so over TLS each unit runs in a process of its own"
        )
    return check_tls(directory, names[0])
