"""Dormant units (Sokar et al. 2023, ReDo) and the other per-layer plasticity statistics.

For a hidden layer with activations h (batch B x units H), unit i's score is

    s_i = E_x |h_i(x)| / ( 1/H * sum_k E_x |h_k(x)| )

and the unit is tau-dormant when s_i <= tau. The ratio is the share of dormant units over all hidden
layers (output layers excluded). A layer whose activations are all zero is entirely dormant.
"""
from __future__ import annotations

import torch
from torch import nn


def hidden_activations(mlp: nn.Sequential, x: torch.Tensor) -> list[torch.Tensor]:
    """Outputs of every activation module of an SB3 MLP (Linear, act, Linear, act, ...)."""
    out = []
    for module in mlp:
        x = module(x)
        if not isinstance(module, nn.Linear):
            out.append(x)
    return out


def dormant_scores(h: torch.Tensor) -> torch.Tensor:
    mean_abs = h.abs().mean(dim=0)
    layer_mean = mean_abs.mean()
    if layer_mean <= 0:
        return torch.zeros_like(mean_abs)
    return mean_abs / layer_mean


def dormant_mask(h: torch.Tensor, tau: float) -> torch.Tensor:
    return dormant_scores(h) <= tau


def dormant_ratio(layers: list[torch.Tensor], tau: float) -> tuple[float, list[float]]:
    """(ratio over all units of all layers, ratio per layer)."""
    masks = [dormant_mask(h, tau) for h in layers]
    total = sum(int(m.numel()) for m in masks)
    overall = sum(int(m.sum()) for m in masks) / max(total, 1)
    return overall, [float(m.float().mean()) for m in masks]


def saturated_ratio(layers: list[torch.Tensor], threshold: float) -> float:
    """Share of (sample, unit) activations with |h| > threshold (tanh saturation)."""
    n = sum(h.numel() for h in layers)
    return float(sum(int((h.abs() > threshold).sum()) for h in layers)) / max(n, 1)


def srank(features: torch.Tensor, delta: float = 0.01) -> int:
    """Effective rank (Kumar et al. 2021): smallest k with sum_{i<=k} sigma_i >= (1 - delta) sum_i sigma_i."""
    sigma = torch.linalg.svdvals(features.double())
    total = sigma.sum()
    if total <= 0:
        return 0
    cumulative = torch.cumsum(sigma, dim=0) / total
    return int(torch.searchsorted(cumulative, torch.tensor(1.0 - delta, dtype=cumulative.dtype)).item()) + 1
