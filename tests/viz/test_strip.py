"""Episode strips: frames with gaze drawn over them, from the library and the command line."""

from __future__ import annotations

import numpy as np
import pytest

from gazereg.data.store import Episode, EpisodeStore
from gazereg.runtime.errors import UsageError

pytest.importorskip("matplotlib")


def _episode(T: int = 40, cam: str = "corner2") -> Episode:
    """A dark scene with a bright object square (left) and goal square (right); contact from frame 20."""
    frames = np.full((T, 48, 48, 3), 30, np.uint8)
    frames[:, 28:32, 10:14] = (0, 200, 255)
    frames[:, 10:14, 34:38] = (255, 0, 255)
    t = np.arange(T)
    obj = np.tile([12 / 48, 30 / 48], (T, 1)).astype(np.float32)
    goal = np.tile([36 / 48, 12 / 48], (T, 1)).astype(np.float32)
    world = lambda uv: np.concatenate([uv, np.zeros((T, 1), np.float32)], 1)  # noqa: E731
    hand = np.where(t[:, None] < 20, [0.0, 0.0, 0.5], world(obj))
    contact = t >= 20
    success = np.zeros(T, bool)
    success[-1] = True
    return Episode(
        task="pick-place-v3",
        instruction="Pick up the puck and place it at the goal.",
        frames={cam: frames},
        state=np.zeros((T, 4), np.float32),
        action=np.zeros((T, 4), np.float32),
        extras={
            f"obj_uv.{cam}": obj,
            f"goal_uv.{cam}": goal,
            f"hand_uv.{cam}": obj,
            "obj_pos": world(obj),
            "goal_pos": world(goal),
            "hand_pos": hand.astype(np.float32),
            "contact": contact,
            "grasp": contact,
            "success": success,
        },
        meta={"fps": 80.0, "seed": 0},
    )


def test_draw_strip_writes_a_png(tmp_path):
    from gazereg.gaze.sources import make_gaze_source
    from gazereg.viz.strip import draw_strip, pick_frames

    assert pick_frames(40, 8)[0] == 0 and pick_frames(40, 8)[-1] == 39 and len(pick_frames(40, 8)) == 8
    assert pick_frames(3, 8) == [0, 1, 2]
    ep = _episode()
    src = make_gaze_source("visuomotor", jitter=0.0)
    heat, valid = src(ep, "corner2", (24, 24))
    tr = src.trace(ep, "corner2")
    out = tmp_path / "s.png"
    fig = draw_strip(
        ep,
        "corner2",
        heatmaps=heat,
        valid=valid,
        points=tr.uv,
        target=tr.target,
        target_names=tr.targets,
        n_frames=6,
        out=out,
    )
    assert out.exists() and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(fig.axes) == 7  # six frames and the timeline
    assert fig.axes[0].get_title() == "t=0 obj" and fig.axes[5].get_title() == "t=39 goal"
    with pytest.raises(ValueError, match="frames"):
        draw_strip(ep, "corner2", heatmaps=heat[:5])
    with pytest.raises(KeyError, match="no camera"):
        draw_strip(ep, "topview")


def test_command_line_strip_from_source_and_prior(tmp_path, capsys):
    import matplotlib.image as mpimg

    from gazereg.viz.cli import main

    store = EpisodeStore(tmp_path / "store", create=True)
    store.write(_episode(), index=0)
    out = tmp_path / "strip.png"
    assert (
        main(
            ["strip", "--store", str(store.root), "--episode", "0", "--camera", "corner2", "--out", str(out)]
        )
        == 0
    )
    img = mpimg.imread(out)
    assert img.shape[1] > 2 * img.shape[0]  # a strip: wider than tall
    # a stored prior is drawn the same way
    heat = np.zeros((40, 8, 8), np.float32)
    heat[:, 2, 6] = 1.0
    store.write_prior("mine", 0, heat, np.ones(40, bool))
    store.write_prior_info("mine", {"source": "test"})
    out2 = tmp_path / "prior.png"
    assert (
        main(["strip", "--store", str(store.root), "--prior", "mine", "--out", str(out2), "--frames", "4"])
        == 0
    )
    assert out2.exists()
    with pytest.raises(UsageError, match="--episode: no episode 7"):
        main(["strip", "--store", str(store.root), "--episode", "7", "--out", str(out2)])
    assert main(["nothing"]) == 2
    assert "strip" in capsys.readouterr().out


def test_viz_functions_are_short_and_import_the_package_at_module_level(load_script):
    """draw_strip is a few helpers under the function limit; own imports sit at the top of the modules."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    facts = load_script("scripts/structure_facts.py")
    for name in ("strip", "overlay"):
        path = root / "src" / "gazereg" / "viz" / f"{name}.py"
        tree = ast.parse(path.read_text())
        module = f"gazereg.viz.{name}"
        long = [(f, n) for f, n in facts.function_lengths(tree, module) if n > facts.MAX_FUNCTION_LINES]
        assert long == []
        inner = [m for m, in_function in facts.imports_of(tree, module, False, "gazereg") if in_function]
        assert inner == []
