"""The Grounded-SAM 2 adapter: Grounding DINO boxes for the prompt, SAM 2 masks inside them (extra `hub`).

The paper grounds the prompt with Grounded-SAM 2. This adapter runs the same two models through
`transformers` from a local folder (nothing is downloaded):

```
weights_dir/
  grounding_dino/   config.json, model.safetensors, tokenizer files [, preprocessor_config.json]
  sam2/             config.json, model.safetensors [, preprocessor_config.json]
```

as `save_pretrained` writes them (e.g. `IDEA-Research/grounding-dino-tiny` and `facebook/sam2.1-hiera-tiny`
downloaded once by the user). Images are preprocessed here with OpenCV (the `transformers` image processors
need torchvision and Pillow, which this package does not require), following the models' published
preprocessing: Grounding DINO resizes the shorter side to 800 px (longer side at most 1333 px), SAM 2 resizes
to 1024 x 1024; both normalise with the ImageNet mean and std. A `preprocessor_config.json` in a folder
overrides sizes, mean and std.

Scores are Grounding DINO's: the highest token probability of each box over the prompt's tokens. Boxes
below `box_threshold` are dropped, overlapping boxes are suppressed (non-maximum suppression at IoU
`nms_iou`), and SAM 2 segments each kept box (one mask per box, `multimask_output=False`).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prompose_grasp._optional import require
from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.perception.grounding.grounder import validate_frame
from prompose_grasp.perception.grounding.language import parse_prompt
from prompose_grasp.perception.grounding.types import Candidate, GroundingResult, GroundingTiming

__all__ = ["GroundingDinoSam2Grounder"]

log = logging.getLogger(__name__)

_IMAGENET_MEAN = (0.485, 0.456, 0.406)
_IMAGENET_STD = (0.229, 0.224, 0.225)


def _preprocessor(folder: Path) -> dict[str, Any]:
    path = folder / "preprocessor_config.json"
    if not path.is_file():
        return {}
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InvalidInputError(f"cannot read {str(path)!r}: {exc}") from exc


def _normalise(rgb: np.ndarray, mean: Any, std: Any) -> np.ndarray:
    """(H, W, 3) uint8 -> (3, H, W) float32 normalised."""
    x = rgb.astype(np.float32) * np.float32(1.0 / 255.0)
    y = (x - np.asarray(mean, np.float32)) / np.asarray(std, np.float32)
    return np.ascontiguousarray(y.transpose(2, 0, 1), dtype=np.float32)


def _nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Indices of boxes kept by greedy non-maximum suppression, best score first. boxes: (N, 4) xyxy."""
    order = np.argsort(-scores, kind="stable")
    area = np.maximum(boxes[:, 2] - boxes[:, 0], 0) * np.maximum(boxes[:, 3] - boxes[:, 1], 0)
    keep: list[int] = []
    while len(order):
        i = int(order[0])
        keep.append(i)
        rest = order[1:]
        x0 = np.maximum(boxes[i, 0], boxes[rest, 0])
        y0 = np.maximum(boxes[i, 1], boxes[rest, 1])
        x1 = np.minimum(boxes[i, 2], boxes[rest, 2])
        y1 = np.minimum(boxes[i, 3], boxes[rest, 3])
        inter = np.maximum(x1 - x0, 0) * np.maximum(y1 - y0, 0)
        iou = inter / np.maximum(area[i] + area[rest] - inter, 1e-12)
        order = rest[iou <= iou_threshold]
    return np.asarray(keep, dtype=np.int64)


class GroundingDinoSam2Grounder:
    """Grounding DINO + SAM 2 through `transformers`, loaded from a local folder (module docstring).

    Args:
        weights_dir: folder with `grounding_dino/` and `sam2/` sub-folders written by `save_pretrained`.
        device: torch device string ("cpu", "cuda", "cuda:1").
        box_threshold: Grounding DINO boxes scoring below this are dropped (the model card's default 0.25).
        nms_iou: boxes overlapping a better one by more than this IoU are dropped.
        max_candidates: at most this many boxes are segmented and returned.

    `ground(rgb, depth_m, intrinsics, prompt)` has the embedded grounder's signature and validation; the
    depth image is only validated (the models see colour only) and `support_plane` is None.
    """

    def __init__(
        self,
        weights_dir: str | Path,
        device: str = "cpu",
        box_threshold: float = 0.25,
        nms_iou: float = 0.7,
        max_candidates: int = 16,
    ):
        transformers = require("transformers", extra="hub")
        torch = require("torch", extra="hub")
        root = Path(weights_dir)
        dino_dir, sam_dir = root / "grounding_dino", root / "sam2"
        for folder in (dino_dir, sam_dir):
            if not (folder / "config.json").is_file():
                raise InvalidInputError(
                    f"{str(folder)!r} holds no config.json; weights_dir must contain grounding_dino/ and "
                    "sam2/ folders written by save_pretrained"
                )
        if not 0.0 <= float(box_threshold) <= 1.0:
            raise InvalidInputError(f"box_threshold must lie in [0, 1], got {box_threshold}")
        if not 0.0 < float(nms_iou) <= 1.0:
            raise InvalidInputError(f"nms_iou must lie in (0, 1], got {nms_iou}")
        if int(max_candidates) < 1:
            raise InvalidInputError(f"max_candidates must be >= 1, got {max_candidates}")
        self._torch = torch
        self.tokenizer = transformers.AutoTokenizer.from_pretrained(str(dino_dir), local_files_only=True)
        self.detector = transformers.GroundingDinoForObjectDetection.from_pretrained(
            str(dino_dir), local_files_only=True
        )
        self.segmenter = transformers.Sam2Model.from_pretrained(str(sam_dir), local_files_only=True)
        self.detector.eval().to(device)
        self.segmenter.eval().to(device)
        dino_pre, sam_pre = _preprocessor(dino_dir), _preprocessor(sam_dir)
        size = dino_pre.get("size", {})
        self._dino_short = int(size.get("shortest_edge", 800))
        self._dino_long = int(size.get("longest_edge", 1333))
        self._dino_mean = dino_pre.get("image_mean", _IMAGENET_MEAN)
        self._dino_std = dino_pre.get("image_std", _IMAGENET_STD)
        sam_size = sam_pre.get("size", {})
        default_side = int(self.segmenter.config.prompt_encoder_config.image_size)
        self._sam_hw = (int(sam_size.get("height", default_side)), int(sam_size.get("width", default_side)))
        self._sam_mean = sam_pre.get("image_mean", _IMAGENET_MEAN)
        self._sam_std = sam_pre.get("image_std", _IMAGENET_STD)
        self._max_text_len = int(getattr(self.detector.config, "max_text_len", 256))
        self.box_threshold = float(box_threshold)
        self.nms_iou = float(nms_iou)
        self.max_candidates = int(max_candidates)
        self.device = device
        self.weights_dir = root
        log.info("loaded Grounding DINO + SAM 2 from %s on %s", root, device)

    def _detect(self, rgb: np.ndarray, text: str) -> tuple[np.ndarray, np.ndarray]:
        """(N, 4) float64 xyxy pixel boxes and (N,) scores for `text`, all queries."""
        torch = self._torch
        H, W = rgb.shape[:2]
        scale = self._dino_short / min(H, W)
        if max(H, W) * scale > self._dino_long:
            scale = self._dino_long / max(H, W)
        h, w = max(1, round(H * scale)), max(1, round(W * scale))
        image = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR if scale > 1 else cv2.INTER_AREA)
        pixels = torch.from_numpy(_normalise(image, self._dino_mean, self._dino_std))[None].to(self.device)
        tokens = self.tokenizer(
            [text], return_tensors="pt", truncation=True, max_length=self._max_text_len, padding=False
        )
        tokens = {k: v.to(self.device) for k, v in tokens.items()}
        with torch.inference_mode():
            out = self.detector(
                pixel_values=pixels,
                pixel_mask=torch.ones((1, h, w), dtype=torch.long, device=self.device),
                **tokens,
            )
        probs = torch.sigmoid(out.logits[0].float())  # (Q, max_text_len)
        ids = tokens["input_ids"][0]
        special = set(self.tokenizer.all_special_ids) | set(self.tokenizer.convert_tokens_to_ids(["."]))
        words = torch.tensor([int(t) not in special for t in ids.tolist()], device=probs.device)
        L = min(len(ids), probs.shape[1])
        word_probs = probs[:, :L][:, words[:L]]
        if word_probs.shape[1] == 0:  # a prompt of special tokens only: fall back to every text position
            word_probs = probs[:, :L]
        scores = word_probs.max(dim=1).values.cpu().numpy().astype(np.float64)
        cxcywh = out.pred_boxes[0].float().cpu().numpy().astype(np.float64)
        boxes = np.stack(
            [
                (cxcywh[:, 0] - 0.5 * cxcywh[:, 2]) * W,
                (cxcywh[:, 1] - 0.5 * cxcywh[:, 3]) * H,
                (cxcywh[:, 0] + 0.5 * cxcywh[:, 2]) * W,
                (cxcywh[:, 1] + 0.5 * cxcywh[:, 3]) * H,
            ],
            axis=1,
        )
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0, W - 1)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0, H - 1)
        return boxes, scores

    def _segment(self, rgb: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(N, H, W) bool SAM 2 masks for (N, 4) xyxy pixel boxes."""
        torch = self._torch
        H, W = rgb.shape[:2]
        sh, sw = self._sam_hw
        image = cv2.resize(rgb, (sw, sh), interpolation=cv2.INTER_LINEAR)
        pixels = torch.from_numpy(_normalise(image, self._sam_mean, self._sam_std))[None].to(self.device)
        scaled = boxes * np.array([sw / W, sh / H, sw / W, sh / H])
        input_boxes = torch.from_numpy(scaled.astype(np.float32))[None].to(self.device)
        with torch.inference_mode():
            out = self.segmenter(pixel_values=pixels, input_boxes=input_boxes, multimask_output=False)
            logits = out.pred_masks[0, :, 0].float()  # (N, h, w) over the whole resized image
            full = torch.nn.functional.interpolate(
                logits[:, None], size=(H, W), mode="bilinear", align_corners=False
            )
        return (full[:, 0] > 0.0).cpu().numpy()

    def ground(
        self, rgb: np.ndarray, depth_m: np.ndarray, intrinsics: CameraIntrinsics, prompt: str
    ) -> GroundingResult:
        """Candidates for `prompt`, best first (see `Grounder.ground` for the arguments)."""
        t0 = time.perf_counter()
        rgb, depth_m, intrinsics, prompt = validate_frame(rgb, depth_m, intrinsics, prompt)
        text = parse_prompt(prompt).text.strip() or prompt.strip().lower()
        boxes, scores = self._detect(rgb, text if text.endswith(".") else f"{text}.")
        keep = np.flatnonzero(scores >= self.box_threshold)
        keep = keep[_nms(boxes[keep], scores[keep], self.nms_iou)][: self.max_candidates]
        t1 = time.perf_counter()
        candidates: tuple[Candidate, ...] = ()
        if len(keep):
            masks = self._segment(rgb, boxes[keep])
            candidates = tuple(
                Candidate(
                    mask=masks[j],
                    box_xyxy=np.rint(boxes[i]).astype(np.int64),
                    score=float(scores[i]),
                    attributes=None,
                )
                for j, i in enumerate(keep)
            )
        t2 = time.perf_counter()
        timing = GroundingTiming(
            plane_s=0.0, segment_s=t2 - t1, describe_s=0.0, score_s=t1 - t0, total_s=t2 - t0
        )
        return GroundingResult(prompt=prompt, candidates=candidates, support_plane=None, timing=timing)
