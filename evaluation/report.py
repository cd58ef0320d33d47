"""What a scenario's run gives back: its figures and the table printed for them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Report:
    """One scenario's result.

    `document` is what `semanticxr eval --json` writes (plain JSON types; its fields are
    described in docs/evaluation.md "Machine-readable outputs"); `table()` is the text the
    command prints. The table is formatted when asked for, so a caller can keep the
    document first whatever formatting does."""

    scenario: str
    """walk | relations | revisit."""
    document: dict
    formatter: Callable[[dict], str]
    """The scenario's table of a document."""

    def table(self) -> str:
        return self.formatter(self.document)
