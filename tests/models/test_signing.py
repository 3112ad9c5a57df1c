"""Signed model folders: keygen, sign, verify; refusals of an unsigned folder, a folder
signed by another key, a manifest edited and re-hashed with the project's own writer after signing
("the hash proves integrity, not origin"), a forged or damaged signature and a tampered file; and
``predict`` / ``evaluate --trusted-key`` accepting a good folder and refusing each bad one, naming
the folder, with behaviour unchanged without ``--trusted-key``.

Ground truth: what the test did to the folder (which key signed, which byte changed), checked
against the ``cryptography`` package's own ed25519 verification where a signature is involved.
"""

from __future__ import annotations

import base64
import hashlib
import json
import shutil
import stat
from pathlib import Path

import pytest
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey
from typer.testing import CliRunner

from synthetic_runs import make_run_table
from terrainml.cli import app
from terrainml.models import artifacts
from terrainml.models.artifacts import ArtifactError, load_artifact, read_manifest, verify_artifact, write_manifest
from terrainml.models.signing import (MANIFEST_NAME, SIGNATURE_NAME, SignatureError, generate_keypair,
                                      key_fingerprint, load_public_key, sign_artifact, verify_artifact_signature)
from terrainml.pipeline.dataset import write_windows
from terrainml.pipeline.train_options import TrainOptions
from terrainml.pipeline.train import train
from terrainml.schema import write_run_parquet

SMALL = {"svm": {"C_grid": (10.0,), "gamma_grid": ("scale",)}}


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def trained(dataset, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("signed") / "svm"
    train(dataset, out, models=("svm",), options=TrainOptions(folds=3, seed=0, ablation=False, model_params=SMALL))
    return out


@pytest.fixture(scope="module")
def keys(tmp_path_factory) -> dict:
    """Two key pairs, 'a' (trusted by the tests) and 'b' (another signer)."""
    folder = tmp_path_factory.mktemp("keys")
    return {name: generate_keypair(folder / name) for name in ("a", "b")}


@pytest.fixture
def model(trained, tmp_path) -> Path:
    """A fresh, unsigned copy of the trained folder."""
    return Path(shutil.copytree(trained, tmp_path / "runs" / "svm"))


@pytest.fixture(scope="module")
def windows_file(dataset, tmp_path_factory) -> Path:
    return write_windows(dataset, tmp_path_factory.mktemp("w") / "w.parquet")


@pytest.fixture(scope="module")
def short_log(tmp_path_factory) -> Path:
    """A 3-s labelled run table for `predict` (one classification window and a bit)."""
    path = tmp_path_factory.mktemp("log") / "short.parquet"
    return write_run_parquet(make_run_table(2, "short", 5, duration_s=3.0), path)


def _rehash_edited(model: Path) -> None:
    """What an attacker with the repository can do: edit the manifest and re-hash it with the
    project's own writer, so that every integrity check passes."""
    doc = read_manifest(model)
    doc["extra"] = {**doc.get("extra", {}), "injected": "by someone else"}
    write_manifest(model, doc)


# ----------------------------------------------------------------------------- keys
def test_keygen_writes_an_ed25519_pem_pair(keys):
    priv, pub = keys["a"]
    assert pub == priv.with_name("a.pub")
    assert stat.S_IMODE(priv.stat().st_mode) == 0o600
    sk = serialization.load_pem_private_key(priv.read_bytes(), password=None)
    pk = serialization.load_pem_public_key(pub.read_bytes())
    assert isinstance(sk, Ed25519PrivateKey) and isinstance(pk, Ed25519PublicKey)
    raw = lambda k: k.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)  # noqa: E731
    assert raw(sk.public_key()) == raw(pk)
    assert key_fingerprint(sk) == key_fingerprint(pk) != key_fingerprint(load_public_key(keys["b"][1]))


def test_keygen_cli_and_no_overwrite(tmp_path):
    runner = CliRunner()
    key = tmp_path / "k" / "release"
    r = runner.invoke(app, ["model", "keygen", "--out", str(key)])
    assert r.exit_code == 0, r.output
    assert key.is_file() and key.with_name("release.pub").is_file()
    before = key.read_bytes()
    r = runner.invoke(app, ["model", "keygen", "--out", str(key)])
    assert r.exit_code == 2 and str(key) in r.output and "already exists" in r.output
    assert key.read_bytes() == before


# ----------------------------------------------------------------------------- sign / verify
def test_signed_folder_verifies_and_loads(model, keys):
    sig = sign_artifact(model, keys["a"][0])
    assert sig == model / SIGNATURE_NAME
    doc = json.loads(sig.read_text())
    # independent check: cryptography's own verification of the stored signature over the bytes
    pk = load_public_key(keys["a"][1])
    pk.verify(base64.b64decode(doc["signature"]), (model / MANIFEST_NAME).read_bytes())
    assert doc["public_key_sha256"] == key_fingerprint(pk)
    assert verify_artifact_signature(model, [keys["a"][1]]) == key_fingerprint(pk)
    # several trusted keys: any one that signed is enough
    assert verify_artifact_signature(model, [keys["b"][1], pk]) == key_fingerprint(pk)
    art = load_artifact(model, trusted_keys=[keys["a"][1]])
    assert art.model_name == "svm"
    # the signature is not hashed into the manifest, so the files check is unchanged
    assert SIGNATURE_NAME not in read_manifest(model)["files"]
    verify_artifact(model)


def test_write_manifest_never_hashes_the_signature(model, keys):
    sign_artifact(model, keys["a"][0])
    write_manifest(model)              # e.g. after adding a report: lists no manifest.sig
    assert SIGNATURE_NAME not in read_manifest(model)["files"]
    sign_artifact(model, keys["a"][0])  # signing again makes the folder trusted again
    load_artifact(model, trusted_keys=[keys["a"][1]])


def test_unsigned_folder_is_refused_naming_it(model, keys):
    with pytest.raises(SignatureError, match="not signed") as exc:
        load_artifact(model, trusted_keys=[keys["a"][1]])
    assert str(model) in str(exc.value)
    load_artifact(model)  # without trusted keys: unchanged


def test_folder_signed_by_another_key_is_refused(model, keys):
    sign_artifact(model, keys["b"][0])
    with pytest.raises(SignatureError, match="not a trusted key") as exc:
        verify_artifact_signature(model, [keys["a"][1]])
    assert str(model) in str(exc.value)
    assert key_fingerprint(load_public_key(keys["b"][1]))[:16] in str(exc.value)


def test_manifest_edited_and_rehashed_after_signing_is_refused(model, keys):
    sign_artifact(model, keys["a"][0])
    _rehash_edited(model)
    # the integrity checks alone cannot see it: the hashes prove integrity, not origin
    verify_artifact(model)
    assert load_artifact(model).manifest["extra"]["injected"] == "by someone else"
    with pytest.raises(SignatureError, match="changed after it was signed") as exc:
        load_artifact(model, trusted_keys=[keys["a"][1]])
    assert str(model) in str(exc.value)


def test_signature_forged_for_the_edited_manifest_is_refused(model, keys):
    sign_artifact(model, keys["a"][0])
    _rehash_edited(model)
    # the attacker also updates the recorded manifest hash, and cannot re-sign with key a
    sig = model / SIGNATURE_NAME
    doc = json.loads(sig.read_text())
    doc["manifest_sha256"] = hashlib.sha256((model / MANIFEST_NAME).read_bytes()).hexdigest()
    sig.write_text(json.dumps(doc))
    with pytest.raises(SignatureError, match="does not verify") as exc:
        verify_artifact_signature(model, [keys["a"][1]])
    assert str(model) in str(exc.value)
    # re-signing with another key and claiming key a's fingerprint fails the same way
    other = Ed25519PrivateKey.generate()
    doc["signature"] = base64.b64encode(other.sign((model / MANIFEST_NAME).read_bytes())).decode()
    sig.write_text(json.dumps(doc))
    with pytest.raises(SignatureError, match="does not verify"):
        verify_artifact_signature(model, [keys["a"][1]])


@pytest.mark.parametrize("content", [b"", b"not json", b"[1, 2]", b'{"schema": "other"}',
                                     b"\xff\xfe\x00garbage", b"{" * 2000])
def test_damaged_signature_file_is_refused(model, keys, content):
    (model / SIGNATURE_NAME).write_bytes(content)
    with pytest.raises(SignatureError, match="not a valid terrainml signature") as exc:
        verify_artifact_signature(model, [keys["a"][1]])
    assert str(model) in str(exc.value)


def test_oversized_signature_file_is_refused_unread(model, keys):
    (model / SIGNATURE_NAME).write_bytes(b" " * (1 << 20))
    with pytest.raises(SignatureError, match="not a signature file"):
        verify_artifact_signature(model, [keys["a"][1]])


def test_tampered_file_of_a_signed_folder_is_refused_naming_the_file(model, keys):
    sign_artifact(model, keys["a"][0])
    skops = model / "svm" / "model.skops"
    data = bytearray(skops.read_bytes())
    data[len(data) // 2] ^= 0xFF
    skops.write_bytes(bytes(data))
    verify_artifact_signature(model, [keys["a"][1]])  # the manifest itself is untouched
    with pytest.raises(ArtifactError, match="sha256 mismatch") as exc:
        load_artifact(model, trusted_keys=[keys["a"][1]])
    assert str(skops) in str(exc.value)


def test_bad_trusted_key_files_are_named(model, keys, tmp_path):
    sign_artifact(model, keys["a"][0])
    missing = tmp_path / "missing.pub"
    with pytest.raises(SignatureError, match="not found") as exc:
        verify_artifact_signature(model, [missing])
    assert str(missing) in str(exc.value)
    junk = tmp_path / "junk.pub"
    junk.write_text("-----BEGIN PUBLIC KEY-----\nAAAA\n-----END PUBLIC KEY-----\n")
    with pytest.raises(SignatureError, match="not a PEM public key") as exc:
        verify_artifact_signature(model, [junk])
    assert str(junk) in str(exc.value)
    # a private key given where a public key is expected is refused, not silently accepted
    with pytest.raises(SignatureError) as exc:
        verify_artifact_signature(model, [keys["a"][0]])
    assert str(keys["a"][0]) in str(exc.value)
    with pytest.raises(SignatureError, match="no trusted public key"):
        verify_artifact_signature(model, [])


def test_manifest_name_is_the_artifacts_one():
    assert artifacts.MANIFEST_NAME == MANIFEST_NAME == "manifest.json"


# ----------------------------------------------------------------------------- CLI
def test_cli_sign_and_verify(model, keys, tmp_path):
    runner = CliRunner()
    r = runner.invoke(app, ["model", "sign", str(model), "--key", str(keys["a"][0])])
    assert r.exit_code == 0, r.output
    assert (model / SIGNATURE_NAME).is_file()
    r = runner.invoke(app, ["model", "verify", str(model), "--trusted-key", str(keys["a"][1])])
    assert r.exit_code == 0, r.output
    r = runner.invoke(app, ["model", "verify", str(model), "--trusted-key", str(keys["b"][1])])
    assert r.exit_code == 2 and str(model) in r.output and "not a trusted key" in r.output
    # a folder whose files no longer match its manifest is not signed
    report = model / "report.md"
    report.write_text(report.read_text() + "\nedited\n")
    (model / SIGNATURE_NAME).unlink()
    r = runner.invoke(app, ["model", "sign", str(model), "--key", str(keys["a"][0])])
    assert r.exit_code == 2 and str(report) in r.output and "Traceback" not in r.output
    assert not (model / SIGNATURE_NAME).exists()


def _bad_folders(trained, keys, root: Path) -> dict[str, Path]:
    """One folder per refusal: unsigned, signed by key b, edited + re-hashed after signing."""
    out = {}
    for case in ("unsigned", "other_key", "rehashed"):
        d = Path(shutil.copytree(trained, root / case))
        if case == "other_key":
            sign_artifact(d, keys["b"][0])
        elif case == "rehashed":
            sign_artifact(d, keys["a"][0])
            _rehash_edited(d)
        out[case] = d
    return out


REASONS = {"unsigned": "not signed", "other_key": "not a trusted key", "rehashed": "changed after it was signed"}


def test_cli_evaluate_with_trusted_key(trained, keys, windows_file, tmp_path):
    runner = CliRunner()
    good = Path(shutil.copytree(trained, tmp_path / "good"))
    sign_artifact(good, keys["a"][0])
    pub = str(keys["a"][1])
    r = runner.invoke(app, ["evaluate", str(good), "--data", str(windows_file), "--trusted-key", pub, "-q"])
    assert r.exit_code == 0, r.output
    assert json.loads(r.stdout)["n_windows"] > 0
    for case, folder in _bad_folders(trained, keys, tmp_path).items():
        r = runner.invoke(app, ["evaluate", str(folder), "--data", str(windows_file), "--trusted-key", pub, "-q"])
        assert r.exit_code == 2, (case, r.output)
        assert str(folder) in r.output and REASONS[case] in r.output and "Traceback" not in r.output
        # without --trusted-key: unchanged (the integrity checks pass for all three)
        r = runner.invoke(app, ["evaluate", str(folder), "--data", str(windows_file), "-q"])
        assert r.exit_code == 0, (case, r.output)


def test_cli_predict_with_trusted_key(trained, keys, short_log, tmp_path):
    runner = CliRunner()
    good = Path(shutil.copytree(trained, tmp_path / "good"))
    sign_artifact(good, keys["a"][0])
    pub = str(keys["a"][1])
    base = ["predict", "--source", str(short_log), "--sink", "stdout"]
    r = runner.invoke(app, base + ["--model", str(good), "--trusted-key", str(keys["b"][1]),
                                   "--trusted-key", pub])
    assert r.exit_code == 0, r.output
    lines = [json.loads(s) for s in r.stdout.splitlines() if s.startswith("{")]
    assert len(lines) == 300   # 3 s at 100 Hz: one message per tick
    for case, folder in _bad_folders(trained, keys, tmp_path).items():
        r = runner.invoke(app, base + ["--model", str(folder), "--trusted-key", pub])
        assert r.exit_code == 2, (case, r.output)
        assert str(folder) in r.output and REASONS[case] in r.output and "Traceback" not in r.output
        assert not r.stdout.strip()  # refused before serving anything
    # without --trusted-key: unchanged
    r = runner.invoke(app, base + ["--model", str(tmp_path / "unsigned")])
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("kind,cause", [
    ("dev_zero", "a character device (a symlink to '/dev/zero'), not a regular file"),
    ("fifo", "a FIFO (named pipe), not a regular file"),
    ("loop", "a symlink loop"),
    ("dangling", "a symlink to 'nowhere.skops', which does not exist"),
    ("folder", "a folder, not a regular file"),
])
def test_special_model_file_is_refused_with_its_real_cause(model, kind, cause):
    """A model file replaced by a symlink to /dev/zero, a FIFO or a symlink
    loop was refused as "missing"; each is named for what it is, before it is opened."""
    import os

    skops = model / "svm" / "model.skops"
    skops.unlink()
    if kind == "dev_zero":
        skops.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(skops)
    elif kind == "loop":
        skops.symlink_to(skops)
    elif kind == "dangling":
        skops.symlink_to("nowhere.skops")
    else:
        skops.mkdir()
    with pytest.raises(ArtifactError) as exc:
        load_artifact(model)
    assert str(exc.value) == f"{skops}: file listed in the manifest is {cause}"
    manifest = model / MANIFEST_NAME
    manifest.unlink()
    os.mkfifo(manifest)
    with pytest.raises(ArtifactError, match="manifest is a FIFO"):
        read_manifest(model)
