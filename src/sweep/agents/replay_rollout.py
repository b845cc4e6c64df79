"""Compiled collect for the JAX SAC and TD3: SB3's off-policy ``collect_rollouts`` for the hover env, in numba.

One call of ``fly_replay`` steps the env vector step after vector step into SB3's ``ReplayBuffer`` arrays until an
episode ends or ``n_steps`` vector steps are done; the caller does what needs Python (infos, resets, the episode
buffer) and calls again. Per step and vehicle, as SB3's ``OffPolicyAlgorithm._sample_action`` + ``_store_transition``:

* warm-up (``warm`` > 0 steps left, SB3's ``num_timesteps < learning_starts``): a uniform action in [-1, 1]^4;
* else SAC: a = tanh(mu(s) + exp(clamp(log_std(s), -20, 2)) * eps) (the squashed Gaussian's sample); TD3: a = tanh(mu(s));
* ``action_noise`` (TD3; SAC with ``action_noise_std``): a <- clip(a + sigma * xi, -1, 1), after the warm-up's too;
* the buffer keeps (s, s', a, r x reward_scale, done, truncated): s' the terminal observation of a vehicle whose episode
  ended (SB3's ``terminal_observation``), done = terminated or truncated, and the time-limit flag as SB3's
  ``timeouts`` (its sample then uses done x (1 - timeout)).

The actor runs from float32 weights laid out (in, out) per layer (``rollout.Mlp``), so its hidden layers are
``rollout.mlp``'s (tanh as XLA's, LayerNorm as torch's). All random numbers are drawn beforehand by the caller.
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from sweep.agents.rollout import FASTMATH, mlp, tanh, widest
from sweep.envs.backends.fast import step_vehicles
from sweep.envs.gusts import add_gusts
from sweep.envs.hover import action_to_rotor_speed, task_outcome

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0   # SB3's SAC actor clamp


class Actor(NamedTuple):
    """The actor as the compiled loop reads it: ``mu`` (hidden layers + the mean head; TD3: its whole MLP) and, for SAC,
    ``log_std`` (the same hidden layers + the log-std head); tanh squashes the output."""
    mu: tuple          # rollout.Mlp
    log_std: tuple     # rollout.Mlp (SAC) or mu again (TD3, unused)
    sac: bool
    relu: bool
    layer_norm: bool


class Replay(NamedTuple):
    """SB3's ``ReplayBuffer`` arrays, (buffer_size, N, ...), written at ``pos`` (the caller keeps pos and full)."""
    observations: np.ndarray
    next_observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    timeouts: np.ndarray


class Draws(NamedTuple):
    """The random numbers of ``n_steps`` vector steps: the Gaussian eps of SAC's sample, the uniform warm-up actions,
    and the exploration noise's standard normals (each (n_steps, N, A))."""
    eps: np.ndarray
    uniform: np.ndarray
    noise: np.ndarray


@numba.njit(cache=True, fastmath=FASTMATH)
def act(obs_row, actor, eps_row, h_in, h_out, mean, log_std, out):
    """The actor's action for one observation: SAC's squashed sample with ``eps_row`` (deterministic with zeros),
    TD3's tanh(mu)."""
    mlp(obs_row, actor.mu, actor.relu, actor.layer_norm, h_in, h_out, mean)
    if actor.sac:
        mlp(obs_row, actor.log_std, actor.relu, actor.layer_norm, h_in, h_out, log_std)
        for a in range(out.shape[0]):
            s = min(max(log_std[a], np.float32(LOG_STD_MIN)), np.float32(LOG_STD_MAX))
            out[a] = tanh(mean[a] + np.exp(s) * eps_row[a])
    else:
        for a in range(out.shape[0]):
            out[a] = tanh(mean[a])


@numba.njit(cache=True)
def fly_replay(t, n_steps, warm, obs, dones, draws, noise_sigma, wind, actor, replay, pos, kernel):
    """Vector steps t, t+1, ... until some episode ends or t = n_steps, each written at replay row ``pos`` (wrapping);
    returns (next t, next pos, wrapped: whether pos passed the end). ``warm``: steps left of the warm-up (uniform
    actions) at t. ``obs`` (N, D) is overwritten with the observation after the last step (the caller resets the
    vehicles whose episode ended). ``noise_sigma`` (A,): the exploration noise's std (zeros: none)."""
    vehicles, physics, outcome = kernel.vehicles, kernel.physics, kernel.outcome
    t_idx, ep_return, reward_scale = kernel.t_idx, kernel.ep_return, kernel.reward_scale
    rewards, terminated, truncated = outcome.rewards, outcome.terminated, outcome.truncated
    task, gust_filters = kernel.task, kernel.gust_filters
    mean_wind, gust_sigma, gust_draws = wind
    turbulent = gust_draws.shape[0] > 0
    n, n_act = obs.shape[0], draws.eps.shape[2]
    size = replay.observations.shape[0]
    width = widest(widest(obs.shape[1], actor.mu), actor.log_std)
    h_in = np.empty(width, np.float32)
    h_out = np.empty(width, np.float32)
    mean = np.empty(n_act, np.float32)
    log_std = np.empty(n_act, np.float32)
    action = np.empty(n_act, np.float32)
    cmd = np.empty((n, n_act))
    clipped = np.empty((n, n_act), np.float32)
    wind_now = np.empty((n, 3))
    speed_min, speed_max = physics.speed_min, physics.speed_max
    wrapped = False
    while t < n_steps:
        for i in range(n):
            if t < warm:
                for a in range(n_act):
                    action[a] = draws.uniform[t, i, a]
            else:
                act(obs[i], actor, draws.eps[t, i], h_in, h_out, mean, log_std, action)
            for a in range(n_act):
                c = min(max(action[a] + noise_sigma[a] * draws.noise[t, i, a], np.float32(-1.0)), np.float32(1.0))
                clipped[i, a] = c
                replay.actions[pos, i, a] = c
                cmd[i, a] = action_to_rotor_speed(c, speed_min, speed_max)
            for k in range(obs.shape[1]):
                replay.observations[pos, i, k] = obs[i, k]
            for k in range(3):
                wind_now[i, k] = mean_wind[t, k]
        if turbulent:
            add_gusts(gust_filters, gust_draws[t], gust_sigma[t], wind_now)
        step_vehicles(vehicles, cmd, wind_now, physics)
        task_outcome(vehicles, clipped, t_idx, task, obs, outcome, kernel.history, mean_wind[t], kernel.vehicle)
        any_done = False
        for i in range(n):
            ep_return[i] += rewards[i]
            replay.rewards[pos, i] = rewards[i] * np.float32(reward_scale)
            done = terminated[i] or truncated[i]
            dones[i] = done
            replay.dones[pos, i] = np.float32(done)
            replay.timeouts[pos, i] = np.float32(truncated[i])
            for k in range(obs.shape[1]):
                replay.next_observations[pos, i, k] = obs[i, k]
            any_done = any_done or done
        t += 1
        pos += 1
        if pos == size:
            pos, wrapped = 0, True
        if any_done:
            break
    return t, pos, wrapped


@numba.njit(cache=True)
def actions_of(obs, actor, eps, out):
    """The actor's action for every row of ``obs`` (SAC: with ``eps`` rows; zeros: the deterministic tanh(mu))."""
    n_act = out.shape[1]
    width = widest(widest(obs.shape[1], actor.mu), actor.log_std)
    h_in = np.empty(width, np.float32)
    h_out = np.empty(width, np.float32)
    mean = np.empty(n_act, np.float32)
    log_std = np.empty(n_act, np.float32)
    for i in range(obs.shape[0]):
        act(obs[i], actor, eps[i], h_in, h_out, mean, log_std, out[i])
