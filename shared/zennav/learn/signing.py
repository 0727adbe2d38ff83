"""Ed25519 signatures of parameter sets (ARCHITECTURE.md section 3): the trainer signs, the predictor verifies with
the public key only. The `cryptography` library (imported when a key is loaded, so `zennav --help` stays fast).

What is signed: the set's checksum (zennav.learn.paramset.checksum, the SHA-256 of every other field of the set,
verified by paramset.validate before the signature) behind a domain prefix, so a signature binds name, version,
kind, arrays, normalisation and metrics, and cannot be replayed as a signature of anything else.
Wire form: "ed25519:<key id>:<signature, 64 bytes hex>"; key id: the first 8 bytes (hex) of the SHA-256 of the raw
public key, so a set signed by another key is told apart from a forged one in the logs.

Key files (``generate``): PEM, the private key PKCS#8 unencrypted (mode 0600; the trainer's host only), the public
key SubjectPublicKeyInfo (every predictor).
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

PREFIX = "ed25519"
_DOMAIN = b"zennav.paramset signature v1\0"
PRIVATE_NAME, PUBLIC_NAME = "paramset-signing.pem", "paramset-verify.pem"


def _key_id(raw_public: bytes) -> str:
    return hashlib.sha256(raw_public).hexdigest()[:16]


def _raw(public_key) -> bytes:
    from cryptography.hazmat.primitives.serialization import Encoding, PublicFormat

    return public_key.public_bytes(Encoding.Raw, PublicFormat.Raw)


def _read(path, what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as e:
        raise ValueError(f"{what} {path}: {e.strerror or e}") from None


class Signer:
    """The trainer's private key: ``sign(checksum)`` -> the wire signature."""

    def __init__(self, private_key):
        self._key = private_key
        self.key_id = _key_id(_raw(private_key.public_key()))

    @classmethod
    def from_file(cls, path) -> Signer:
        """Load a PEM Ed25519 private key; ValueError (one line) when it is missing or not one."""
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
        from cryptography.hazmat.primitives.serialization import load_pem_private_key

        pem = _read(path, "signing key")
        try:
            key = load_pem_private_key(pem, password=None)
        except (ValueError, TypeError) as e:
            raise ValueError(f"signing key {path}: not an unencrypted PEM private key ({e})") from None
        if not isinstance(key, Ed25519PrivateKey):
            raise ValueError(f"signing key {path}: {type(key).__name__}, not an Ed25519 private key")
        return cls(key)

    def sign(self, checksum: str) -> str:
        return f"{PREFIX}:{self.key_id}:{self._key.sign(_DOMAIN + checksum.encode()).hex()}"


class Verifier:
    """The predictor's public key: ``check(checksum, signature)`` -> '' or why the signature is not valid."""

    def __init__(self, public_key):
        self._key = public_key
        self.key_id = _key_id(_raw(public_key))

    @classmethod
    def from_file(cls, path) -> Verifier:
        """Load a PEM Ed25519 public key; ValueError (one line) when it is missing or not one."""
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey
        from cryptography.hazmat.primitives.serialization import load_pem_public_key

        pem = _read(path, "verify key")
        try:
            key = load_pem_public_key(pem)
        except (ValueError, TypeError) as e:
            raise ValueError(f"verify key {path}: not a PEM public key ({e})") from None
        if not isinstance(key, Ed25519PublicKey):
            raise ValueError(f"verify key {path}: {type(key).__name__}, not an Ed25519 public key")
        return cls(key)

    def check(self, checksum: str, signature: str) -> str:
        """'' when signature is this key's over checksum, else the reason (one line)."""
        from cryptography.exceptions import InvalidSignature

        parts = signature.split(":")
        if len(parts) != 3 or parts[0] != PREFIX:
            return f"not an {PREFIX}:<key id>:<hex> signature"
        if parts[1] != self.key_id:
            return f"signed by key {parts[1][:16]!r}, not by the trusted key {self.key_id}"
        try:
            sig = bytes.fromhex(parts[2])
        except ValueError:
            return "signature is not hex"
        try:
            self._key.verify(sig, _DOMAIN + checksum.encode())
        except InvalidSignature:
            return "signature does not verify"
        return ""


def generate(directory) -> tuple[Path, Path]:
    """A new key pair in directory (created): (private key path, mode 0600; public key path). Refuses to overwrite
    an existing private key (FileExistsError)."""
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
    from cryptography.hazmat.primitives.serialization import Encoding, NoEncryption, PrivateFormat, PublicFormat

    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    priv_path, pub_path = d / PRIVATE_NAME, d / PUBLIC_NAME
    key = Ed25519PrivateKey.generate()
    fd = os.open(priv_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key.private_bytes(Encoding.PEM, PrivateFormat.PKCS8, NoEncryption()))
    pub_path.write_bytes(key.public_key().public_bytes(Encoding.PEM, PublicFormat.SubjectPublicKeyInfo))
    return priv_path, pub_path
