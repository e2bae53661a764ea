"""One config namespace (issue 34 item 2): a preset name means one thing across kinds, `gazereg presets` lists
them all with one line each, and renaming them changed no preset's values (before_issue34.json: every preset
of every kind as `to_dict` gave it before the renaming, with os.cpu_count() = 2)."""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path
from typing import Any

import pytest

from gazereg import cli
from gazereg.experiment.presets import KINDS, catalogue
from gazereg.runtime.config import to_dict

BEFORE = json.loads((Path(__file__).parent / "before_issue34.json").read_text())

# kind in the snapshot -> (kind in `gazereg presets`, {name before: name now})
RENAMED = {
    "experiment": ("experiment", {n: n for n in BEFORE["experiment"]}),
    "train": ("training recipe", {"smoke": "ci", "quick": "cpu", "tuned": "tuned", "paper": "gpu"}),
    "eval": (
        "evaluation budget",
        {
            "default": "clean-10",
            "smoke": "clean-dim-2",
            "quick": "clean-dim-noise-10",
            "libero": "libero-spatial-25",
            "paper": "robustness-50",
        },
    ),
    "collect": ("collection budget", {"quick": "demos-3x30", "smoke": "demos-2x2", "paper": "demos-10x50"}),
    "policy": ("policy size", {"tiny": "tiny", "paper": "large"}),
    "glc": ("GLC size", {"full": "official", "small": "small"}),
    "glc_train": ("GLC training recipe", {"small": "scratch-small", "full": "finetune-official"}),
}


def _presets(kind: str) -> dict[str, Any]:
    return dict(next(k for k in KINDS if k.kind == kind).presets())


def _unchanged(before: Any, now: Any, path: str = "") -> list[str]:
    """Paths where `now` differs from `before`; keys added to a config since the snapshot are not compared."""
    if isinstance(before, dict) and isinstance(now, dict):
        return [p for k, v in before.items() for p in _unchanged(v, now.get(k, "<missing>"), f"{path}.{k}")]
    return [] if before == now else [f"{path}: {before!r} -> {now!r}"]


@pytest.fixture
def two_cores(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 2)  # the presets with one worker per core, as snapshotted


ADDED_SINCE = {
    "experiment": {
        "aloha",
        "demo",
        "ml45_finetune",
        "ml45_scratch",
        "ml45_study",
        "ml45_study50",
        "libero_object",
        "libero_goal",
        "libero_10",
    },
    "evaluation budget": {"aloha-50", "libero-object-25", "libero-goal-25", "libero-10-25"},
}
"""presets added after the snapshot (nothing to compare them with)"""


CHANGED_SINCE = {
    ("experiment", "libero"): {
        ".arms": (
            ["baseline", "gaze", "glc", "perturbed"],
            ["baseline", "gaze", "glc", "uniform", "perturbed"],
        ),
        ".train.mixed_precision": ("auto", "no"),
    },
    ("experiment", "libero_smoke"): {
        ".arms": (
            ["baseline", "gaze", "glc", "perturbed"],
            ["baseline", "gaze", "glc", "uniform", "perturbed"],
        ),
    },
}
"""values changed on purpose since the snapshot, (snapshot kind, name) -> {path: (before, now)}: LIBERO trains in
float32 on every CPU, as its sittings run on whichever CPU a session gets, and adds the uniform control of the
paper's table (config_sims.libero_suite)"""


def test_every_preset_keeps_its_values_under_its_new_name(two_cores):
    for snap_kind, (kind, names) in RENAMED.items():
        presets = _presets(kind)
        assert set(presets) - ADDED_SINCE.get(kind, set()) == set(names.values()), kind
        for old, new in names.items():
            before = BEFORE[snap_kind][old]
            if snap_kind == "glc_train" and before["config"] == "full":
                before = {**before, "config": "official"}  # the GLC size's new name; the same architecture
            changed = CHANGED_SINCE.get((snap_kind, old), {}).items()
            expected = [f"{path}: {a!r} -> {b!r}" for path, (a, b) in changed]
            assert _unchanged(before, to_dict(presets[new]())) == expected, f"{kind} {old} -> {new}"


def test_quick_resolves_as_before(two_cores):
    """Every value of `quick` (the main job until `make demo` became the generalist's fine-tuning, `demo`) as
    before (options added to the configs since, such as training's data.extra_instructions, are not in the
    snapshot)."""
    from gazereg.experiment.config import quick

    assert _unchanged(BEFORE["experiment"]["quick"], to_dict(quick())) == []
    assert to_dict(quick())["train"]["steps"] == 5000 and to_dict(quick())["eval"]["episodes"] == 25


def test_the_renamed_glc_size_is_the_same_architecture():
    from gazereg.gaze.glc.model import GLCConfig
    from gazereg.gaze.sources.glc import CONFIGS

    assert CONFIGS["official"]() == GLCConfig() == GLCConfig.full()


def test_a_name_means_one_thing_across_kinds():
    rows = [(k.kind, name) for k, name, _ in catalogue()]
    twice = {name: n for name, n in Counter(name for _, name in rows).items() if n > 1}
    assert twice == {}
    assert {kind for kind, _ in rows} == {kind for kind, _ in RENAMED.values()} | {"pretraining"}


def test_every_kind_a_command_takes_by_preset_names_its_default_and_no_other_kind_does():
    """A command's default is named (never the registry's order): each kind taken by `--preset` names one of
    its own presets; a kind no command takes by `--preset` (sizes) names none."""
    for kind in KINDS:
        if "--preset" in kind.used_by:
            assert kind.default in kind.presets(), kind.kind
        else:
            assert kind.default is None, kind.kind


def test_gazereg_presets_lists_every_preset_with_one_line(capsys):
    assert cli.main(["presets"]) == 0
    out = capsys.readouterr().out.splitlines()
    for kind, name, line in catalogue():
        assert f"{kind.kind} ({kind.used_by}):" in out
        assert line, f"{kind.kind} {name} has no description"
        rows = [r for r in out if r.strip().startswith(name) and r.strip()[len(name) :][:2] in ("  ", "* ")]
        assert any(line in r for r in rows), (kind.kind, name)
    assert cli.main(["presets", "--kind", "experiment"]) == 0
    rows = [r.split()[0] for r in capsys.readouterr().out.splitlines() if r.startswith("  ")]
    starred = [name for name in rows if name.endswith("*")]
    assert starred == ["demo*"]  # `gazereg experiment`'s default, not the registry's first
    assert cli.main(["presets", "--kind", "GLC size"]) == 0
    assert capsys.readouterr().out.splitlines()[:3] == [
        "GLC size (--glc.config, config= of the glc gaze source, gazereg glc eval --config):",
        "  official   Official GLC (MViT-B 16x4 conv): input (B,3,8,256,256) -> logits (B,1,8,64,64); 70.18 M params.",
        "  small      Same code, narrow and shallow: input (B,3,8,96,96) -> logits (B,1,8,24,24); ~3.5 M params.",
    ]


@pytest.mark.parametrize(
    ("command", "old", "now"),
    [
        ("train", "quick", "['ci', 'cpu', 'gpu', 'tuned']"),
        (
            "eval",
            "paper",
            "['aloha-50', 'clean-10', 'clean-dim-2', 'clean-dim-noise-10', 'libero-10-25', 'libero-goal-25', "
            "'libero-object-25', 'libero-spatial-25', 'robustness-50']",
        ),
        ("collect", "smoke", "['demos-10x50', 'demos-2x2', 'demos-3x30']"),
    ],
)
def test_a_former_name_is_refused_in_one_line_listing_the_kinds_names(capsys, command, old, now):
    assert cli.main([command, "--preset", old]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"gazereg {command}: error: unknown preset {old!r} for gazereg {command}; choose one of {now}"
    ]
