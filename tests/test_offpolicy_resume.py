"""SAC and TD3, SB3's and the compiled, killed with SIGKILL mid-run and resumed by the same command: the replay buffer,
the round so far, the exploration noise, the warm-up's uniform draws and RECOM's and L2's state all come back, and the
metric histories equal an uninterrupted run's bit for bit (its own module: it runs beside test_reliability.py)."""
from __future__ import annotations

import pytest

from test_reliability import kill_then_resume

# RECOM + L2 on 32x32 networks, rounds of 512 steps, learning from step 1200: the kill comes after the checkpoint at
# 1024, inside the warm-up, so the uniform warm-up draws, the first gradient steps and RECOM's first losses all
# happen after the resume; RECOM's LR free to move (lr_max 0.01 above TD3's 1e-3).
RUN = ["seed=4", "+remedy@agent.recom=recom", "+remedy@agent.l2=l2", "agent.recom.interval=512", "agent.recom.window=2",
       "agent.recom.gain=1e-6", "agent.recom.lr_max=0.01", "train.checkpoint_every=1024", "wind.segment_steps=2048",
       "eval.episodes=2", "env.episode_seconds=1.0", "agent.policy.net_arch=[32,32]", "plasticity.probe.steps=50"]


# SB3's runs (the reference) in the slow suite: the same code path but 4x slower; the default suite keeps JAX's
# The reward curriculum's stages every 1000 steps (1000 before the checkpoint at 1024, 2000 after the resume): the
# weights in force and the replay's re-scored rewards come back too.
CURRICULUM = ["env.reward_curriculum.every=1000", "eval.policy=final"]


@pytest.mark.parametrize("algorithm,learner,total,n_envs,extra", [
    pytest.param("sac", "sb3", 3072, 1, [], marks=pytest.mark.slow),
    pytest.param("td3", "sb3", 3072, 1, [], marks=pytest.mark.slow),
    ("sac", "jax", 6144, 1, []), ("td3", "jax", 6144, 2, []),
    pytest.param("td3", "jax", 4096, 2, CURRICULUM, marks=pytest.mark.slow)])
def test_kill_minus_9_then_same_command_finishes_the_same_off_policy_run(tmp_path, checkpoint_dir, algorithm, learner,
                                                                         total, n_envs, extra):
    """jax: faster, a longer run; TD3 on JAX with 2 envs (replay rows of 2 transitions, turns of 2 env steps)."""
    config = [f"agent={algorithm}", *RUN, f"agent.{algorithm}.round_steps=512", f"agent.{algorithm}.learning_starts=1200",
              f"agent.{algorithm}.batch_size=64", f"agent.learner={learner}", f"train.total_timesteps={total}",
              f"env.n_envs={n_envs}", *extra]
    kill_then_resume(tmp_path, checkpoint_dir, config, total, loss="train/critic_loss", step=512, kill_after=1024)
