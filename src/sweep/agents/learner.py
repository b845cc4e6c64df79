"""``Learner``: the one contract between a learner (PPO, SAC, TD3) and everything that reads or writes its networks.

``SB3PPO``, ``SB3SAC``, ``SB3TD3`` (SB3's own classes, the references) and ``JaxPPO``, ``JaxSAC``, ``JaxTD3`` (their
compiled equivalents) implement it, and remedies, diagnostics and checkpoints use nothing else: no ``isinstance`` on
the learner, no ``model.policy``, no private SB3 fields outside the learner modules. tests/test_learner.py and
tests/test_offpolicy.py hold them to it.

Parameters are NumPy arrays named as the SB3 policy's ``state_dict`` in torch's (out, in) layout (SAC's entropy
coefficient as ``log_ent_coef``); ``networks`` says which arrays form which layer of each *trained* network, with its
role (``policy``: PPO's policy network, the actor; ``value``: PPO's value network, each critic) that remedy settings
name (``sweep.agents.networks``). Target networks are not parameters: ``target_arrays`` reads them, ``reset_targets``
copies the networks into them, nothing else writes them. ``groups`` maps the words of a remedy's ``params`` setting
to parameter-name prefixes.

Random state. A remedy draws only from ``learner.rng`` (``networks.remedy_rng(seed)``), never from a global
RNG; ``learner_state`` holds that generator and every other one the learner owns (JAX: its action noise),
and the checkpoint stores it together with torch's, NumPy's and Python's global RNGs. Both learners draw
PPO's minibatch order from NumPy's *global* RNG (``np.random.permutation`` per epoch), as SB3's
``RolloutBuffer.get`` does: that keeps the two learners update-for-update equal for the same seed, and is
why a remedy must never touch ``np.random``.

The loop (``sweep.training.loop``) drives a learner one turn at a time: ``begin``, then per turn ``collect``
(a ``RolloutRecord``), ``log_rollout`` (at a round's end) and ``update`` (an ``UpdateRecord``, SAC/TD3: an
``OffPolicyUpdate``); ``sweep.agents.onpolicy`` implements these for PPO on SB3's ``OnPolicyAlgorithm`` steps (a turn
is a round: one rollout, one update), ``sweep.agents.offpolicy`` for SAC and TD3 (a turn is ``train_freq`` env steps
and ``gradient_steps`` gradient steps; a round, ``round_steps`` env steps). Nothing outside the learner modules reads SB3's
loop fields (logger values, ``rollout_buffer``, ``ep_info_buffer``, ``lr_schedule``; tests/test_learner.py).

Per-step remedies. ``add_step_transform(t)``: ``t`` (a ``StepTransform``) acts on the parameters after every
optimizer step from then on, inside the update: a step hook on SB3's optimizer, traced into the jitted update on
JAX. A remedy that must act more often than once per update (weight clipping) is one; the final policy is then the
one the transform left, since it acts inside the last update too.

Optimizer state. ``reset_optimizer(masks)`` zeroes Adam's first and second moments where a mask is True
(the step count, hence the bias correction, is kept): what ReDo and CBP do to the weights they re-initialise.
"""
from __future__ import annotations

from typing import Any, Mapping, NamedTuple, Protocol, runtime_checkable

import numpy as np

from sweep.agents.networks import Network
from sweep.training.records import RolloutRecord, Samples, UpdateRecord


class Hidden(NamedTuple):
    """One hidden layer's activations on a batch (B x units): the input of the nonlinearity and its output."""

    pre: np.ndarray
    post: np.ndarray


class StepTransform(Protocol):
    """A per-step remedy: what it makes of the parameters right after each optimizer step (SGD step), on both
    learners. ``params`` maps names to arrays of the learner's own kind: the parameters that optimizer steps (PPO:
    all; SAC/TD3: the actor's, or the critics', each after its own optimizer's step, so a step never writes weights a
    later loss of the same gradient step still holds in its graph) and ``xp`` is their module (``torch`` on SB3,
    where it runs in a step hook of the optimizer; ``jax.numpy`` on JAX, where it is traced into the compiled
    update): a pure function of its arguments and of constants fixed before training, using only functions both
    modules share (``xp.clip``, ``xp.where``, arithmetic). Returns the new values of the parameters it changes."""

    def __call__(self, params: Mapping[str, Any], xp: Any) -> dict[str, Any]: ...


@runtime_checkable
class Learner(Protocol):
    num_timesteps: int
    rng: np.random.Generator               # the remedies' generator (checkpointed)
    networks: tuple[Network, ...]          # the trained networks: PPO's (policy, value); (actor, critic_0, critic_1)
    minibatches_per_update: int            # gradient steps of one update (PPO: n_epochs x rollout / batch_size; a round's)
    groups: dict[str, tuple[str, ...]]     # a remedy's ``params`` words (policy, value, log_std) -> parameter-name prefixes

    # -- the loop's steps --
    def begin(self, timesteps: int, reset: bool = True) -> int:
        """Set up for ``timesteps`` more steps (``reset``: from 0, env reset); returns the timestep to train to."""

    def collect(self) -> RolloutRecord:
        """One turn's env steps into the rollout buffer (PPO) or the replay buffer (SAC, TD3)."""

    def set_logger(self, logger) -> None:
        """The SB3 ``Logger`` the learner's log lines go to (the loop's: written to, never read)."""

    def log_rollout(self, iteration: int) -> None:
        """Write the rollout's log line (``rollout/*``, ``time/*``) with everything recorded since the last."""

    def update(self) -> UpdateRecord:
        """The turn's update: one PPO update on the last rollout, or SAC's/TD3's gradient steps on the replay buffer."""

    def recent_samples(self, n: int) -> Samples:
        """The ``n`` most recent steps of the last rollout (PPO) or transitions of the replay buffer (SAC, TD3)."""

    def set_learning_rate(self, value: float | None = None) -> float:
        """Every following update uses ``value`` (None: the rate in force now); returns it."""

    def training_state(self) -> dict[str, Any]:
        """The loop state (timesteps, last observations, episode buffers) and ``learner_state()``."""

    def load_training_state(self, state: dict[str, Any]) -> None:
        """The loop state of ``training_state`` (before ``begin(..., reset=False)``)."""

    # -- the networks --
    def parameter_arrays(self) -> dict[str, np.ndarray]:
        """Copies of every parameter, by name."""

    def write_parameters(self, arrays: Mapping[str, np.ndarray]) -> None:
        """Overwrite the named parameters (others unchanged); the next action and update use them."""

    def initial_parameters(self) -> dict[str, np.ndarray]:
        """theta_0: the parameters as the learner was built (copies)."""

    def target_arrays(self) -> dict[str, np.ndarray]:
        """Copies of the target networks' parameters, by name (off-policy; PPO: none). Not trained, not written by
        remedies: they follow their networks (Polyak) and ``reset_targets``."""

    def reset_targets(self, names=None) -> None:
        """The target copies of the named parameters (None: every target network) become copies of them (off-policy;
        PPO has none): what a reset does."""

    def hidden_activations(self, obs: np.ndarray) -> dict[str, list[Hidden]]:
        """Per network (``policy``, ``value``), each hidden layer's (pre, post) activations on ``obs``."""

    def reset_optimizer(self, masks: Mapping[str, np.ndarray]) -> None:
        """Zero Adam's m and v of the parameter entries where ``masks[name]`` is True; step count kept."""

    def reset_optimizer_state(self) -> None:
        """Adam as it was built: every moment zero and the step count zero (reset-all)."""

    def optimizer_moments(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Adam's (m, v) per parameter (zeros before the first step)."""

    def use_l2(self, coef: float, mode: str = "decoupled", params=("policy", "value"), biases: bool = True,
               anchor: str = "zero") -> None:
        """Weight decay toward 0 (``anchor=zero``, L2) or toward theta_0 (``anchor=init``, L2-Init)."""

    def add_step_transform(self, transform: StepTransform) -> None:
        """Apply ``transform`` after every optimizer step from now on (a per-step remedy: weight clipping)."""

    def loss_grad_norm(self, samples: Samples) -> float:
        """Norm of the learner's loss gradient on ``samples`` (``recent_samples``) at the current parameters, before
        clipping: PPO's total loss; SAC's and TD3's critic TD loss."""

    def learner_state(self) -> dict[str, Any]:
        """Parameters, optimizer state and the learner's own generators, for a checkpoint."""

    def load_learner_state(self, state: dict[str, Any]) -> None:
        """Restore ``learner_state`` (parameters, optimizer, the learner's generators)."""


__all__ = ["Hidden", "Learner", "StepTransform"]
