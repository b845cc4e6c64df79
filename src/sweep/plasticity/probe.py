"""A direct plasticity probe (Lyle et al. 2022, "Understanding and preventing capacity loss in RL").

At every change of condition (the wind's segment) and at the end of training, a *copy* of the policy network is fitted for N
steps (Adam, minibatches of the most recent observations) to fixed random regression targets,

    min_theta  1/B sum_x || f_theta(x) - y(x) ||^2,     y = g(x) / std(g(x)),

with g a network of the same shape drawn afresh from the init distribution (orthogonal weights, gain
sqrt 2, a unit-gain head) by the probe's own generator: a fixed random function of the observations,
standardised per output, so a plastic network fits it in a few hundred steps (loss ~0 is reachable, 1 is
the loss of predicting 0),

and the loss is logged after N/10 steps (``plasticity/probe_loss_early``) and after N steps
(``plasticity/probe_loss``, the mean of the last N/10 steps). A network that has lost plasticity fits worse
than a fresh one (tests/test_plasticity.py saturates units by hand to check it). With ``fresh`` (default) the
same fit is also run from a network drawn afresh from the init distribution, on the same observations, targets
and minibatches (``plasticity/probe_loss_fresh``): the reference at the same moment, since the observations
(and so the difficulty of the targets) change as the policy learns; probe_loss / probe_loss_fresh > 1 is
plasticity lost relative to a new network. The copy is a torch
module built from ``learner.parameter_arrays()`` (either learner); the probe draws only from its own
generator, so the learner's weights, optimizer state and every RNG are untouched (tested).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from sweep.agents.learner import Learner
from sweep.agents.networks import HIDDEN_GAIN, LAYER_NORM_EPS, adam_kwargs, fresh_parameters, orthogonal
from sweep.config import MISSING, Activation, HookSettings, at_least, positive, positive_int
from sweep.training.hooks import Hook
from sweep.training.records import Condition


def probe_fit(learner: Learner, observations: np.ndarray, steps: int = 500, batch_size: int = 256,
              lr: float = 1e-3, seed: int = 0, activation: str = "tanh", fresh: bool = False) -> tuple[float, float]:
    """(loss after steps/10, final loss) of fitting a copy of the policy network to random targets; with
    ``fresh``, of fitting a network of its shape drawn afresh (weights from a generator of its own, so the
    targets and minibatches are those of the copy's fit with the same ``seed``)."""
    net = learner.networks[0]
    arrays = learner.parameter_arrays()
    if fresh:
        shapes = {k: v.shape for k, v in arrays.items()}
        arrays = fresh_parameters(shapes, (net,), np.random.default_rng([int(seed), 1]))
    params = {k: torch.tensor(v, dtype=torch.float32, requires_grad=True) for k, v in arrays.items()
              if k.startswith(tuple(net.linears) + tuple(n for n in net.norms if n))}
    act = torch.tanh if activation == "tanh" else torch.relu

    def forward(x: torch.Tensor) -> torch.Tensor:
        for layer, norm in zip(net.hidden, net.norms):
            x = x @ params[f"{layer}.weight"].T + params[f"{layer}.bias"]
            if norm:
                x = torch.nn.functional.layer_norm(x, x.shape[-1:], params[f"{norm}.weight"], params[f"{norm}.bias"],
                                                   LAYER_NORM_EPS)
            x = act(x)
        return x @ params[f"{net.head}.weight"].T + params[f"{net.head}.bias"]

    rng = np.random.default_rng(seed)   # the probe's own generator: no global RNG is touched
    columns = arrays[f"{net.hidden[0]}.weight"].shape[1]   # an asymmetric actor reads the leading columns
    obs = torch.as_tensor(np.asarray(observations, np.float32)[:, :columns])
    y = np.asarray(observations, np.float64)[:, :columns]
    for layer in (*net.hidden, net.head):   # g: a fresh random network of the same shape
        w = orthogonal(arrays[f"{layer}.weight"].shape, HIDDEN_GAIN if layer != net.head else 1.0, rng)
        y = y @ w.T
        y = np.tanh(y) if layer != net.head else y
    targets = torch.as_tensor((y - y.mean(0)) / (y.std(0) + 1e-8), dtype=torch.float32)
    optimizer = torch.optim.Adam(params.values(), lr=lr, **adam_kwargs(1e-8))   # torch's default eps
    losses = np.empty(steps)
    for step in range(steps):
        idx = torch.as_tensor(rng.integers(0, len(obs), min(batch_size, len(obs))))
        loss = torch.mean((forward(obs[idx]) - targets[idx]) ** 2)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses[step] = loss.item()
    tenth = max(steps // 10, 1)
    return float(losses[tenth - 1]), float(losses[-tenth:].mean())


class PlasticityProbe(Hook):
    """Runs ``probe_fit`` at the first rollout end under each new condition (``at_change``) and after the last
    update (``at_end``), on the learner's ``observations`` most recent observations; ``steps=0``: never."""

    @dataclass
    class Settings(HookSettings):   # conf/hooks/probe.yaml: the plasticity.probe.* keys
        steps: int = at_least(0, unit=" (0: no probe)")
        batch_size: int = positive_int()
        lr: float = positive()
        observations: int = positive_int()
        activation: Activation = MISSING
        seed: int = at_least(0)
        fresh: bool = MISSING

    def __init__(self, steps: int = 500, batch_size: int = 256, lr: float = 1e-3, observations: int = 1024,
                 activation: str = "tanh", seed: int = 0, fresh: bool = True) -> None:
        self.fresh = bool(fresh)
        self.steps, self.batch_size, self.lr = int(steps), int(batch_size), float(lr)
        self.n_obs, self.activation, self.seed = int(observations), activation, int(seed)
        self.probes = 0

    def state_dict(self) -> dict:
        return {"probes": self.probes}

    def load_state_dict(self, state: dict) -> None:
        self.probes = state["probes"]

    def measure(self, learner: Learner) -> dict[str, float]:
        if self.steps <= 0:
            return {}
        obs = learner.recent_samples(self.n_obs).observations
        args = (obs, self.steps, self.batch_size, self.lr, self.seed + self.probes, self.activation)
        early, final = probe_fit(learner, *args)
        out = {"plasticity/probe_loss_early": early, "plasticity/probe_loss": final}
        if self.fresh:
            out["plasticity/probe_loss_fresh"] = probe_fit(learner, *args, fresh=True)[1]
        self.probes += 1
        return out

    def at_change(self, learner: Learner, condition: Condition) -> dict[str, float]:
        return self.measure(learner)

    def at_end(self, learner: Learner, update) -> dict[str, float]:
        return self.measure(learner)
