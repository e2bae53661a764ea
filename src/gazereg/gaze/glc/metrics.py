"""Gaze-estimation metrics of the GLC paper, plus trivial baselines to read them against.

Protocol (official GLC evaluation):

1. prediction maps (the per-frame softmax of `logits / 2`) are min-max normalised per frame:
   `(p - min) / (max - min + 1e-6)`;
2. ground truth = the Gaussian target heatmap binarised at `> 0.001`;
3. for each threshold in `linspace(0, 0.02, 11)`: binary prediction `p > thr`; per frame
   `recall = TP / (|GT| + 1e-6)` and `precision = TP / (|pred| + 1e-6)`, averaged over the selected
   (fixation) frames; `F1 = 2 R P / (R + P + 1e-6)` from the averaged R and P;
4. the reported F1 / recall / precision are those at the threshold with the best F1;
5. AUC: per frame, a one-hot at the (truncated) centre of mass of the normalised prediction is blurred
   with a Gaussian (sigma 3.2 px on a 64-px map, scaled with the map), min-max normalised, and
   `AUC = 1 - fraction of pixels scoring higher than the pixel of the true gaze point`. The blur is
   truncated at 4 sigma, so every miss farther than that scores the same (~0.95 on 64x64 maps). The AUC
   reads nothing of a map but its centre of mass: a uniform map scores exactly as a point at the frame's
   centre does (and a centre prior as a point at its centre), high wherever the gaze clusters near the
   centre; read F1 to tell a map from the centre.

Under this protocol even a perfect prediction (the target map itself) has precision ~0.7: the
binarised target (> 0.001) is narrower than the region above 2% of the normalised peak.

Maps can be `(N, 1, T, h, w)`, `(N, T, h, w)`, `(T, h, w)` or `(h, w)` tensors or arrays; masks and
gaze points follow the same leading dims (`(N, T)` and `(N, T, 2)`, points normalised `(u right, v down)`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch

from gazereg.gaze.glc.targets import gaze_target_maps

THRESHOLDS = np.linspace(0.0, 0.02, 11)
GT_BINARY_THRESHOLD = 0.001
AUC_SIGMA_AT_64 = 3.2


def _frames(x, ndim_tail: int = 2) -> np.ndarray:
    """Any array/tensor -> float64 numpy of shape `(F, *tail)` (a channel dim of 1 is dropped)."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().double().numpy()
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 5 and x.shape[1] == 1:
        x = x[:, 0]
    return x.reshape((-1,) + x.shape[x.ndim - ndim_tail :])


def _mask(mask, n: int) -> np.ndarray:
    if mask is None:
        return np.ones(n, dtype=bool)
    if isinstance(mask, torch.Tensor):
        mask = mask.detach().cpu().numpy()
    m = np.asarray(mask).astype(bool).reshape(-1)
    if m.shape[0] != n:
        raise ValueError(f"frame mask has {m.shape[0]} entries for {n} frames")
    return m


def minmax_normalize(maps) -> np.ndarray:
    """Per-frame `(p - min) / (max - min + 1e-6)`; returns float64 `(F, h, w)`."""
    p = _frames(maps)
    lo = p.min(axis=(1, 2), keepdims=True)
    hi = p.max(axis=(1, 2), keepdims=True)
    return (p - lo) / (hi - lo + 1e-6)


@dataclass(frozen=True)
class GazeScores:
    """Scores at the best threshold, plus the per-threshold curves (as lists)."""

    f1: float
    recall: float
    precision: float
    threshold: float
    n_frames: int
    auc: float | None = None
    thresholds: tuple[float, ...] = ()
    f1_curve: tuple[float, ...] = ()
    recall_curve: tuple[float, ...] = ()
    precision_curve: tuple[float, ...] = ()

    def to_dict(self) -> dict:
        return asdict(self)


def f1_recall_precision(
    pred_maps,
    gt_heatmaps,
    frame_mask=None,
    thresholds=THRESHOLDS,
    normalize: bool = True,
) -> GazeScores:
    """F1, recall and precision at the best of `thresholds` (GLC protocol, steps 1-4 above).

    Args:
        pred_maps: predicted maps (probabilities, i.e. `softmax(logits / 2)` per frame).
        gt_heatmaps: target heatmaps of the same shape (binarised at > 0.001).
        frame_mask: which frames count (e.g. fixation frames); None = all.
        thresholds: thresholds on the min-max normalised prediction.
        normalize: apply the per-frame min-max normalisation (False if already done).
    """
    p = minmax_normalize(pred_maps) if normalize else _frames(pred_maps)
    g = _frames(gt_heatmaps) > GT_BINARY_THRESHOLD
    if p.shape != g.shape:
        raise ValueError(f"prediction frames {p.shape} and ground truth frames {g.shape} differ")
    keep = _mask(frame_mask, p.shape[0])
    p, g = p[keep], g[keep]
    if p.shape[0] == 0:
        raise ValueError("no frames selected")
    g_count = g.sum(axis=(1, 2))
    rec, prec = [], []
    for thr in thresholds:
        b = p > thr
        tp = (b & g).sum(axis=(1, 2))
        rec.append(float(np.mean(tp / (g_count + 1e-6))))
        prec.append(float(np.mean(tp / (b.sum(axis=(1, 2)) + 1e-6))))
    r, pr = np.array(rec), np.array(prec)
    f1 = 2 * r * pr / (r + pr + 1e-6)
    i = int(np.argmax(f1))
    return GazeScores(
        f1=float(f1[i]),
        recall=float(r[i]),
        precision=float(pr[i]),
        threshold=float(thresholds[i]),
        n_frames=int(p.shape[0]),
        thresholds=tuple(float(t) for t in thresholds),
        f1_curve=tuple(float(v) for v in f1),
        recall_curve=tuple(rec),
        precision_curve=tuple(prec),
    )


def _gaussian_kernel1d(sigma: float, truncate: float = 4.0) -> np.ndarray:
    radius = int(truncate * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    k = np.exp(-0.5 * (x / sigma) ** 2)
    return k / k.sum()


def gaussian_blur(img: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian filter of a 2-D array with mirror ('reflect', edge repeated) borders and a
    kernel radius of `int(4 sigma + 0.5)` (the conventions of `scipy.ndimage.gaussian_filter`)."""
    k = _gaussian_kernel1d(sigma)
    r = k.shape[0] // 2
    out = np.asarray(img, dtype=np.float64)
    for axis in (0, 1):
        pad = [(0, 0), (0, 0)]
        pad[axis] = (r, r)
        padded = np.pad(out, pad, mode="symmetric")
        n = out.shape[axis]
        acc = np.zeros_like(out)
        for j in range(k.shape[0]):
            sl = [slice(None), slice(None)]
            sl[axis] = slice(j, j + n)
            acc += k[j] * padded[tuple(sl)]
        out = acc
    return out


def center_of_mass(img: np.ndarray) -> tuple[float, float]:
    """`(row, col)` centre of mass; NaN where the map sums to 0."""
    total = img.sum()
    if total == 0:
        return (math.nan, math.nan)
    rows, cols = np.indices(img.shape)
    return (float((rows * img).sum() / total), float((cols * img).sum() / total))


def auc_scores(
    pred_maps, gaze_points, frame_mask=None, sigma: float | None = None, normalize: bool = True
) -> float:
    """GLC's AUC (step 5 above), averaged over the selected frames.

    Args:
        pred_maps: predicted maps `(..., h, w)`.
        gaze_points: true gaze `(..., 2)` normalised `(u, v)`; the target pixel is
            `(round(v * (h-1)), round(u * (w-1)))`, clipped into the map.
        frame_mask: frames to use (fixations, valid gaze); None = all.
        sigma: blur in pixels; default `3.2 * h / 64`.
    """
    p = minmax_normalize(pred_maps) if normalize else _frames(pred_maps)
    pts = _frames(gaze_points, ndim_tail=1)
    if pts.shape[0] != p.shape[0]:
        raise ValueError(f"{pts.shape[0]} gaze points for {p.shape[0]} frames")
    keep = _mask(frame_mask, p.shape[0])
    _, h, w = p.shape
    sigma = AUC_SIGMA_AT_64 * h / 64 if sigma is None else sigma
    scores = []
    for f in np.flatnonzero(keep):
        r, c = center_of_mass(p[f])
        z = np.zeros((h, w))
        if math.isnan(r) or math.isnan(c):
            z[h // 2, w // 2] = 1.0
        else:
            z[int(r), int(c)] = 1.0
        z = gaussian_blur(z, sigma)
        z = (z - z.min()) / (z.max() - z.min())
        gi = int(np.clip(np.rint(pts[f, 1] * (h - 1)), 0, h - 1))
        gj = int(np.clip(np.rint(pts[f, 0] * (w - 1)), 0, w - 1))
        scores.append(1.0 - float((z > z[gi, gj]).sum()) / (h * w))
    if not scores:
        raise ValueError("no frames selected")
    return float(np.mean(scores))


def evaluate_gaze(
    pred_maps,
    gaze_points,
    valid=None,
    frame_mask=None,
    gt_heatmaps=None,
    thresholds=THRESHOLDS,
) -> GazeScores:
    """All GLC metrics for predicted maps against gaze points.

    Args:
        pred_maps: `(N, [1,] T, h, w)` predicted probability maps.
        gaze_points: `(N, T, 2)` normalised `(u, v)`.
        valid: `(N, T)` whether the gaze point exists (missing -> uniform target, excluded from AUC).
        frame_mask: `(N, T)` frames to score (e.g. fixations); combined with `valid` for the AUC.
        gt_heatmaps: targets; default the training targets (`gazereg.gaze.glc.targets.gaze_target_maps`).
    """
    p = _frames(pred_maps)
    pts = torch.as_tensor(_frames(gaze_points, ndim_tail=1), dtype=torch.float32)
    n = p.shape[0]
    vmask = _mask(valid, n)
    fmask = _mask(frame_mask, n)
    if gt_heatmaps is None:
        gt_heatmaps = gaze_target_maps(pts, torch.as_tensor(vmask), p.shape[1:]).numpy()
    scores = f1_recall_precision(p, gt_heatmaps, fmask, thresholds)
    in_frame = ((pts >= 0) & (pts <= 1)).all(-1).numpy()
    auc_mask = fmask & vmask & in_frame
    auc = auc_scores(p, pts.numpy(), auc_mask) if auc_mask.any() else None
    return GazeScores(**{**scores.to_dict(), "auc": auc})


# ---- baselines -------------------------------------------------------------------------------------
def uniform_maps(shape: tuple[int, ...]) -> torch.Tensor:
    """Uniform maps `(..., h, w)` summing to 1 per frame (after min-max they are all 0: F1 = 0)."""
    h, w = shape[-2:]
    return torch.full(shape, 1.0 / (h * w))


def center_prior_maps(
    shape: tuple[int, ...],
    center: tuple[float, float] = (0.5, 0.5),
    sigma: tuple[float, float] = (0.15, 0.15),
) -> torch.Tensor:
    """Gaussian centre-bias maps `(..., h, w)` (per frame summing to 1), the same for every frame.

    `center = (u, v)` and `sigma = (su, sv)` are in normalised image units; `fit_center_prior` estimates
    them from training gaze points.
    """
    h, w = shape[-2:]
    v = (torch.arange(h, dtype=torch.float64) + 0.5) / h
    u = (torch.arange(w, dtype=torch.float64) + 0.5) / w
    g = torch.exp(
        -0.5 * (((u[None, :] - center[0]) / sigma[0]) ** 2 + ((v[:, None] - center[1]) / sigma[1]) ** 2)
    )
    g = (g / g.sum()).float()
    return g.expand(shape).clone()


def fit_center_prior(gaze_points, valid=None) -> tuple[tuple[float, float], tuple[float, float]]:
    """Mean and standard deviation of in-frame gaze points `(..., 2)` -> `(center, sigma)`."""
    pts = _frames(gaze_points, ndim_tail=1)
    keep = _mask(valid, pts.shape[0]) & ((pts >= 0) & (pts <= 1)).all(-1)
    pts = pts[keep]
    if pts.shape[0] < 2:
        return (0.5, 0.5), (0.15, 0.15)
    mu, sd = pts.mean(0), np.maximum(pts.std(0), 1e-3)
    return (float(mu[0]), float(mu[1])), (float(sd[0]), float(sd[1]))
