"""Signed model artifacts: an ed25519 signature over ``manifest.json`` (design §9).

The manifest already holds the sha256 of every file of a model folder, so it proves the folder's
*integrity*: nothing changed since the manifest was written. It cannot prove *origin*: anyone can
edit the manifest and re-hash it with :func:`terrainml.models.artifacts.write_manifest`. A
signature made with a private key the serving side does not hold can. ``manifest.sig`` sits next
to the manifest (it is not listed in it) and holds::

    {"algorithm": "ed25519", "manifest_sha256": ..., "public_key_sha256": ...,
     "schema": "terrainml.model.signature", "schema_version": 1, "signature": BASE64,
     "signed_file": "manifest.json"}

The signature covers the manifest's bytes exactly; ``public_key_sha256`` (the key's fingerprint:
sha256 of its 32 raw bytes) says which key made it. Keys are PEM files: PKCS#8 for the private
key, SubjectPublicKeyInfo for ``KEY.pub`` (:func:`generate_keypair`).

:func:`verify_artifact_signature` refuses, naming the folder and the reason, an unsigned folder,
one signed by a key outside the trusted set, and one whose manifest changed after signing.
Signing is optional for users: :func:`terrainml.models.artifacts.load_artifact` checks it only
when given ``trusted_keys`` (``predict`` and ``evaluate --trusted-key``). The crypto is the
``cryptography`` package's; nothing here is hand-written.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import os
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterable, Union

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from terrainml.atomic import write_text


__all__ = ["MANIFEST_NAME", "SIGNATURE_NAME", "SignatureError", "generate_keypair", "key_fingerprint",
           "load_private_key", "load_public_key", "public_key_path", "sign_artifact",
           "verify_artifact_signature"]

#: The manifest of a model folder (hashes every other file) and its detached signature.
MANIFEST_NAME = "manifest.json"
SIGNATURE_NAME = "manifest.sig"
SIGNATURE_SCHEMA = "terrainml.model.signature"
SIGNATURE_VERSION = 1
# a signature file is ~400 B; anything far larger is not one (and is not read into memory)
_MAX_SIGNATURE_BYTES = 64 * 1024

PublicKeyLike = Union[str, os.PathLike, Ed25519PublicKey]


class SignatureError(ValueError):
    """A model folder's signature is missing, untrusted or does not match (the message names the folder)."""


# ---------------------------------------------------------------------------- keys
def public_key_path(private_key_path: str | Path) -> Path:
    """``KEY.pub``: where :func:`generate_keypair` writes the public key of ``KEY``."""
    p = Path(private_key_path)
    return p.with_name(p.name + ".pub")


def generate_keypair(private_key_path: str | Path) -> tuple[Path, Path]:
    """Write a new ed25519 key pair: ``KEY`` (PEM PKCS#8, mode 0600) and ``KEY.pub`` (PEM).

    Refuses (FileExistsError) to overwrite either file: a key is not replaced by accident.

    Returns
    -------
    (private key path, public key path).
    """
    priv_path, pub_path = Path(private_key_path), public_key_path(private_key_path)
    for p in (priv_path, pub_path):
        if p.exists():
            raise FileExistsError(f"{p}: already exists; not overwriting a key")
    key = Ed25519PrivateKey.generate()
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    # O_EXCL: never follow a file created meanwhile; 0600: the private key is readable by its owner only
    fd = os.open(priv_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    pub_path.write_bytes(key.public_key().public_bytes(serialization.Encoding.PEM,
                                                       serialization.PublicFormat.SubjectPublicKeyInfo))
    return priv_path, pub_path


def _read_key_file(path: Path, what: str) -> bytes:
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise SignatureError(f"{path}: {what} not found") from None
    except OSError as exc:
        raise SignatureError(f"{path}: cannot read the {what} ({exc.strerror or exc})") from None


def _load_key(path: str | Path, what: str, load: Callable[[bytes], Any], key_type: type, pem_kind: str):
    """The ``key_type`` key that ``load`` parses from a PEM file; SignatureError naming the file otherwise."""
    path = Path(path)
    data = _read_key_file(path, what)
    try:
        key = load(data)
    except (ValueError, TypeError) as exc:
        raise SignatureError(f"{path}: not {pem_kind} ({exc})") from None
    if not isinstance(key, key_type):
        raise SignatureError(f"{path}: not an ed25519 {what} ({type(key).__name__})")
    return key


def load_private_key(path: str | Path) -> Ed25519PrivateKey:
    """An unencrypted ed25519 private key from a PEM file; SignatureError naming the file otherwise."""
    return _load_key(path, "private key", partial(serialization.load_pem_private_key, password=None),
                     Ed25519PrivateKey, "an unencrypted PEM private key")


def load_public_key(path: str | Path) -> Ed25519PublicKey:
    """An ed25519 public key from a PEM file (``KEY.pub``); SignatureError naming the file otherwise."""
    return _load_key(path, "public key", serialization.load_pem_public_key, Ed25519PublicKey, "a PEM public key")


def key_fingerprint(key: Ed25519PublicKey | Ed25519PrivateKey) -> str:
    """Hex sha256 of the public key's 32 raw bytes (what ``manifest.sig`` records)."""
    if isinstance(key, Ed25519PrivateKey):
        key = key.public_key()
    raw = key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()


# ---------------------------------------------------------------------------- sign / verify
def _manifest_bytes(directory: Path) -> bytes:
    path = directory / MANIFEST_NAME
    if not directory.is_dir():
        raise SignatureError(f"{directory}: no such model folder")
    if not path.is_file():
        raise SignatureError(f"{path}: manifest missing; not a terrainml model folder")
    return path.read_bytes()


def sign_artifact(directory: str | Path, private_key_path: str | Path) -> Path:
    """Sign ``directory/manifest.json`` with the ed25519 key in ``private_key_path``.

    The manifest is signed as it is: verify the folder first
    (:func:`terrainml.models.artifacts.verify_artifact`, as ``terrainml model sign`` does), and
    sign again after any later :func:`~terrainml.models.artifacts.write_manifest`. An existing
    signature is replaced.

    Returns
    -------
    Path of ``manifest.sig``.
    """
    directory = Path(directory)
    key = load_private_key(private_key_path)
    manifest = _manifest_bytes(directory)
    doc = {
        "schema": SIGNATURE_SCHEMA, "schema_version": SIGNATURE_VERSION, "algorithm": "ed25519",
        "signed_file": MANIFEST_NAME, "manifest_sha256": hashlib.sha256(manifest).hexdigest(),
        "public_key_sha256": key_fingerprint(key),
        "signature": base64.b64encode(key.sign(manifest)).decode("ascii"),
    }
    path = directory / SIGNATURE_NAME
    write_text(path, json.dumps(doc, indent=2, sort_keys=True) + "\n")
    return path


def _read_signature(directory: Path) -> dict:
    path = directory / SIGNATURE_NAME
    if not path.is_file():
        raise SignatureError(f"{directory}: refused: the model is not signed ({SIGNATURE_NAME} missing); "
                             "a trusted key needs a model signed with `terrainml model sign`")
    if path.stat().st_size > _MAX_SIGNATURE_BYTES:
        raise SignatureError(f"{directory}: refused: {SIGNATURE_NAME} is not a signature file "
                             f"({path.stat().st_size:,} bytes)")
    try:
        doc = json.loads(path.read_bytes().decode("utf-8"))
        if not isinstance(doc, dict) or doc.get("schema") != SIGNATURE_SCHEMA:
            raise ValueError(f"schema {doc.get('schema') if isinstance(doc, dict) else None!r}")
        if doc.get("schema_version") != SIGNATURE_VERSION or doc.get("algorithm") != "ed25519":
            raise ValueError(f"version {doc.get('schema_version')!r}, algorithm {doc.get('algorithm')!r}")
        doc["signature"] = base64.b64decode(str(doc["signature"]), validate=True)
        doc["public_key_sha256"] = str(doc["public_key_sha256"])
        doc["manifest_sha256"] = str(doc["manifest_sha256"])
    except (UnicodeDecodeError, ValueError, KeyError, binascii.Error) as exc:
        raise SignatureError(f"{directory}: refused: {SIGNATURE_NAME} is not a valid terrainml "
                             f"signature ({type(exc).__name__}: {exc})") from None
    return doc


def _trusted(keys: Iterable[PublicKeyLike]) -> dict[str, Ed25519PublicKey]:
    out = {}
    for k in keys:
        key = k if isinstance(k, Ed25519PublicKey) else load_public_key(k)
        out[key_fingerprint(key)] = key
    return out


def verify_artifact_signature(directory: str | Path, trusted_public_keys: Iterable[PublicKeyLike]) -> str:
    """Check that ``directory/manifest.json`` was signed by one of ``trusted_public_keys``.

    Parameters
    ----------
    directory : model folder (``runs/NAME``).
    trusted_public_keys : public keys (PEM paths such as ``KEY.pub``, or loaded keys). None of
        them: every folder is refused.

    Returns
    -------
    The fingerprint of the key that signed.

    Raises
    ------
    SignatureError
        Naming the folder: unsigned, signed by an untrusted key, manifest changed after signing
        (edited, or re-hashed with the project's own writer), or a signature that does not verify.
        A trusted key file that is missing or not an ed25519 public key is named instead.
    """
    directory = Path(directory)
    keys = _trusted(trusted_public_keys)
    if not keys:
        raise SignatureError(f"{directory}: refused: no trusted public key given")
    manifest = _manifest_bytes(directory)
    doc = _read_signature(directory)
    fp = doc["public_key_sha256"]
    if fp not in keys:
        raise SignatureError(f"{directory}: refused: signed by key {fp[:16]}, which is not a trusted key "
                             f"(trusted: {', '.join(f[:16] for f in keys)})")
    if hashlib.sha256(manifest).hexdigest() != doc["manifest_sha256"]:
        raise SignatureError(f"{directory}: refused: {MANIFEST_NAME} changed after it was signed (edited "
                             "and re-hashed?): its hashes prove integrity, not origin")
    try:
        keys[fp].verify(doc["signature"], manifest)
    except InvalidSignature:
        raise SignatureError(f"{directory}: refused: the signature in {SIGNATURE_NAME} does not verify "
                             f"with trusted key {fp[:16]}") from None
    return fp
