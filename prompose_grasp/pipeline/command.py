"""Free-text pick-and-place commands -> what to pick and where to put it.

A small grammar does the structure; the sentence embedding does the vocabulary:

    <verb phrase> <object phrase> [<preposition> <target phrase>]

- the verb phrase is matched against the known actions by MiniLM similarity ("grab", "fetch" -> pick;
  "drop", "set", "put" -> place; "pile up" -> stack), so synonyms work without a word list;
- the object phrase is passed to grounding as is ("the red mug left of the bowl");
- the target phrase after the first place preposition ("in", "into", "on", "onto", "to", "inside", "on top
  of") is a fixture of the cell when its head noun names one ("the blue bin", "the tote", "the conveyor
  belt": `PLACE_TARGETS`); otherwise it names an object to put things in or on ("the white bowl", "the tea
  box"), which the pipeline grounds in the image like the object to pick (`Command.target == "object"`).

Commands are read in English: full-width forms are normalised first (NFKC) and accents dropped; a command
with no word in Latin letters (Japanese, Chinese, Arabic, emoji) raises `CommandNotUnderstood` saying so. A
command that names no object, or whose verb or target matches nothing well enough, raises it too, with the
parts that were understood and examples of what works.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from prompose_grasp.errors import PromposeError
from prompose_grasp.perception.grounding.language import fold_text

__all__ = ["ACTIONS", "PLACE_TARGETS", "Command", "CommandNotUnderstood", "CommandParser"]

#: action -> phrases that name it (matched by sentence similarity to the command's verb phrase).
ACTIONS: dict[str, tuple[str, ...]] = {
    "pick": ("pick up", "grab", "take", "lift", "get", "fetch", "grasp", "pick"),
    "place": (
        "put",
        "place",
        "move",
        "drop",
        "set",
        "transfer",
        "bring",
        "load",
        "unload",
        "unstack",
        "depalletise",
        "depalletize",
    ),
    "stack": ("stack", "pile up", "palletise", "palletize", "build a stack of"),
}

#: place target kind -> phrases that name it.
PLACE_TARGETS: dict[str, tuple[str, ...]] = {
    "bin": ("bin", "tote", "crate", "container", "basket", "bucket"),
    "table": ("table", "desk", "counter", "workbench", "surface"),
    "pallet": ("pallet", "skid", "wooden pallet"),
    "conveyor": ("conveyor", "conveyor belt", "belt", "line"),
}

_PREPOSITIONS = ("on top of", "onto", "into", "inside", "in", "on", "to")
_PLACE_SPLIT = re.compile(r"\s+(" + "|".join(p.replace(" ", r"\s+") for p in _PREPOSITIONS) + r")\s+")
#: prepositions that put an object inside its target (the rest put it on top).
_INTO = ("into", "inside", "in")
_POLITE = re.compile(r"^(?:please\s+)?(?:(?:can|could|would)\s+you\s+)?(?:please\s+)?")
_FROM = re.compile(r"\s+(?:from|off|out of)\s+.*$")
_ARTICLE = re.compile(r"^(?:the|a|an|all|all the|some|every)\s+")
#: the longest known verb phrase, in words ("build a stack of").
_MAX_VERB_WORDS = 4

EXAMPLES = (
    "pick up the red mug",
    "put the mustard bottle in the bin",
    "place the yellow carton on the pallet",
    "stack the brown cartons on the pallet",
    "move the can onto the conveyor",
)


class CommandNotUnderstood(PromposeError):
    """A command could not be parsed into an object and an action (and a target where one is needed)."""


@dataclass(frozen=True)
class Command:
    """A parsed command.

    Attributes:
        text: the command as given.
        action: "pick" (pick and lift), "place" (pick and put at the target) or "stack" (several objects
            onto the target in a pattern).
        object_prompt: what to pick, for grounding ("the red mug left of the bowl").
        plural: the object phrase names several objects ("the cartons", "all boxes").
        target: place target kind ("bin", "table", "pallet", "conveyor"), "object" when the target phrase
            names an object to ground in the image ("the white bowl"), or None for a plain pick.
        target_prompt: the target phrase as written ("the blue bin"), or "".
        verb_score, target_score: cosine similarities of the verb / target phrase with the best match (1.0
            for an exact word; nan for an object target or none).
        into: the preposition puts the object inside the target ("in", "into", "inside"), not on top.
    """

    text: str
    action: str
    object_prompt: str
    plural: bool
    target: str | None
    target_prompt: str
    verb_score: float
    target_score: float
    into: bool = False


#: Nouns plural in form that name one object: a pair of blades, jaws, lenses or legs made as one thing ("pick
#: up the scissors" is one pick, and the wrong-object check judges it as one object), and words whose final
#: "s" is no plural ending.
_ONE_OBJECT_PLURALS = frozenset(
    {
        "scissors", "shears", "secateurs", "pruners", "pliers", "tongs", "tweezers", "clippers", "cutters",
        "snips", "glasses", "eyeglasses", "spectacles", "sunglasses", "goggles", "binoculars", "headphones",
        "earphones", "jeans", "trousers", "pants", "shorts", "tights", "leggings", "pajamas", "pyjamas",
        "overalls", "thermos", "lens",
    }
)  # fmt: skip


def _looks_plural(phrase: str) -> bool:
    """Whether a phrase names several objects: "all boxes", "both cans", "the cartons" (not "the glass", "the
    scissors", "the asparagus" or "a pair of socks")."""
    words = phrase.split()
    if not words:
        return False
    if words[0] in ("all", "every", "both"):
        return True
    head = words[-1]
    if head in _ONE_OBJECT_PLURALS or "pair of" in phrase or head.endswith(("ss", "us", "is")):
        return False
    return len(head) > 3 and head.endswith("s")


def _fixture_of(phrase: str) -> str | None:
    """The fixture kind whose words name the phrase's head noun ("the blue bin" -> bin, "conveyor belt" ->
    conveyor), or None."""
    words = phrase.split()
    for n in (2, 1):  # two-word names first ("conveyor belt", "wooden pallet")
        tail = " ".join(words[-n:])
        for kind, phrases in PLACE_TARGETS.items():
            if tail in phrases:
                return kind
    return None


class CommandParser:
    """Parses commands with the shared MiniLM encoder (loaded on first use).

    Args:
        text_encoder: any `perception.text.TextEncoder`; default: the shared MiniLM.
        min_verb_score: below this cosine similarity a verb is "not understood". MiniLM puts unrelated short
            phrases at 0.0-0.35 and synonyms at 0.5-1.0 (measured on the phrases of `ACTIONS` against each
            other and against object nouns); 0.45 sits between.
    """

    def __init__(self, text_encoder: Any | None = None, min_verb_score: float = 0.45):
        self._encoder = text_encoder
        self.min_verb_score = min_verb_score
        self._tables: dict[str, tuple[list[str], np.ndarray]] = {}

    def _best(self, phrase: str, table: dict[str, tuple[str, ...]], name: str) -> tuple[str, float]:
        """The entry of `table` whose phrases are most similar to `phrase`, and that similarity."""
        if name not in self._tables:
            keys = [k for k, phrases in table.items() for _ in phrases]
            self._tables[name] = (
                keys,
                self.encoder.encode([p for phrases in table.values() for p in phrases]),
            )
        keys, E = self._tables[name]
        sims = E @ self.encoder.encode([phrase])[0]
        i = int(np.argmax(sims))
        return keys[i], float(sims[i])

    @property
    def encoder(self) -> Any:
        if self._encoder is None:
            from prompose_grasp.perception.text import default_text_encoder

            self._encoder = default_text_encoder()
        return self._encoder

    def _verb(self, words: list[str]) -> tuple[str, float, int]:
        """(action, similarity, number of words) of the verb phrase at the start of `words`: the longest
        known phrase when one matches exactly ("pick up"), else the first word by similarity ("fetch")."""
        for n in range(min(_MAX_VERB_WORDS, len(words)), 0, -1):
            phrase = " ".join(words[:n])
            for action, phrases in ACTIONS.items():
                if phrase in phrases:
                    return action, 1.0, n
        if not words:
            return "", 0.0, 0
        action, score = self._best(words[0], ACTIONS, "actions")
        return action, score, 1

    def parse(self, text: str) -> Command:
        """Parse one command; raises `CommandNotUnderstood` with what was understood and examples."""
        if not isinstance(text, str) or not text.strip():
            raise CommandNotUnderstood(self._explain(text, "the command is empty"))
        folded = fold_text(text)  # full-width forms to ASCII, accents dropped
        if not re.search(r"[A-Za-z]", folded):
            raise CommandNotUnderstood(
                self._explain(
                    text,
                    "it has no word in Latin letters; commands are read in English (the text encoder, "
                    "all-MiniLM-L6-v2, understands English)",
                )
            )
        clean = _POLITE.sub("", " ".join(re.sub(r"[^\w\s'-]", " ", folded.lower()).split()))
        parts = _PLACE_SPLIT.split(clean, maxsplit=1)
        head, target_phrase = parts[0], (parts[2] if len(parts) > 2 else "")
        into = len(parts) > 2 and parts[1] in _INTO
        words = head.split()
        action, verb_score, n_verb = self._verb(words)
        if verb_score < self.min_verb_score:
            raise CommandNotUnderstood(self._explain(text, f"no known action in {' '.join(words[:2])!r}"))
        # "the cartons from the pallet": where they are now is no part of what they are
        object_prompt = _FROM.sub("", " ".join(words[n_verb:])).strip()
        if not object_prompt:
            raise CommandNotUnderstood(self._explain(text, "it names no object to pick"))
        target, target_score = None, float("nan")
        if target_phrase:
            phrase = _ARTICLE.sub("", target_phrase + " ").strip()
            if not phrase:
                raise CommandNotUnderstood(self._explain(text, "it names no place after the preposition"))
            fixture = _fixture_of(phrase)
            if fixture is not None:
                target, target_score = fixture, 1.0
            else:  # an object to put it in or on ("the white bowl"): grounded in the image by the pipeline
                target, target_score = "object", float("nan")
            if action == "pick":
                action = "place"
        elif action in ("place", "stack"):
            raise CommandNotUnderstood(
                self._explain(text, f"{action!r} needs a place, e.g. '... in the bin'")
            )
        return Command(
            text=text,
            action=action,
            object_prompt=object_prompt,
            plural=_looks_plural(object_prompt),
            target=target,
            target_prompt=target_phrase,
            verb_score=verb_score,
            target_score=target_score,
            into=into,
        )

    @staticmethod
    def _explain(text: object, why: str) -> str:
        return f"could not understand the command {text!r}: {why}. Commands look like: " + "; ".join(
            repr(e) for e in EXAMPLES
        )
