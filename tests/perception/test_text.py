"""Text encoders: the embedded MiniLM (real weights, offline) and the BERT adapter on a tiny random model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.text import (
    BertTextEncoder,
    MiniLMTextEncoder,
    TextEncoder,
    default_text_encoder,
    similarity,
)

# float32 embeddings: a unit vector's norm is 1 to ~1e-7 (eps 1.2e-7 times a few dozen terms); 1e-5 is slack.
NORM_ATOL = 1e-5


@pytest.fixture(scope="module")
def minilm() -> MiniLMTextEncoder:
    return default_text_encoder("cpu")


def test_minilm_is_shared_per_device_and_meets_the_protocol(minilm):
    assert default_text_encoder("cpu") is minilm
    assert isinstance(minilm, TextEncoder)
    assert minilm.dim == 384  # all-MiniLM-L6-v2's width


def test_minilm_embeddings_are_unit_float32_and_deterministic(minilm):
    texts = ["mug", "coffee cup with a handle", "wooden pallet"]
    a = minilm.encode(texts)
    assert a.shape == (3, 384) and a.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=NORM_ATOL)
    np.testing.assert_array_equal(minilm.encode(texts), a)
    # one text alone gives the same row as in a batch (padding does not leak into the mean);
    # batched float32 matmuls may round differently: 1e-5 is far below any similarity that matters.
    np.testing.assert_allclose(minilm.encode("wooden pallet")[0], a[2], atol=1e-5)


def test_minilm_semantics_mug_is_near_a_handled_cup(minilm):
    e = minilm.encode(["mug", "coffee cup with a handle", "wooden pallet"])
    s = similarity(e[0], e[1:])[0]
    assert s[0] > s[1] + 0.2  # a wide semantic margin, not a coin flip (measured 0.61 vs 0.31)


def test_minilm_token_features(minilm):
    tok = minilm.encode_tokens("small red mug")
    # [CLS] small red mug [SEP]: every word is in the WordPiece vocabulary
    assert tok.shape == (5, 384) and tok.dtype == np.float32
    assert np.all(np.isfinite(tok))
    # the sentence embedding is the normalised mean of the token features (MiniLM's pooling)
    mean = tok.mean(axis=0)
    # float32 sums over 5 tokens: 1e-5 absolute on unit-scale entries
    np.testing.assert_allclose(mean / np.linalg.norm(mean), minilm.encode("small red mug")[0], atol=1e-5)


def test_minilm_cache_gives_the_model_rows_and_copies(minilm):
    texts = ["a cache test phrase", "another cache test phrase"]
    assert not any(t in minilm._cache for t in texts)  # not in memory yet: from the disk store or the model
    first = minilm.encode(texts)
    # the model itself, uncached: the same rows (1e-5: batched float32 rounding, see the test above)
    np.testing.assert_allclose(first, minilm._encode_batch(texts), atol=1e-5)
    # cached: bit-identical whatever the batch, in the caller's order, with duplicates
    again = minilm.encode([texts[1], "mug", texts[0], texts[1]])
    np.testing.assert_array_equal(again[[2, 0, 3]], first[[0, 1, 1]])
    again[:] = 0.0  # the caller owns its array: the cache is not written through it
    np.testing.assert_array_equal(minilm.encode(texts), first)


def test_minilm_is_sentence_transformers_numbers(minilm):
    """The numpy MiniLM (`perception.minilm`) computes what sentence-transformers computes on the same folder:
    sentence embeddings and token features, of short, padded and truncated texts."""
    st = pytest.importorskip("sentence_transformers")
    reference = st.SentenceTransformer(str(minilm.model_path), device="cpu", local_files_only=True)
    texts = ["mug", "the small red mug with a handle", "Café crème bottle!", "pallet " * 300]
    ours = minilm._encode_batch(texts)  # the model itself, not a cache
    theirs = reference.encode(texts, convert_to_numpy=True, normalize_embeddings=True)
    # the same float32 operations in another library's kernels (summation order, erf): unit vectors agree to
    # ~1e-7 per entry (measured); 1e-6 leaves room for other BLAS builds
    np.testing.assert_allclose(ours, theirs, atol=1e-6)
    assert minilm.max_tokens == reference.max_seq_length == 256  # truncation where sentence-transformers cuts
    tokens = minilm.encode_tokens("small red mug")
    ref_tokens = reference.encode("small red mug", output_value="token_embeddings", convert_to_numpy=False)
    # unnormalised hidden states of magnitude ~1-10: 2e-6 measured, 1e-5 leaves room for the BLAS
    np.testing.assert_allclose(tokens, ref_tokens.detach().cpu().numpy(), atol=1e-5)


def test_minilm_cache_keeps_the_most_recent_texts(minilm):
    size = minilm.cache_size
    try:
        minilm.cache_size = 2
        minilm.encode(["cache lru one", "cache lru two", "cache lru three"])
        assert len(minilm._cache) == 2 and "cache lru one" not in minilm._cache
        minilm.encode("cache lru two")  # used again: now the most recent
        minilm.encode("cache lru four")
        assert list(minilm._cache) == ["cache lru two", "cache lru four"]
    finally:
        minilm.cache_size = size


@pytest.mark.parametrize("bad", ["", "   ", [], ["mug", " "], [3], b"mug", None])
def test_minilm_rejects_empty_or_non_text(minilm, bad):
    with pytest.raises(InvalidInputError):
        minilm.encode(bad)


def test_minilm_rejects_blank_token_text_and_bad_folders(minilm, tmp_path):
    with pytest.raises(InvalidInputError):
        minilm.encode_tokens("  ")
    with pytest.raises(InvalidInputError):
        minilm.encode_tokens(["mug"])  # one text, not a list
    with pytest.raises(InvalidInputError):
        MiniLMTextEncoder(model_path=tmp_path)
    with pytest.raises(InvalidInputError):
        default_text_encoder("")


def test_similarity_known_answers():
    a = np.array([[1.0, 0.0], [0.0, 2.0]])
    b = np.array([[3.0, 0.0], [1.0, 1.0], [0.0, -1.0]])
    expected = np.array([[1.0, np.sqrt(0.5), 0.0], [0.0, np.sqrt(0.5), -1.0]])
    np.testing.assert_allclose(similarity(a, b), expected, atol=1e-15)  # float64 rounding only
    assert similarity([1.0, 1.0], [2.0, 2.0]).shape == (1, 1)
    with pytest.raises(InvalidInputError):
        similarity([0.0, 0.0], [1.0, 0.0])
    with pytest.raises(InvalidInputError):
        similarity([1.0, 0.0], [1.0, 0.0, 0.0])
    with pytest.raises(InvalidInputError):
        similarity([np.nan, 1.0], [1.0, 0.0])


# ----------------------------------------------------------------------------------------------------
# BERT adapter on a tiny random model (no download)

_VOCAB = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", "mug", "cup", "with", "a", "handle", "wooden"]
_VOCAB += ["pallet", "red", "small", "the", "##s"]


@pytest.fixture(scope="module")
def tiny_bert(tmp_path_factory) -> tuple[Path, object]:
    transformers = pytest.importorskip("transformers")
    torch = pytest.importorskip("torch")
    d = tmp_path_factory.mktemp("tiny_bert")
    (d / "vocab.txt").write_text("\n".join(_VOCAB) + "\n")
    (d / "tokenizer_config.json").write_text(
        json.dumps({"tokenizer_class": "BertTokenizer", "do_lower_case": True, "model_max_length": 64})
    )
    config = transformers.BertConfig(
        vocab_size=len(_VOCAB),
        hidden_size=32,
        num_hidden_layers=2,
        num_attention_heads=2,
        intermediate_size=64,
        max_position_embeddings=64,
    )
    torch.manual_seed(0)
    model = transformers.BertModel(config).eval()
    model.save_pretrained(str(d))
    return d, model


def _reference_hidden(model, ids: list[int]) -> np.ndarray:
    import torch

    with torch.no_grad():
        out = model(input_ids=torch.tensor([ids]), attention_mask=torch.ones(1, len(ids), dtype=torch.long))
    return out.last_hidden_state[0].numpy()


def test_bert_adapter_round_trips_the_saved_model(tiny_bert):
    d, model = tiny_bert
    enc = BertTextEncoder(d)
    assert isinstance(enc, TextEncoder) and enc.dim == 32
    tok = enc.encode_tokens("the small red mugs")
    ids = [_VOCAB.index(t) for t in ["[CLS]", "the", "small", "red", "mug", "##s", "[SEP]"]]
    # the in-memory model before saving, fed hand-built ids: loading must reproduce it (same float32 ops)
    ref = _reference_hidden(model, ids)
    assert tok.shape == (7, 32) and tok.dtype == np.float32
    np.testing.assert_allclose(tok, ref, atol=1e-6)  # identical weights; 1e-6 covers kernel order only
    sentence = enc.encode("the small red mugs")[0]
    mean = ref.mean(axis=0)
    np.testing.assert_allclose(sentence, mean / np.linalg.norm(mean), atol=1e-6)  # same, after pooling


def test_bert_adapter_batches_with_padding_masked(tiny_bert):
    d, _ = tiny_bert
    enc = BertTextEncoder(d)
    batch = enc.encode(["mug", "a wooden pallet with a handle", "zebra"])
    assert batch.shape == (3, 32) and batch.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(batch, axis=1), 1.0, atol=NORM_ATOL)
    for i, text in enumerate(["mug", "a wooden pallet with a handle", "zebra"]):
        # padded positions are masked out of the mean: each row equals the text encoded alone
        # (float32 attention over a padded batch differs by rounding only: 1e-5)
        np.testing.assert_allclose(batch[i], enc.encode(text)[0], atol=1e-5)


def test_bert_adapter_rejects_bad_input(tiny_bert, tmp_path):
    d, _ = tiny_bert
    with pytest.raises(InvalidInputError):
        BertTextEncoder(tmp_path)  # no config.json
    with pytest.raises(InvalidInputError):
        BertTextEncoder(d, max_tokens=1)
    enc = BertTextEncoder(d)
    with pytest.raises(InvalidInputError):
        enc.encode("")
    with pytest.raises(InvalidInputError):
        enc.encode_tokens("\t")
