"""Reading a user's YAML file with errors that name the file (design §3, §5).

Robot specs, topic maps and dataset specs are all hand-written YAML; a missing file or a syntax
error must surface as the caller's own error type, with the path first, never a bare yaml traceback.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

import yaml


def read_yaml_file(path: Path, error: type[Exception], not_found: str) -> Any:
    """Parse the YAML file at ``path``; raise ``error`` if it is missing (message ``not_found``) or malformed."""
    if not path.is_file():
        raise error(not_found)
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise error(f"{path}: not valid YAML: {exc}") from None


def read_builtin_yaml(package: str, folder: str, name: str) -> Any:
    """Parse the YAML file ``folder/name.yaml`` shipped inside ``package`` (a built-in spec)."""
    return yaml.safe_load(resources.files(package).joinpath(folder, f"{name}.yaml").read_text())
