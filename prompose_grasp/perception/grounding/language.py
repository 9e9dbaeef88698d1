"""Prompt parsing: the words the grounder handles explicitly (colour, size, spatial) and the noun phrase.

The parser is small and rule-based on purpose: the open-vocabulary part (what a "mustard bottle" looks
like) goes to the sentence embedding, while the words whose meaning is a measurement (colours, sizes,
positions) are read here and checked against what the grounder measured.

Prompts are read in English: full-width and other compatibility forms are first normalised (NFKC:
"ｒｅｄ　ｍｕｇ" -> "red mug") and accents dropped ("café" -> "cafe"); a prompt with no Latin
letter left (Japanese, Chinese, Arabic, emoji) is refused by `check_prompt` with that reason.

Handled forms (case and punctuation are ignored):

- command verbs and fillers in front are dropped: "pick up the red mug" -> "red mug"; a destination
  after put / place / move / drop ("put the can in the bin") is dropped;
- colour words (`COLOUR_WORDS`: palette names and common synonyms such as "gray", "violet", "navy"),
  except where the word names the thing, not its colour: in a compound naming a content or a product
  ("olive oil bottle", "orange juice carton", "red wine bottle": `COLOUR_COMPOUNDS`), and as the noun itself
  when nothing else names the object ("the orange", "the small lime": `COLOUR_NOUNS`);
- size words: superlatives "largest / biggest / smallest / tallest / shortest / longest" (ranked among
  the candidates) and adjectives "big / large / small / little / tiny / tall / short / long";
- relations to a reference object: "X left of Y", "X to the right of Y", "X behind Y", "X in front of Y",
  "X next to / beside / near / close to Y", "X nearest to Y";
- absolute positions: "nearest / closest" (to the camera), "farthest / furthest", "leftmost", "rightmost",
  "on the left", "on the right", "in the front", "in the back".
"""

from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass

from prompose_grasp.errors import InvalidInputError

__all__ = [
    "COLOUR_COMPOUNDS",
    "COLOUR_NOUNS",
    "COLOUR_WORDS",
    "GENERIC_NOUNS",
    "ParsedPrompt",
    "check_prompt",
    "fold_text",
    "parse_prompt",
]

#: word -> palette name (`describe.PALETTE`)
COLOUR_WORDS: dict[str, str] = {
    "red": "red", "crimson": "red", "scarlet": "red", "maroon": "red",
    "orange": "orange",
    "yellow": "yellow", "golden": "yellow", "gold": "yellow",
    "green": "green", "olive": "green", "lime": "green",
    "cyan": "cyan", "turquoise": "cyan", "teal": "cyan", "aqua": "cyan",
    "blue": "blue", "navy": "blue",
    "purple": "purple", "violet": "purple", "lilac": "purple", "magenta": "pink",
    "pink": "pink",
    "brown": "brown", "tan": "brown", "beige": "brown",
    "black": "black",
    "white": "white",
    "grey": "grey", "gray": "grey", "silver": "grey",
}  # fmt: skip

#: A colour word followed by one of these words names what the object holds or which product it is, not the
#: object's colour: an olive oil bottle is clear or dark green glass, a red wine bottle green, an orange juice
#: carton printed white; the pair stays in the noun and asks for no colour.
COLOUR_COMPOUNDS: dict[str, frozenset[str]] = {
    "olive": frozenset({"oil"}),
    "orange": frozenset({"juice", "soda", "marmalade"}),
    "lime": frozenset({"juice"}),
    "red": frozenset({"wine", "bull", "beans", "lentils"}),
    "white": frozenset({"wine", "vinegar", "out", "rice", "beans", "board"}),
    "green": frozenset({"tea", "beans", "peas", "olives"}),
    "black": frozenset({"tea", "pepper", "beans", "olives", "board"}),
    "brown": frozenset({"sugar", "rice"}),
}
#: Colour words that are also things (fruits): the noun when no other word names the object ("pick up the
#: orange"), a colour when one does ("the orange ball").
COLOUR_NOUNS = frozenset({"orange", "lime", "olive"})

#: superlative / adjective -> (measure, direction, strong): measure is "volume", "height" or "length";
#: direction +1 prefers bigger values; strong marks superlatives (ranked, weighted higher).
_SIZE_WORDS: dict[str, tuple[str, int, bool]] = {
    "largest": ("volume", 1, True), "biggest": ("volume", 1, True), "smallest": ("volume", -1, True),
    "tallest": ("height", 1, True), "highest": ("height", 1, True), "shortest": ("height", -1, True),
    "longest": ("length", 1, True),
    "large": ("volume", 1, False), "big": ("volume", 1, False), "huge": ("volume", 1, False),
    "small": ("volume", -1, False), "little": ("volume", -1, False), "tiny": ("volume", -1, False),
    "tall": ("height", 1, False), "short": ("height", -1, False), "long": ("length", 1, False),
}  # fmt: skip

#: Nouns that say nothing about what the object is: no shape knowledge is drawn from them.
GENERIC_NOUNS = frozenset({"object", "objects", "thing", "things", "item", "items", "one", "stuff", "it"})

_FILLERS = frozenset({"one", "dark", "light"})
_ARTICLES = frozenset(
    {"the", "a", "an", "this", "that", "some", "any", "my", "your", "of", "all", "both", "every", "each"}
)
_LEADING = re.compile(
    r"^(?:please\s+)?(?:(?:can|could|would)\s+you\s+)?(?:please\s+)?"
    r"(?:pick\s+up|pick|grab|grasp|take|get|fetch|find|locate|bring(?:\s+me)?|hand(?:\s+me)?|give(?:\s+me)?|"
    r"lift|move|push|put|place|drop|select|show(?:\s+me)?|point\s+(?:at|to)|segment|detect)\s+"
)
_DESTINATION_VERBS = re.compile(r"^(?:please\s+)?(?:put|place|move|drop|bring|push)\s")
_DESTINATION = re.compile(
    r"\s(?:into|onto|inside|in|on|to)\s+(?!front\b|back\b|the\s+(?:left|right|front|back)\b)"
)

# relation patterns: (regex splitting "target <rel> reference", relation name); the first match wins
_RELATIONS: tuple[tuple[re.Pattern[str], str], ...] = tuple(
    (re.compile(rf"\s(?:{pattern})\s"), name)
    for pattern, name in (
        (r"(?:that\s+is\s+|which\s+is\s+)?(?:to\s+the\s+|on\s+the\s+)?left\s+(?:side\s+)?of", "left_of"),
        (r"(?:that\s+is\s+|which\s+is\s+)?(?:to\s+the\s+|on\s+the\s+)?right\s+(?:side\s+)?of", "right_of"),
        (r"(?:that\s+is\s+|which\s+is\s+)?in\s+front\s+of", "in_front_of"),
        (r"(?:that\s+is\s+|which\s+is\s+)?(?:behind|in\s+back\s+of|at\s+the\s+back\s+of)", "behind"),
        (
            r"(?:that\s+is\s+|which\s+is\s+)?(?:next\s+to|beside|besides|near|close\s+to|nearest\s+to|closest\s+to|"
            r"by)",
            "near",
        ),
    )
)
_SELF_REFERENCES = re.compile(r"^(?:the\s+)?(?:camera|me|you|us|robot|viewer)$")
_ABSOLUTE: tuple[tuple[re.Pattern[str], str], ...] = tuple(
    (re.compile(pattern), name)
    for pattern, name in (
        (r"\b(?:on|to|at)\s+the\s+left(?:\s+side)?\b|\bleftmost\b|\bleft\b", "leftmost"),
        (r"\b(?:on|to|at)\s+the\s+right(?:\s+side)?\b|\brightmost\b|\bright\b", "rightmost"),
        (
            r"\b(?:nearest|closest)(?:\s+to\s+(?:the\s+)?(?:camera|me|you|us|robot))?\b|\b(?:in|at)\s+the\s+front\b|"
            r"\bfront(?:most)?\b",
            "nearest",
        ),
        (
            r"\b(?:farthest|furthest)(?:\s+(?:from|to)\s+(?:the\s+)?(?:camera|me|you|us|robot))?\b|"
            r"\b(?:in|at)\s+the\s+back\b|\bback(?:most)?\b|\brearmost\b",
            "farthest",
        ),
    )
)


@dataclass(frozen=True)
class ParsedPrompt:
    """A prompt taken apart.

    Attributes:
        text: the cleaned phrase of the target (lower case, command verbs and destination dropped), colour and
            size words included ("small red mug"); scored against descriptions with the sentence embedding.
        noun: `text` without articles, colour, size and position words ("mug"); "" when nothing is left.
        colours: palette names the prompt asks for (a candidate should have one of them).
        size: (measure, direction, strong) or None (`_SIZE_WORDS`).
        position: absolute position word ("leftmost", "rightmost", "nearest", "farthest") or None.
        relation: relation to a reference object ("left_of", "right_of", "behind", "in_front_of", "near") or
            None; `reference` is then the parsed reference phrase.
    """

    text: str
    noun: str
    colours: tuple[str, ...] = ()
    size: tuple[str, int, bool] | None = None
    position: str | None = None
    relation: str | None = None
    reference: ParsedPrompt | None = None

    @property
    def generic(self) -> bool:
        """True when the noun says nothing about the object's kind ("the largest object")."""
        return not self.noun or all(w in GENERIC_NOUNS for w in self.noun.split())


def fold_text(text: str) -> str:
    """`text` as the parser reads it: NFKC-normalised (full-width letters, digits and spaces become their
    ASCII forms, ligatures their letters) with accents dropped (NFKD, combining marks removed)."""
    text = unicodedata.normalize("NFKC", text)
    decomposed = unicodedata.normalize("NFKD", text)
    return "".join(c for c in decomposed if not unicodedata.combining(c))


_LATIN_LETTER = re.compile(r"[A-Za-z]")


def check_prompt(prompt: object, what: str = "prompt") -> str:
    """A prompt the grounder can read, NFKC-normalised and stripped ("ｒｅｄ ｍｕｇ" -> "red mug").

    Raises:
        InvalidInputError: not a str, blank, or without a Latin letter once folded (`fold_text`): the
            parser and the text encoder (all-MiniLM-L6-v2, trained on English) read English words only.
    """
    if not isinstance(prompt, str):
        raise InvalidInputError(f"{what} must be a str naming the object, got {type(prompt).__name__}")
    text = unicodedata.normalize("NFKC", prompt).strip()
    if not text:
        raise InvalidInputError(f"{what} is empty; name the object, e.g. 'the red mug'")
    if not _LATIN_LETTER.search(fold_text(text)):
        raise InvalidInputError(
            f"{what} {prompt!r} has no word in Latin letters; the text encoder (all-MiniLM-L6-v2) and the "
            "prompt parser understand English: name the object in English, e.g. 'the red mug'"
        )
    return text


def _clean(text: str) -> str:
    text = fold_text(text).lower().replace("-", " ")
    text = re.sub(r"[^a-z0-9\s]", " ", text)
    return re.sub(r"\s+", " ", text).strip()


def _parse_phrase(text: str, allow_relation: bool) -> ParsedPrompt:
    text = f" {text} "
    if allow_relation:
        for pattern, name in _RELATIONS:
            m = pattern.search(text)
            if m is None:
                continue
            target, reference = text[: m.start()].strip(), text[m.end() :].strip()
            if not target or not reference:
                continue
            if _SELF_REFERENCES.match(reference):  # "nearest to the camera" is an absolute position
                break
            parsed = _parse_phrase(target, allow_relation=False)
            ref = _parse_phrase(reference, allow_relation=False)
            return ParsedPrompt(
                parsed.text, parsed.noun, parsed.colours, parsed.size, parsed.position, name, ref
            )
    text = text.strip()
    position = None
    rest = text
    for pattern, name in _ABSOLUTE:
        if pattern.search(rest):
            position = name
            rest = pattern.sub(" ", rest)
            break
    words = rest.split()
    size = None
    for w in words:
        if w in _SIZE_WORDS and (size is None or (_SIZE_WORDS[w][2] and not size[2])):
            size = _SIZE_WORDS[w]
    colour_at = _colour_positions(words)
    colours = tuple(dict.fromkeys(COLOUR_WORDS[words[i]] for i in colour_at))
    noun_words = [
        w
        for i, w in enumerate(words)
        if w not in _ARTICLES and i not in colour_at and w not in _SIZE_WORDS and w not in _FILLERS
    ]
    clean_text = " ".join(w for w in words if w not in _ARTICLES)
    return ParsedPrompt(clean_text or text, " ".join(noun_words), colours, size, position)


def _colour_positions(words: list[str]) -> list[int]:
    """Indices of the words read as colours: colour words, less those naming a content or product with the
    next word (`COLOUR_COMPOUNDS`) and a fruit's name left as the only noun (`COLOUR_NOUNS`)."""
    at = [
        i
        for i, w in enumerate(words)
        if w in COLOUR_WORDS and not (i + 1 < len(words) and words[i + 1] in COLOUR_COMPOUNDS.get(w, ()))
    ]
    # "one" and "thing" name no kind, but say that the colour word before them is a colour
    named = [
        w
        for i, w in enumerate(words)
        if i not in at
        and w not in _ARTICLES
        and w not in _SIZE_WORDS
        and (w in GENERIC_NOUNS or w not in _FILLERS)
    ]
    if not named and at and words[at[-1]] in COLOUR_NOUNS:
        at = at[:-1]  # "the orange", "the small lime": the fruit
    return at


def parse_prompt(prompt: str) -> ParsedPrompt:
    """Parse a prompt; see the module docstring for the handled forms.

    Raises:
        InvalidInputError: the prompt is blank or has no Latin letter (`check_prompt`).
    """
    text = _clean(check_prompt(prompt))
    is_destination_command = bool(_DESTINATION_VERBS.match(text))
    for _ in range(2):  # "please pick up" + "the"
        text = _LEADING.sub("", text)
    if is_destination_command:
        m = _DESTINATION.search(f" {text} ")
        if m is not None and m.start() > 0:
            text = text[: m.start()].strip()
    return _parse_phrase(text, allow_relation=True)
