"""Write the fixed vocabularies' MiniLM embeddings that ship with the package.

    python -m prompose_grasp.perception.shipped_embeddings

`ProMPose.default()` embeds ~3,300 fixed texts (the object-knowledge table's names and synonyms, the
grounder's description vocabulary and shape-family sentences, the prior library's family descriptions).
On a first call after installing that took ~1 min on 2 shared cores; with this file the first call reads
them (`embedding_store.EmbeddingStore`, `shipped`). The file is keyed by the model's content
(`MiniLMTextEncoder.content_key`): another model, or another embedding implementation, does not read it. A
vocabulary changed since the file was written costs only its new texts, embedded at first use and kept in
the user cache; run this again when a vocabulary changes (tests/perception/test_embedding_store.py says
when the file no longer covers them).
"""

from __future__ import annotations

import logging
import os
import sys
import tempfile

import numpy as np

from prompose_grasp.perception.text import SHIPPED_EMBEDDINGS, MiniLMTextEncoder, default_text_encoder

log = logging.getLogger(__name__)


def vocabulary_texts() -> list[str]:
    """Every text `ProMPose.default()` embeds before any prompt, in first-use order."""
    from prompose_grasp.perception.estimator import ProMPose

    encoder = default_text_encoder()
    seen: dict[str, None] = {}
    inner = encoder.encode

    def recording(texts):  # type: ignore[no-untyped-def]
        seen.update(dict.fromkeys([texts] if isinstance(texts, str) else list(texts)))
        return inner(texts)

    encoder.encode = recording  # type: ignore[method-assign]
    try:
        ProMPose.default()
    finally:
        del encoder.encode
    return list(seen)


def main() -> int:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    # an empty cache and no shipped file: every text goes through the encoder and is recorded
    os.environ["PROMPOSE_GRASP_CACHE"] = tempfile.mkdtemp(prefix="prompose_vocab_")
    if SHIPPED_EMBEDDINGS.is_file():
        SHIPPED_EMBEDDINGS.unlink()
    texts = vocabulary_texts()
    encoder = MiniLMTextEncoder(persistent=False, cache_size=0)
    E = encoder._encode_batch(texts)
    SHIPPED_EMBEDDINGS.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(SHIPPED_EMBEDDINGS, texts=np.asarray(texts, dtype=str), embeddings=E,
                        key=np.asarray(encoder.content_key))  # fmt: skip
    log.info("wrote %d embeddings to %s", len(texts), SHIPPED_EMBEDDINGS)
    return 0


if __name__ == "__main__":
    sys.exit(main())
