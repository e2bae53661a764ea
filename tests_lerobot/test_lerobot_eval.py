"""LeRobot's own `lerobot-eval` on Meta-World (`--env.type=metaworld`) with a gaze-trained checkpoint and its plain
export (lerobot_policy_gazereg.export): the same successes, rewards and actions on the same seeds, for
smolvla_gaze and pi0_gaze.

The checkpoints: the real `lerobot-train` (2 steps with the gaze term) on the tiny LeRobot v3 fixture, offline (the
tiny SmolVLM of lerobot_policy_gazereg.testing; for pi0 the tiny PaliGemma models and tokenizer, installed by a
sitecustomize as in test_pi0_gaze.py). The fixture's camera `observation.images.front` is fed Meta-World's
`observation.image` with lerobot-eval's `--rename_map`; its wrist camera is absent in Meta-World (SmolVLA skips a
missing camera, pi0 gives it an empty image).

Two test-only patches of lerobot's Meta-World env, in the same sitecustomize (lerobot-eval itself is unchanged):
- lerobot 0.6.1's `MetaworldEnv` fixes its episodes at 500 steps (`_max_episode_steps`; `--env.episode_length` is
  not passed to it), about 100 s of CPU rendering per episode here; the patch makes them EPISODE_STEPS long;
- every action the env is stepped with is appended to a file (lerobot-eval's `--eval.recording=true`, which would
  record them, fails on Meta-World in 0.6.1: its feature name `pixels/top` holds a '/', refused by the data set
  writer), so the test compares the actions themselves, not only eval_info.json's rewards and successes.

LIBERO is not evaluated here: see docs/lerobot.md (its assets come from the hub).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

EPISODE_STEPS = 10  # two action chunks of 5 per episode
EPISODES = 2  # seeds 1000 and 1001 (lerobot-eval's --seed default 1000, one env: one seed per episode)
TASK = "push-v3"
CAM = "observation.images.front"
SITE = textwrap.dedent(
    """
    import os, sys
    if os.path.basename(sys.argv[0]).startswith(("lerobot-eval", "lerobot-train")):
        if os.environ.get("GAZEREG_TEST_TINY_PI"):
            from lerobot_policy_gazereg.testing import install_tiny_pi_models
            install_tiny_pi_models()
        if os.environ.get("GAZEREG_TEST_ACTIONS"):
            from lerobot.envs import metaworld as mw

            init, step = mw.MetaworldEnv.__init__, mw.MetaworldEnv.step

            def __init__(self, *args, **kwargs):
                init(self, *args, **kwargs)
                self._max_episode_steps = int(os.environ["GAZEREG_TEST_EPISODE_STEPS"])

            def logged_step(self, action):
                with open(os.environ["GAZEREG_TEST_ACTIONS"], "a") as f:
                    f.write(" ".join(repr(float(a)) for a in action) + "\\n")
                return step(self, action)

            mw.MetaworldEnv.__init__, mw.MetaworldEnv.step = __init__, logged_step
    """
)


@pytest.fixture(scope="module")
def lane_env(tmp_path_factory) -> dict:
    """Environment of the lerobot-train / lerobot-eval subprocesses: offline, the sitecustomize above, a tiny
    tokenizer cached as google/paligemma-3b-pt-224, and a working MuJoCo GL backend."""
    pytest.importorskip(
        "metaworld", reason="lerobot's metaworld env needs metaworld (scripts/lerobot_lane.sh)"
    )
    from lerobot_policy_gazereg.testing import make_offline_paligemma_cache

    from gazereg.envs.render import select_gl_backend
    from gazereg.runtime.errors import UsageError

    try:
        gl = select_gl_backend()
    except UsageError as e:
        pytest.skip(f"no OpenGL backend for MuJoCo: {e}")
    root = tmp_path_factory.mktemp("eval_env")
    site = root / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(SITE)
    path = os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))
    return {**os.environ, "HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "OMP_NUM_THREADS": "1",
            "HF_HUB_CACHE": str(make_offline_paligemma_cache(root / "hub")), "PYTHONPATH": path,
            "MUJOCO_GL": gl, "GAZEREG_TEST_EPISODE_STEPS": str(EPISODE_STEPS)}  # fmt: skip


def _policy_args(kind: str, tiny_vlm: Path) -> list[str]:
    common = ["--policy.chunk_size=5", "--policy.n_action_steps=5", "--policy.device=cpu",
              "--policy.push_to_hub=false", "--policy.gaze_weight=1.0", f"--policy.gaze_camera={CAM}",
              "--policy.scheduler_warmup_steps=0"]  # fmt: skip
    if kind == "smolvla":
        return ["--policy.type=smolvla_gaze", f"--policy.vlm_model_name={tiny_vlm}", "--policy.num_vlm_layers=4",
                "--policy.load_vlm_weights=false", "--policy.resize_imgs_with_padding=[64,64]",
                "--policy.gaze_layers=[1,3]", *common]  # fmt: skip
    return ["--policy.type=pi0_gaze", "--policy.image_resolution=[56,56]", "--policy.max_state_dim=8",
            "--policy.max_action_dim=8", "--policy.tokenizer_max_length=32", "--policy.gaze_layers=[1]",
            *common]  # fmt: skip


def _run(cmd: list[str], env: dict, cwd: Path) -> str:
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=cwd)
    log = r.stdout + r.stderr
    assert r.returncode == 0, log[-4000:]
    return log


def _train(kind: str, tiny_vlm: Path, dataset_root: Path, env: dict, out: Path) -> Path:
    """The pretrained_model/ folder of a 2-step lerobot-train run with the gaze term."""
    env = {**env, "GAZEREG_TEST_TINY_PI": "1"} if kind == "pi0" else env
    cmd = [str(Path(sys.executable).with_name("lerobot-train")), *_policy_args(kind, tiny_vlm),
           "--dataset.repo_id=local/lerobot_v3_tiny", f"--dataset.root={dataset_root}", "--dataset.episodes=[0]",
           "--dataset.video_backend=pyav", "--batch_size=10", "--steps=2", "--log_freq=1", "--save_freq=2",
           "--num_workers=0", "--wandb.enable=false", f"--output_dir={out}"]  # fmt: skip
    log = _run(cmd, env, out.parent)
    kls = [float(x) for x in re.findall(r"loss/gaze_kl:([-0-9.naif]+)", log)]
    assert len(kls) == 2 and all(k > 0 for k in kls), log[-3000:]  # trained with the gaze term
    return out / "checkpoints" / "last" / "pretrained_model"


def _eval(kind: str, policy: Path, env: dict, out: Path) -> tuple[dict, list[list[float]]]:
    """(eval_info.json's metrics of the task, the actions the env was stepped with) of lerobot-eval."""
    actions = out.with_suffix(".actions")
    env = {**env, "GAZEREG_TEST_ACTIONS": str(actions)}
    if kind == "pi0":
        env["GAZEREG_TEST_TINY_PI"] = "1"
    cmd = [str(Path(sys.executable).with_name("lerobot-eval")), f"--policy.path={policy}",
           "--env.type=metaworld", f"--env.task={TASK}", f"--eval.n_episodes={EPISODES}", "--eval.batch_size=1",
           "--eval.use_async_envs=false", "--policy.device=cpu",
           '--rename_map={"observation.image": "' + CAM + '"}', f"--output_dir={out}"]  # fmt: skip
    _run(cmd, env, out.parent)
    (task,) = json.loads((out / "eval_info.json").read_text())["per_task"]
    assert task["task_group"] == TASK
    rows = [[float(a) for a in line.split()] for line in actions.read_text().splitlines()]
    return task["metrics"], rows


@pytest.mark.parametrize("kind", ["smolvla", "pi0"])
def test_lerobot_eval_gaze_checkpoint_and_plain_export_act_the_same(
    kind, tmp_path, tiny_vlm, dataset_root, lane_env
):
    from lerobot_policy_gazereg.export import export_plain_checkpoint

    gaze_ckpt = _train(kind, tiny_vlm, dataset_root, lane_env, tmp_path / "train")
    plain = tmp_path / "plain"
    result = export_plain_checkpoint(gaze_ckpt, plain)
    assert (result.gaze_type, result.base_type) == (f"{kind}_gaze", kind)

    gaze, gaze_actions = _eval(kind, gaze_ckpt, lane_env, tmp_path / "eval_gaze")
    base, base_actions = _eval(kind, plain, lane_env, tmp_path / "eval_plain")

    assert len(gaze["successes"]) == EPISODES
    assert gaze["successes"] == base["successes"]
    assert gaze["sum_rewards"] == base["sum_rewards"] and gaze["max_rewards"] == base["max_rewards"]
    assert len(gaze_actions) == EPISODES * EPISODE_STEPS and all(len(a) == 4 for a in gaze_actions)
    assert gaze_actions == base_actions  # bit for bit: same weights, same processors, same noise
    # not a degenerate rollout: the policy's actions change along an episode and the two seeds differ
    assert len({tuple(a) for a in gaze_actions}) > EPISODE_STEPS
    assert gaze["sum_rewards"][0] != gaze["sum_rewards"][1]
