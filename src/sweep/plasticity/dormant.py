"""Dormant units (Sokar et al. 2023, ReDo), the readings a tanh network can show, and the other per-layer
plasticity statistics, on NumPy arrays of hidden activations (batch B x units H), whichever learner made them.

Unit i's score is

    s_i = E_x |h_i(x)| / ( 1/H * sum_k E_x |h_k(x)| )

and the unit is tau-dormant when s_i <= tau. The ratio is the share of dormant units over all hidden
layers (output layers excluded). A layer whose activations are all zero is entirely dormant.
"""
from __future__ import annotations

import numpy as np


def dormant_scores(h: np.ndarray) -> np.ndarray:
    mean_abs = np.abs(h).mean(axis=0)
    layer_mean = mean_abs.mean()
    if layer_mean <= 0:
        return np.zeros_like(mean_abs)
    return mean_abs / layer_mean


def dormant_mask(h: np.ndarray, tau: float) -> np.ndarray:
    return dormant_scores(h) <= tau


def dormant_ratio(layers: list[np.ndarray], tau: float) -> tuple[float, list[float]]:
    """(ratio over all units of all layers, ratio per layer)."""
    return pooled([dormant_mask(np.asarray(h), tau) for h in layers])


def pooled(masks: list[np.ndarray]) -> tuple[float, list[float]]:
    """(share of units over all layers, share per layer) of per-unit boolean masks."""
    total = sum(m.size for m in masks)
    return sum(int(m.sum()) for m in masks) / max(total, 1), [float(m.mean()) for m in masks]


def dead_tanh_mask(h: np.ndarray, saturation: float = 0.99, fraction: float = 0.99) -> np.ndarray:
    """Units saturated (|h| > ``saturation``) on at least ``fraction`` of the batch: a tanh unit stuck at +-1
    passes no gradient and carries no information, yet Sokar's |h| score rates it as maximally active. This is
    Dohare et al. (2024)'s dead unit ("active on <= 1% of inputs") carried over to a saturating activation."""
    return (np.abs(h) > saturation).mean(axis=0) >= fraction


def signed_mean_mask(h: np.ndarray, tau: float) -> np.ndarray:
    """Units whose output averages to about 0 over the batch: |E_x h_i| / (1/H sum_k E_x |h_k|) <= tau. NOT the
    same as a unit that does nothing (a unit swinging between -1 and +1 scores 0); a candidate for what the
    paper computed, measured beside the others."""
    layer_mean = np.abs(h).mean(axis=0).mean()
    if layer_mean <= 0:
        return np.ones(h.shape[1], bool)
    return np.abs(h.mean(axis=0)) / layer_mean <= tau


def active_ratio(layers: list[np.ndarray], activation: str, saturation: float = 0.99) -> tuple[float, list[float]]:
    """Plasticine's active-unit share over (sample, unit) pairs: ReLU, h > 0; tanh, 1 - share with |h| > saturation."""
    def share(h):
        return float((h > 0).mean()) if activation == "relu" else float(1.0 - (np.abs(h) > saturation).mean())
    n = sum(np.asarray(h).size for h in layers)
    return sum(share(h) * np.asarray(h).size for h in layers) / max(n, 1), [share(h) for h in layers]


def saturated_ratio(layers: list[np.ndarray], threshold: float) -> float:
    """Share of (sample, unit) activations with |h| > threshold (tanh saturation)."""
    n = sum(np.asarray(h).size for h in layers)
    return float(sum(int((np.abs(h) > threshold).sum()) for h in layers)) / max(n, 1)


def srank(features: np.ndarray, delta: float = 0.01) -> int:
    """Effective rank (Kumar et al. 2021): smallest k with sum_{i<=k} sigma_i >= (1 - delta) sum_i sigma_i."""
    sigma = np.linalg.svd(np.asarray(features, dtype=np.float64), compute_uv=False)
    total = sigma.sum()
    if total <= 0:
        return 0
    cumulative = np.cumsum(sigma) / total
    return int(np.searchsorted(cumulative, 1.0 - delta)) + 1
