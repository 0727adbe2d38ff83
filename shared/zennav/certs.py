"""Development credentials for the secure bus (`zennav certs DIR`): a CA, one certificate per service identity
(common name = the identity) and the zenoh user/password dictionary.

Files written to DIR (private keys and secrets mode 0600)::

    ca.pem, ca.key              the development CA (keep ca.key off the vehicle: it signs new identities)
    <identity>.pem, .key        certificate and key of each identity in IDENTITIES (ECDSA P-256, SAN = the name,
                                the router's also every --host name or address clients connect to)
    usrpwd.txt                  the router's dictionary (``transport/auth/usrpwd/dictionary_file``), user:password
    <identity>.secret           that identity's password (its user name is the identity)

The identities are the roles of deploy/secure/router.json5's access-control subjects; zennav.bus.open_config
turns DIR + identity into the session's TLS and user/password settings.
"""
from __future__ import annotations

import datetime as dt
import ipaddress
import os
import secrets
from collections.abc import Iterable
from pathlib import Path

#: Service identities: a certificate and a password each (the ACL subjects of deploy/secure/router.json5).
IDENTITIES = ("router", "ingest", "ins", "attitude", "predictor", "trainer", "monitor", "record", "launch")
DEFAULT_HOSTS = ("localhost", "127.0.0.1")


def _write(path: Path, data: bytes, private: bool) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.exists():
        path.unlink()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if private else 0o644)
    with os.fdopen(fd, "wb") as f:
        f.write(data)


def _san(names: Iterable[str]):
    from cryptography import x509

    out: list[x509.GeneralName] = []
    for n in dict.fromkeys(names):
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(n)))
        except ValueError:
            out.append(x509.DNSName(n))
    return x509.SubjectAlternativeName(out)


def make_certs(out_dir: str | os.PathLike, hosts: Iterable[str] = (), days: float = 365.0,
               identities: Iterable[str] = IDENTITIES) -> list[Path]:
    """Write a fresh CA, a certificate/key and a password per identity, and the dictionary, to out_dir.
    hosts: extra DNS names or IP addresses of the router (its certificate's SAN; localhost and 127.0.0.1
    always). days: validity. Returns the files written."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    out = Path(out_dir)
    now = dt.datetime.now(dt.timezone.utc) - dt.timedelta(minutes=5)
    until = now + dt.timedelta(days=days)
    pem = serialization.Encoding.PEM
    written: list[Path] = []

    def key_pem(key) -> bytes:
        return key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "zennav development CA")])
    ca_ski = x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key())
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(now).not_valid_after(until)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                       crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
          .add_extension(ca_ski, critical=False)
          .sign(ca_key, hashes.SHA256()))
    for name, data, private in (("ca.pem", ca.public_bytes(pem), False), ("ca.key", key_pem(ca_key), True)):
        _write(out / name, data, private)
        written.append(out / name)

    dictionary = []
    for ident in identities:
        key = ec.generate_private_key(ec.SECP256R1())
        names = [ident, *DEFAULT_HOSTS, *hosts] if ident == "router" else [ident]
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, ident)]))
                .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(now).not_valid_after(until)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                             data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                             crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .add_extension(_san(names), critical=False)
                .add_extension(x509.AuthorityKeyIdentifier.from_issuer_subject_key_identifier(ca_ski), critical=False)
                .sign(ca_key, hashes.SHA256()))
        password = secrets.token_hex(24)  # hex: never starts with "-", which a CLI would take for an option
        dictionary.append(f"{ident}:{password}\n")
        for fname, data, private in ((f"{ident}.pem", cert.public_bytes(pem), False),
                                     (f"{ident}.key", key_pem(key), True),
                                     (f"{ident}.secret", password.encode(), True)):
            _write(out / fname, data, private)
            written.append(out / fname)
    _write(out / "usrpwd.txt", "".join(dictionary).encode(), True)
    written.append(out / "usrpwd.txt")
    return written
