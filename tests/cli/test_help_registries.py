"""The help lists the built-in topic maps, robots, window specs, dataset specs and terrain
catalogues from their registries, and the light registries the help reads agree with the code that
uses them.

``terrainml --help`` must not import the numeric stack, so the names live in light modules
(:mod:`terrainml.io.topicmap_names`, :mod:`terrainml.robots`, :mod:`terrainml.features.window_presets`,
:mod:`terrainml.io.dataset_spec_names`, :mod:`terrainml.lookup.catalogue_names`); these tests hold
them to the files and specs they name.
"""

from __future__ import annotations

import re
from importlib import resources

from cli_tree import ROOT, render_help

from terrainml.features.window_presets import DEFAULT_WINDOWS, WINDOW_SPEC_SUMMARIES, WINDOW_SPECS
from terrainml.io.dataset_spec_names import BUILTIN_SPECS
from terrainml.io.topicmap_names import BUILTIN_MAPS
from terrainml.lookup.catalogue_names import BUILTIN_CATALOGUES
from terrainml.robots import BUILTIN_ROBOTS, REFERENCE_ROBOT

_WIDE = 400   # columns: no name is cut by the wrapping


def _yaml_stems(package: str, folder: str = "") -> set[str]:
    root = resources.files(package)
    root = root.joinpath(folder) if folder else root
    return {p.name.removesuffix(".yaml") for p in root.iterdir() if p.name.endswith(".yaml")}


def test_registries_name_the_shipped_files():
    """Every built-in name is a YAML file of the package, and every such file is listed."""
    assert set(BUILTIN_MAPS) == _yaml_stems("terrainml.io", "topicmaps")
    assert set(BUILTIN_SPECS) == _yaml_stems("terrainml.io", "datasets")
    assert set(BUILTIN_CATALOGUES) == _yaml_stems("terrainml.lookup", "catalogues")
    assert set(BUILTIN_ROBOTS) == _yaml_stems("terrainml.robots")
    assert REFERENCE_ROBOT in BUILTIN_ROBOTS


def test_heavy_modules_use_the_light_registries():
    """The readers check names against the same registries the help lists (one definition each)."""
    import terrainml.features.windows as windows
    import terrainml.io.ingest.dataset_spec as dataset_spec
    import terrainml.io.topicmap as topicmap
    import terrainml.lookup.catalogue as catalogue
    import terrainml.pipeline.dataset as dataset
    import terrainml.robot as robot

    assert topicmap.BUILTIN_MAPS is BUILTIN_MAPS
    assert dataset_spec.BUILTIN_SPECS is BUILTIN_SPECS and catalogue.BUILTIN_CATALOGUES is BUILTIN_CATALOGUES
    assert robot.BUILTIN_ROBOTS is BUILTIN_ROBOTS and robot.REFERENCE_ROBOT == REFERENCE_ROBOT
    assert windows.WINDOW_SPECS is WINDOW_SPECS
    assert dataset.DEFAULT_WINDOWS == DEFAULT_WINDOWS


def test_window_summaries_say_what_the_specs_cut():
    """One summary per named spec; every window length a summary states is the spec's ``window_s``."""
    from terrainml.features.windows import window_spec

    assert set(WINDOW_SPEC_SUMMARIES) == set(WINDOW_SPECS)
    for name, summary in WINDOW_SPEC_SUMMARIES.items():
        stated = re.match(r"(?:the .*?)?(\d+(?:\.\d+)?) s windows", summary)
        assert stated, f"{name}: the summary states no window length: {summary!r}"
        assert float(stated[1]) == window_spec(name).window_s, name


def test_help_lists_every_built_in_name():
    """``ingest`` and ``estimate`` name every topic map and robot, ``ingest`` every dataset spec,
    ``lookup show`` every terrain catalogue."""
    for path in (("ingest",), ("estimate",)):
        out = render_help(path, _WIDE)
        assert all(name in out for name in BUILTIN_MAPS), (path, BUILTIN_MAPS)
        assert all(name in out for name in BUILTIN_ROBOTS), (path, BUILTIN_ROBOTS)
    assert all(name in render_help(("ingest",), _WIDE) for name in BUILTIN_SPECS)
    assert all(name in render_help(("lookup", "show"), _WIDE) for name in BUILTIN_CATALOGUES)


def test_robot_option_help_lists_every_built_in_robot():
    """Every ``--robot`` of the app names all the built-in robots."""
    lacking = []

    def walk(cmd, path):
        for p in cmd.params:
            if "--robot" in p.opts and not all(r in (p.help or "") for r in BUILTIN_ROBOTS):
                lacking.append(" ".join(path))
        for name, sub in (getattr(cmd, "commands", None) or {}).items():
            walk(sub, path + (name,))

    walk(ROOT, ())
    assert set(lacking) <= _ROBOT_HELP_ELSEWHERE, lacking


#: ``--robot`` options whose help need not list the built-in robots: none
_ROBOT_HELP_ELSEWHERE: set[str] = set()


def test_dataset_help_names_the_default_window_spec():
    """The root help and ``dataset build --help`` describe the default spec the code uses."""
    build = next(p for p in ROOT.commands["dataset"].commands["build"].params if p.name == "windows")
    assert build.default == DEFAULT_WINDOWS
    summary = f"{DEFAULT_WINDOWS} spec by default: {WINDOW_SPEC_SUMMARIES[DEFAULT_WINDOWS]}"
    assert summary in " ".join(render_help((), _WIDE).split())
    out = " ".join(render_help(("dataset", "build"), _WIDE).split())
    assert all(f"{name} ({summary})" in out for name, summary in WINDOW_SPEC_SUMMARIES.items())
    assert f"Default: {DEFAULT_WINDOWS}." in out
