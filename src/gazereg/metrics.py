"""Alignment metrics between an attention map and a gaze map (saliency-benchmark definitions).

All functions take maps of shape (..., N) (flattened patch grids or pixels) and return (...) values.
`gaze` is the reference (a density, or fixation points for NSS/AUC via a binary map), `attn` the prediction.
"""

from __future__ import annotations

import torch
from torch import Tensor

from gazereg.losses import gaze_kl

_EPS = 1e-12


def _norm(x: Tensor) -> Tensor:
    x = x.double().clamp_min(0)
    return x / x.sum(-1, keepdim=True).clamp_min(_EPS)


def kl(gaze: Tensor, attn: Tensor) -> Tensor:
    """KL(gaze || attn) in nats; 0 when equal."""
    return gaze_kl(_norm(gaze), _norm(attn)).float()


def cc(gaze: Tensor, attn: Tensor) -> Tensor:
    """Pearson correlation coefficient between the maps, in [-1, 1] (0 if either is constant)."""
    g = gaze.double() - gaze.double().mean(-1, keepdim=True)
    a = attn.double() - attn.double().mean(-1, keepdim=True)
    den = (g.pow(2).sum(-1) * a.pow(2).sum(-1)).sqrt()
    return torch.where(den > _EPS, (g * a).sum(-1) / den.clamp_min(_EPS), torch.zeros_like(den)).float()


def sim(gaze: Tensor, attn: Tensor) -> Tensor:
    """Histogram intersection sum_i min(g_i, a_i) of the normalised maps, in [0, 1]."""
    return torch.minimum(_norm(gaze), _norm(attn)).sum(-1).float()


def nss(fixations: Tensor, attn: Tensor) -> Tensor:
    """Normalised scanpath saliency: mean of the standardised attention at fixated entries (fixations > 0)."""
    a = attn.double()
    z = (a - a.mean(-1, keepdim=True)) / a.std(-1, keepdim=True).clamp_min(_EPS)
    fix = (fixations > 0).double()
    return ((z * fix).sum(-1) / fix.sum(-1).clamp_min(1)).float()


def auc_judd(fixations: Tensor, attn: Tensor) -> Tensor:
    """AUC-Judd: thresholds at the attention values of fixated entries; TPR over fixated, FPR over the rest.

    Returns NaN for a map without fixations or without non-fixated entries (undefined)."""
    a = attn.double().reshape(-1, attn.shape[-1])
    f = (fixations > 0).reshape(-1, attn.shape[-1])
    out = torch.full((a.shape[0],), float("nan"), dtype=torch.float64)
    for i in range(a.shape[0]):
        pos, n = f[i], a.shape[1]
        n_fix = int(pos.sum())
        if n_fix == 0 or n_fix == n:
            continue
        thresholds = torch.sort(a[i][pos], descending=True).values
        tp, fp = [0.0], [0.0]
        for t in thresholds:
            above = a[i] >= t
            tp.append(float((above & pos).sum()) / n_fix)
            fp.append(float((above & ~pos).sum()) / (n - n_fix))
        tp.append(1.0)
        fp.append(1.0)
        out[i] = torch.trapezoid(torch.tensor(tp, dtype=torch.float64), torch.tensor(fp, dtype=torch.float64))
    return out.reshape(attn.shape[:-1]).float()


def mass_in_region(attn: Tensor, region: Tensor) -> Tensor:
    """Fraction of the (normalised) attention inside a region (..., N) bool, in [0, 1]."""
    return (_norm(attn) * region.double()).sum(-1).float()


def top_fixations(gaze: Tensor, frac: float = 0.1) -> Tensor:
    """Binary 'fixation' map: the smallest set of entries holding at least `frac` of the top of the gaze
    density, i.e. entries >= the (1 - frac) quantile (at least the arg-max)."""
    g = gaze.double()
    thr = torch.quantile(g, 1 - frac, dim=-1, keepdim=True)
    fix = g >= thr
    return fix | (g == g.max(-1, keepdim=True).values)


def alignment_metrics(gaze: Tensor, attn: Tensor, valid: Tensor | None = None) -> dict[str, float]:
    """Mean KL, CC, SIM, NSS and AUC-Judd over valid rows of (B, N) maps (fixations: top 10% of gaze)."""
    gaze, attn = gaze.detach(), attn.detach()
    if valid is not None:
        gaze, attn = gaze[valid], attn[valid]
    if gaze.shape[0] == 0:
        return {}
    fix = top_fixations(gaze)
    auc = auc_judd(fix, attn)
    return {
        "kl": float(kl(gaze, attn).mean()),
        "cc": float(cc(gaze, attn).mean()),
        "sim": float(sim(gaze, attn).mean()),
        "nss": float(nss(fix, attn).mean()),
        "auc_judd": float(auc[~auc.isnan()].mean()) if (~auc.isnan()).any() else float("nan"),
    }
