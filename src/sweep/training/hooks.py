"""Hooks: everything that extends training (remedies, RECOM, diagnostics, the probe, evaluation, best-policy
keeping, the NaN guard, the checkpointer, the progress line), one class each, built from config.

A hook has one method per moment of the loop (``sweep.training.loop``) and *returns* what it wants logged:

    setup(learner, training)        training starts; when resuming, the learner has its timesteps and episode
                                    buffers back, its weights and the hooks' states come after setup
    after_rollout(learner, rollout) a rollout ended, before the update that learns from it
    at_change(learner, condition)   the first rollout end under a new condition of the schedule, unless it is
                                    the run's last rollout (a change the run meets as it ends: no training
                                    follows it, and a fresh twin's final policy would be a fresh draw)
    after_update(learner, update)   an update ended and training goes on (the next rollout uses what hooks leave)
    at_end(learner, update)         the last update ended (what the hooks return is logged at the final step)

Its state (``state_dict`` / ``load_state_dict``) is checkpointed under its name, the config key it was built
from. A hook that reads another's result names it in ``requires`` and finds it in ``training.hooks[name]``
at setup; the other must come earlier in the list (checked when the hooks are built). None reads the logger.

``build_hooks(cfg)``: the agent's enabled remedies (``agent.<key>`` blocks with a ``_target_``, in config order),
then the ``hooks`` config (conf/hooks/, in the declared order); a hook with ``runs_last`` (the checkpointer,
which saves what every other hook left) is moved to the end. Each block is ``hydra.utils.instantiate``d
without its ``enabled`` key.
"""
from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, Iterator, Mapping

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from sweep.config import remedy_blocks, runs
from sweep.training.records import Condition, RolloutRecord, UpdateRecord

if TYPE_CHECKING:
    from sweep.agents.learner import Learner
    from sweep.training.loop import Training

log = logging.getLogger("sweep")
Metrics = dict[str, float]


class Hook:
    """Base class: every moment does nothing and logs nothing; no state.

    What a hook built from config declares beside itself (README "Add a remedy"):
      ``Settings``      its schema: a ``sweep.config.HookSettings`` dataclass, one field per ``__init__`` argument
                        (required: a block whose class has none is a config error);
      ``check_config``  rules across keys, raising ``sweep.config.ConfigError`` before training (optional);
      ``curves``        the ``sweep.metrics.Curve``s of what it logs, which the report draws (optional);
      ``algorithms``    the algorithms it works with (default: all); another is refused before training.
    """

    name: str = ""
    algorithms: tuple[str, ...] = ("ppo", "sac", "td3")   # the agent.algorithm values it works with (validate)
    requires: tuple[str, ...] = ()
    runs_last: bool = False
    Settings: type | None = None
    curves: tuple = ()

    @classmethod
    def check_config(cls, where: str, settings: dict, cfg: dict) -> None:
        """Raise ``ConfigError`` if this hook cannot run with the resolved config ``cfg`` (its block at ``where``,
        e.g. ``agent.recom``, holding ``settings``)."""

    def setup(self, learner: Learner, training: Training) -> None:
        pass

    def after_rollout(self, learner: Learner, rollout: RolloutRecord) -> Metrics:
        return {}

    def at_change(self, learner: Learner, condition: Condition) -> Metrics:
        return {}

    def after_update(self, learner: Learner, update: UpdateRecord) -> Metrics:
        return {}

    def at_end(self, learner: Learner, update: UpdateRecord | None) -> Metrics:
        return {}

    def state_dict(self) -> dict[str, Any]:
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        pass


class Hooks:
    """The run's hooks in order; each moment calls them all and merges what they return (a later hook's value of
    the same key wins). ``on_metrics`` receives each hook's metrics as soon as it returns them (the loop keeps
    what an update's hooks return for the next log line, so a checkpoint taken by a later hook holds it)."""

    def __init__(self, hooks: list[Hook]) -> None:
        for hook in hooks:   # one built from config is named by its key; one built by hand by its class
            hook.name = hook.name or type(hook).__name__
        names = [h.name for h in hooks]
        if len(set(names)) != len(names) or not all(names):
            raise ValueError(f"hooks need distinct non-empty names, got {names}")
        self.hooks = [h for h in hooks if not h.runs_last] + [h for h in hooks if h.runs_last]
        for i, hook in enumerate(self.hooks):
            before = {h.name for h in self.hooks[:i]}
            for need in hook.requires:
                if need not in before:
                    raise ValueError(f"hook {hook.name!r} ({type(hook).__name__}) requires hook {need!r} before it; "
                                     f"the hooks are, in order: {', '.join(h.name for h in self.hooks)}")

    def __iter__(self) -> Iterator[Hook]:
        return iter(self.hooks)

    def __getitem__(self, name: str) -> Hook:
        for hook in self.hooks:
            if hook.name == name:
                return hook
        raise KeyError(f"no hook {name!r}; the hooks are: {', '.join(h.name for h in self.hooks)}")

    def __contains__(self, name: str) -> bool:
        return any(h.name == name for h in self.hooks)

    def call(self, moment: str, learner: Learner, arg: Any, on_metrics=None) -> Metrics:
        out: Metrics = {}
        for hook in self.hooks:
            metrics = getattr(hook, moment)(learner, arg) or {}
            if on_metrics is not None:
                on_metrics(metrics)
            out.update(metrics)
        return out

    def state_dict(self) -> dict[str, dict[str, Any]]:
        return {h.name: h.state_dict() for h in self.hooks}

    def load_state_dict(self, states: Mapping[str, dict[str, Any]]) -> None:
        """Each hook gets the state saved under its name; a hook with none starts afresh (e.g. one added since)."""
        for hook in self.hooks:
            if hook.name in states:
                hook.load_state_dict(states[hook.name])
            else:
                log.warning("hook %r has no state in the checkpoint; it starts afresh", hook.name)
        for name in set(states) - {h.name for h in self.hooks}:
            log.warning("the checkpoint holds state of hook %r, which this run does not have; ignored", name)


def _build(name: str, spec: DictConfig) -> Hook | None:
    if not runs(spec):
        return None
    plain = OmegaConf.to_container(spec, resolve=True)   # resolved where it sits: its interpolations reach the root
    plain.pop("enabled", None)
    hook = instantiate(plain, _recursive_=False)   # a hook given config blocks (eval, env) builds from them itself
    if not isinstance(hook, Hook):
        raise TypeError(f"{name}: {spec._target_} built a {type(hook).__name__}, not a sweep.training.hooks.Hook")
    hook.name = name
    return hook


def remedy_hooks(agent: DictConfig) -> list[Hook]:
    """The agent's enabled remedies (``sweep.config.remedy_blocks``), in config order."""
    names = remedy_blocks(OmegaConf.to_container(agent, resolve=True))
    return [h for h in (_build(k, agent[k]) for k in names) if h is not None]


def build_hooks(cfg: DictConfig) -> Hooks:
    """The run's hooks: the agent's remedies, then ``cfg.hooks`` in declared order (see the module docstring)."""
    hooks = remedy_hooks(cfg.agent) + [h for h in (_build(k, v) for k, v in cfg.hooks.items()) if h is not None]
    return Hooks(hooks)


__all__ = ["Hook", "Hooks", "Metrics", "build_hooks", "remedy_hooks"]
