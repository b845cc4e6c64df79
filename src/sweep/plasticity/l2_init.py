"""L2-Init, regenerative regularization (Kumar et al. 2023, "Maintaining plasticity in continual learning via
regenerative regularization"): L2 toward the initial parameters instead of toward 0,

    loss += (lambda / 2) * || theta - theta_0 ||^2

so weights that stop being useful drift back to where the network was trainable, not to 0. Applied like this
project's L2 (``sweep.plasticity.l2``, same ``mode``, ``params`` and ``biases``), with theta_0 the learner's
``initial_parameters()``. At ``coef=0`` it is plain PPO, bit for bit (tests/test_remedies.py).
"""
from __future__ import annotations

from sweep.plasticity.l2 import L2Regularization


class L2Init(L2Regularization):
    anchor = "init"
