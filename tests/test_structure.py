"""The package's shape: no import loops (lazy imports and string imports count), no import running back up the
layers (scripts/structure_facts.py LAYERS), every module in a layer, the package's own modules imported at module
level (lazy imports are for heavy third-party packages), files under 400 lines and functions under 60."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def structure(load_script):
    """scripts/structure_facts.py: the package's facts (`analyse`) and its rules."""
    return load_script("scripts/structure_facts.py")


@pytest.fixture(scope="module")
def facts(structure):
    """`analyse` of src/gazereg, once for the tests that read the package's own facts."""
    return structure.analyse(ROOT / "src" / "gazereg")


def test_no_import_loops_and_no_back_arrows(facts):
    assert facts["loops"] == []
    assert facts["package_loops"] == []
    assert facts["back_arrows"] == []
    assert facts["unlayered"] == []


def test_string_imports_are_edges_of_the_package_graph(facts):
    # the command tables name their modules as "module:function": those are edges the loops and layers see
    assert facts["string_imports"] >= 20
    assert "gazereg.cli -> gazereg.training.glc_cli" in facts["string_import_edges"]
    assert "gazereg.envs.base -> gazereg.envs.metaworld.env" in facts["string_import_edges"]
    assert facts["dangling_string_imports"] == []


def test_the_core_sits_below_data_and_gaze(structure):
    core = structure.layer_of("gazereg.patches")
    for module in ("gazereg.heatmaps", "gazereg.aggregation", "gazereg.losses", "gazereg.metrics"):
        assert structure.layer_of(module) == core, module
    assert structure.layer_of("gazereg.data.dataset") > core
    assert structure.layer_of("gazereg.gaze.priors") > structure.layer_of("gazereg.data.dataset")


def test_own_imports_at_module_level_and_short_files_and_functions(facts):
    assert facts["function_level_imports"] == 0
    assert facts["long_files"] == []
    assert facts["long_functions"] == []


def test_the_analysis_sees_loops_and_back_arrows(structure, tmp_path):
    pkg = tmp_path / "gazereg"
    (pkg / "data").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "__init__.py").write_text("")
    (pkg / "losses.py").write_text("def f():\n    from gazereg.data import store\n")
    (pkg / "data" / "store.py").write_text("from gazereg import losses\n")
    facts = structure.analyse(pkg)
    assert facts["loops"] == [["gazereg.data.store", "gazereg.losses"]]
    assert facts["back_arrows"] == ["gazereg.losses -> gazereg.data.store"]
    assert facts["function_level_imports"] == 1


def test_the_analysis_sees_string_imports(structure, tmp_path):
    pkg = tmp_path / "gazereg"
    (pkg / "data").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "__init__.py").write_text("")
    (pkg / "losses.py").write_text(
        '"""Mentions gazereg.data.store and `gazereg.data.store:X` in prose: no edge."""\n'
        "import importlib\n"
        "from importlib import import_module\n"
        "TABLE = {'x': 'gazereg.data'}\n"
        "def f(name):\n"
        "    importlib.import_module(TABLE[name])\n"
        "    return import_module('gazereg.data.store')\n"
    )
    (pkg / "data" / "store.py").write_text(
        "COMMANDS = {'a': ('gazereg.losses:f', 'help'), 'b': ('gazereg.nowhere:main', 'help')}\n"
        "OTHER = 'torch.nn:Module'\n"
    )
    facts = structure.analyse(pkg)
    assert facts["loops"] == [["gazereg.data.store", "gazereg.losses"]]
    assert facts["back_arrows"] == ["gazereg.losses -> gazereg.data.store"]
    assert facts["string_imports"] == 2
    assert facts["string_import_edges"] == [
        "gazereg.data.store -> gazereg.losses",
        "gazereg.losses -> gazereg.data.store",
    ]
    assert facts["dangling_string_imports"] == ["gazereg.data.store -> gazereg.nowhere"]
    assert facts["computed_string_imports"] == ["gazereg.losses"]
    assert facts["function_level_imports"] == 0
