"""What a page needs to answer a plain question offline as the server does:
`GET /v1/answering/{model_id}`, data only (no user data, no session: no credential needed).

- `rule`: the text tower's match rule (app.answering.relevance.rule_for: its calibration, or
  the rule the server itself falls back to for a tower without one);
- `background`: the background labels in `background_vocabulary()` order, each with its
  texts as `texts_of` gives them with the shipped `background_texts()` (the label first);
- `background_embeddings`: the tower's shipped embeddings of the background's texts when the
  server's rater reads them (`texts` in `background_text_list()` order, `dtype` float16 or
  float32, `dim`, the little-endian rows base64), else null: the page then embeds the texts
  with the tower itself, as the server does;
- `relational`: the question reader's relation phrases, those that take an anchor after them
  ("on", "next to") and those about the asker ("on my left", "nearby"), and its superlative
  words (app.relations.grammar). The reader reads a relation only at one of its phrases, an
  anchored one only with a word after it (its anchor), and a superlative only at one of its
  words; so a question in which none of them stands so, word for word, is plain to the
  reader, and a page without the reader can tell the questions it may answer alone from
  those that need the server.
"""

from __future__ import annotations

import base64
import functools

import numpy as np
from fastapi import APIRouter, Response
from fastapi import Path as PathParam
from pydantic import BaseModel

from app.answering.relevance import (
    background_text_list,
    background_texts,
    background_vocabulary,
    rule_for,
    shipped_rows,
    texts_of,
)
from app.protocol.rest import ErrorBody, UnprocessableBody
from app.relations import grammar

MAX_MODEL_ID_CHARS = 128
"""Longest model id asked for (a tower's `embedding.model`)."""

router = APIRouter(prefix="/v1")


class Rule(BaseModel):
    """app.answering.relevance.MatchRule: score = w_z z + w_gap gap + w_name z_name + bias."""

    w_z: float
    w_gap: float
    w_name: float
    bias: float
    alike_cosine: float


class ShippedRows(BaseModel):
    texts: list[str]
    """The background's texts, in `background_text_list()` order."""
    dtype: str
    """float16 or float32."""
    dim: int
    rows: str
    """The rows [len(texts), dim], little-endian, base64."""


class Relational(BaseModel):
    anchored: list[str]
    """The reader's relation phrases that take an anchor ("on", "next to", "in front of")."""
    from_asker: list[str]
    """Its phrases about the asker, with no anchor after them ("on my left", "nearby")."""
    superlatives: list[str]
    """Its superlative words ("closest", "biggest", ...)."""


class AnsweringData(BaseModel):
    model: str
    rule: Rule
    background: list[tuple[str, list[str]]]
    """[label, [text, ...]] per background label, the label its first text."""
    background_embeddings: ShippedRows | None
    relational: Relational


@router.get(
    "/answering/{model_id:path}",
    summary="A text tower's match rule and background, to rate answers offline (public)",
    response_model=AnsweringData,
    openapi_extra={"security": []},
    responses={
        404: {
            "model": ErrorBody,
            "description": "no such path: a model_id with a line break (no tower has one)",
        },
        422: {"model": UnprocessableBody, "description": "model_id empty or over 128 characters"},
    },
)
def answering_data(
    response: Response,
    model_id: str = PathParam(
        ...,
        min_length=1,
        max_length=MAX_MODEL_ID_CHARS,
        description="the text tower's `embedding.model`, as a session record names it",
    ),
) -> dict:
    response.headers["Cache-Control"] = "no-cache"
    return _answering_data(model_id)


@functools.lru_cache(maxsize=8)
def _answering_data(model_id: str) -> dict:
    rule = rule_for(model_id)
    shipped = background_texts()
    phrases = grammar.question_phrases()
    return {
        "model": model_id,
        "rule": {
            "w_z": rule.w_z,
            "w_gap": rule.w_gap,
            "w_name": rule.w_name,
            "bias": rule.bias,
            "alike_cosine": rule.alike_cosine,
        },
        "background": [[label, texts_of(label, shipped)] for label in background_vocabulary()],
        "background_embeddings": _shipped_rows(model_id),
        "relational": {
            "anchored": phrases["anchored"],
            "from_asker": phrases["from_asker"],
            "superlatives": phrases["superlatives"],
        },
    }


def _shipped_rows(model_id: str) -> dict | None:
    """The tower's shipped background embeddings as the rater reads them (of exactly
    `background_text_list()`), else None."""
    shipped = shipped_rows(model_id)
    if shipped is None:
        return None
    texts, rows = shipped
    if texts != background_text_list() or rows.ndim != 2 or len(rows) != len(texts):
        return None  # stale: the rater embeds the texts itself, and so does the page
    dtype = "float16" if rows.dtype == np.float16 else "float32"
    data = np.ascontiguousarray(rows, "<f2" if dtype == "float16" else "<f4").tobytes()
    return {
        "texts": texts,
        "dtype": dtype,
        "dim": int(rows.shape[1]),
        "rows": base64.b64encode(data).decode("ascii"),
    }
