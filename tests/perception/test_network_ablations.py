"""The paper Table 2 ablation switches of `NetworkConfig` change what they claim to change, and nothing else
breaks: each variant is checked by a behaviour that only the switched-off part can produce."""

from __future__ import annotations

import pytest
import torch
from network_fixtures import random_inputs

from prompose_grasp.errors import UnknownNameError
from prompose_grasp.perception.network import ABLATIONS, NetworkConfig, ProMPoseNet, network_config
from prompose_grasp.perception.network.model import generic_prior_points

torch.set_num_threads(1)


def _model(ablation: str) -> ProMPoseNet:
    torch.manual_seed(0)
    return ProMPoseNet(network_config("tiny", ablation)).eval()


@pytest.mark.parametrize("ablation", sorted(ABLATIONS))
def test_every_ablation_builds_and_round_trips_its_config(ablation):
    config = network_config("tiny", ablation)
    assert NetworkConfig.from_dict(config.to_dict()) == config
    with torch.no_grad():
        out = _model(ablation)(**random_inputs(config, B=1, n=3))
    assert out["R"].shape == (1, 3, 3, 3) and bool(torch.isfinite(out["t"]).all())


def test_unknown_ablation_and_bad_switch_values_are_refused():
    with pytest.raises(UnknownNameError):
        network_config("tiny", "no_vision")
    with pytest.raises(UnknownNameError):
        network_config("tiny", fusion="sideways")


def test_temporal_module_is_what_couples_frames():
    # Change only frame 2 of a 3-frame window: with phi_temp the other frames' outputs move, without it they
    # stay bit-identical (each frame is decoded from its own tokens).
    for ablation, coupled in (("full", True), ("no_temporal", False)):
        model = _model(ablation)
        x = random_inputs(model.config, B=1, n=3, seed=3)
        y = {k: v.clone() for k, v in x.items()}
        y["points"][:, 2] += 0.05
        with torch.no_grad():
            a, b = model(**x)["t"][:, :2], model(**y)["t"][:, :2]
        # float32: identical arithmetic gives identical numbers; a coupled change is orders above 1e-6 m
        assert torch.allclose(a, b, atol=1e-7) != coupled, ablation


def test_generic_prior_ignores_the_text_conditioned_prior():
    x = random_inputs(network_config("tiny"), B=1, n=2, seed=4)
    y = {k: v.clone() for k, v in x.items()}
    y["prior_points"] = y["prior_points"] * torch.tensor([0.2, 1.0, 0.5])  # a different shape
    for ablation, sees_prior in (("full", True), ("no_generative_prior", False)):
        model = _model(ablation)
        with torch.no_grad():
            a, b = model(**x), model(**y)
        assert torch.allclose(a["R"], b["R"], atol=1e-7) != sees_prior, ablation
    cube = generic_prior_points(2000)
    # every point lies on a face of the unit cube: max |coordinate| is exactly 0.5
    assert torch.allclose(cube.abs().amax(dim=1), torch.full((2000,), 0.5))
    assert torch.equal(cube, generic_prior_points(2000))  # deterministic


def test_symmetric_fusion_lets_every_token_query():
    model = _model("symmetric_fusion")
    x = random_inputs(model.config, B=1, n=1, L=5)
    with torch.no_grad():
        out = model(**x)
    att = out["aca_attention"]
    # self-attention over all tokens: a square attention matrix whose side is visual + geometry + prior +
    # text tokens (the asymmetric ACA has one row per visual token only)
    assert att.shape[-1] == att.shape[-2] > model.config.visual_tokens
    full = _model("full")
    with torch.no_grad():
        assert full(**x)["aca_attention"].shape[-2] == full.config.visual_tokens


def test_without_decoupling_the_aca_sees_scale():
    # Scaling the observed cloud about its centre leaves the canonicalised copy unchanged, so with decoupling
    # the ACA input is scale-free; without it the fused features change. The pose-token MLPs see d_t in both
    # variants, so compare the ACA output itself.
    for ablation, scale_free in (("full", True), ("no_decoupling", False)):
        model = _model(ablation)
        x = random_inputs(model.config, B=1, n=1, seed=5)
        y = {k: v.clone() for k, v in x.items()}
        centre = x["points"].mean(dim=2, keepdim=True)
        y["points"] = centre + 1.7 * (x["points"] - centre)
        seen: list[torch.Tensor] = []
        hook = model.fusion.register_forward_hook(lambda m, i, o, seen=seen: seen.append(o["fused"]))
        with torch.no_grad():
            model(**x), model(**y)
        hook.remove()
        # canonicalisation divides by the extent: identical up to float32 rounding (~1e-6 relative)
        assert torch.allclose(seen[0], seen[1], atol=1e-4) == scale_free, ablation
