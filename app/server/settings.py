"""Server settings: one typed dataclass; CLI flags and SEMANTICXR_* environment variables map
onto its fields (flag > environment > default)."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

from app.perception import BACKENDS, DEFAULT_BACKEND
from app.protocol import MAX_INSTANCES_PER_FRAME
from app.server.edges import default_allowed_hosts
from app.speech.recognisers import AsrSettingError, parse_asr
from app.store import StoreURLError, check_store_url, sqlite_url

STORE_FILE = "semanticxr.sqlite3"
"""The SQLite file the default store keeps in data_dir (existing databases use this name)."""


@dataclass
class ServerSettings:
    host: str | None = None
    """Interface to listen on; default 127.0.0.1 (this machine only), with --https every
    interface, IPv4 and IPv6 ('', which binds both; 0.0.0.0 is IPv4 only, :: IPv6 only)."""
    port: int = 8000
    """TCP port."""
    data_dir: str = "data"
    """Folder of the default store's SQLite file (sessions, knobs, confirmed objects, delta seq)."""
    store: str | None = None
    """Store URL: sqlite:///<relative path>, sqlite:////<absolute path> or postgresql://user:password@host:port/db; default semanticxr.sqlite3 in data_dir."""
    max_tombstones: int = 100_000
    """Removed ids a session keeps for resuming subscribers (older resumes get a full snapshot)."""
    api_key: str | None = None
    """Key needed to create and list sessions; each session then has its own token. None runs open."""
    max_message_bytes: int = 8 << 20
    """Largest WebSocket message accepted (bigger closes the socket with code 1009)."""
    max_body_bytes: int = 1 << 20
    """Largest REST request body."""
    max_sessions: int = 10_000
    """Sessions the store keeps, in memory or not; past it, creating or importing one is refused (409) until some are deleted."""
    max_resident_sessions: int = 64
    """Sessions whose maps are held in memory at once; to load another, the least recently used one without an open socket is unloaded (none: 503 with Retry-After)."""
    idle_unload_s: float = 600.0
    """Seconds without frames, requests or open sockets after which a session's map is saved and unloaded from memory (its next use loads it again)."""
    session_retention_days: float | None = None
    """Days a session may go unused (no frames, no requests, no sockets) before it is deleted with its map, checked at start and periodically; unset keeps sessions until deleted."""
    perception: str = DEFAULT_BACKEND
    """Perception backends loaded at start, comma-separated; sessions use the first unless they choose."""
    models_dir: str | None = None
    """Folder with one sub-folder per model for --perception models (load from it only, never the hub); default: Hugging Face ids."""
    static_tower: str | None = None
    """A static text tower file (`semanticxr towers distil --out FILE`) for the sessions
    created with text_tower "static" (kept in DATA_DIR/towers); unset: the server distils
    one from its text tower on first need (minutes, once) and keeps it there."""
    mapping_workers: int = 1
    """Threads that map keyframes, shared round-robin by the sessions with one waiting (each maps one at a time). Mapping holds the GIL: a second thread maps no faster and costs CPU (32 devices: 6.7 against 7.9 ms a frame, keyframe ack p95 893 against 975 ms); raise it for --perception models, whose networks release the GIL."""
    decode_workers: int = 1
    """Threads that unpack, decode and validate frames (apart from mapping, so neither queues behind the other); one is enough while decoding holds the GIL."""
    max_frame_pixels: int = 1920 * 1440
    """Most pixels of a frame's RGB, depth or instance image (refused from the declared size, before decoding)."""
    max_instances_per_frame: int = 256
    """Most detections.instances a frame may list (at most the protocol's 1024)."""
    max_objects: int = 20_000
    """Objects (candidates and confirmed) a session's map holds; at the cap only matches are mapped."""
    max_subscribers: int = 32
    """Update subscribers per session."""
    max_connections: int = 1000
    """Open connections and requests in flight, all together; beyond, HTTP answers 503."""
    max_bad_frames: int = 50
    """Consecutive bad frames before a stream is closed as abusive (code 1008)."""
    max_query_k: int = 100
    """Largest k a query may ask for."""
    asr: str = "pocketsphinx"
    """Speech recogniser of spoken questions (POST .../query/speech): 'pocketsphinx'
    (embedded, offline, its vocabulary shaped by each session's labels) or 'whisper:DIR' (a
    Whisper model and processor saved with transformers' save_pretrained in DIR, loaded
    from it only)."""
    asr_workers: int = 1
    """Recogniser processes (each loads the recogniser on its first question); a question
    finding all busy is answered 503 with Retry-After."""
    asr_timeout_s: float = 20.0
    """Longest a question may take to decode and recognise; past it its recogniser process
    is killed and restarted, and the question answered 503 with Retry-After."""
    max_audio_bytes: int = 4 << 20
    """Largest spoken question (POST .../query/speech body): 30 s of browser audio can pass
    --max-body-bytes."""
    log_level: str = "info"
    """uvicorn log level."""
    allowed_hosts: str | None = None
    """Comma-separated Host names the server answers to ('*' any, '*.example.com' subdomains);
    default: the loopback names for a loopback bind, any Host for a wildcard bind (0.0.0.0, ::),
    the certificate's names with --https."""
    https: bool = False
    """Serve HTTPS and wss:// (a phone's WebXR page needs a secure context) with a
    self-signed certificate for this machine's names (localhost, its hostname, the addresses
    of its interfaces), made once in DATA_DIR/tls (owner-only) and made anew when they
    change; answer to those names unless --allowed-hosts says otherwise. Without --host,
    listen on every interface. Clients trust it with --tls-ca DATA_DIR/tls/cert.pem."""
    tls_cert: str | None = None
    """A PEM certificate (chain) to serve HTTPS with instead of the self-signed one (with
    --tls-key; implies --https): the server answers to the names it holds."""
    tls_key: str | None = None
    """The PEM private key of --tls-cert."""
    allow_origin: str = ""
    """Comma-separated browser origins (scheme://host:port) besides the server's own that may
    open its WebSockets."""
    cluster: str | None = None
    """Run as the gateway of a cluster of map shards on Ray: 'auto' starts a local Ray (or
    joins the one `ray start --head` runs here), 'ray://HOST:10001' joins that cluster. Needs a
    postgresql:// --store, which every shard and gateway shares. Unset: one process, as usual."""
    shards: int = 2
    """With --cluster: how many map shards (named detached Ray actors mapshard-0..N-1) to run."""
    shard_name: str | None = None
    """This server is the map shard of that name (set by --cluster for each shard): it claims
    the sessions it loads in the store, renews their leases and registers its address for the
    gateways. Unset: a standalone server, which claims nothing."""
    shard_url: str | None = None
    """The address gateways reach this shard at (default: http://HOST:PORT of its own bind)."""
    shard_lease_s: float = 5.0
    """How long a shard's claim on a session lasts without renewal (it renews every second):
    after a shard dies or hangs, its sessions move to another shard after at most this long."""
    models_service: str | None = None
    """The Ray Serve application that runs the `models` perception backend for the map shards
    (their crops embedded together, in shared batches): set by --cluster when --perception
    includes models (default name semanticxr-models). Unset: each server loads its own models."""

    def allowed_host_list(self) -> list[str] | None:
        """The Host names served (None: any), from allowed_hosts or the bind address."""
        if self.allowed_hosts is None:
            return default_allowed_hosts(self.host)
        return [h.strip() for h in self.allowed_hosts.split(",") if h.strip()]

    def allowed_origin_list(self) -> list[str]:
        return [o.strip() for o in self.allow_origin.split(",") if o.strip()]

    def __post_init__(self) -> None:
        """Resolve the default bind; raise SettingsError naming the setting whose value
        cannot work."""
        if (self.tls_cert is None) != (self.tls_key is None):
            raise SettingsError(
                "tls_cert and tls_key go together: give both (--tls-cert CERT.pem "
                "--tls-key KEY.pem), or neither for --https's self-signed certificate"
            )
        self.https = self.https or self.tls_cert is not None
        if self.host is None:
            self.host = "" if self.https else "127.0.0.1"
        if self.https and self.cluster is not None:
            raise SettingsError(
                "https: a cluster's gateways serve plain HTTP; put a TLS proxy in front of "
                "them, or run one server with --https"
            )
        if not 0 <= self.port <= 65535:
            raise SettingsError(f"port must be within [0, 65535], got {self.port}")
        for name in _POSITIVE:
            if getattr(self, name) < 1:
                raise SettingsError(f"{name} must be at least 1, got {getattr(self, name)}")
        if not self.shard_lease_s > 1.5:
            raise SettingsError(
                f"shard_lease_s must be over 1.5 seconds (leases are renewed every second), "
                f"got {self.shard_lease_s}"
            )
        if self.cluster is not None and not self.store_url.startswith(("postgresql:", "postgres:")):
            raise SettingsError(
                "cluster: the shards and gateways of a cluster share one PostgreSQL store; give "
                "--store postgresql://USER:PASSWORD@HOST:5432/DB"
            )
        if self.models_service is not None:
            if "models" not in self.perception_backends:
                raise SettingsError(
                    f"models_service: the models deployment serves --perception models, which "
                    f"is not in --perception {self.perception}"
                )
            if self.cluster is None and self.shard_name is None:
                raise SettingsError(
                    "models_service: only map shards use the models deployment (give --cluster)"
                )
        if not self.idle_unload_s > 0:
            raise SettingsError(f"idle_unload_s must be over 0 seconds, got {self.idle_unload_s}")
        if self.session_retention_days is not None and not self.session_retention_days > 0:
            raise SettingsError(
                f"session_retention_days must be over 0 days (or unset to keep sessions), "
                f"got {self.session_retention_days}"
            )
        if self.max_instances_per_frame > MAX_INSTANCES_PER_FRAME:
            raise SettingsError(
                f"max_instances_per_frame must be at most {MAX_INSTANCES_PER_FRAME} (the wire "
                f"protocol's limit), got {self.max_instances_per_frame}"
            )
        if self.api_key is not None and not self.api_key.strip():
            raise SettingsError("api_key must not be empty (leave it unset to run open)")
        unknown = [name for name in self.perception_backends if name not in BACKENDS]
        if unknown or not self.perception_backends:
            raise SettingsError(
                f"perception: unknown backend {', '.join(map(repr, unknown)) or repr('')}; "
                f"available: {', '.join(BACKENDS)}"
            )
        if self.static_tower is not None and not Path(self.static_tower).is_file():
            raise SettingsError(f"static_tower: {self.static_tower} is not a file")
        if not self.asr_timeout_s > 0:
            raise SettingsError(f"asr_timeout_s must be over 0 seconds, got {self.asr_timeout_s}")
        try:
            parse_asr(self.asr)
        except AsrSettingError as exc:
            raise SettingsError(str(exc)) from None
        try:
            check_store_url(self.store_url)
        except StoreURLError as exc:
            raise SettingsError(str(exc)) from None

    @property
    def perception_backends(self) -> list[str]:
        """The backends `perception` names, in order (the first is the sessions' default)."""
        return list(dict.fromkeys(n.strip() for n in self.perception.split(",") if n.strip()))

    @property
    def shard_address(self) -> str:
        """Where gateways reach this server as a map shard."""
        return self.shard_url or f"http://{self.host}:{self.port}"

    @property
    def store_url(self) -> str:
        """The store to open: `store`, or the SQLite file in data_dir."""
        return self.store or sqlite_url(Path(self.data_dir) / STORE_FILE)

    @classmethod
    def from_env(cls, **overrides) -> ServerSettings:
        """Defaults, then SEMANTICXR_<FIELD> environment variables (an empty one counts as
        unset, as compose files leave them), then non-None overrides."""
        values = {}
        for f in dataclasses.fields(cls):
            variable = f"SEMANTICXR_{f.name.upper()}"
            env = os.environ.get(variable)
            if not env:
                continue
            if f.type in ("str", "str | None"):
                values[f.name] = env
            elif f.type == "bool":
                if env.strip().lower() not in _BOOLEANS:
                    raise SettingsError(f"{variable} must be true or false, got {env!r}")
                values[f.name] = _BOOLEANS[env.strip().lower()]
            elif f.type in ("float", "float | None"):
                try:
                    values[f.name] = float(env)
                except ValueError:
                    raise SettingsError(f"{variable} must be a number, got {env!r}") from None
            else:
                try:
                    values[f.name] = int(env)
                except ValueError:
                    raise SettingsError(f"{variable} must be an integer, got {env!r}") from None
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)


class SettingsError(ValueError):
    """A server setting (flag or environment variable) with a value that cannot work."""


_BOOLEANS = {"1": True, "true": True, "yes": True, "0": False, "false": False, "no": False}
"""How a SEMANTICXR_* variable says a boolean setting."""

_POSITIVE = (
    "max_message_bytes",
    "max_body_bytes",
    "max_sessions",
    "max_resident_sessions",
    "mapping_workers",
    "decode_workers",
    "max_frame_pixels",
    "max_instances_per_frame",
    "max_objects",
    "max_subscribers",
    "max_connections",
    "max_bad_frames",
    "max_query_k",
    "asr_workers",
    "max_audio_bytes",
    "max_tombstones",
    "shards",
)
