"""Compiled rollout for the JAX learner: SB3's ``collect_rollouts`` loop, for the hover env, in numba.

One call of ``fly`` runs the policy in the env step after step, writing SB3's rollout buffer, until an
episode ends or the rollout is full; the caller then does what needs Python (SB3's infos, resets,
callbacks) and calls again. Per step and vehicle, exactly as SB3's ``OnPolicyAlgorithm.collect_rollouts``
with ``ActorCriticPolicy`` (Gaussian, state-independent std):

* value V(s) and action a = mu(s) + exp(log_std) * eps, eps ~ N(0, 1) drawn beforehand by the caller;
  log pi(a|s) = sum_i -eps_i^2 / 2 - log_std_i - log sqrt(2 pi);
* the env gets a clipped to [-1, 1]; the buffer keeps the unclipped a and the reward times the env's
  ``reward_scale``;
* a truncated episode's reward gets + gamma V(terminal observation) (SB3's timeout bootstrap).

The env step is the env's own compiled pieces: the fast backend's ``step_vehicles`` (physics) and
``task_outcome`` (observation, reward, termination), so the task is the one ``HoverVecEnv.step`` runs.
``gae`` is SB3's ``RolloutBuffer.compute_returns_and_advantage``.

``fly``'s inputs are named: the networks as a ``Policy``, the rollout buffer's arrays as a ``Buffer``, the
env's state and constants as its ``HoverKernel`` (``HoverVecEnv.kernel``).

The networks run here in float32 from weights laid out (in, out) per layer, with the LayerNorm's scale and
shift per hidden layer (``Mlp``; unused without ``layer_norm``); the JAX learner re-exports them after every
update. ``tanh`` is the float32 rational approximation XLA's CPU backend (Eigen) evaluates: within 2.6e-7 of
tanh, bit-identical to ``jnp.tanh`` for ~80% of inputs (libm's: ~30%), and it vectorises, so the rollout's
policy is the update's policy, 3x cheaper. The networks' fast math fuses multiply-adds but reorders no sum
(``FASTMATH``), so a build numba compiles in the process and one it loads from its cache give the same numbers.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from sweep.envs.backends.fast import step_vehicles
from sweep.envs.gusts import add_gusts
from sweep.envs.hover import action_to_rotor_speed, task_outcome

LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
# The networks' fast-math flags: fused multiply-adds and no NaN/inf/signed-zero care, but no reassociation and no
# reciprocals. numba links a callee's code into each caller and optimises it again there, and a process that compiles
# ``mlp`` itself runs its own build where one that loads the callers from numba's cache runs theirs: with reassociation
# and reciprocals (``fastmath=True``) those builds summed LayerNorm's mean and variance in other orders, so the first
# jobs on a new machine flew LayerNorm networks with other last bits (README, Determinism). These flags give every
# build the same numbers (tests/test_reference_history.py compiles afresh and from the cache).
FASTMATH = {"contract", "nnan", "ninf", "nsz"}


@numba.njit(cache=True, fastmath=FASTMATH, inline="always")
def tanh(x):
    """float32 tanh: x p(x^2) / q(x^2) on x clamped to +-7.9053 (Eigen's ptanh_float coefficients)."""
    x = min(max(x, np.float32(-7.90531110763549805)), np.float32(7.90531110763549805))
    x2 = x * x
    p = np.float32(-2.76076847742355e-16)
    p = p * x2 + np.float32(2.00018790482477e-13)
    p = p * x2 + np.float32(-8.60467152213735e-11)
    p = p * x2 + np.float32(5.12229709037114e-08)
    p = p * x2 + np.float32(1.48572235717979e-05)
    p = p * x2 + np.float32(6.37261928875436e-04)
    p = p * x2 + np.float32(4.89352455891786e-03)
    q = np.float32(1.19825839466702e-06)
    q = q * x2 + np.float32(1.18534705686654e-04)
    q = q * x2 + np.float32(2.26843463243900e-03)
    q = q * x2 + np.float32(4.89352518554385e-03)
    return x * p / q


class Mlp(NamedTuple):
    """One network as the compiled code reads it: per layer, float32."""
    weights: tuple  # (in, out) matrices
    biases: tuple   # (out,)
    scales: tuple   # LayerNorm scale per hidden layer (unused without layer_norm)
    shifts: tuple   # LayerNorm shift per hidden layer


class Policy(NamedTuple):
    """SB3's ``ActorCriticPolicy`` (Gaussian, state-independent std): the action mean and value networks."""
    pi: Mlp
    vf: Mlp
    log_std: np.ndarray  # (A,) float32
    relu: bool           # hidden activation ReLU (else tanh)
    layer_norm: bool     # LayerNorm before each hidden activation


class Buffer(NamedTuple):
    """SB3's ``RolloutBuffer`` arrays that ``fly`` writes, (n_steps, N, ...)."""
    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    episode_starts: np.ndarray
    values: np.ndarray
    log_probs: np.ndarray


@numba.njit(cache=True, fastmath=FASTMATH)
def mlp(x, net, relu, layer_norm, h_in, h_out, out):
    """out = MLP(x) for one input row: hidden layers Linear [-> LayerNorm(scale, shift)] -> tanh (or ReLU), linear
    output. ``h_in``/``h_out`` are scratch rows at least as wide as the widest layer (``widest``)."""
    weights, biases, scales, shifts = net
    n_layers = len(weights)
    for k in range(x.shape[0]):
        h_in[k] = x[k]
    for layer in range(n_layers):
        w, b = weights[layer], biases[layer]
        n_in, n_out = w.shape
        dst = out if layer == n_layers - 1 else h_out
        for j in range(n_out):
            dst[j] = b[j]
        for k in range(n_in):
            xk = h_in[k]
            for j in range(n_out):
                dst[j] += xk * w[k, j]
        if layer < n_layers - 1:
            if layer_norm:  # torch.nn.LayerNorm: biased variance, eps 1e-5
                mean = np.float32(0.0)
                for j in range(n_out):
                    mean += h_out[j]
                mean /= np.float32(n_out)
                var = np.float32(0.0)
                for j in range(n_out):
                    var += (h_out[j] - mean) * (h_out[j] - mean)
                inv = np.float32(1.0) / np.sqrt(var / np.float32(n_out) + np.float32(1e-5))
                g, c = scales[layer], shifts[layer]
                for j in range(n_out):
                    h_out[j] = (h_out[j] - mean) * inv * g[j] + c[j]
            for j in range(n_out):
                h_in[j] = max(h_out[j], np.float32(0.0)) if relu else tanh(h_out[j])


@numba.njit(cache=True, inline="always")
def widest(width, net):
    """The larger of ``width`` and the widest layer output of ``net`` (the scratch rows ``mlp`` needs)."""
    for layer in range(len(net.weights)):
        width = max(width, net.weights[layer].shape[1])
    return width


@numba.njit(cache=True)
def fly(t, n_steps, obs, episode_starts, dones, noise, wind, policy, gamma, buffer, kernel):
    """Steps t, t+1, ... of a rollout until some episode ends or t = n_steps; returns the next t.

    ``obs`` (N, D) is the observation before step t and is overwritten with the one after the last step
    (the terminal one for vehicles whose episode ended: the caller resets them). ``wind`` is the env's
    ``RolloutWind`` of every step of the rollout (mean wind, gusts), ``noise`` (n_steps, N, A) the Gaussian draws. ``policy`` is a
    ``Policy``, ``buffer`` a ``Buffer``, ``kernel`` the env's ``HoverKernel`` (``sweep.envs.hover``)."""
    pi, vf, log_std, relu, layer_norm = policy
    vehicles, physics, outcome = kernel.vehicles, kernel.physics, kernel.outcome
    t_idx, ep_return, reward_scale = kernel.t_idx, kernel.ep_return, kernel.reward_scale
    rewards, terminated, truncated = outcome.rewards, outcome.terminated, outcome.truncated
    task, gust_filters = kernel.task, kernel.gust_filters
    mean_wind, gust_sigma, gust_draws = wind
    turbulent = gust_draws.shape[0] > 0
    buf_obs, buf_actions, buf_rewards, buf_starts, buf_values, buf_log_probs = buffer  # read once: see step_vehicles
    n, n_act = obs.shape[0], noise.shape[2]
    width = widest(widest(obs.shape[1], pi), vf)
    h_in = np.empty(width, np.float32)
    h_out = np.empty(width, np.float32)
    mean = np.empty(n_act, np.float32)
    value = np.empty(1, np.float32)
    std = np.exp(log_std)
    log_norm = 0.0
    for a in range(n_act):
        log_norm += log_std[a] + LOG_SQRT_2PI
    cmd = np.empty((n, n_act))
    clipped = np.empty((n, n_act), np.float32)
    wind_now = np.empty((n, 3))
    speed_min, speed_max = physics.speed_min, physics.speed_max
    while t < n_steps:
        for i in range(n):
            mlp(obs[i], pi, relu, layer_norm, h_in, h_out, mean)
            mlp(obs[i], vf, relu, layer_norm, h_in, h_out, value)
            log_prob = 0.0
            for a in range(n_act):
                eps = noise[t, i, a]
                action = mean[a] + std[a] * eps
                buf_actions[t, i, a] = action
                c = min(max(action, np.float32(-1.0)), np.float32(1.0))
                clipped[i, a] = c
                cmd[i, a] = action_to_rotor_speed(c, speed_min, speed_max)
                log_prob -= 0.5 * eps * eps
            buf_log_probs[t, i] = log_prob - log_norm
            buf_values[t, i] = value[0]
            buf_starts[t, i] = episode_starts[i]
            for k in range(obs.shape[1]):
                buf_obs[t, i, k] = obs[i, k]
            for k in range(3):
                wind_now[i, k] = mean_wind[t, k]
        if turbulent:
            add_gusts(gust_filters, gust_draws[t], gust_sigma[t], wind_now)
        step_vehicles(vehicles, cmd, wind_now, physics)
        task_outcome(vehicles, clipped, t_idx, task, obs, outcome, kernel.history, mean_wind[t], kernel.vehicle)
        any_done = False
        for i in range(n):
            ep_return[i] += rewards[i]
            reward = rewards[i] * np.float32(reward_scale)
            if truncated[i]:
                mlp(obs[i], vf, relu, layer_norm, h_in, h_out, value)
                reward += np.float32(gamma) * value[0]
            buf_rewards[t, i] = reward
            dones[i] = terminated[i] or truncated[i]
            episode_starts[i] = dones[i]
            any_done = any_done or dones[i]
        t += 1
        if any_done:
            break
    return t


@numba.njit(cache=True)
def outputs_of(obs, net, relu, layer_norm, out):
    """``out[i] = net(obs[i])`` for every row of ``obs``; ``out`` is (N, outputs)."""
    width = widest(obs.shape[1], net)
    h_in = np.empty(width, np.float32)
    h_out = np.empty(width, np.float32)
    for i in range(obs.shape[0]):
        mlp(obs[i], net, relu, layer_norm, h_in, h_out, out[i])


@numba.njit(cache=True)
def values_of(obs, vf_weights, vf_biases, vf_scales, vf_shifts, relu, layer_norm, out):
    """V(obs) for every row of ``obs`` into ``out`` (N,) (the value network's layers, as ``Mlp``'s fields)."""
    outputs_of(obs, Mlp(vf_weights, vf_biases, vf_scales, vf_shifts), relu, layer_norm, out.reshape((out.shape[0], 1)))


@numba.njit(cache=True)
def actions_of(obs, pi_weights, pi_biases, pi_scales, pi_shifts, relu, layer_norm, out):
    """The Gaussian's mean mu(obs) for every row of ``obs`` (the deterministic action, unclipped) into ``out``."""
    outputs_of(obs, Mlp(pi_weights, pi_biases, pi_scales, pi_shifts), relu, layer_norm, out)


@numba.njit(cache=True)
def gae(rewards, values, episode_starts, last_values, last_dones, gamma, gae_lambda, advantages, returns):
    """SB3's ``compute_returns_and_advantage``: GAE(lambda) advantages and TD(lambda) returns, (T, N) arrays."""
    n_steps, n = rewards.shape
    last_gae = np.zeros(n, np.float32)
    for step in range(n_steps - 1, -1, -1):
        for i in range(n):
            if step == n_steps - 1:
                non_terminal = np.float32(1.0) - np.float32(last_dones[i])
                next_value = last_values[i]
            else:
                non_terminal = np.float32(1.0) - episode_starts[step + 1, i]
                next_value = values[step + 1, i]
            delta = rewards[step, i] + np.float32(gamma) * next_value * non_terminal - values[step, i]
            last_gae[i] = delta + np.float32(gamma) * np.float32(gae_lambda) * non_terminal * last_gae[i]
            advantages[step, i] = last_gae[i]
            returns[step, i] = last_gae[i] + values[step, i]
