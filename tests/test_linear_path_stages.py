"""The correction's linear path on its own (issue 40's knockout options, measured and not
adopted): every input seen only linearly (``SafeConfig.all_linear``) makes the output affine
in every input; the linear stage (``SafeConfig.linear_first_epochs``) moves only the linear
path and the output bias, leaves the hidden layers silent, and after it they learn from
their initial weights; patience counts from the release."""

from __future__ import annotations

import numpy as np
import torch
from test_safe_twin import DT

from uavdyn.airframes import load_airframe
from uavdyn.learned.formulations import CorrectionLayout
from uavdyn.learned.torch_model import TorchCorrection
from uavdyn.model import structure_of


def _network(linear_only=()) -> tuple[TorchCorrection, int]:
    airframe = load_airframe("aerosonde")
    layout = CorrectionLayout(structure_of(airframe), (0.05, 0.2), inputs="physical",
                              output="coefficient")
    n_in = layout.n_inputs
    return TorchCorrection(airframe.kind, "improved", 6, "relu", np.zeros(n_in), np.ones(n_in),
                           np.ones(3), DT, seed=3, structure=layout.structure, layout=layout,
                           linear=True, linear_only=linear_only), n_in


def _slopes(model: TorchCorrection, rows: torch.Tensor, i: int, h: float = 1e-6) -> np.ndarray:
    up, down = rows.clone(), rows.clone()
    up[:, i] += h
    down[:, i] -= h
    with torch.no_grad():
        return ((model(up) - model(down)) / (2 * h)).numpy()


def _train(model: TorchCorrection, rows: torch.Tensor, steps: int, linear_stage: bool) -> None:
    """Adam steps on a target no affine map fits, as ``train_epoch`` takes them."""
    opt = torch.optim.Adam(model.parameters(), lr=0.05)
    for _ in range(steps):
        opt.zero_grad()
        torch.sum((model(rows) - torch.sin(3.0 * rows[:, :1])) ** 2).backward()
        if linear_stage:
            model.drop_hidden_gradients()
        opt.step()
        model.hold_linear_only()


def _is_affine(model: TorchCorrection, rows: torch.Tensor, n_in: int) -> bool:
    return all(np.allclose(s, s[0], rtol=1e-6, atol=1e-9)
               for s in (_slopes(model, rows, i) for i in range(n_in)))


def test_every_input_seen_only_linearly_makes_the_output_affine():
    n_in = _network()[1]
    model, _ = _network(linear_only=tuple(range(n_in)))
    rows = torch.as_tensor(np.random.default_rng(5).normal(size=(64, n_in)))
    before = model(rows).detach().clone()
    _train(model, rows, 5, linear_stage=False)
    assert torch.all(model.layers[0].weight == 0.0)
    assert not torch.allclose(model(rows).detach(), before)  # it trained
    assert _is_affine(model, rows, n_in)


def test_the_linear_stage_moves_the_linear_path_only_then_the_hidden_layers_learn():
    model, n_in = _network()
    rows = torch.as_tensor(np.random.default_rng(6).normal(size=(64, n_in)))
    hidden = [p.detach().clone() for layer in model.layers for p in layer.parameters()]
    _train(model, rows, 5, linear_stage=True)
    after = [p.detach() for layer in model.layers for p in layer.parameters()]
    assert all(torch.equal(a, b) for a, b in zip(after[:-1], hidden[:-1]))  # all but b_out
    assert not torch.equal(after[-1], hidden[-1])  # the output bias learns
    assert torch.any(model.skip != 0.0)
    assert torch.all(model.layers[-1].weight == 0.0)
    assert _is_affine(model, rows, n_in)
    _train(model, rows, 5, linear_stage=False)  # released: from their initial weights
    assert torch.any(model.layers[-1].weight != 0.0)
    assert not _is_affine(model, rows, n_in)


def test_patience_counts_from_the_release_of_the_hidden_layers(tmp_path):
    """With a learning rate too small to move any weight no epoch makes progress: patience 1
    ends the run at epoch 2 (epoch 1 sets the first mean ratio), and with a linear stage of
    3 epochs at epoch 4."""
    from emulated_data import emulated_dataset

    from uavdyn.flightdata import load_dataset
    from uavdyn.learned.safe import SafeConfig, train_safe

    airframe = load_airframe("aerosonde")
    truth = airframe.replace(C_m_0=airframe.params.C_m_0 + 0.01)
    sorties = load_dataset(emulated_dataset(tmp_path / "data", truth, 4, 6.0)).sorties
    base = dict(epochs=10, batches_per_epoch=1, batch_windows=4, horizon_s=1.0,
                progress=False, memory_tau=(0.1,), patience=1, lr=1e-300, lr_final=1e-300)
    plain = train_safe(sorties[:2], sorties[2:], airframe, SafeConfig(**base))
    staged = train_safe(sorties[:2], sorties[2:], airframe,
                        SafeConfig(**base, linear_first_epochs=3))
    assert plain.history[-1]["epoch"] == 2
    assert staged.history[-1]["epoch"] == 4
    assert "after epoch 3" in staged.stopped and "after epoch 1" in plain.stopped
    assert staged.config.linear_first_epochs == 3
