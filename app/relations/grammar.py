"""Reading a question about how things stand: its target, relations, anchors and superlative.

"the mug on the desk near the window" -> target "mug", on ["desk"], near ["window"];
"which chair is next to the sofa" -> "chair", next_to ["sofa"]; "what's under the bed" -> any
target, under ["bed"]; "the lamp closest to me" -> "lamp", closest, from the asker. No model,
no network and no numpy: a token-level parser over a small English grammar, so the server and
the device read a question alike.

    query    := filler* scaffold* target clause* tail*
    target   := determiner* (superlative | word)*            "the closest red mug"
    clause   := [and] lead_in relation anchor | [and] lead_in between anchor and anchor
              | [and] [is] [the] superlative [to | from] anchor
    lead_in  := [that | which | who] [I left | we put ...] [is | are ...] [right | just ...]
                [sitting | lying | placed | hanging ...] [right | just ...]
    anchor   := determiner* word+                             "the kitchen counter"

Words in a noun phrase run until a function word (that, and, to, is, where, not ...), the start
of another relation or a superlative. A relation needs an anchor noun phrase right after it
("keys on a ring" is a relation reading; "something to lie on", "the on switch", "turn on the
lamp" are not): whether the anchor names a map object is the caller's to decide, by grounding.
A query whose words are not all taken by the grammar ("a clock on the wall that tells the
time") reads as plain: `relations=[]`, no superlative, and the caller answers as today.

Each step looks at most a few words ahead and every word is read once, so parsing is linear
in the text's length (no regular expression but the tokenizer's, which cannot backtrack).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

RELATION_KINDS = (
    "on", "in", "under", "above", "below", "near", "next_to", "between",
    "left_of", "right_of", "in_front_of", "behind",
)  # fmt: skip
"""The relations a clause may name (`between` has two anchors, the others one)."""
VIEWPOINT_KINDS = frozenset({"left_of", "right_of", "in_front_of", "behind"})
"""Relations seen from where the asker stands."""
SUPERLATIVE_KINDS = ("closest", "farthest", "biggest", "smallest", "highest", "lowest")
"""Superlatives within the target's category; closest / farthest from the asker or an anchor."""


@dataclass(frozen=True)
class RelationClause:
    """One relation the target stands in."""

    kind: str
    """One of RELATION_KINDS."""
    anchors: list[str]
    """Anchor noun phrases, determiners removed: two for `between`, one otherwise, none when
    the anchor is the asker ("near me", "on my left", "in front of me")."""


@dataclass(frozen=True)
class Superlative:
    """The target's extreme copy: "the biggest table", "the lamp closest to the window"."""

    kind: str
    """One of SUPERLATIVE_KINDS."""
    anchors: list[str] = field(default_factory=list)
    """For closest / farthest: the phrase distance is measured from ("closest to the window":
    ["window"]); empty: from the asker. Always empty for the other kinds."""


@dataclass(frozen=True)
class Reading:
    """What a query asks for, as far as the grammar reads it."""

    target: str
    """The noun phrase asked about, determiners and question words removed, adjectives kept
    ("the red mug" -> "red mug"); "" when unspecified ("what is on the table", "anything under
    the bed"): the caller ranks every object by relation x anchor. In a plain reading, the
    query's words after the question words."""
    relations: list[RelationClause]
    """Clauses all about the target, in the query's order; [] in a plain reading."""
    superlative: Superlative | None
    """The superlative, if any."""
    viewer: bool
    """The answer depends on where the asker stands: closest / farthest without an anchor, a
    clause about the asker ("near me") or a viewpoint relation (left / right / in front /
    behind), so the caller needs the asker's position."""

    @property
    def any_target(self) -> bool:
        """The target is unspecified: any object may answer."""
        return not self.target


def is_relational(reading: Reading) -> bool:
    """Whether the reading asks more than a plain query: a relation or a superlative. A plain
    reading is answered exactly as today (one text embedding ranked against the objects)."""
    return bool(reading.relations) or reading.superlative is not None


def parse(text: str) -> Reading:
    """Read `text` (any length, any characters; never raises, linear time)."""
    return _Parser(tokenize(text)).reading()


# --- words ------------------------------------------------------------------------------------

# Each repetition starts with ' or -, so a match cannot be split two ways: no backtracking.
_WORD = re.compile(r"[^\W_]+(?:['\-][^\W_]+)*")
_IS_AFTER = frozenset({"what", "where", "that", "there", "it", "here", "who", "which", "how"})
_CONTRACTIONS = {
    "where'd": ("where", "did"), "can't": ("cannot",), "cant": ("cannot",),
    "won't": ("will", "not"),
    "whats": ("what", "is"), "wheres": ("where", "is"), "thats": ("that", "is"),
    "im": ("i", "am"), "ive": ("i", "have"),
}  # fmt: skip
_SUFFIXES = (("n't", ("not",)), ("'re", ("are",)), ("'m", ("am",)), ("'ve", ("have",)),
             ("'ll", ("will",)), ("'d", ("would",)))  # fmt: skip


def tokenize(text: str) -> list[str]:
    """Lower-case words of `text`, punctuation dropped, contractions spelt out ("what's" ->
    "what", "is"; "didn't" -> "did", "not"); a possessive stays one word ("john's")."""
    text = text.lower().replace("\u2019", "'").replace("\u2018", "'").replace("`", "'")
    words: list[str] = []
    for match in _WORD.finditer(text):
        word = match.group()
        if word in _CONTRACTIONS:
            words.extend(_CONTRACTIONS[word])
        elif word.endswith("'s") and word[:-2] in _IS_AFTER:
            words.extend((word[:-2], "is"))
        else:
            for suffix, spelt in _SUFFIXES:
                if word.endswith(suffix) and len(word) > len(suffix):
                    words.extend((word[: -len(suffix)], *spelt))
                    break
            else:
                words.append(word)
    return words


def _set(text: str) -> frozenset[str]:
    return frozenset(text.split())


def _phrases(*texts: str) -> tuple[tuple[str, ...], ...]:
    return tuple(tuple(text.split()) for text in texts)


_RELATIONS: dict[str, tuple[tuple[str, ...], ...]] = {
    "on": _phrases("on top of", "on", "upon", "onto", "atop"),
    "in": _phrases("inside of", "inside", "in", "within", "into"),
    "under": _phrases("under", "underneath", "beneath"),
    "below": _phrases("below"),
    "above": _phrases("above", "over"),
    "near": _phrases(
        "near", "near to", "close to", "nearby", "close by", "not far from", "around"
    ),
    "next_to": _phrases(
        "next to", "beside", "by", "alongside", "alongside of", "adjacent to", "at",
        "by the side of", "at the side of", "to the side of",
    ),
    "between": _phrases("between", "in between"),
    "left_of": _phrases(
        "left of", "to the left of", "on the left of", "at the left of", "on the left side of",
        "to the left side of", "on the left-hand side of", "to the left-hand side of",
    ),
    "right_of": _phrases(
        "right of", "to the right of", "on the right of", "at the right of",
        "on the right side of", "to the right side of", "on the right-hand side of",
        "to the right-hand side of",
    ),
    "in_front_of": _phrases("in front of", "infront of", "ahead of"),
    "behind": _phrases("behind", "at the back of", "in back of", "at the rear of"),
}  # fmt: skip
"""Relation phrases taking an anchor right after them."""
_RELATIONS_FROM_ASKER: dict[str, tuple[tuple[str, ...], ...]] = {
    "left_of": _phrases(
        "on the left", "to the left", "on my left", "to my left", "on your left",
        "to your left", "on the left side", "on the left-hand side",
    ),
    "right_of": _phrases(
        "on the right", "to the right", "on my right", "to my right", "on your right",
        "to your right", "on the right side", "on the right-hand side",
    ),
    "near": _phrases("nearby", "close by", "near here", "around here", "close to here"),
    "in_front_of": _phrases("in front"),
    "behind": _phrases("behind"),
}  # fmt: skip
"""Relation phrases with no anchor after them: the anchor is the asker ("the mug on the left")."""

_SUPERLATIVES = {
    "closest": "closest", "nearest": "closest", "farthest": "farthest", "furthest": "farthest",
    "farthermost": "farthest", "biggest": "biggest", "largest": "biggest",
    "smallest": "smallest", "tiniest": "smallest", "littlest": "smallest",
    "highest": "highest", "topmost": "highest", "uppermost": "highest",
    "lowest": "lowest", "bottommost": "lowest", "lowermost": "lowest",
}  # fmt: skip

_FILLERS = _phrases(
    "please", "hey", "hi", "ok", "okay", "so", "um", "uh", "hmm", "well", "kindly",
    "can you", "could you", "would you", "will you",
)  # fmt: skip
"""Words before a question that say nothing about it."""
_SCAFFOLDS = _phrases(
    "where did i leave", "where did i put", "where did i last see", "where did i",
    "where have i left", "where have i put", "where do i keep", "where can i find",
    "where do i find",
    "where would i find", "where could i find", "where is", "where are", "where was", "where were",
    "do you know where", "tell me where", "show me where", "tell me what is", "tell me what are",
    "tell me", "help me find", "i am looking for", "looking for", "look for", "search for",
    "i need", "i want", "i lost", "i cannot find", "i can not find", "i do not see",
    "show me", "show", "find me", "find", "locate", "get me", "give me", "bring me", "point to",
    "point at", "point out", "highlight", "do you see", "see", "is there", "are there",
    "was there", "were there", "there is", "there are", "is", "are",
    "what is there", "what do you see", "what can you see", "what do we have", "what do i have",
    "what is", "what are", "what was", "what", "which one is", "which is", "which are", "which",
)  # fmt: skip
"""Question words before the target ("where did I leave my", "which", "show me")."""
_TAILS = _phrases(
    "please", "right now", "now", "again", "thanks", "thank you", "for me", "currently",
    "at the moment", "is", "are",
)  # fmt: skip
"""Words after a question that say nothing about it."""

_DETERMINERS = _set(
    "the a an my our your his her their its this that these those some any each every all another"
)
_NP_STOPS = _set(
    "and or but not nor that which who whom whose where when while whereas to is are was were "
    "am be been being if because so than then"
)
"""Function words that end a noun phrase."""
_NOT_AN_ANCHOR = _NP_STOPS | _set(
    "with for of from at by in on into onto off up down out away about over under through "
    "top there it them again too now please"
)
"""Words that cannot begin an anchor ("a board to write on with markers": no anchor)."""
_ASKER = frozenset({"me", "myself", "us", "you", "yourself"})
"""An anchor that is the asker ("near me"): the clause has no anchor phrase."""
_ANY = _set(
    "anything something everything thing things stuff object objects item items what whatever "
    "one ones"
)
"""A target of only these words is unspecified ("anything under the table")."""
_IDIOMS = {
    "by": _set(
        "hand far now then accident mistake default chance car bus train foot mail post name "
        "size day night way"
    ),
    "at": _set(
        "night home all once least most last first work times noon midnight random rest school"
    ),
    "in": _set(
        "use stock case general time person order charge fact advance total particular detail "
        "half pieces"
    ),
    "on": _set("sale fire time purpose demand average hold"),
    "over": _set("here"),
    "under": _set("construction warranty pressure control"),
}
"""A preposition followed by one of these bare words is an idiom, not a relation ("by hand")."""
_IMPERATIVES = _set(
    "turn switch put plug log sign try hold carry take get keep go come sit lie lay stand rest "
    "hang look check pick set throw drop leave move click tap press step climb jump lean fall "
    "sleep write type cook read play watch work eat stay"
)
"""A bare verb before a preposition makes a phrasal verb ("turn on the lamp"), not a relation."""

_MAX_DETERMINERS = 3
"""At most this many determiners start a noun phrase."""
_RELATIVE_PRONOUNS = frozenset({"that", "which", "who"})
_SUBJECTS = frozenset({"i", "you", "we", "they", "he", "she", "someone"})
_AUXILIARIES = frozenset({"have", "had", "did", "just", "last", "recently"})
_PLACING_VERBS = _set(
    "left leave put placed set dropped kept keep stored hid hidden saw seen stashed"
)
_COPULAS = frozenset({"is", "are", "was", "were", "be", "been", "being"})
_ADVERBS = frozenset({"right", "just", "directly", "straight", "immediately", "still", "currently"})
_POSTURES = _set(
    "sitting sits sat lying lies lay laying standing stands stood resting rests placed put kept "
    "left located positioned situated hanging hangs hung mounted stored leaning leans set "
    "perched stacked parked tucked hidden hiding attached fixed found stuck"
)


def _index(
    table: dict[str, tuple[tuple[str, ...], ...]], anchored: bool
) -> dict[str, list[tuple[tuple[str, ...], str, bool]]]:
    by_first: dict[str, list[tuple[tuple[str, ...], str, bool]]] = {}
    for kind, phrases in table.items():
        for phrase in phrases:
            by_first.setdefault(phrase[0], []).append((phrase, kind, anchored))
    return by_first


def _relation_index() -> dict[str, list[tuple[tuple[str, ...], str, bool]]]:
    merged = _index(_RELATIONS, True)
    for first, entries in _index(_RELATIONS_FROM_ASKER, False).items():
        merged.setdefault(first, []).extend(entries)
    for entries in merged.values():
        entries.sort(key=lambda entry: (-len(entry[0]), not entry[2]))  # longest, anchored first
    return merged


_RELATION_INDEX = _relation_index()


# --- parser -----------------------------------------------------------------------------------


@dataclass
class _Found:
    """A relation phrase found at a position: its kind, where it ends (and its anchor, if
    `anchored`, starts)."""

    kind: str
    end: int
    anchored: bool


@dataclass
class _Phrase:
    """A noun phrase: its words (determiners dropped), where it ends, whether it is the asker."""

    words: list[str]
    end: int
    asker: bool = False

    @property
    def text(self) -> str:
        return " ".join(self.words)


class _Parser:
    def __init__(self, words: list[str]):
        self.words = words
        self.start, self.stop = 0, len(words)
        self.superlative: Superlative | None = None
        self.superlative_word_only = False  # "the closest lamp": an anchor may follow ("to me")

    # Positions are indices into self.words; reads past self.stop see "".
    def word(self, k: int) -> str:
        return self.words[k] if k < self.stop else ""

    def starts_with(self, k: int, phrase: tuple[str, ...]) -> bool:
        return k + len(phrase) <= self.stop and tuple(self.words[k : k + len(phrase)]) == phrase

    def longest(self, k: int, phrases: tuple[tuple[str, ...], ...]) -> int:
        """The length of the longest of `phrases` at k (0: none)."""
        return max((len(p) for p in phrases if self.starts_with(k, p)), default=0)

    def reading(self) -> Reading:
        self.strip_tails()
        while (n := self.longest(self.start, _FILLERS) or self.longest(self.start, _SCAFFOLDS)) > 0:
            self.start += n
        parsed = self.parse_structure()
        if parsed is None or not (parsed[1] or self.superlative):  # plain, or only partly read
            return Reading(self.plain_target(), [], None, False)
        target_words, relations = parsed
        if target_words and all(w in _ANY for w in target_words):
            target_words = []
        target = " ".join(target_words)
        superlative = self.superlative
        viewer = any(c.kind in VIEWPOINT_KINDS or not c.anchors for c in relations) or (
            superlative is not None
            and superlative.kind in ("closest", "farthest")
            and not superlative.anchors
        )
        return Reading(target, relations, superlative, viewer)

    def strip_tails(self) -> None:
        while self.stop > self.start:
            n = max((len(t) for t in _TAILS if self.starts_with(self.stop - len(t), t)), default=0)
            if n == 0 or self.stop - n < self.start:
                return
            self.stop -= n

    def plain_target(self) -> str:
        """The words after the question words, leading determiners dropped."""
        return " ".join(self.words[self.after_determiners(self.start) : self.stop])

    def parse_structure(self) -> tuple[list[str], list[RelationClause]] | None:
        """(target words, clauses), or None when some words do not fit the grammar."""
        k, target_words, saw_determiner = self.start, [], False
        while k < self.stop:
            w = self.words[k]
            may_relate = bool(target_words) or not saw_determiner
            bare_verb = (
                len(target_words) == 1 and not saw_determiner and target_words[0] in _IMPERATIVES
            )
            if may_relate and self.relation_at(k, bare_verb) is not None:
                break
            if not target_words and w in _DETERMINERS:
                saw_determiner = True
            elif w in _SUPERLATIVES and self.superlative is None and not target_words:
                self.superlative = Superlative(_SUPERLATIVES[w])
                self.superlative_word_only = True
            elif w in _NP_STOPS or (w in _SUPERLATIVES and target_words):
                break
            elif w == "from" and self.superlative_word_only and target_words:
                break  # "the furthest chair from the tv"
            elif w not in _DETERMINERS:
                target_words.append(w)
            k += 1
        relations: list[RelationClause] = []
        while k < self.stop:
            joined = relations or self.superlative is not None
            after = k + 1 if self.words[k] in ("and", "also") and joined else k
            end = self.clause_at(after, relations)
            if end is None:
                return None
            k = end
        return target_words, relations

    def clause_at(self, k: int, relations: list[RelationClause]) -> int | None:
        """Parse one clause (relation, superlative or a superlative's anchor) at k into
        `relations` / self.superlative; where it ends, or None."""
        found = self.relation_at(k, False)
        if found is not None:
            if not found.anchored:
                relations.append(RelationClause(found.kind, []))
                return found.end
            first = self.noun_phrase(found.end)
            if first is None:
                return None
            if found.kind != "between":
                relations.append(RelationClause(found.kind, [] if first.asker else [first.text]))
                return first.end
            if self.word(first.end) != "and" or first.asker:
                return None
            second = self.noun_phrase(first.end + 1)
            if second is None or second.asker:
                return None
            relations.append(RelationClause("between", [first.text, second.text]))
            return second.end
        return self.superlative_at(k)

    def superlative_at(self, k: int) -> int | None:
        """[is] [the] superlative [one] [away | (to | from) anchor | anchor], or the anchor of
        a superlative said before the target ("the nearest chair to the window")."""
        if self.superlative_word_only and self.superlative and self.word(k) in ("to", "from"):
            self.superlative_word_only = False
            return self.superlative_anchor(k + 1, self.superlative.kind)
        if self.superlative is not None:
            return None
        j = k + (self.word(k) in _COPULAS)
        j += self.word(j) == "the"
        kind = _SUPERLATIVES.get(self.word(j))
        if kind is None:
            return None
        self.superlative = Superlative(kind)
        j += 1
        j += self.word(j) in ("one", "ones")
        if kind not in ("closest", "farthest"):
            return j
        if self.word(j) == "away":
            return j + 1
        if self.word(j) in ("to", "from"):
            return self.superlative_anchor(j + 1, kind)
        if self.anchor_starts(j, ""):
            return self.superlative_anchor(j, kind)
        return j

    def superlative_anchor(self, k: int, kind: str) -> int | None:
        phrase = self.noun_phrase(k)
        if phrase is None:
            return None
        self.superlative = Superlative(kind, [] if phrase.asker else [phrase.text])
        return phrase.end

    def relation_at(self, k: int, bare_verb: bool) -> _Found | None:
        """A lead-in and a relation phrase at k, with an anchor after it (or, for a phrase
        about the asker, none). Looks a bounded number of words ahead."""
        for start in reversed(self.lead_in_ends(k)):
            if start == k and bare_verb:  # "turn on the lamp"
                continue
            for phrase, kind, anchored in _RELATION_INDEX.get(self.word(start), ()):
                if not self.starts_with(start, phrase):
                    continue
                end = start + len(phrase)
                if anchored == self.anchor_starts(end, phrase[-1]):
                    return _Found(kind, end, anchored)
        return None

    def lead_in_ends(self, k: int) -> list[int]:
        """Where a relation phrase may start after the optional lead-in words at k, nearest
        first: [that | which | who] [I left ...] [is ...] [right ...] [sitting ...] [right ...]."""
        ends = [k]

        def extend(step: Callable[[int], int | None]) -> None:
            for p in list(ends):
                q = step(p)
                if q is not None and q not in ends:
                    ends.append(q)

        extend(lambda p: p + 1 if self.word(p) in _RELATIVE_PRONOUNS else None)
        extend(self.subject_clause_end)
        extend(lambda p: p + 1 if self.word(p) in _COPULAS else None)
        extend(lambda p: p + 1 if self.word(p) in _ADVERBS else None)
        extend(lambda p: p + 1 if self.word(p) in _POSTURES else None)
        extend(lambda p: p + 1 if self.word(p) in _ADVERBS else None)
        return sorted(ends)

    def subject_clause_end(self, k: int) -> int | None:
        """'I left', 'we have put', 'you just placed': a subject, auxiliaries, a placing verb."""
        if self.word(k) not in _SUBJECTS:
            return None
        j = k + 1
        for _ in range(2):
            j += self.word(j) in _AUXILIARIES
        return j + 1 if self.word(j) in _PLACING_VERBS else None

    def anchor_starts(self, k: int, preposition: str) -> bool:
        """Whether an anchor noun phrase begins at k (after `preposition`)."""
        j = self.after_determiners(k)
        w = self.word(j)
        if not w or (w in _NOT_AN_ANCHOR and w not in _ASKER):
            return False
        return not (j == k and w in _IDIOMS.get(preposition, ()))

    def after_determiners(self, k: int) -> int:
        """Past at most _MAX_DETERMINERS determiners at k ("all the"): bounded, so that
        looking for an anchor at every word stays linear."""
        j = k
        while j < k + _MAX_DETERMINERS and self.word(j) in _DETERMINERS:
            j += 1
        return j

    def noun_phrase(self, k: int) -> _Phrase | None:
        """The anchor noun phrase at k: words up to a function word, a relation or a
        superlative; None when there is none."""
        j = self.after_determiners(k)
        if self.word(j) in _ASKER:
            return _Phrase([], j + 1, asker=True)
        if not self.word(j) or self.word(j) in _NOT_AN_ANCHOR:
            return None
        words: list[str] = []
        while j < self.stop:
            w = self.words[j]
            if words and (w in _SUPERLATIVES or self.relation_at(j, False) is not None):
                break
            if w in _NP_STOPS:
                break
            if w not in _DETERMINERS:
                words.append(w)
            j += 1
        return _Phrase(words, j) if words else None


def question_phrases() -> dict[str, list[str]]:
    """The phrases this reader knows, by role: "scaffolds" (question words before the target:
    "where did i leave", "show me"), "relations" (with and without an anchor: "on top of",
    "to my left"), of which "anchored" take an anchor after them and "from_asker" do not,
    "superlatives", "determiners", "fillers" and "tails". A speech recogniser shapes its
    vocabulary with them, so that what it hears is what the reader reads; the page tells a
    relational question from a plain one with them."""
    anchored, from_asker = _joined(_RELATIONS), _joined(_RELATIONS_FROM_ASKER)
    return {
        "scaffolds": [" ".join(p) for p in _SCAFFOLDS],
        "relations": list(dict.fromkeys([*anchored, *from_asker])),
        "anchored": anchored,
        "from_asker": from_asker,
        "superlatives": list(_SUPERLATIVES),
        "determiners": sorted(_DETERMINERS),
        "fillers": [" ".join(p) for p in _FILLERS],
        "tails": [" ".join(p) for p in _TAILS],
    }


def _joined(table: dict[str, tuple[tuple[str, ...], ...]]) -> list[str]:
    """A relation table, phrase by phrase, each once."""
    return list(dict.fromkeys(" ".join(p) for phrases in table.values() for p in phrases))
