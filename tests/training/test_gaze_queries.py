"""`--gaze.queries`: whose attention to the gaze camera's patches the gaze term regularizes (issue 36 item 3):
the action queries (the default, unchanged), the instruction's real tokens (padding left out), or both."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import sys
from pathlib import Path

import pytest
import torch

from gazereg.attention.probe import AttentionProbe, ProbeSpec, QuerySet
from gazereg.cli import main as cli_main
from gazereg.data.dataset import describe_store
from gazereg.evaluation.alignment import attention_maps
from gazereg.policies import make_policy, register_policy, unregister_policy
from gazereg.policies.vla import VLAPolicy
from gazereg.policies.vla.processor_vla import Tokenizer
from gazereg.runtime.errors import UsageError
from gazereg.training import loop
from gazereg.training.config import GazeConfig, TrainConfig, ci, upgrade_saved
from gazereg.training.logger import read_metrics
from gazereg.training.setup import setup

ROOT = Path(__file__).resolve().parents[2]
INSTR = ["reach the bright square", "press the button under the square"]


def ci_policy(seed: int = 0) -> VLAPolicy:
    """The `ci` recipe's VLA (2 layers, width 64, 48 px, 12 text tokens), resolved for one camera."""
    torch.manual_seed(seed)
    tok = Tokenizer.build(INSTR, max_len=ci().policy.max_text_len)
    cfg = dataclasses.replace(
        ci().policy,
        cameras=("cam",),
        camera_hw=((48, 48),),
        state_dim=3,
        action_dim=2,
        vocab_size=tok.vocab_size,
    )
    return VLAPolicy(cfg, tok).eval()


def a_batch(policy: VLAPolicy, B: int = 3, seed: int = 0) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    c = policy.config
    ids, mask = policy.tokenizer([INSTR[i % 2] for i in range(B)])  # 4 and 6 real tokens of 12
    return {
        "image.cam": torch.randint(0, 256, (B, 48, 48, 3), generator=g, dtype=torch.uint8),
        "state": torch.randn(B, c.state_dim, generator=g),
        "action": torch.randn(B, c.chunk, c.action_dim, generator=g),
        "action_pad": torch.zeros(B, c.chunk, dtype=torch.bool),
        "text_ids": ids,
        "text_mask": mask,
    }


def probed(policy: VLAPolicy, spec: ProbeSpec, batch: dict) -> tuple[AttentionProbe, list[torch.Tensor]]:
    """The probe after one forward, and every layer's full (B, H, T, T) attention of that forward."""
    with AttentionProbe(policy, spec, adapter="tap") as probe:
        _, info = policy(batch, generator=torch.Generator().manual_seed(0), output_attentions=True)
    return probe, info["attentions"]


# ----- (1) action: today's numbers ----------------------------------------------------------------------------
def test_action_queries_are_the_default_and_give_exactly_the_previous_distribution():
    p, layers = ci_policy(), (0, 1)
    b = a_batch(p)
    spec = p.probe_spec("cam", layers, QuerySet.ACTION, b["text_mask"])
    assert spec == p.gaze_probe_spec("cam", layers) and spec.query_weights is None
    assert spec.queries == p.action_positions() and GazeConfig().query_set is QuerySet.ACTION
    probe, _ = probed(p, spec, b)
    # the formula before the option existed: plain means over heads and queries, then over layers, renormalised
    old = torch.stack([probe.rows(i).mean(dim=(1, 2)) for i in probe.layers]).mean(0)
    assert torch.equal(probe.distribution(), old / old.sum(-1, keepdim=True).clamp_min(1e-12))
    assert torch.equal(
        probe.patch_mass(), torch.stack([probe.rows(i).sum(-1).mean((1, 2)) for i in layers]).mean(0)
    )
    # explicit uniform weights are the same mean (up to float rounding)
    uniform = dataclasses.replace(spec, query_weights=torch.ones(3, p.config.chunk))
    torch.testing.assert_close(probed(p, uniform, b)[0].mean_rows(), probe.mean_rows(), rtol=1e-6, atol=1e-7)


# ----- (2) language: the valid text rows' attention to the patches ---------------------------------------------
def test_language_is_the_mean_over_heads_layers_and_valid_text_rows_renormalised_over_the_patches():
    p, layers = ci_policy(), (0, 1)
    b = a_batch(p)
    spec = p.probe_spec("cam", layers, QuerySet.LANGUAGE, b["text_mask"])
    probe, attentions = probed(p, spec, b)
    text, patches = p.text_positions(), p.patch_positions("cam")
    expected = []
    for i in range(3):
        valid = torch.arange(p.n_tokens)[text][b["text_mask"][i]]  # the real tokens' positions
        rows = torch.stack([a[i][:, valid][..., patches] for a in attentions])  # (layers, H, n_valid, N)
        mean = rows.mean(dim=(0, 1, 2))
        expected.append(mean / mean.sum())
    torch.testing.assert_close(probe.distribution(), torch.stack(expected), rtol=1e-5, atol=1e-7)
    assert spec.query_weights.tolist() == b["text_mask"].float().tolist()


def test_a_padding_token_changes_nothing_in_the_language_distribution():
    p, layers = ci_policy(), (0, 1)
    b = a_batch(p)
    pad = b["text_ids"].clone()
    pad[~b["text_mask"]] = 3  # another embedding (and so query) at every padding position, still masked
    b2 = {**b, "text_ids": pad}
    spec = p.probe_spec("cam", layers, QuerySet.LANGUAGE, b["text_mask"])
    assert torch.equal(probed(p, spec, b)[0].distribution(), probed(p, spec, b2)[0].distribution())
    # the same rows weighted alike (padding included) do move: the weights are what leaves the padding out
    unweighted = dataclasses.replace(spec, query_weights=None)
    a, c = probed(p, unweighted, b)[0].distribution(), probed(p, unweighted, b2)[0].distribution()
    assert not torch.allclose(a, c)


def test_language_refuses_an_empty_instruction_and_needs_the_text_mask():
    p = ci_policy()
    mask = torch.zeros(2, p.config.max_text_len, dtype=torch.bool)
    mask[0, :3] = True
    with pytest.raises(UsageError, match="1 of 2 sample"):
        p.probe_spec("cam", None, QuerySet.LANGUAGE, mask)
    assert p.probe_spec("cam", None, QuerySet.BOTH, mask).query_weights[1].sum() == p.config.chunk
    with pytest.raises(ValueError, match="text_mask"):
        p.probe_spec("cam", None, QuerySet.LANGUAGE)


# ----- (3) both: every valid row counts once -------------------------------------------------------------------
def test_both_is_the_query_count_weighted_combination_of_action_and_language():
    p, layers = ci_policy(), (0, 1)
    b = a_batch(p)
    mean = {q: probed(p, p.probe_spec("cam", layers, q, b["text_mask"]), b)[0].mean_rows() for q in QuerySet}
    K, n_text = p.config.chunk, b["text_mask"].sum(1, keepdim=True).float()
    combined = (K * mean[QuerySet.ACTION] + n_text * mean[QuerySet.LANGUAGE]) / (K + n_text)
    torch.testing.assert_close(mean[QuerySet.BOTH], combined, rtol=1e-5, atol=1e-7)
    assert not torch.allclose(mean[QuerySet.BOTH], mean[QuerySet.ACTION])


# ----- (4) training with language queries ----------------------------------------------------------------------
def run_cfg(store, run_dir, **gaze) -> TrainConfig:
    base = ci()
    data = dataclasses.replace(base.data, store=Path(store.root), val_fraction=0.25)
    return dataclasses.replace(
        base, run_dir=Path(run_dir), data=data, gaze=GazeConfig(prior="square", weight=1.0, **gaze)
    )


def gaze_term_gradients(store, run_dir, queries):
    """The text embedding's gradient from the gaze term alone (action loss x 0), gaze on layer 0 only."""
    run = setup(run_cfg(store, run_dir, layers=(0,), queries=queries))
    forward = run.model.forward

    def gaze_term_only(*args, **kw):
        loss, info = forward(*args, **kw)
        return loss * 0, info

    run.model.forward = gaze_term_only
    batch = next(iter(run.loader))
    spec = run.batch_gaze_spec(batch)
    out = loop.step(run, 0, batch)
    return run, spec, out, run.policy.text_embed.weight.grad


def test_the_language_gaze_term_reaches_the_real_tokens_embeddings_and_not_the_padding(tiny_store, tmp_path):
    run, spec, out, grad = gaze_term_gradients(tiny_store, tmp_path / "lang", "language")
    assert math.isfinite(out.terms["loss/gaze_kl"]) and out.terms["loss"] == pytest.approx(
        out.terms["loss/gaze_kl"]
    )
    assert spec is not run.gaze_spec and spec.queries == run.policy.text_positions()
    assert grad is not None and grad[1:].abs().sum() > 0  # the instruction's words (ids 1..) move
    assert not grad[0].any()  # the padding id: neither a weighted query nor an attended key
    # the action queries' layer-0 attention renormalised over the patches does not depend on the words (their
    # keys enter only the softmax's denominator, which the renormalisation cancels): rounding traces only
    run_a, spec_a, _, grad_a = gaze_term_gradients(tiny_store, tmp_path / "act", "action")
    assert spec_a is run_a.gaze_spec
    assert grad_a.abs().max() < 0.01 * grad[1:].abs().max()


def test_gazereg_train_with_language_queries_records_the_option_and_a_finite_kl(tiny_store, tmp_path, capsys):
    run = tmp_path / "run"
    argv = ["--preset", "ci", "--data.store", str(tiny_store.root), "--run-dir", str(run), "--steps", "2"]
    argv += ["--data.val-fraction", "0.25"]
    assert loop.main([*argv, "--gaze.prior", "square", "--gaze.queries", "language"]) == 0
    assert json.loads((run / "config.json").read_text())["gaze"]["queries"] == "language"
    last = read_metrics(run / "metrics.jsonl")[-1]
    assert math.isfinite(last["loss/gaze_kl"]) and math.isfinite(last["val/gaze_kl"])
    capsys.readouterr()


# ----- (5) refusals and records -------------------------------------------------------------------------------
def test_a_bad_query_set_exits_2_with_one_line_naming_the_option(tiny_store, tmp_path, capsys):
    run = tmp_path / "run"
    argv = ["train", "--preset", "ci", "--data.store", str(tiny_store.root), "--run-dir", str(run)]
    assert cli_main([*argv, "--gaze.queries", "vision"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gazereg train: error: --gaze.queries must be one of action, language, both, got 'vision'"]
    assert not run.exists()


def load_toy_policy():
    """tests/policies/toy_policy.py (another registered policy type, giving the action queries only)."""
    if "toy_policy" in sys.modules:  # imported by tests/policies in this session
        return sys.modules["toy_policy"]
    spec = importlib.util.spec_from_file_location("toy_policy", ROOT / "tests" / "policies" / "toy_policy.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["toy_policy"] = module
    spec.loader.exec_module(module)
    return module


def test_a_policy_without_language_queries_refuses_them_in_one_line():
    toy = load_toy_policy()
    register_policy(toy.ToyPolicy)
    try:
        TrainConfig(policy=toy.ToyConfig(), gaze=GazeConfig(queries="action"))  # the default still works
        with pytest.raises(UsageError) as e:
            TrainConfig(policy=toy.ToyConfig(), gaze=GazeConfig(queries="language"))
    finally:
        unregister_policy("toy")
    assert str(e.value) == (
        "--gaze.queries language: the toy policy cannot regularize the attention of language queries; "
        "it gives action only"
    )


def test_runs_saved_before_the_option_resume_as_action_queries():
    old = {"gaze": {"prior": "square", "target": "attention"}, "data": {"extra_instructions": []}}
    assert upgrade_saved(old)["gaze"]["queries"] == "action"
    new = {"gaze": {"prior": "square", "target": "attention", "queries": "both"}, "data": {}}
    assert upgrade_saved(new)["gaze"]["queries"] == "both"


# ----- evaluation's alignment ---------------------------------------------------------------------------------
def test_alignment_measures_the_action_queries_unless_told_the_trained_query_set(tiny_store):
    policy = make_policy(ci_policy().config, describe_store(tiny_store, [0, 1], ("cam",))).eval()
    policy.set_normalization([0.0] * 4, [1.0] * 4, [0.0] * 4, [1.0] * 4)
    maps = {
        q: attention_maps(policy, tiny_store, [0, 1], "cam", "square", queries=q)["attention"]
        for q in QuerySet
    }
    default = attention_maps(policy, tiny_store, [0, 1], "cam", "square")["attention"]
    assert torch.equal(default, maps[QuerySet.ACTION])
    assert not torch.allclose(maps[QuerySet.LANGUAGE], maps[QuerySet.ACTION])
    assert maps[QuerySet.LANGUAGE].shape == default.shape == (24, policy.config.n_patches)
