"""Bounded YAML: every YAML the project reads refuses an alias bomb, a
recursive alias and an oversized file quickly, naming the file."""

from __future__ import annotations

import pytest

from terrainml._yaml_checks import MAX_YAML_ALIASES, MAX_YAML_BYTES, MAX_YAML_NODES, load_bounded_yaml
from terrainml.experiments.recipes import load_recipe
from terrainml.io.ingest.dataset_spec import DatasetSpecError, load_dataset_spec
from terrainml.io.topicmap import TopicMapError, load_topic_map
from terrainml.lookup.catalogue import CatalogueError, load_catalogue
from terrainml.robot import RobotSpec, RobotSpecError


def _bomb(levels: int, width: int = 10) -> str:
    """Lines whose aliases expand to width**levels strings ("billion laughs")."""
    lines = [f"l0: &l0 [{', '.join(['lol'] * width)}]"]
    lines += [f"l{k}: &l{k} [{', '.join([f'*l{k - 1}'] * width)}]" for k in range(1, levels)]
    return "\n".join(lines) + "\n"


LOADERS = [
    ("dataset spec", load_dataset_spec, DatasetSpecError),
    ("robot spec", RobotSpec.from_yaml, RobotSpecError),
    ("topic map", load_topic_map, TopicMapError),
    ("catalogue", load_catalogue, CatalogueError),
    ("recipe", load_recipe, ValueError),
]


@pytest.mark.parametrize("kind,load,error", LOADERS, ids=[k for k, _, _ in LOADERS])
def test_alias_bomb_is_refused_naming_the_file(tmp_path, kind, load, error):
    # 10^6 strings once expanded (5x past the node limit with only 50 alias references); the
    # sweep's 10^9 one ran 46 s into a MemoryError that named the CSV instead of the spec
    assert 10 ** 6 > MAX_YAML_NODES
    path = tmp_path / "bomb.yaml"
    path.write_text(_bomb(6))
    with pytest.raises(error) as info:
        load(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: refused") and "alias bomb" in msg.replace(str(path), "")


def test_a_billion_laughs_is_refused(tmp_path):
    path = tmp_path / "spec.yaml"
    path.write_text(_bomb(9))   # 10^9 strings
    with pytest.raises(DatasetSpecError, match="alias bomb"):
        load_dataset_spec(path)


def test_recursive_alias_and_alias_count_and_size_are_bounded(tmp_path):
    rec = tmp_path / "rec.yaml"
    rec.write_text("a: &a [1, *a]\n")
    with pytest.raises(RobotSpecError, match=f"{rec}.*contains itself"):
        RobotSpec.from_yaml(rec)
    many = tmp_path / "many.yaml"
    many.write_text("x: &x 1\ny: [" + ", ".join(["*x"] * (MAX_YAML_ALIASES + 1)) + "]\n")
    with pytest.raises(TopicMapError, match=f"{many}.*alias references"):
        load_topic_map(many)
    big = tmp_path / "big.yaml"
    big.write_text("# " + "x" * MAX_YAML_BYTES + "\n")
    with pytest.raises(CatalogueError, match=f"{big}.*larger than"):
        load_catalogue(big)


def test_ordinary_aliases_still_load():
    doc = load_bounded_yaml("base: &b {unit: A, scale: 2}\nleft: *b\nright: *b\n")
    assert doc == {"base": {"unit": "A", "scale": 2}, "left": {"unit": "A", "scale": 2},
                   "right": {"unit": "A", "scale": 2}}
