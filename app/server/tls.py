"""HTTPS for `semanticxr serve --https`: a phone reaches the server by its LAN address, and
WebXR needs a secure context.

- `machine_names`: what this machine is reached by (localhost, the loopback addresses, the
  hostname and every non-loopback address of its interfaces).
- `self_signed_certificate`: a certificate for those names and its key, made once in a
  folder (the data dir's `tls/`, 0700; files 0600) and reused while it still names exactly
  them, matches its key and is not about to expire; otherwise made anew.
- `certificate_names`: the names a certificate holds (the Host names the server answers to).
- `page_address`: the address a phone on the LAN most likely reaches, for the start-up URL.

No server here: `app/server/runner.py` hands the files to uvicorn. Keys never reach a log.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import socket
import ssl
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from app.server.edges import LOOPBACK_HOSTS, WILDCARD_BINDS

TLS_DIR = "tls"
"""The folder of data_dir that holds the self-signed certificate and its key."""
CERT_FILE = "cert.pem"
KEY_FILE = "key.pem"
VALIDITY_DAYS = 397
"""How long a made certificate is valid: browsers refuse server certificates valid for more
than 398 days."""
RENEW_BEFORE_DAYS = 30
"""A certificate that expires within this many days is made anew at start."""


class TlsError(ValueError):
    """A certificate or key that cannot be used; the message names the file."""


@dataclass(frozen=True)
class Certificate:
    """A certificate and its key on disk, and the names it holds."""

    cert_path: Path
    key_path: Path
    names: tuple[str, ...]
    """DNS names and IP addresses, as `certificate_names` reads them."""
    made: bool
    """Made by this call (False: an existing one reused, or the operator's)."""
    self_signed: bool
    """This machine's own (browsers warn about it once); False: the operator's."""


def interface_addresses() -> list[str]:
    """Every IPv4 and IPv6 address of this machine's network interfaces (loopback included)."""
    import psutil

    return [
        address.address
        for addresses in psutil.net_if_addrs().values()
        for address in addresses
        if address.family in (socket.AF_INET, socket.AF_INET6)
    ]


def machine_names(hostname: str, addresses: Iterable[str]) -> list[str]:
    """localhost, 127.0.0.1, ::1, `hostname` and every non-loopback address of `addresses`,
    once each, in that order. IPv6 link-local addresses (fe80::/10) are left out: a browser's
    URL cannot carry the zone they need."""
    names = [*LOOPBACK_HOSTS, hostname.strip().lower()]
    for text in addresses:
        address = ipaddress.ip_address(text.split("%", 1)[0])
        if address.is_loopback or (address.version == 6 and address.is_link_local):
            continue
        names.append(str(address))
    return list(dict.fromkeys(name for name in names if name))


def this_machine_names() -> list[str]:
    """`machine_names` of this host, now."""
    return machine_names(socket.gethostname(), interface_addresses())


def page_address(names: Sequence[str]) -> str | None:
    """Of `names`, the address a phone on the same network most likely reaches: a private
    IPv4 address, else another non-loopback IPv4, else a non-loopback IPv6; None if none."""
    addresses = [a for a in map(_address_or_none, names) if a is not None and not a.is_loopback]
    ranked = sorted(addresses, key=lambda a: (a.version, not a.is_private, a.is_link_local))
    return str(ranked[0]) if ranked else None


def page_host(bind_host: str, names: Sequence[str]) -> str:
    """The host of the start-up URL: the bind address when it is one, else (a wildcard bind)
    `page_address(names)`, else the first name that is neither loopback nor a wildcard."""
    if bind_host not in WILDCARD_BINDS:
        return bind_host
    others = [n for n in names if n not in LOOPBACK_HOSTS and not n.startswith("*")]
    return page_address(names) or (others[0] if others else "localhost")


def url_host(host: str) -> str:
    """`host` as a URL writes it: an IPv6 address in brackets."""
    address = _address_or_none(host)
    return f"[{host}]" if address is not None and address.version == 6 else host


def self_signed_certificate(
    directory: Path, names: Sequence[str], now: datetime.datetime | None = None
) -> Certificate:
    """The certificate for exactly `names` in `directory` (made there if it is missing,
    names other names, does not match its key, cannot be read or expires within
    RENEW_BEFORE_DAYS). The folder is 0700 and both files 0600."""
    now = now or datetime.datetime.now(datetime.UTC)
    directory.mkdir(parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    cert_path, key_path = directory / CERT_FILE, directory / KEY_FILE
    wanted = _name_set(names)
    try:
        certificate = x509.load_pem_x509_certificate(cert_path.read_bytes())
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
        reusable = (
            _name_set(_names_of(certificate)) == wanted
            and key.public_key() == certificate.public_key()
            and certificate.not_valid_after_utc - now > datetime.timedelta(days=RENEW_BEFORE_DAYS)
        )
    except (OSError, ValueError, TypeError, x509.ExtensionNotFound):
        reusable = False
    if reusable:
        for path in (cert_path, key_path):
            os.chmod(path, 0o600)
        names_held = tuple(_names_of(certificate))
        return Certificate(cert_path, key_path, names_held, made=False, self_signed=True)
    cert_pem, key_pem = make_self_signed(names, now)
    # The key first: a certificate beside a key it does not match is made anew next time.
    _write_private(key_path, key_pem)
    _write_private(cert_path, cert_pem)
    names_held = tuple(certificate_names(cert_pem))
    return Certificate(cert_path, key_path, names_held, made=True, self_signed=True)


def given_certificate(cert_path: Path, key_path: Path) -> Certificate:
    """An operator's certificate and key (--tls-cert, --tls-key), loaded as the server will
    load them, so that a wrong file stops the start with its name; TlsError otherwise."""
    try:
        names = certificate_names(cert_path.read_bytes())
    except OSError as exc:
        raise TlsError(f"--tls-cert: cannot read {cert_path}: {exc.strerror}") from None
    except TlsError as exc:
        raise TlsError(f"--tls-cert: {cert_path} is {exc}") from None
    try:
        # the callback keeps OpenSSL from prompting on the terminal for an encrypted key
        ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(
            cert_path, key_path, password=lambda: b""
        )
    except OSError as exc:
        reason = getattr(exc, "reason", None) or exc.strerror or exc
        raise TlsError(
            f"--tls-key: {key_path} is not a readable, unencrypted PEM key of {cert_path} "
            f"({reason})"
        ) from None
    return Certificate(cert_path, key_path, tuple(names), made=False, self_signed=False)


def make_self_signed(names: Sequence[str], now: datetime.datetime) -> tuple[bytes, bytes]:
    """(certificate PEM, key PEM): an ECDSA P-256 key and a self-signed server certificate
    for `names` (DNS names and IP addresses), valid from an hour before `now` (a phone's
    clock may lag) for VALIDITY_DAYS."""
    if not names:
        raise ValueError("a certificate needs at least one name")
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "SemanticXR (self-signed)"),
            x509.NameAttribute(NameOID.COMMON_NAME, _common_name(names)),
        ]
    )
    public_key_id = x509.SubjectKeyIdentifier.from_public_key(key.public_key())
    certificate = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(hours=1))
        .not_valid_after(now + datetime.timedelta(days=VALIDITY_DAYS))
        .add_extension(x509.SubjectAlternativeName(_general_names(names)), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=False,
                crl_sign=False,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(public_key_id, critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(public_key_id),
            critical=False,
        )
        .sign(key, hashes.SHA256())
    )
    key_pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    return certificate.public_bytes(serialization.Encoding.PEM), key_pem


def certificate_names(cert_pem: bytes) -> list[str]:
    """The DNS names and IP addresses of a PEM certificate's subjectAltName (its common name
    when it has none, as old certificates do); TlsError if it is not a certificate."""
    try:
        certificate = x509.load_pem_x509_certificate(cert_pem)
    except ValueError as exc:
        raise TlsError(f"not a PEM certificate ({exc})") from None
    return _names_of(certificate)


def _names_of(certificate: x509.Certificate) -> list[str]:
    try:
        alternative = certificate.extensions.get_extension_for_class(x509.SubjectAlternativeName)
    except x509.ExtensionNotFound:
        common = certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
        return [str(common[0].value).lower()] if common else []
    dns = alternative.value.get_values_for_type(x509.DNSName)
    ips = alternative.value.get_values_for_type(x509.IPAddress)
    return [name.lower() for name in dns] + [str(ip) for ip in ips]


def _general_names(names: Sequence[str]) -> list[x509.GeneralName]:
    general: list[x509.GeneralName] = []
    for name in names:
        address = _address_or_none(name)
        general.append(x509.IPAddress(address) if address else x509.DNSName(name.lower()))
    return general


def _common_name(names: Sequence[str]) -> str:
    """The first DNS name that is not localhost (the hostname), else the first name; at most
    64 characters, X.509's limit."""
    hosts = [n for n in names if _address_or_none(n) is None and n != "localhost"]
    return (hosts or list(names))[0][:64]


def _name_set(names: Iterable[str]) -> set[str]:
    return {str(_address_or_none(n) or n.lower()) for n in names}


def _address_or_none(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(text)
    except ValueError:
        return None


def _write_private(path: Path, data: bytes) -> None:
    """Write `data` to `path` readable by its owner only (0600 from the start, never wider),
    replacing the old file whole."""
    partial = path.with_name(path.name + ".part")
    partial.unlink(missing_ok=True)
    fd = os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(partial, 0o600)  # a umask cannot widen it, but make it explicit
    os.replace(partial, path)
