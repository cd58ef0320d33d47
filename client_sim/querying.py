"""Query-mode switching on the device: server query (SQ) or local query (LQ).

The paper's rule (knob `net_latency_switch_threshold_ms`): ask the server while the network
is fast, answer from the local map when it is slow or down. Concretely, a query goes to
the server (SQ, `GET /v1/sessions/{sid}/query`) when

- the RTT is known and at most `threshold_ms`, and
- the server answers within `server_timeout_s`;

otherwise it is answered locally (LQ): the text is embedded on the device and matched
against the local map. A failed or slow SQ falls back to LQ within the same call.

Where the RTT comes from: the streaming client's smoothed RTT (`DeviceClient.rtt_ms`, acks
and pings). `math.inf` from it means the link is known to be down, and LQ is used with no
network call. When it is unknown (None: nothing streamed or followed yet, or just after
reconnecting), one `GET /healthz` is timed and that round trip is the RTT for this query;
a probe that fails or takes longer than `server_timeout_s` means LQ.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from app.client import SessionApi
from app.mapping.relevance import is_match, rate_hits
from app.semantics import TextEncoder
from client_sim.local_map import LocalMap

SQ, LQ = "SQ", "LQ"


def planned_mode(rtt_ms: float | None, threshold_ms: float) -> str:
    """The mode ("SQ" or "LQ") the RTT alone picks ("?" if unknown); a failed SQ still
    ends in LQ."""
    if rtt_ms is None:
        return "?"
    return SQ if rtt_ms <= threshold_ms else LQ


@dataclass
class QueryAnswer:
    """One answered query."""

    text: str
    mode: str
    """Who answered: "SQ" (server query) or "LQ" (local query)."""
    results: list[dict]
    """Best first: {"id", "label", "score", "relevance", "bbox": [x0, y0, z0, x1, y1, z1],
    "centroid"}; relevance in [0, 1] as app.mapping.relevance rates it."""
    latency_ms: float
    """End to end for the mode that answered: the HTTP round trip of SQ, or embedding plus
    search of LQ."""
    reason: str
    """Why this mode, e.g. "RTT 12 ms <= 100 ms" or "SQ failed (ReadTimeout); fell back"."""
    total_ms: float = 0.0
    """The whole call, including an RTT probe or a failed SQ before the fallback."""
    rtt_ms: float | None = field(default=None)
    """The RTT the decision used (None: unknown, inf: link down)."""

    @property
    def match(self) -> bool:
        """Whether a hit is a confident match (False: "no confident match", hits listed)."""
        return is_match([hit["relevance"] for hit in self.results])


class QueryRouter:
    """Answers text queries by SQ or LQ (module docstring); one instance per device.

    local_map / encoder: the device's local map and the session's text encoder (same model
    as the server). rtt_ms: the streaming client's smoothed RTT in ms (None unknown, inf
    down). server_timeout_s: longest wait for the server (probe or SQ) before LQ.
    """

    def __init__(
        self,
        server_url: str,
        session_id: str,
        token: str | None,
        local_map: LocalMap,
        encoder: TextEncoder,
        threshold_ms: float = 100.0,
        rtt_ms: Callable[[], float | None] = lambda: None,
        server_timeout_s: float = 1.0,
    ):
        self.api = SessionApi(server_url, session_id, token, timeout_s=server_timeout_s)
        self.local_map = local_map
        self.encoder = encoder
        self.threshold_ms = float(threshold_ms)
        self.rtt_ms = rtt_ms
        self.server_timeout_s = float(server_timeout_s)

    def planned_mode(self) -> str:
        """The mode a query would take now from the streaming RTT alone ("?" if unknown)."""
        return planned_mode(self.rtt_ms(), self.threshold_ms)

    async def query(self, text: str, k: int = 5) -> QueryAnswer:
        """The k best matches for `text`, from the server or the local map."""
        start_s = time.perf_counter()
        rtt = self.rtt_ms()
        if rtt is None:
            rtt, probe_problem = await self._probe_rtt_ms()
            source = "probed RTT"
        else:
            probe_problem, source = None, "RTT"
        if rtt is None:
            reason = f"server unreachable ({probe_problem})"
        elif math.isinf(rtt):
            reason = "link down (the streaming client is reconnecting)"
        elif rtt > self.threshold_ms:
            reason = f"{source} {rtt:.0f} ms > {self.threshold_ms:g} ms"
        else:
            sq_start_s = time.perf_counter()
            try:
                results = await self.api.query(text, k)
            except Exception as exc:  # any failure of the server path means: answer locally
                reason = f"SQ failed ({type(exc).__name__}: {exc}); fell back to LQ"
            else:
                now_s = time.perf_counter()
                return QueryAnswer(
                    text=text,
                    mode=SQ,
                    results=results,
                    latency_ms=(now_s - sq_start_s) * 1e3,
                    reason=f"{source} {rtt:.0f} ms <= {self.threshold_ms:g} ms",
                    total_ms=(now_s - start_s) * 1e3,
                    rtt_ms=rtt,
                )
        return await self._local_query(text, k, reason, start_s, rtt)

    async def aclose(self) -> None:
        await self.api.aclose()

    async def __aenter__(self) -> QueryRouter:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    # --- the two modes --------------------------------------------------------------------

    async def _probe_rtt_ms(self) -> tuple[float | None, str | None]:
        """(RTT of one GET /healthz in ms, None) or (None, what went wrong)."""
        start_s = time.perf_counter()
        try:
            await self.api.health()
        except Exception as exc:
            return None, f"health probe: {type(exc).__name__}: {exc}"
        return (time.perf_counter() - start_s) * 1e3, None

    async def _local_query(
        self, text: str, k: int, reason: str, start_s: float, rtt: float | None
    ) -> QueryAnswer:
        lq_start_s = time.perf_counter()
        # Embedding is the slow part (~15 ms): off the loop, so deltas and acks keep flowing.
        # The search runs on the loop, the only place the local map is touched.
        embedding = await asyncio.to_thread(self.encoder.encode_query, text)
        hits = self.local_map.query_embedding(embedding, k)
        labels = [hit.label for hit in hits]
        # Rated as the server rates SQ hits; off the loop (the first one embeds the vocabulary).
        rating = await asyncio.to_thread(rate_hits, self.encoder, embedding, labels)
        now_s = time.perf_counter()
        return QueryAnswer(
            text=text,
            mode=LQ,
            results=[
                {
                    "id": hit.id,
                    "label": hit.label,
                    "score": hit.score,
                    "relevance": relevance,
                    "bbox": hit.bbox,
                    "centroid": hit.centroid,
                }
                for hit, relevance in zip(hits, rating.relevance, strict=True)
            ],
            latency_ms=(now_s - lq_start_s) * 1e3,
            reason=reason,
            total_ms=(now_s - start_s) * 1e3,
            rtt_ms=rtt,
        )
