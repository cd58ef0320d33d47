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

Questions about how things stand ("the mug on the desk", "the lamp closest to me") are
answered alike both ways (LQ = SQ, docs/evaluation.md "Relations"): SQ sends the device's
position (`from`, the local map's user position, which the streaming client sets to its newest
pose), and LQ asks the local map (`LocalMap.relational_query`: the server's own
`app.answering.ask` on the same points) from that position, along the session's up axis (the
session record's `up`, learnt while online; Z until it says). Each relational hit carries
`relation` {"kind", "anchors": [{"id", "label"}], "degree"} and the answer's `match` is the
relational one (best score >= app.answering.things.MATCH_MIN_SCORE) both ways.

LQ needs the session's own text encoder: the model and dimension the session announces in
`embedding` (MiniLM, packaged; a static tower, downloaded from the server by its hash and
cached; or CLIP's text tower on the `models` backend, read from `--models-dir`;
`session_encoder_loader`). An encoder that differs is refused
(`EncoderMismatchError`): its scores against the map would be noise. Without one, local
queries are off: every query goes to the server while it answers, whatever the RTT, and a
query it cannot answer gets mode "none" and no results.
"""

from __future__ import annotations

import asyncio
import hashlib
import math
import os
import ssl
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from app.answering.ask import relational_reading
from app.answering.phrases import phrases_of
from app.answering.relevance import (
    LabelTexts,
    background_texts,
    is_match,
    rate_hits,
    rater_for,
    texts_of,
)
from app.answering.things import is_match as is_relational_match
from app.client import SessionApi
from app.client.rest import ApiError, fetch_text_tower
from app.mapping.places import up_vector
from app.relations.bodies import Z_UP
from app.relations.grammar import Reading
from app.semantics import DEFAULT_MODEL_ID, TextEncoder
from app.semantics.static import is_static_model_id, static_model_id
from client_sim.local_map import LocalMap

SQ, LQ, NONE = "SQ", "LQ", "none"
PRESENT = "present"
"""A hit's `state` (living map): the object is in the map now (not removed)."""
UP_REFRESH_S = 30.0
"""While the session's up axis is not settled (neither set at creation nor inferred from
the poses yet), the router reads the session record again after an SQ at most this often."""
SETTLED_UP = ("set", "inferred")
"""`up_source` values after which a session's up axis no longer changes."""


class LocalQueriesOff(Exception):
    """This device has no text encoder for the session: it answers through the server only.
    The message says why and what would turn local queries on."""


class EncoderMismatchError(ValueError):
    """The device's text encoder is not the one the session announces: LQ is refused."""


def check_encoder(encoder: TextEncoder, embedding: dict) -> None:
    """EncoderMismatchError unless `encoder` is the session's announced model and dimension."""
    if (encoder.model_id, encoder.dim) != (embedding["model"], embedding["dim"]):
        raise EncoderMismatchError(
            f"refusing local queries: the session embeds with {embedding['model']} "
            f"({embedding['dim']}-d) and this device's encoder is {encoder.model_id} "
            f"({encoder.dim}-d); scores across two models' spaces mean nothing"
        )


def default_tower_cache() -> Path:
    """Where the device keeps the static text towers it downloaded, by hash:
    $XDG_CACHE_HOME/semanticxr/towers, by default ~/.cache/semanticxr/towers."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "semanticxr" / "towers"


def session_encoder_loader(
    embedding: dict,
    models_dir: str | None,
    *,
    server_url: str | None = None,
    ssl_context: ssl.SSLContext | None = None,
    tower_cache: str | os.PathLike[str] | None = None,
) -> Callable[[], TextEncoder]:
    """A function that loads the session's text encoder (seconds: run it off the loop) and
    checks it against the announcement. Quick checks first, here:

    - the default MiniLM: packaged, always available;
    - a static tower ("static-<sha16>" with `embedding.sha256`): from `tower_cache` (default
      `default_tower_cache()`), else downloaded from `server_url` by its hash and cached
      (`static_tower_loader`); LocalQueriesOff with neither;
    - another model (CLIP's text tower on the `models` backend): from `models_dir`, found as
      the server finds it (the folder whose model id is the announced one); LocalQueriesOff
      without `models_dir` or when it holds no text tower, EncoderMismatchError when it holds
      a different one.
    """
    model = embedding["model"]
    if is_static_model_id(model):
        return static_tower_loader(embedding, server_url, ssl_context, tower_cache)
    if model == DEFAULT_MODEL_ID:

        def load_default() -> TextEncoder:
            from app.semantics import get_text_encoder

            encoder = get_text_encoder()
            check_encoder(encoder, embedding)
            return encoder

        return load_default
    if models_dir is None:
        raise LocalQueriesOff(
            f"the session embeds with {model} ({embedding['dim']}-d); give --models-dir DIR "
            f"(the folder the server's --models-dir holds) to answer queries on the device"
        )
    from app.perception.models.weights import text_towers_in

    towers = text_towers_in(models_dir)
    if not towers:
        raise LocalQueriesOff(
            f"the session embeds with {model} ({embedding['dim']}-d) and --models-dir "
            f"{models_dir} holds no text tower (no CLIP model folder)"
        )
    matching = [t for t in towers if t.model_id == model]
    if not matching:
        held = ", ".join(f"{t.model_id} in {t.source}" for t in towers)
        raise EncoderMismatchError(
            f"refusing local queries: the session embeds with {model} ({embedding['dim']}-d) "
            f"and --models-dir {models_dir} holds {held}"
        )
    tower = matching[0]

    def load_tower() -> TextEncoder:
        from app.perception.models.embedder import load_text_encoder

        encoder = load_text_encoder(tower.source, tower.local_only, tower.model_id)
        check_encoder(encoder, embedding)
        return encoder

    return load_tower


def static_tower_loader(
    embedding: dict,
    server_url: str | None,
    ssl_context: ssl.SSLContext | None = None,
    tower_cache: str | os.PathLike[str] | None = None,
) -> Callable[[], TextEncoder]:
    """`session_encoder_loader` for a static tower: a function that reads the tower of the
    announced hash from the cache, or downloads it from the server (`GET
    /v1/text-towers/{sha256}`, at most MAX_TOWER_BYTES) and caches it, then checks that the
    bytes hash to `embedding.sha256` and that the tower is the announced model and dimension
    (EncoderMismatchError otherwise; ConnectionError when the download fails). Raises at once
    EncoderMismatchError when the announcement's hash does not name its model, and
    LocalQueriesOff when the tower is neither cached nor downloadable."""
    model, sha256 = embedding["model"], embedding.get("sha256")
    if not isinstance(sha256, str) or not _is_sha256(sha256) or static_model_id(sha256) != model:
        raise EncoderMismatchError(
            f"refusing local queries: the session embeds with the static tower {model}, but "
            f"announces its sha256 as {sha256!r}, which does not name it (64 lowercase hex "
            f"digits starting with the model id's)"
        )
    cache = Path(tower_cache) if tower_cache is not None else default_tower_cache()
    cached = cache / f"{sha256}.tower"
    if server_url is None and not cached.is_file():
        raise LocalQueriesOff(
            f"the session embeds with the static tower {model}, which is not in {cache}, and "
            f"no server to download it from was given"
        )

    def load_static() -> TextEncoder:
        from app.answering.towers import map_static_encoder
        from app.semantics.static import StaticTower, TowerError

        data = _read_cached_tower(cached, sha256)
        if data is None:
            assert server_url is not None  # checked above (a bad cached copy: downloaded again)
            try:
                data = fetch_text_tower(server_url, sha256, ssl_context=ssl_context)
            except ApiError as exc:
                raise ConnectionError(f"cannot download the session's text tower: {exc}") from None
            got = hashlib.sha256(data).hexdigest()
            if got != sha256:
                raise EncoderMismatchError(
                    f"refusing local queries: the server sent a text tower whose sha256 is "
                    f"{got}, not the {sha256} the session embeds with"
                )
        try:
            tower = StaticTower.from_bytes(data)
        except TowerError as exc:
            raise EncoderMismatchError(
                f"refusing local queries: the text tower {sha256} is not a static tower: {exc}"
            ) from None
        encoder = map_static_encoder(tower)  # labels as the server embeds them
        check_encoder(encoder, embedding)
        _write_cached_tower(cached, data)
        return encoder

    return load_static


def _is_sha256(text: str) -> bool:
    return len(text) == 64 and all(c in "0123456789abcdef" for c in text)


def _read_cached_tower(path: Path, sha256: str) -> bytes | None:
    """The cached tower file of that hash; None when absent, unreadable or not of that hash
    (a damaged copy is removed: it is downloaded again)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if hashlib.sha256(data).hexdigest() != sha256:
        path.unlink(missing_ok=True)
        return None
    return data


def _write_cached_tower(path: Path, data: bytes) -> None:
    """Keep a checked tower in the cache (atomically: a reader never sees half a file); a
    cache that cannot be written costs only a download next time."""
    if path.is_file():
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_name(f"{path.name}.{os.getpid()}.part")
        partial.write_bytes(data)
        partial.replace(path)
    except OSError:
        pass


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
    """Who answered: "SQ" (server query), "LQ" (local query), or "none" (local queries off
    and the server did not answer)."""
    results: list[dict]
    """Best first: {"id", "label", "score", "relevance", "bbox": [x0, y0, z0, x1, y1, z1],
    "centroid", "last_seen_t", "state", "relation"}; relevance in [0, 1] as
    app.answering.relevance rates it (of the target phrase, for a relational question);
    last_seen_t in device-clock seconds as the server holds it (the same by SQ and LQ; None
    from a server that does not send it); state "present" (the local map holds only present
    objects, and SQ does not ask for removed ones); relation {"kind", "anchors": [{"id",
    "label"}], "degree"} for a question about how things stand, else None."""
    latency_ms: float
    """End to end for the mode that answered: the HTTP round trip of SQ, or embedding plus
    search of LQ."""
    reason: str
    """Why this mode, e.g. "RTT 12 ms <= 100 ms" or "SQ failed (ReadTimeout); fell back"."""
    total_ms: float = 0.0
    """The whole call, including an RTT probe or a failed SQ before the fallback."""
    rtt_ms: float | None = field(default=None)
    """The RTT the decision used (None: unknown, inf: link down)."""
    verdict: bool | None = None
    """The answer's own `match` where it has one: the server's (SQ), or a relational LQ's
    (its best score >= app.answering.things.MATCH_MIN_SCORE); None: from the hits' relevance."""
    transcript: str | None = None
    """A spoken question (`QueryRouter.ask_aloud`): what the server heard; None for a typed
    one."""
    confidence: float | None = None
    """A spoken question: the recogniser's confidence in the transcript, where it gives one."""
    asr_ms: float | None = None
    """A spoken question: the server's time recognising it (within `latency_ms`)."""
    ranked_by: str | None = None
    """The `embedding.model` of the text tower that ranked the hits: the server's answer's
    (SQ; MiniLM when it re-ranked a static session's), the device's own (LQ); None: unknown."""

    @property
    def match(self) -> bool:
        """Whether the answer is a confident match (False: "no confident match", hits
        listed): a relational answer's best hit stands in the relation; a plain one's hit
        is confidently what was asked for."""
        if self.verdict is not None:
            return self.verdict
        return is_match([hit["relevance"] for hit in self.results])


class QueryRouter:
    """Answers text queries by SQ or LQ (module docstring); one instance per device.

    local_map / encoder: the device's local map and the session's text encoder (same model
    as the server), or encoder None: local queries off (`local_off_reason` says why), every
    query to the server. embedding: the session's announcement ({"model", "dim"}); when
    given, an encoder that differs is refused (EncoderMismatchError). rtt_ms: the streaming
    client's smoothed RTT in ms (None unknown, inf down). server_timeout_s: longest wait for
    the server (probe or SQ) before LQ. up: the session's up axis ("+z", "+y", ...) if the
    caller knows it (the session record's `up`); otherwise it is read from the record after
    an SQ, and Z until then. ssl_context: whom an https:// server must prove to be (default:
    the system's CAs).
    """

    def __init__(
        self,
        server_url: str,
        session_id: str,
        token: str | None,
        local_map: LocalMap,
        encoder: TextEncoder | None,
        threshold_ms: float = 100.0,
        rtt_ms: Callable[[], float | None] = lambda: None,
        server_timeout_s: float = 1.0,
        embedding: dict | None = None,
        local_off_reason: str = "no text encoder on this device",
        up: str | None = None,
        ssl_context: ssl.SSLContext | None = None,
        rerank: bool = False,
    ):
        if encoder is not None and embedding is not None:
            check_encoder(encoder, embedding)
        self.api = SessionApi(
            server_url, session_id, token, timeout_s=server_timeout_s, ssl_context=ssl_context
        )
        self.local_map = local_map
        self.encoder = encoder
        self.local_off_reason = local_off_reason
        self.threshold_ms = float(threshold_ms)
        self.rtt_ms = rtt_ms
        self.server_timeout_s = float(server_timeout_s)
        self.rerank = rerank
        """Ask the server to re-rank a static tower's answer with MiniLM (SQ only: the
        answer's `ranked_by` then differs from LQ's)."""
        self.up: str | None = up
        """The session's up axis as the router knows it ("+z", ...; None: not known, Z)."""
        self._up_settled = up is not None  # given by the caller: taken as settled
        self._up_read_s = -math.inf  # time.monotonic() of the last read of the record

    def planned_mode(self) -> str:
        """The mode a query would take now from the streaming RTT alone ("?" if unknown)."""
        if self.encoder is None:
            return SQ
        return planned_mode(self.rtt_ms(), self.threshold_ms)

    async def query(self, text: str, k: int = 5) -> QueryAnswer:
        """The k best matches for `text`, from the server or the local map (mode "none" and
        no results when local queries are off and the server does not answer)."""
        start_s = time.perf_counter()
        rtt = self.rtt_ms()
        if self.encoder is None:
            return await self._server_only(text, k, start_s, rtt)
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
            why = f"{source} {rtt:.0f} ms <= {self.threshold_ms:g} ms"
            try:
                return await self._server_query(text, k, why, start_s, rtt)
            except Exception as exc:  # any failure of the server path means: answer locally
                reason = f"SQ failed ({type(exc).__name__}: {exc}); fell back to LQ"
        return await self._local_query(text, k, reason, start_s, rtt)

    async def ask_aloud(self, audio: bytes, content_type: str, k: int = 5) -> QueryAnswer:
        """A spoken question (a whole audio file of `content_type`), recognised and answered
        by the server whatever the RTT: the device cannot recognise speech, so there is no
        LQ. Asked from where the device stands, as SQ asks. Mode "none", no results and the
        server's words in `reason` when it refuses the audio (415, 413, 400, 422, 503) or does
        not answer."""
        start_s = time.perf_counter()
        rtt = self.rtt_ms()
        try:
            answer = await self.api.query_speech(
                audio, content_type, k, from_xyz=self.local_map.user_position, rerank=self.rerank
            )
        except Exception as exc:  # refused or unreachable: said, not raised
            return _unanswered("", f"not answered: {exc}", start_s, rtt)
        now_s = time.perf_counter()
        return QueryAnswer(
            text=answer["text"],
            mode=SQ,
            results=answer["results"],
            latency_ms=(now_s - start_s) * 1e3,
            reason="spoken: recognised on the server (offline)",
            total_ms=(now_s - start_s) * 1e3,
            rtt_ms=rtt,
            verdict=answer["match"],
            transcript=answer["transcript"],
            confidence=answer["confidence"],
            asr_ms=answer["asr_ms"],
        )

    async def aclose(self) -> None:
        await self.api.aclose()

    async def __aenter__(self) -> QueryRouter:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.aclose()

    # --- the two modes --------------------------------------------------------------------

    async def _server_query(
        self, text: str, k: int, reason: str, start_s: float, rtt: float | None
    ) -> QueryAnswer:
        """SQ: the server's answer (raises whatever the server path raises)."""
        sq_start_s = time.perf_counter()
        # Parsed by the protocol (QueryHit): last_seen_t None, state "present" from an older
        # server. The asker stands where the device is: questions seen from them ("closest
        # to me") are answered from where LQ would answer them.
        answer = await self.api.query_result(
            text, k, from_xyz=self.local_map.user_position, rerank=self.rerank
        )
        now_s = time.perf_counter()
        if relational_reading(text) is not None:
            await self._read_up()  # LQ will need it once the network is gone
        return QueryAnswer(
            text=text,
            mode=SQ,
            results=answer["results"],
            latency_ms=(now_s - sq_start_s) * 1e3,
            reason=reason,
            total_ms=(time.perf_counter() - start_s) * 1e3,
            rtt_ms=rtt,
            verdict=answer["match"],
            ranked_by=answer.get("ranked_by"),
        )

    async def _read_up(self) -> None:
        """The session's up axis from its record, while it is not settled (at most every
        UP_REFRESH_S); a failed read changes nothing."""
        if self._up_settled or time.monotonic() - self._up_read_s < UP_REFRESH_S:
            return
        self._up_read_s = time.monotonic()
        try:
            record = await self.api.fetch()
        except Exception:  # the answer came; the axis can wait for the next one
            return
        if record.up is not None:
            self.up = record.up
            self._up_settled = record.up_source in SETTLED_UP

    def up_axis(self) -> np.ndarray:
        """The up axis LQ measures relations along, float64 [3]: the session's, else Z."""
        return Z_UP if self.up is None else up_vector(self.up)

    async def _server_only(
        self, text: str, k: int, start_s: float, rtt: float | None
    ) -> QueryAnswer:
        """Local queries off: SQ whatever the RTT (slow beats nothing), unless the link is
        known to be down."""
        off = "local queries off"  # why: said once by the caller (local_off_reason)
        if rtt is not None and math.isinf(rtt):
            problem = "link down (the streaming client is reconnecting)"
        else:
            try:
                return await self._server_query(text, k, off, start_s, rtt)
            except Exception as exc:
                problem = f"SQ failed ({type(exc).__name__}: {exc})"
        return _unanswered(text, f"{problem}; {off}", start_s, rtt)

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
        reading = relational_reading(text)
        if reading is not None:
            answer = await self._local_relational_query(text, reading, k, reason, start_s, rtt)
            if answer is not None:
                return answer
        lq_start_s = time.perf_counter()
        # Embedding is the slow part (~15 ms): off the loop, so deltas and acks keep flowing.
        # The search runs on the loop, the only place the local map is touched.
        embedding = await asyncio.to_thread(self.encoder.encode_query, text)
        hits = self.local_map.query_embedding(embedding, k)
        labels = [hit.label for hit in hits]
        # Rated as the server rates SQ hits; off the loop (the first one embeds the vocabulary).
        rating = await asyncio.to_thread(
            rate_hits, self.encoder, embedding, labels, self.local_map.label_texts()
        )
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
                    "last_seen_t": hit.last_seen_t,  # as the server sent it: SQ's value
                    "state": PRESENT,
                    "relation": None,
                }
                for hit, relevance in zip(hits, rating.relevance, strict=True)
            ],
            latency_ms=(now_s - lq_start_s) * 1e3,
            reason=reason,
            total_ms=(now_s - start_s) * 1e3,
            rtt_ms=rtt,
            ranked_by=self.encoder.model_id,
        )

    async def _local_relational_query(
        self,
        text: str,
        reading: Reading,
        k: int,
        reason: str,
        start_s: float,
        rtt: float | None,
    ) -> QueryAnswer | None:
        """LQ of a question about how things stand, as SQ answers it; None: answer it as a
        plain question (the map lacks its anchor, or it is seen from an unknown position)."""
        lq_start_s = time.perf_counter()
        # The slow parts off the loop: embedding the phrases (into the encoder's cache, where
        # the answer finds them) and, once, the rater's vocabulary. The map is read on the
        # loop, the only place it is touched.
        labels = self.local_map.labels()
        await asyncio.to_thread(
            _prepare, self.encoder, phrases_of(reading), labels, self.local_map.label_texts()
        )
        hits = self.local_map.relational_query(reading, self.encoder, up=self.up_axis(), k=k)
        if hits is None:
            return None
        results = []
        for hit in hits:
            held = self.local_map.get(hit.id)
            results.append(
                {
                    "id": hit.id,
                    "label": hit.label,
                    "score": hit.cosine,  # as the server reports a relational hit
                    "relevance": hit.relevance,
                    "bbox": held["bbox"],
                    "centroid": held["centroid"],
                    "last_seen_t": held["last_seen_t"],
                    "state": PRESENT,
                    "relation": {
                        "kind": hit.relation.kind,
                        "anchors": [{"id": i, "label": name} for i, name in hit.relation.anchors],
                        "degree": hit.relation.degree,
                    },
                }
            )
        now_s = time.perf_counter()
        return QueryAnswer(
            text=text,
            mode=LQ,
            results=results,
            latency_ms=(now_s - lq_start_s) * 1e3,
            reason=reason,
            total_ms=(now_s - start_s) * 1e3,
            rtt_ms=rtt,
            verdict=is_relational_match(hits),
            ranked_by=self.encoder.model_id,
        )


def _unanswered(text: str, reason: str, start_s: float, rtt: float | None) -> QueryAnswer:
    """Mode "none": no answer, and why, after the whole call's time."""
    took_ms = (time.perf_counter() - start_s) * 1e3
    return QueryAnswer(
        text=text,
        mode=NONE,
        results=[],
        latency_ms=took_ms,
        reason=reason,
        total_ms=took_ms,
        rtt_ms=rtt,
    )


def _prepare(
    encoder: TextEncoder, phrases: list[str], labels: list[str], label_texts: LabelTexts
) -> None:
    """In a worker thread: what a relational answer embeds, into the encoder's caches (the
    phrases, the map's labels and their texts, the rater's vocabulary)."""
    encoder.encode(phrases)
    encoder.encode(labels)
    encoder.encode(
        [t for label in labels for t in texts_of(label, label_texts, background_texts())]
    )
    rater_for(encoder)
