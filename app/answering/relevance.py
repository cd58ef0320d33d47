"""How well a query's hits answer it: a calibrated relevance in [0, 1] and a match verdict.

Raw cosine scores do not say whether anything matches: "xyzzy plugh" scores 0.33 against a
coffee maker, "the milk cold" 0.35 against the refrigerator it means. What does tell them
apart is how the query scores against a hit's *label* compared with every other label it
could have meant: a fixed background vocabulary (the `models` backend's indoor vocabulary and
a few everyday things people lose). A label is scored by the best cosine over its *texts*:
the label, its synonyms, what it is and what kind of thing it is, from WordNet
(app.answering.label_knowledge), so "my rucksack" finds a backpack and "where can I sit down
to watch a movie" a sofa; the background labels are scored over theirs the same way
(`background_texts`, shipped in this package). Three numbers, in standard deviations of the
query's scores over the background, so they do not depend on the encoder's cosine scale:

- `z`: how far the hit's label (over its texts) stands out from the background. A real
  query singles out a few labels; a nonsense query scores them all alike.
- `gap`: how far the hit's label is behind the best background label not *alike* it (label
  names at cosine >= alike_cosine): "keys" on a map without keys finds a keyboard, but the
  label "keys" scores far above it; "the bedside table" names a nightstand, and the
  background's own "bedside table" is alike it, so it does not count against it.
- `z_name`: how far the label's name alone stands out (a name the query says outright).

A hit's relevance is a ramp of a calibrated linear score of the three, w . (z, gap, z_name)
+ bias, crossing CONFIDENT where the score is 0: `relevance >= 0.5` and "confident match"
are one test. The weights, bias and alike_cosine are fitted per text tower by `python -m
bench.relevance --calibrate` on the synthetic categories' names and paraphrases (never on the
held-out wordings of bench/data/wordings/) and shipped in `match_rules.json`, keyed by the
session's `embedding.model`, with the tower's embeddings of the background's texts
(`background_embeddings/`, so no end embeds them at start). Server (SQ) and device (LQ)
both rate their hits here with the same label texts (the server serves them with the
session's labels), so both answer alike.
"""

from __future__ import annotations

import functools
import io
import json
import logging
import re
import threading
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from typing import NamedTuple

import numpy as np

from app.semantics import TextEncoder
from app.semantics.static import is_static_model_id

log = logging.getLogger(__name__)

RAMP = 2.0
"""Half-width of the relevance ramp in units of the linear score: relevance goes 0 -> 1 over
score -RAMP .. +RAMP (0 at the limit)."""
CONFIDENT = 0.5
"""Relevance from which a hit is a confident match."""

EVERYDAY_LABELS = (
    "keys", "wallet", "phone", "glasses", "sunglasses", "watch", "charger", "earphones",
    "passport", "ring", "remote", "medicine", "shoes", "cat", "dog", "person",
)  # fmt: skip
"""Things people ask for that the indoor vocabulary lacks (or has only in the singular)."""


def background_vocabulary() -> list[str]:
    """The labels a query is weighed against: the `models` backend's vocabulary + EVERYDAY."""
    text = resources.files("app.perception.models").joinpath("vocabulary.txt").read_text("utf-8")
    tags = [line.split("#", 1)[0].strip() for line in text.splitlines()]
    return list(dict.fromkeys([t for t in tags if t] + list(EVERYDAY_LABELS)))


@dataclass(frozen=True)
class MatchRule:
    """A text tower's match rule (`python -m bench.relevance --calibrate` fits it):
    score = w_z z + w_gap gap + w_name z_name + bias, a confident match from 0."""

    w_z: float = 0.9
    """Weight of the label's standing-out over its texts."""
    w_gap: float = -0.6
    """Weight of how far the label trails the best background label not alike it."""
    w_name: float = 0.6
    """Weight of the label name's own standing-out."""
    bias: float = -5.0
    """The score of a label that stands out by nothing."""
    alike_cosine: float = 0.7
    """Cosine of two label names from which they are alike (the gap ignores alike labels)."""

    def score(self, z: float, gap: float, z_name: float) -> float:
        return self.w_z * z + self.w_gap * gap + self.w_name * z_name + self.bias


RULES_RESOURCE = "match_rules.json"
"""The calibration record in this package: {"towers": {embedding.model: {w_z, w_gap, w_name,
bias, alike_cosine, ...}}} (extra keys say what it was calibrated on)."""
BACKGROUND_TEXTS_RESOURCE = "background_texts.json"
"""The background vocabulary's label texts in this package ({label: [text, ...]}), read from
WordNet when calibrating, so every end holds the same without WordNet."""


STATIC_RULE_KEY = "static"
"""The record of static towers distilled from MiniLM: a distillation elsewhere (other float
rounding, another hash) takes the rule calibrated here."""


def rule_for(model_id: str) -> MatchRule:
    """The calibrated rule of a text tower by its `embedding.model` name (a static tower
    without its own: STATIC_RULE_KEY's); for a tower without a record, the first record's rule (its inputs are in standard deviations, so it carries
    over roughly) and a warning, or MatchRule() when there is none."""
    towers = _read_resource(RULES_RESOURCE).get("towers", {})
    record = towers.get(model_id)
    if record is None and is_static_model_id(model_id):
        record = towers.get(STATIC_RULE_KEY)  # calibrated on another distillation of it
    if record is None:
        log.warning("no match calibration for text tower %r: another tower's rule", model_id)
        record = next(iter(towers.values()), {})
    fields = MatchRule.__dataclass_fields__
    return MatchRule(**{k: float(v) for k, v in record.items() if k in fields})


@functools.cache
def background_texts() -> dict[str, tuple[str, ...]]:
    """The background vocabulary's label texts shipped in this package (empty when absent:
    each label its own text). Every end holds them: a background label's texts need not be
    served."""
    return {k: tuple(v) for k, v in _read_resource(BACKGROUND_TEXTS_RESOURCE).items()}


BACKGROUND_EMBEDDINGS_DIR = "background_embeddings"
"""Folder of this package with each text tower's embeddings of the background's texts
(`background_embeddings_name`), written by `python -m bench.relevance --calibrate` so no end
embeds them at start."""


def background_text_list() -> list[str]:
    """The background's texts in the order their embeddings are shipped: each label's texts
    (`texts_of`, the label first), label by label, each text once."""
    shipped = background_texts()
    return list(
        dict.fromkeys(t for label in background_vocabulary() for t in texts_of(label, shipped))
    )


def background_embeddings_name(model_id: str) -> str:
    """The file of a tower's shipped background embeddings (its model id, made a file name)."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", model_id) + ".npz"


def shipped_rows(model_id: str) -> tuple[list[str], np.ndarray] | None:
    """(texts, rows [n, dim] as stored: float16) of the tower's shipped background
    embeddings, or None when this package ships none for it."""
    resource = resources.files("app.answering").joinpath(
        BACKGROUND_EMBEDDINGS_DIR, background_embeddings_name(model_id)
    )
    if not resource.is_file():
        return None
    with np.load(io.BytesIO(resource.read_bytes()), allow_pickle=False) as shipped:
        return shipped["texts"].tolist(), shipped["embeddings"]


def shipped_embeddings(
    model_id: str, texts: Sequence[str], dim: int
) -> dict[str, np.ndarray] | None:
    """{text: float32 [dim]} of the tower's shipped embeddings when they are of exactly these
    texts at this dimension; None (and a warning when a file is there but stale) otherwise:
    the rater then embeds them itself."""
    shipped = shipped_rows(model_id)
    if shipped is None:
        return None
    shipped_texts, rows = shipped
    if shipped_texts != list(texts) or rows.shape != (len(texts), dim):
        log.warning("shipped background embeddings of %r are stale: embedding them", model_id)
        return None
    return dict(zip(shipped_texts, rows.astype(np.float32), strict=True))


def _read_resource(name: str) -> dict:
    resource = resources.files("app.answering").joinpath(name)
    if not resource.is_file():
        return {}
    return json.loads(resource.read_text("utf-8"))


@dataclass(frozen=True)
class Rating:
    """The hits of one query, rated."""

    relevance: list[float]
    """Per hit, in [0, 1]; >= CONFIDENT is a confident match."""
    match: bool
    """Whether any hit is a confident match."""


def is_match(relevances: Sequence[float]) -> bool:
    """Whether hits of these relevances answer the query (one of them is confident)."""
    return any(r >= CONFIDENT for r in relevances)


LabelTexts = Mapping[str, Sequence[str]]
"""label -> its texts (app.answering.label_knowledge); a label without an entry is its own
only text."""


class Standing(NamedTuple):
    """How a query rates one label against the background (module docstring)."""

    z: float
    gap: float
    z_name: float

    def relevance(self, rule: MatchRule) -> float:
        """The label's relevance under a rule (`relevance_of` its score)."""
        return relevance_of(rule.score(self.z, self.gap, self.z_name))


class QueryRater:
    """Rates hits by their labels' texts against the background's, embedded once by
    `encoder`, with the tower's rule (`rule_for(encoder.model_id)`)."""

    def __init__(
        self,
        encoder: TextEncoder,
        vocabulary: Sequence[str] | None = None,
        vocabulary_texts: LabelTexts | None = None,
        rule: MatchRule | None = None,
    ):
        """vocabulary: the background labels (None: `background_vocabulary()`, with the
        shipped `background_texts()` unless vocabulary_texts is given)."""
        self.encoder = encoder
        self.vocabulary = list(vocabulary) if vocabulary is not None else background_vocabulary()
        if vocabulary_texts is None:
            vocabulary_texts = background_texts() if vocabulary is None else {}
        self.rule = rule if rule is not None else rule_for(encoder.model_id)
        self._vocabulary_texts = vocabulary_texts
        texts = [texts_of(label, vocabulary_texts) for label in self.vocabulary]
        self._text_owner = np.repeat(np.arange(len(texts)), [len(t) for t in texts])  # [T]
        self._texts = [t for ts in texts for t in ts]  # [T]
        shipped = None
        if vocabulary is None and vocabulary_texts is background_texts():
            shipped = shipped_embeddings(encoder.model_id, background_text_list(), encoder.dim)
        self._shipped = shipped or {}
        self._text_embeddings = self._embed([t for ts in texts for t in ts])  # [T, dim]
        self._name_embeddings = self._embed(self.vocabulary)  # [V, dim] unit rows

    def rate(
        self,
        query_embedding: np.ndarray,
        labels: Sequence[str],
        label_texts: LabelTexts | None = None,
    ) -> Rating:
        """query_embedding: float [dim] of the query text; labels: the hits' labels, best
        first; label_texts: their texts (None, or a label missing: the background's texts of
        a background label, else the label alone).
        Relevance per hit and whether any matches."""
        standings = self.standing(query_embedding, labels, label_texts)
        if standings is None:  # no labels, or every label alike: nothing stands out
            return Rating([0.0] * len(labels), False)
        relevance = [s.relevance(self.rule) for s in standings]
        return Rating(relevance, is_match(relevance))

    def standing(
        self,
        query_embedding: np.ndarray,
        labels: Sequence[str],
        label_texts: LabelTexts | None = None,
    ) -> list[Standing] | None:
        """Per label, its `Standing` for the query; None for no labels or a query that
        scores every background label alike."""
        if not labels:
            return None
        query = np.asarray(query_embedding, np.float32)
        scores = np.full(len(self.vocabulary), -np.inf)  # [V] best over each label's texts
        np.maximum.at(scores, self._text_owner, (self._text_embeddings @ query).astype(np.float64))
        spread = float(scores.std())
        if spread < 1e-6:
            return None
        mean = float(scores.mean())
        distinct = list(dict.fromkeys(labels))
        names = self._embed(distinct)  # [L, dim], from the encoder's cache
        alike = names @ self._name_embeddings.T >= self.rule.alike_cosine  # [L, V]
        name_scores = (names @ query).astype(np.float64)
        by_label: dict[str, Standing] = {}
        for i, label in enumerate(distinct):
            given = label_texts if label_texts is not None else {}  # an empty Mapping is falsy
            texts = texts_of(label, given, self._vocabulary_texts)
            score = float(np.max(self._embed(texts) @ query))
            rivals = scores[~alike[i]]
            best = float(rivals.max()) if len(rivals) else score
            by_label[label] = Standing(
                (score - mean) / spread,
                (best - score) / spread,
                (name_scores[i] - mean) / spread,
            )
        return [by_label[label] for label in labels]

    def rival(self, query_embedding: np.ndarray, label: str) -> tuple[str, str] | None:
        """The background label the `gap` of `label` is measured against (the best the query
        scores over its texts, of those not alike `label`) and the text of it the query
        scores best; None when every background label is alike `label`. For reading
        failures (bench.relevance --failures): which thing the query seems to name instead."""
        query = np.asarray(query_embedding, np.float32)
        alike = self._embed([label]) @ self._name_embeddings.T >= self.rule.alike_cosine  # [1, V]
        scores = (self._text_embeddings @ query).astype(np.float64)  # [T]
        scores[alike[0][self._text_owner]] = -np.inf
        if not np.isfinite(scores).any():
            return None
        best = int(np.argmax(scores))
        return self.vocabulary[self._text_owner[best]], self._texts[best]

    def _embed(self, texts: Sequence[str]) -> np.ndarray:
        """float32 [n, dim] unit rows: the shipped rows of background texts, the encoder's for
        the others (so a background label's texts weigh the same as a hit and as a rival)."""
        missing = [t for t in texts if t not in self._shipped]
        encoded = dict(zip(missing, self.encoder.encode(missing), strict=True)) if missing else {}
        if not texts:
            return np.zeros((0, self.encoder.dim), np.float32)
        return np.stack([self._shipped[t] if t in self._shipped else encoded[t] for t in texts])


def texts_of(label: str, label_texts: LabelTexts, fallback: LabelTexts | None = None) -> list[str]:
    """A label's texts from `label_texts` (else from `fallback`), the label itself first."""
    given = label_texts.get(label)
    if given is None and fallback is not None:
        given = fallback.get(label)
    return [label, *(t for t in given or () if t != label)]


def relevance_of(score: float) -> float:
    """A label's relevance in [0, 1] from its rule score (`MatchRule.score`): a ramp crossing
    CONFIDENT at 0."""
    return round(float(np.clip(CONFIDENT + score / (2 * RAMP), 0.0, 1.0)), 5)


_raters: weakref.WeakKeyDictionary[TextEncoder, QueryRater] = weakref.WeakKeyDictionary()
_raters_lock = threading.Lock()


def rate_hits(
    encoder: TextEncoder,
    query_embedding: np.ndarray,
    labels: Sequence[str],
    label_texts: LabelTexts | None = None,
) -> Rating:
    """`QueryRater.rate` with one rater per encoder (the background's texts are embedded on first use,
    a few seconds with MiniLM on 2 cores; `rater_for(encoder)` ahead of time avoids the wait)."""
    return rater_for(encoder).rate(query_embedding, labels, label_texts)


def rater_for(encoder: TextEncoder) -> QueryRater:
    """The encoder's rater, made (and its vocabulary embedded) on first use."""
    with _raters_lock:
        rater = _raters.get(encoder)
    if rater is None:
        rater = QueryRater(encoder)  # outside the lock: embedding the vocabulary is slow
        with _raters_lock:
            rater = _raters.setdefault(encoder, rater)
    return rater
