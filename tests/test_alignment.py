"""Attention summaries: the object-mass report and the clean-vs-perturbed attention shift."""

import pytest
import torch

from gazereg.evaluation.alignment import alignment_report, attention_shift


def _maps(attn: torch.Tensor) -> dict[str, torch.Tensor]:
    region = torch.zeros_like(attn, dtype=torch.bool)
    region[:, 0] = True  # the object sits on patch 0
    return {"attention": attn, "object_region": region, "episode_t": torch.tensor([[0, 0], [0, 1], [1, 0]])}


def test_report_gives_object_mass_next_to_chance():
    attn = torch.tensor([[0.7, 0.1, 0.1, 0.1]] * 3)
    r = alignment_report(_maps(attn))
    assert r["frames"] == 3
    assert r["object_mass"] == pytest.approx(0.7) and r["object_mass_chance"] == pytest.approx(0.25)


def test_shift_is_zero_for_unmoved_attention_and_large_for_moved():
    on_object = torch.tensor([[0.7, 0.1, 0.1, 0.1]] * 3)
    elsewhere = torch.tensor([[0.1, 0.1, 0.1, 0.7]] * 3)
    same = attention_shift(_maps(on_object), _maps(on_object.clone()))
    assert same["agreement"]["kl"] == pytest.approx(0.0, abs=1e-6) and same["agreement"][
        "cc"
    ] == pytest.approx(1.0)
    moved = attention_shift(_maps(on_object), _maps(elsewhere))
    assert moved["agreement"]["kl"] > 1.0 and moved["agreement"]["cc"] < 0
    assert moved["perturbed"]["object_mass"] == pytest.approx(0.1)


def test_shift_refuses_frames_that_do_not_match():
    a, b = _maps(torch.full((3, 4), 0.25)), _maps(torch.full((3, 4), 0.25))
    b["episode_t"] = torch.tensor([[0, 0], [0, 1], [2, 0]])
    with pytest.raises(ValueError, match="same \\(episode, t\\) frames"):
        attention_shift(a, b)
