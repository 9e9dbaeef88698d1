"""Sentence embeddings kept between processes (`perception.embedding_store`) and the MiniLM that loads only
when a text is in no cache."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from prompose_grasp.perception.embedding_store import EmbeddingStore
from prompose_grasp.perception.text import MiniLMTextEncoder, default_text_encoder

ROOT = Path(__file__).resolve().parents[2]
TEXTS = ["a store test mug", "the store test pallet", "a green store test bottle"]

# A process that encodes TEXTS with a fresh default MiniLM and reports the rows, whether the model loaded and
# whether torch was imported at all.
_CHILD = """
import json, sys
import numpy as np
from prompose_grasp.perception.text import MiniLMTextEncoder
enc = MiniLMTextEncoder()
E = enc.encode(json.loads(sys.argv[1]))
enc.flush()
np.save(sys.argv[2], E)
print(json.dumps({"loaded": enc.loaded, "torch": "torch" in sys.modules}))
"""


def _child(cache: Path, out: Path) -> dict:
    env = {**os.environ, "PROMPOSE_GRASP_CACHE": str(cache)}
    run = subprocess.run(
        [sys.executable, "-c", _CHILD, json.dumps(TEXTS), str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, check=True, timeout=300,
    )  # fmt: skip
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_a_second_process_reads_the_embeddings_without_loading_the_model(tmp_path):
    first = _child(tmp_path / "cache", tmp_path / "first.npy")
    # nothing stored yet: the model computed them, in numpy (torch is not imported for text at all)
    assert first == {"loaded": True, "torch": False}
    second = _child(tmp_path / "cache", tmp_path / "second.npy")
    assert second == {"loaded": False, "torch": False}  # every text stored: not even the weights load
    stored, computed = np.load(tmp_path / "second.npy"), np.load(tmp_path / "first.npy")
    np.testing.assert_array_equal(stored, computed)  # float32 rows written and read back exactly
    # ... and they are the model's numbers: computed here without any cache (same batch, same kernels;
    # 1e-6 leaves room for another thread count between the processes)
    fresh = MiniLMTextEncoder(persistent=False, cache_size=0)._encode_batch(TEXTS)
    np.testing.assert_allclose(stored, fresh, atol=1e-6)


def test_a_bad_store_is_recomputed_and_an_unwritable_one_skipped_with_a_log_line(tmp_path, caplog):
    caplog.set_level("INFO", logger="prompose_grasp.perception.embedding_store")
    reference = default_text_encoder().encode(TEXTS)
    path = tmp_path / "store.npz"
    path.write_bytes(b"not an archive")
    store = EmbeddingStore(path, 384)
    assert store.get(TEXTS) == {}
    assert "unreadable" in caplog.text
    store.put(TEXTS, reference)
    store.flush()
    again = EmbeddingStore(path, 384).get(TEXTS)
    np.testing.assert_array_equal(np.stack([again[t] for t in TEXTS]), reference)
    # another width (another model under the same name) is not used
    assert EmbeddingStore(path, 768).get(TEXTS) == {}
    assert "does not fit" in caplog.text
    # a cache folder that cannot exist: the rows stay in memory, a log line says so, nothing raises
    blocker = tmp_path / "file"
    blocker.write_text("x")
    store = EmbeddingStore(blocker / "sub" / "store.npz", 384)
    store.put(TEXTS, reference)
    store.flush()
    assert "not written" in caplog.text
    assert set(store.get(TEXTS)) == set(TEXTS)


def test_concurrent_writers_merge_rather_than_overwrite(tmp_path):
    rng = np.random.default_rng(0)
    a, b = EmbeddingStore(tmp_path / "s.npz", 4), EmbeddingStore(tmp_path / "s.npz", 4)
    assert a.get(["x"]) == {} and b.get(["y"]) == {}  # both read the (empty) file before either writes
    a.put(["x"], rng.normal(size=(1, 4)))
    a.flush()
    b.put(["y"], rng.normal(size=(1, 4)))
    b.flush()
    assert set(EmbeddingStore(tmp_path / "s.npz", 4).get(["x", "y"])) == {"x", "y"}


def test_the_store_key_changes_with_the_model_files(tmp_path):
    src = default_text_encoder().model_path
    model = tmp_path / "model"
    shutil.copytree(src, model, ignore=shutil.ignore_patterns("model.safetensors"))
    (model / "model.safetensors").write_bytes(b"weights stand-in: the key reads size and mtime only")
    key = MiniLMTextEncoder(model).cache_key
    assert MiniLMTextEncoder(model).cache_key == key  # stable for the same files
    os.utime(model / "model.safetensors", ns=(1, 1))
    assert MiniLMTextEncoder(model).cache_key != key  # new weights: the old rows are not read
    key = MiniLMTextEncoder(model).cache_key
    (model / "tokenizer.json").write_text((model / "tokenizer.json").read_text().replace("[UNK]", "[UNK2]"))
    assert MiniLMTextEncoder(model).cache_key != key
    with pytest.raises(Exception, match="BERT with GELU"):
        (model / "config.json").write_text(json.dumps({"model_type": "gpt2"}))
        MiniLMTextEncoder(model)


def test_the_shipped_vocabulary_embeddings_cover_a_default_estimator_and_are_the_models(tmp_path):
    """`ProMPose.default()` with an empty user cache reads every fixed vocabulary from the file shipped in
    the package and loads no model (when this fails after a vocabulary changed, run
    `python -m prompose_grasp.perception.shipped_embeddings`); its rows are the model's numbers."""
    from prompose_grasp.perception.text import SHIPPED_EMBEDDINGS

    code = (
        "import sys, json\nfrom prompose_grasp import ProMPose\nfrom prompose_grasp.perception.text import "
        "default_text_encoder\nProMPose.default()\n"
        "print(json.dumps({'loaded': default_text_encoder().loaded, 'torch': 'torch' in sys.modules}))"
    )
    env = {**os.environ, "PROMPOSE_GRASP_CACHE": str(tmp_path / "empty")}
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                         check=True, timeout=600)  # fmt: skip
    assert json.loads(run.stdout.strip().splitlines()[-1]) == {"loaded": False, "torch": False}
    with np.load(SHIPPED_EMBEDDINGS) as z:
        texts, E, key = z["texts"].tolist(), z["embeddings"], str(z["key"])
    encoder = MiniLMTextEncoder(persistent=False, cache_size=0)
    assert key == encoder.content_key
    sample = np.random.default_rng(0).choice(len(texts), size=48, replace=False)
    fresh = encoder._encode_batch([texts[i] for i in sample])
    # computed in other batches than the file's: float32 rounding of the padded batch only (~1e-7)
    np.testing.assert_allclose(E[sample], fresh, atol=1e-6)
