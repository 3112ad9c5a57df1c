"""CLI commands of the models area: ``terrainml train`` (:mod:`terrainml.commands.train_cmd`),
``terrainml evaluate`` (:mod:`terrainml.commands.evaluate_cmd`) and ``terrainml model
keygen|sign|verify`` (signed model folders, :mod:`terrainml.models.signing`).

Exit codes: 0 on success, 2 when the model folder or a key is unusable (message names the file);
never a traceback.
"""

from __future__ import annotations

from pathlib import Path
from typing import List

import typer

from terrainml.commands._common import check_output_writable, console, fail
from terrainml.commands._model_inputs import TRUSTED_KEY_HELP
from terrainml.commands.evaluate_cmd import evaluate
from terrainml.commands.train_cmd import train

model_app = typer.Typer(help="Sign model folders and check their signatures (ed25519).", no_args_is_help=True)


@model_app.command("keygen")
def keygen(out: Path = typer.Option(..., "--out", "-o", help="Private key file to create (PEM); the public "
                                    "key goes to OUT.pub.")) -> None:
    """Create an ed25519 key pair for signing model folders: OUT (private, mode 0600) and OUT.pub.

    Example: terrainml model keygen --out keys/release (keep keys/release secret; ship keys/release.pub)
    """
    from terrainml.models.signing import generate_keypair, key_fingerprint, load_public_key, public_key_path

    for p in (out, public_key_path(out)):
        if p.exists():
            fail(f"{p}: already exists; not overwriting a key")
        check_output_writable(p)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        priv, pub = generate_keypair(out)
    except OSError as exc:
        fail(f"{out}: cannot write the key ({exc})")
    console.print(f"[green]wrote[/] {priv} (private: keep it secret) and {pub} (public: give it to "
                  f"`--trusted-key`); fingerprint {key_fingerprint(load_public_key(pub))[:16]}", highlight=False)


@model_app.command("sign")
def sign(
    model_dir: Path = typer.Argument(..., help="Model folder written by `terrainml train`."),
    key: Path = typer.Option(..., "--key", "-k", help="Private key (PEM) from `terrainml model keygen`."),
) -> None:
    """Verify a model folder (every file's sha256), then sign its manifest (manifest.sig).

    Example: terrainml model sign runs/svm --key keys/release
    """
    from terrainml.models.artifacts import ArtifactError, verify_artifact
    from terrainml.models.signing import SignatureError, sign_artifact

    try:
        verify_artifact(model_dir)   # never sign a folder whose files no longer match its manifest
        path = sign_artifact(model_dir, key)
    except (ArtifactError, SignatureError) as exc:
        fail(str(exc))
    except OSError as exc:
        fail(f"{model_dir}: cannot write the signature ({exc})")
    console.print(f"[green]signed[/] {model_dir}: wrote {path}", highlight=False)


@model_app.command("verify")
def verify(
    model_dir: Path = typer.Argument(..., help="Model folder."),
    trusted_key: List[Path] = typer.Option(..., "--trusted-key", help=TRUSTED_KEY_HELP),
) -> None:
    """Check a model folder's files and its signature by one of the trusted keys (exit 2 if not).

    Example: terrainml model verify runs/svm --trusted-key keys/release.pub
    """
    from terrainml.models.artifacts import ArtifactError, verify_artifact
    from terrainml.models.signing import SignatureError, verify_artifact_signature

    try:
        fp = verify_artifact_signature(model_dir, trusted_key)
        verify_artifact(model_dir)
    except (ArtifactError, SignatureError) as exc:
        fail(str(exc))
    console.print(f"[green]ok[/] {model_dir}: files match the manifest, signed by trusted key {fp[:16]}",
                  highlight=False)


def register(app: typer.Typer) -> None:
    """Add this area's commands to the top-level app."""
    app.command("train")(train)
    app.command("evaluate")(evaluate)
    app.add_typer(model_app, name="model")
