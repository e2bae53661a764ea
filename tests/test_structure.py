"""The package's shape: no import loops (lazy imports count), no import running back up the layers
(scripts/structure_facts.py LAYERS), every module in a layer, the package's own modules imported at module level
(lazy imports are for heavy third-party packages), files under 400 lines and functions under 60."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_facts():
    spec = importlib.util.spec_from_file_location("structure_facts", ROOT / "scripts" / "structure_facts.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_no_import_loops_and_no_back_arrows():
    facts = load_facts().analyse(ROOT / "src" / "gazereg")
    assert facts["loops"] == []
    assert facts["package_loops"] == []
    assert facts["back_arrows"] == []
    assert facts["unlayered"] == []


def test_own_imports_at_module_level_and_short_files_and_functions():
    facts = load_facts().analyse(ROOT / "src" / "gazereg")
    assert facts["function_level_imports"] == 0
    assert facts["long_files"] == []
    assert facts["long_functions"] == []


def test_the_analysis_sees_loops_and_back_arrows(tmp_path):
    pkg = tmp_path / "gazereg"
    (pkg / "data").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "data" / "__init__.py").write_text("")
    (pkg / "losses.py").write_text("def f():\n    from gazereg.data import store\n")
    (pkg / "data" / "store.py").write_text("from gazereg import losses\n")
    facts = load_facts().analyse(pkg)
    assert facts["loops"] == [["gazereg.data.store", "gazereg.losses"]]
    assert facts["back_arrows"] == ["gazereg.losses -> gazereg.data.store"]
    assert facts["function_level_imports"] == 1
