"""The Grounding DINO + SAM 2 adapter on tiny randomly initialised models (plumbing, not accuracy)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, MissingDependencyError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.perception.grounding import GroundingDinoSam2Grounder, GroundingResult

transformers = pytest.importorskip("transformers")
torch = pytest.importorskip("torch")

H, W = 48, 64
K = CameraIntrinsics(60.0, 60.0, (W - 1) / 2, (H - 1) / 2, W, H)
VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", "the", "a", "red", "blue", "mug", "box", "can"]


@pytest.fixture(scope="module")
def weights_dir(tmp_path_factory):
    """Tiny random Grounding DINO (Swin + BERT) and SAM 2 (Hiera) saved the way users save real ones."""
    root = tmp_path_factory.mktemp("grounded_sam2")
    torch.manual_seed(0)
    dino_dir, sam_dir = root / "grounding_dino", root / "sam2"
    dino_dir.mkdir()
    (dino_dir / "vocab.txt").write_text("\n".join(VOCAB) + "\n")
    tokenizer = transformers.BertTokenizerFast(vocab_file=str(dino_dir / "vocab.txt"))
    swin = transformers.SwinConfig(
        image_size=64,
        patch_size=4,
        embed_dim=8,
        depths=[1, 1, 1, 1],
        num_heads=[1, 1, 1, 1],
        window_size=2,
        out_features=["stage2", "stage3", "stage4"],
    )
    bert = transformers.BertConfig(
        vocab_size=len(VOCAB),
        hidden_size=32,
        num_hidden_layers=1,
        num_attention_heads=2,
        intermediate_size=32,
        max_position_embeddings=64,
    )
    # d_model 32: the model's GroupNorm uses 32 groups; 2 decoder layers: box heads are tied from layer 1 on
    dino = transformers.GroundingDinoConfig(
        backbone_config=swin,
        text_config=bert,
        d_model=32,
        encoder_layers=1,
        decoder_layers=2,
        num_queries=12,
        encoder_ffn_dim=32,
        decoder_ffn_dim=32,
        encoder_attention_heads=2,
        decoder_attention_heads=2,
        num_feature_levels=3,
        encoder_n_points=2,
        decoder_n_points=2,
        max_text_len=32,
        use_timm_backbone=False,
    )
    transformers.GroundingDinoForObjectDetection(dino).save_pretrained(str(dino_dir))
    tokenizer.save_pretrained(str(dino_dir))
    (dino_dir / "preprocessor_config.json").write_text(
        json.dumps({"size": {"shortest_edge": 64, "longest_edge": 96}})
    )
    hiera = transformers.Sam2HieraDetConfig(
        hidden_size=8,
        image_size=[128, 128],
        blocks_per_stage=[1, 1, 2, 1],
        embed_dim_per_stage=[8, 16, 32, 64],
        num_attention_heads_per_stage=[1, 1, 1, 1],
        window_size_per_stage=[4, 4, 4, 2],
        global_attention_blocks=[3],
        window_positional_embedding_background_size=[2, 2],
    )
    vision = transformers.Sam2VisionConfig(
        backbone_config=hiera,
        backbone_channel_list=[64, 32, 16, 8],
        backbone_feature_sizes=[[32, 32], [16, 16], [8, 8]],
        fpn_hidden_size=32,
    )
    sam = transformers.Sam2Config(
        vision_config=vision,
        prompt_encoder_config=transformers.Sam2PromptEncoderConfig(
            hidden_size=32, image_size=128, patch_size=16
        ),
        mask_decoder_config=transformers.Sam2MaskDecoderConfig(
            hidden_size=32, mlp_dim=64, num_attention_heads=2, iou_head_hidden_dim=32
        ),
    )
    transformers.Sam2Model(sam).save_pretrained(str(sam_dir))
    return root


@pytest.fixture(scope="module")
def frame():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    depth = np.full((H, W), 0.8, np.float32)
    return rgb, depth


def test_adapter_returns_image_size_masks_best_first(weights_dir, frame):
    g = GroundingDinoSam2Grounder(weights_dir, box_threshold=0.0, max_candidates=5)
    result = g.ground(*frame, K, "the red mug")
    assert isinstance(result, GroundingResult) and result.support_plane is None
    assert 1 <= len(result.candidates) <= 5
    scores = [c.score for c in result.candidates]
    assert scores == sorted(scores, reverse=True)
    assert all(0.0 <= s <= 1.0 for s in scores)  # sigmoid probabilities
    for c in result.candidates:
        assert c.mask.shape == (H, W) and c.mask.dtype == np.bool_
        x0, y0, x1, y1 = c.box_xyxy
        assert 0 <= x0 <= x1 <= W - 1 and 0 <= y0 <= y1 <= H - 1
        assert c.attributes is None
    # kept boxes do not overlap by more than the NMS threshold
    boxes = np.array([c.box_xyxy for c in result.candidates], float)
    for i in range(len(boxes)):
        for j in range(i + 1, len(boxes)):
            a, b = boxes[i], boxes[j]
            iw = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
            ih = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
            union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - iw * ih
            # boxes are rounded to whole pixels after NMS: allow 0.1 of IoU slack on 10-60 px boxes
            assert iw * ih / max(union, 1e-9) <= 0.7 + 0.1
    again = g.ground(*frame, K, "the red mug")  # inference is deterministic
    for x, y in zip(result.candidates, again.candidates):
        np.testing.assert_array_equal(x.mask, y.mask)
        assert x.score == y.score


def test_adapter_threshold_and_errors(weights_dir, frame, tmp_path):
    g = GroundingDinoSam2Grounder(weights_dir, box_threshold=1.0)
    assert g.ground(*frame, K, "blue box").candidates == ()  # sigmoid scores never reach 1
    with pytest.raises(InvalidInputError, match="prompt is empty"):
        g.ground(*frame, K, "")
    with pytest.raises(InvalidInputError, match="no valid reading"):
        g.ground(frame[0], np.zeros((H, W), np.float32), K, "mug")
    with pytest.raises(InvalidInputError, match="grounding_dino/ and sam2/"):
        GroundingDinoSam2Grounder(tmp_path)
    with pytest.raises(InvalidInputError, match="box_threshold"):
        GroundingDinoSam2Grounder(weights_dir, box_threshold=1.5)


def test_adapter_names_the_extra_when_transformers_is_missing(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "transformers", None)  # import now raises ImportError
    with pytest.raises(MissingDependencyError, match=r"prompose-grasp\[hub\]"):
        GroundingDinoSam2Grounder(tmp_path)
