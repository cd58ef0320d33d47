"""The `models` perception backend as one Ray Serve deployment that every map shard calls.

Without it each shard loads its own OWL-ViT and CLIP and embeds one keyframe's crops per
forward pass. Here the models load once, in the replica of the Serve application
`semanticxr-models` (`start_models`; `serve --cluster` starts it before the shards when
--perception includes models), and:

- **crops are embedded in shared batches**: `embed_crops` is a `@serve.batch` method whose
  batch is counted in crops (`batch_size_fn`), not requests, so the crops of keyframes
  from many sessions and shards that arrive within `BATCH_WAIT_S` of each other (or while
  the previous pass runs) go through CLIP's image tower in one forward pass, up to
  `MAX_BATCH_CROPS`; each request gets its own rows back. `max_ongoing_requests` is twice
  the batch, so a full batch fits beside the detections in flight.
- **detection is one request per keyframe**: `OwlViTDetector.detect` takes one image
  (keyframes differ in size, and its boxes are scaled to each image), so detections are
  not batched; they run beside the embedding (each model has its own lock).
- **the baseline stays one crop per pass**: `embed_one_crop` is not batched, so the
  baseline organisation costs in the cluster what it costs in one process.
- **text stays in the shard**: a shard loads CLIP's text tower alone (`ClipTextTower`, as
  a device does: 63 M of CLIP B/32's 151 M weights) for its sessions' queries, labels
  and vocabulary. A query is answered on the REST path and must not queue behind a batch
  of crops in the replica (the image and text towers share one lock); and the numbers are
  the same as `ClipEmbedder.embed_texts` on the same checkpoint. The shard checks that its
  text tower is the deployment's model and that both use one vocabulary.

A shard's `ModelsBackend` is the ordinary one made on `RemoteDetector` and
`RemoteEmbedder` (`use_models_service`), which have the methods it calls on the local
models; their image calls block on `.result()`, which is fine: mapping runs in worker
threads, not on an event loop. Ray carries the numpy arrays between the processes of one
cluster (nothing here crosses the public network boundary).
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import time
from dataclasses import dataclass

import numpy as np
from ray import serve

from app.perception.models.weights import CPU_PROFILE
from app.server.settings import ServerSettings

log = logging.getLogger("semanticxr.cluster")

APP_NAME = "semanticxr-models"
"""The Serve application (and its one deployment's) name when --models-service is unset."""
MAX_BATCH_CROPS = 64
"""Most crops in one forward pass of the image tower: two keyframes at the default
max_objects (32). A models dir whose max_objects is larger raises it to that. The replica
takes twice as many requests at once (`max_ongoing_requests`): a batch has at most this many
requests (each has a crop or more), and detections are in flight beside it."""
BATCH_WAIT_S = 0.02
"""How long a keyframe's crops wait for others to share their forward pass (a keyframe
takes about 2 s on 2 CPU cores, so this costs 1 % of its latency)."""
REQUEST_TIMEOUT_S = 120.0
"""Longest a shard waits for one detection or embedding from the deployment."""
START_TIMEOUT_S = 300.0
"""Longest `start_models` waits for the replica to load the models."""


class ModelsDeploymentError(RuntimeError):
    """The models deployment cannot start; the message says why (a missing model's fix)."""


def _crop_count(crops_per_request: list[list[np.ndarray]]) -> int:
    return sum(len(crops) for crops in crops_per_request)


@serve.deployment(
    name=APP_NAME,
    num_replicas=1,
    ray_actor_options={"num_cpus": 0},
    logging_config={"enable_access_log": False},  # not a log line per keyframe and crop
)
class ModelsDeployment:
    """The `models` backend's networks, loaded once: OWL-ViT detection per keyframe and CLIP
    image embeddings of crops, batched across requests. Ray schedules it by memory, not CPU
    (num_cpus=0, as the shards), so it fits beside them on a small node. It asks for no GPU,
    so it runs the CPU profile even on a GPU node (Ray hides the GPUs from it)."""

    def __init__(
        self,
        models_dir: str | None,
        max_batch_crops: int = MAX_BATCH_CROPS,
        batch_wait_s: float = BATCH_WAIT_S,
    ):
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # before torch loads
        logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
        from app.perception import BackendOptions, make_backend

        # The same factory a server uses: a missing model fails with its fix, before torch.
        self.backend = make_backend("models", BackendOptions(models_dir=models_dir))
        self.max_batch_crops = max(max_batch_crops, self.backend.settings.max_objects)
        """Most crops in one forward pass: at least one keyframe's most (a request must fit)."""
        self.embed_crops.set_max_batch_size(self.max_batch_crops)
        self.embed_crops.set_batch_wait_timeout_s(batch_wait_s)
        self.forward_passes = 0
        """Batched forward passes of the image tower so far."""
        self.requests = 0
        """`embed_crops` requests answered so far (keyframes)."""
        self.crops = 0
        """Crops embedded by `embed_crops` so far."""

    async def describe(self) -> dict:
        """What a shard checks its own side against: model id, embedding width, CLIP's logit
        scale, the detector's vocabulary, the batch limit in crops."""
        embedder = self.backend.embedder
        return {
            "model_id": embedder.model_id,
            "dim": embedder.dim,
            "logit_scale": embedder.logit_scale,
            "vocabulary": list(self.backend.vocabulary),
            "max_batch_crops": self.max_batch_crops,
        }

    async def detect(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`OwlViTDetector.detect` of one keyframe: uint8 [H, W, 3] -> boxes float32 [P, 4]
        (RGB pixels), scores float32 [P], query index int64 [P]."""
        return await asyncio.to_thread(self.backend.detector.detect, rgb)

    @serve.batch(
        max_batch_size=MAX_BATCH_CROPS, batch_wait_timeout_s=BATCH_WAIT_S, batch_size_fn=_crop_count
    )
    async def embed_crops(self, crops_per_request: list[list[np.ndarray]]) -> list[np.ndarray]:
        """Called with one keyframe's uint8 [h, w, 3] crops; answers float32 [n, dim] unit
        rows. Serve hands it the crops of every request in the batch: one forward pass for
        all of them, split back per request."""
        flat = [crop for crops in crops_per_request for crop in crops]
        rows = await asyncio.to_thread(self.backend.embedder.embed_crops_batched, flat)
        self.forward_passes += 1
        self.requests += len(crops_per_request)
        self.crops += len(flat)
        ends = np.cumsum([len(crops) for crops in crops_per_request])
        return np.split(rows, ends[:-1])

    async def embed_one_crop(self, crop: np.ndarray) -> np.ndarray:
        """The baseline organisation: this crop alone in a forward pass -> float32 [1, dim]."""
        return await asyncio.to_thread(self.backend.embedder.embed_crops_batched, [crop])

    async def stats(self) -> dict[str, int]:
        """Batched forward passes, requests and crops so far (`embed_crops` only)."""
        return {
            "forward_passes": self.forward_passes,
            "requests": self.requests,
            "crops": self.crops,
        }


def start_models(
    settings: ServerSettings,
    max_batch_crops: int = MAX_BATCH_CROPS,
    batch_wait_s: float = BATCH_WAIT_S,
    timeout_s: float = START_TIMEOUT_S,
) -> str:
    """Run the models deployment on the connected Ray cluster, as the Serve application
    `settings.models_service` (default `APP_NAME`), loading from `settings.models_dir`;
    its name once it answers. Idempotent: an application of that name that is running or
    starting is waited for, not deployed again. No HTTP proxy (shards call it by handle).
    ModelsDeploymentError with the replica's error (a missing model's fix) when it cannot
    start."""
    name = settings.models_service or APP_NAME
    if _app_status(name) not in ("RUNNING", "DEPLOYING"):
        serve.start(proxy_location="Disabled")
        app = ModelsDeployment.options(name=name, max_ongoing_requests=2 * max_batch_crops).bind(
            settings.models_dir, max_batch_crops, batch_wait_s
        )
        serve.run_many(
            [serve.RunTarget(target=app, name=name, route_prefix=None)],
            wait_for_applications_running=False,
        )
    deadline = time.monotonic() + timeout_s
    while (status := _app_status(name)) != "RUNNING":
        failed = status in ("DEPLOY_FAILED", "UNHEALTHY", None)
        if failed or time.monotonic() > deadline:
            app = serve.status().applications.get(name)
            why = "\n".join(_last_error(d.message) for d in app.deployments.values()) if app else ""
            raise ModelsDeploymentError(
                f"--perception models: the models deployment {name!r} "
                + (f"failed ({status or 'gone'})" if failed else f"not up in {timeout_s:.0f} s")
                + f": {why}"
            )
        time.sleep(0.2)
    log.info("models deployment %s serves the map shards' perception", name)
    return name


def _last_error(message: str) -> str:
    """The last exception's text in a replica's traceback (the whole message without one)."""
    raised = list(re.finditer(r"^[A-Za-z_][\w.]*(?:Error|Exception): ", message, re.MULTILINE))
    return message[raised[-1].end() :] if raised else message


def _app_status(name: str) -> str | None:
    app = serve.status().applications.get(name)
    return None if app is None else str(app.status.value)


@dataclass(frozen=True)
class DeploymentFacts:
    """What `ModelsDeployment.describe` answers."""

    model_id: str
    dim: int
    logit_scale: float
    vocabulary: list[str]
    max_batch_crops: int


class RemoteDetector:
    """`OwlViTDetector`'s methods, as `ModelsBackend` calls them, on the deployment."""

    def __init__(self, handle, facts: DeploymentFacts):
        self._handle = handle
        self._vocabulary = facts.vocabulary

    def set_vocabulary(self, tags: list[str]) -> None:
        """The deployment's detector is prompted with its own vocabulary; it must be this."""
        if list(tags) != self._vocabulary:
            raise ValueError(
                f"the models deployment's vocabulary ({len(self._vocabulary)} tags) is not this "
                f"shard's ({len(tags)} tags): give the shards and the deployment one --models-dir"
            )

    def detect(self, rgb: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self._handle.detect.remote(rgb).result(timeout_s=REQUEST_TIMEOUT_S)


class RemoteEmbedder:
    """`ClipEmbedder`'s methods, as `ModelsBackend` calls them: crops to the deployment (a
    keyframe's together, batched there with other keyframes'; the baseline's one request per
    crop), texts to this process's CLIP text tower."""

    def __init__(self, handle, facts: DeploymentFacts, text_tower):
        if (text_tower.model_id, text_tower.dim) != (facts.model_id, facts.dim):
            raise ValueError(
                f"this shard's CLIP text tower ({text_tower.model_id}, {text_tower.dim} wide) is "
                f"not the models deployment's ({facts.model_id}, {facts.dim} wide)"
            )
        self._handle = handle
        self._text_tower = text_tower
        self.model_id, self.dim, self.logit_scale = facts.model_id, facts.dim, facts.logit_scale

    def embed_crops_batched(self, crops: list[np.ndarray]) -> np.ndarray:
        """uint8 [h, w, 3] crops -> float32 [n, dim] unit rows, in one request."""
        if not crops:
            return np.zeros((0, self.dim), np.float32)
        return self._handle.embed_crops.remote(crops).result(timeout_s=REQUEST_TIMEOUT_S)

    def embed_crops_one_by_one(self, crops: list[np.ndarray]) -> np.ndarray:
        """The baseline organisation: one request, one forward pass, per crop."""
        if not crops:
            return np.zeros((0, self.dim), np.float32)
        return np.concatenate(
            [
                self._handle.embed_one_crop.remote(crop).result(timeout_s=REQUEST_TIMEOUT_S)
                for crop in crops
            ]
        )

    def embed_texts(self, texts: list[str]) -> np.ndarray:
        return self._text_tower.embed_texts(texts)


def use_models_service(models_dir: str | None, app_name: str = APP_NAME):
    """Make this process's `models` backend (what `make_backend("models", ...)` then returns
    for `models_dir`) the one on the deployment `app_name`: its detector and image tower
    there, CLIP's text tower loaded here from models_dir. Returns the backend."""
    from app.perception.models.backend import load_models_backend
    from app.perception.models.embedder import ClipTextTower
    from app.perception.models.weights import resolve_models

    handle = serve.get_app_handle(app_name)
    facts = DeploymentFacts(**handle.describe.remote().result(timeout_s=REQUEST_TIMEOUT_S))
    clip = resolve_models(CPU_PROFILE, models_dir)["embedder"]
    text_tower = ClipTextTower.load(clip.source, clip.local_only, clip.model_id)
    models = (RemoteDetector(handle, facts), RemoteEmbedder(handle, facts, text_tower))
    backend = load_models_backend(models_dir, CPU_PROFILE, models=models)
    log.info(
        "perception 'models' on the models deployment %s (%s; crops batched up to %d)",
        app_name,
        facts.model_id,
        facts.max_batch_crops,
    )
    return backend
