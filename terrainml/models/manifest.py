"""A model folder's ``manifest.json``: written in one canonical form that hashes every file of
the folder and itself, read back and verified before anything in the folder is trusted.

:func:`write_manifest` lists every file (sha256 and size; not the manifest, nor its signature
``manifest.sig``) and writes the manifest in its canonical form (sorted keys, 2-space indent)
with ``manifest_sha256``, the sha256 of that text without the field. :func:`read_manifest`
checks the canonical form, the self-hash, the schema and its version; :func:`verify_artifact`
also every listed file's presence, kind, size and sha256. Every refusal raises
:class:`ArtifactError` naming the file. The fields are described in
:mod:`terrainml.models.artifacts`.
"""

from __future__ import annotations

import errno
import hashlib
import json
import math
import os
import stat
from pathlib import Path
from typing import Any

import numpy as np

from terrainml.atomic import write_text
from terrainml.hashing import sha256_file
from terrainml.models.signing import MANIFEST_NAME, SIGNATURE_NAME

__all__ = ["ArtifactError", "SCHEMA", "SCHEMA_VERSION", "json_safe", "write_manifest", "read_manifest",
           "verify_artifact", "file_problem"]

SCHEMA = "terrainml.model"
SCHEMA_VERSION = 1


class ArtifactError(ValueError):
    """A model folder cannot be trusted or used (the message names the file)."""


def json_safe(obj: Any) -> Any:
    """Recursively convert numpy scalars/arrays to Python and non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def _canonical(doc: dict) -> str:
    return json.dumps(doc, indent=2, sort_keys=True, allow_nan=False, ensure_ascii=True) + "\n"


def _self_hash(doc: dict) -> str:
    body = {k: v for k, v in doc.items() if k != "manifest_sha256"}
    return hashlib.sha256(_canonical(body).encode()).hexdigest()


def write_manifest(directory: str | Path, doc: dict | None = None) -> dict:
    """(Re)write ``manifest.json`` hashing every file in ``directory`` (recursively).

    ``doc`` None re-reads the existing manifest (without verifying files) and refreshes the
    file list, e.g. after reports were added. The signature (``manifest.sig``, if any) is not
    hashed: it signs the manifest, and a rewritten manifest no longer matches it (sign again).
    """
    directory = Path(directory)
    if doc is None:
        doc = json.loads((directory / MANIFEST_NAME).read_text())
    doc = {k: v for k, v in doc.items() if k not in ("files", "manifest_sha256")}
    files = {}
    for p in sorted(directory.rglob("*")):
        rel = p.relative_to(directory).as_posix()
        # the folder's own manifest and signature only: a sensor member's manifest is a file
        # of this folder like any other (hashed, so signing this manifest covers the members)
        if p.is_file() and rel not in (MANIFEST_NAME, SIGNATURE_NAME):
            files[rel] = {"sha256": sha256_file(p), "bytes": p.stat().st_size}
    doc["files"] = files
    doc = json_safe(doc)
    doc["manifest_sha256"] = _self_hash(doc)
    write_text(directory / MANIFEST_NAME, _canonical(doc))   # last, whole or not at all
    return doc


_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"),
          (stat.S_ISDIR, "a folder"))


def file_problem(path: Path) -> str | None:
    """Why ``path`` is not a readable regular file (None when it is), its real cause.

    "missing" only when nothing is there (a dangling symlink says where it points); a symlink
    loop, a device (``/dev/zero``), a FIFO, a socket or a folder are named as such, so a model
    file replaced by one is refused before it is opened (reading a FIFO blocks, a device never
    ends). A symlink to a regular file is followed.
    """
    try:
        st = path.stat()
    except FileNotFoundError:
        if path.is_symlink():
            return f"a symlink to {os.readlink(path)!r}, which does not exist"
        return "missing"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return "a symlink loop"
        return f"cannot be read ({exc.strerror or exc})"
    if stat.S_ISREG(st.st_mode):
        return None
    what = next((name for test, name in _KINDS if test(st.st_mode)), "not a regular file")
    via = f" (a symlink to {os.readlink(path)!r})" if path.is_symlink() else ""
    return f"{what}{via}, not a regular file"


def read_manifest(directory: str | Path) -> dict:
    """Read and verify ``manifest.json`` itself (canonical form, self-hash, schema)."""
    directory = Path(directory)
    path = directory / MANIFEST_NAME
    if not directory.is_dir():
        raise ArtifactError(f"{directory}: no such model folder (train one with `terrainml train`)")
    problem = file_problem(path)
    if problem == "missing":
        raise ArtifactError(f"{path}: manifest missing; not a terrainml model folder")
    if problem is not None:
        raise ArtifactError(f"{path}: manifest is {problem}")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
        doc = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ArtifactError(f"{path}: corrupt manifest (not valid JSON: {exc})") from None
    if not isinstance(doc, dict):
        raise ArtifactError(f"{path}: corrupt manifest (not a JSON object)")
    if doc.get("schema") != SCHEMA:
        raise ArtifactError(f"{path}: not a terrainml model manifest (schema {doc.get('schema')!r})")
    if doc.get("schema_version") != SCHEMA_VERSION:
        raise ArtifactError(f"{path}: manifest schema version {doc.get('schema_version')!r}; this "
                            f"terrainml reads version {SCHEMA_VERSION}")
    if doc.get("manifest_sha256") != _self_hash(doc):
        raise ArtifactError(f"{path}: manifest sha256 mismatch: the manifest was modified after "
                            "it was written")
    if text != _canonical(doc):
        raise ArtifactError(f"{path}: manifest is not in its canonical form: it was modified "
                            "after it was written")
    return doc


def verify_artifact(directory: str | Path) -> dict:
    """Verify the manifest and the sha256 of every file it lists; return the manifest."""
    directory = Path(directory)
    doc = read_manifest(directory)
    files = doc.get("files")
    if not isinstance(files, dict) or not files:
        raise ArtifactError(f"{directory / MANIFEST_NAME}: manifest lists no files")
    for rel, info in files.items():
        p = directory / rel
        problem = file_problem(p)
        if problem is not None:
            raise ArtifactError(f"{p}: file listed in the manifest is {problem}")
        if p.stat().st_size != info.get("bytes"):
            raise ArtifactError(f"{p}: size {p.stat().st_size} B differs from the manifest's "
                                f"{info.get('bytes')} B: the file was modified")
        if sha256_file(p) != info.get("sha256"):
            raise ArtifactError(f"{p}: sha256 mismatch: the file was modified after training")
    for name, entry in doc.get("models", {}).items():
        for rel in entry.get("files", []):
            if rel not in files:
                raise ArtifactError(f"{directory / rel}: model file of {name!r} not hashed in the manifest")
    for rel in doc.get("attachments") or []:
        if rel not in files:
            raise ArtifactError(f"{directory / rel}: attachment not hashed in the manifest")
    nov = doc.get("novelty")
    if nov is not None and (not isinstance(nov, dict) or nov.get("file") not in files):
        raise ArtifactError(f"{directory / MANIFEST_NAME}: novelty entry names no file hashed in the manifest")
    return doc
