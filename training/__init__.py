"""Training of the learned correction (PyTorch, CPU, float64): datasets of one-step pairs and
rollout windows built from sorties, the torch twin of the hybrid step, and the training loop.

Torch is needed only here; the trained weights are used through :mod:`uavdyn.hybrid`.
"""
