"""Where the `models` backend's weights come from: Hugging Face ids or `--models-dir DIR`.

No heavy imports here: the server checks that every model is present (and says how to fetch
the missing ones) before it loads anything, and `serve` exits 2 on a missing model.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

MODEL_ID_FILE = "semanticxr_model_id.txt"
"""Optional file in a model folder naming the model, when it is not the hub id's weights
(`models tiny` writes one, so a tiny model never passes for the real one)."""
SETTINGS_FILE = "semanticxr.json"
"""Optional per-models-dir settings (`ModelSettings` fields as JSON) beside the model folders."""


@dataclass(frozen=True)
class ModelSpec:
    """One model of a profile: its hub id and the sub-folder of `--models-dir` holding it."""

    role: str
    """What the model does in the profile: detector, embedder, segmenter."""
    hub_id: str
    folder: str


@dataclass(frozen=True)
class Profile:
    """The models a perception profile runs. The CPU profile masks boxes by depth; a GPU
    profile would add a `segmenter` (a SAM-family model) and may swap in a stronger detector:
    a new Profile, with the backend choosing masks by whether it has a segmenter."""

    name: str
    detector: ModelSpec
    embedder: ModelSpec
    segmenter: ModelSpec | None = None

    @property
    def models(self) -> list[ModelSpec]:
        return [m for m in (self.detector, self.embedder, self.segmenter) if m is not None]


CPU_PROFILE = Profile(
    name="cpu",
    detector=ModelSpec("detector", "google/owlvit-base-patch32", "owlvit-base-patch32"),
    embedder=ModelSpec("embedder", "openai/clip-vit-base-patch32", "clip-vit-base-patch32"),
)
"""OWL-ViT B/32 boxes + depth-mode masks + CLIP ViT-B/32 crop embeddings (~2 s per keyframe
on 2 CPU cores, docs/evaluation.md "Measured facts")."""

PROFILES = {p.name: p for p in (CPU_PROFILE,)}


@dataclass(frozen=True)
class ModelSettings:
    """Per-models-dir settings, read from `DIR/semanticxr.json` when present."""

    detection_threshold: float = 0.1
    """Lowest detector score (sigmoid of OWL-ViT's best query logit) a box needs."""
    max_objects: int = 32
    """Most boxes kept per keyframe, best first (the batch the embedder sees)."""
    nms_iou: float = 0.5
    """Boxes overlapping a better one by more than this IoU are dropped."""
    vocabulary: str | None = None
    """A vocabulary file (one tag a line) instead of the packaged indoor one; relative to DIR."""


class MissingModelsError(RuntimeError):
    """A model the backend needs is not where it must load from; the message says how to
    fetch it."""


@dataclass(frozen=True)
class ResolvedModel:
    spec: ModelSpec
    source: str
    """What `from_pretrained` gets: a folder, or the hub id."""
    local_only: bool
    model_id: str
    """The id announced to clients (sessions announce the embedder's)."""


def fetch_commands(profile: Profile, models_dir: str | None) -> list[str]:
    """The shell commands that put the profile's models where the backend looks."""
    target = models_dir or "DIR"
    return [f"hf download {m.hub_id} --local-dir {Path(target) / m.folder}" for m in profile.models]


def missing_models_message(
    profile: Profile, models_dir: str | None, missing: list[ModelSpec]
) -> str:
    if models_dir is not None:
        where = "\n".join(f"  {Path(models_dir) / m.folder}   ({m.hub_id})" for m in missing)
        lines = [
            f"perception 'models' ({profile.name} profile) needs these model folders in "
            f"--models-dir, and they are missing:",
            where,
            "Fetch them on a machine with hub access (then copy the folders here):",
            *(f"  {c}" for c in fetch_commands(profile, models_dir)),
            f"or, for tests (small random weights): semanticxr models tiny --out {models_dir}",
        ]
    else:
        lines = [
            f"perception 'models' ({profile.name} profile) needs these models, not in the "
            f"Hugging Face cache (HF_HUB_OFFLINE is set, so nothing is downloaded):",
            *(f"  {m.hub_id}" for m in missing),
            "On a machine with hub access, run with HF_HUB_OFFLINE=0 to fetch them on first use, or "
            "put them in a folder and pass --models-dir DIR:",
            *(f"  {c}" for c in fetch_commands(profile, None)),
            "or, for tests (small random weights): semanticxr models tiny --out DIR",
        ]
    return "\n".join(lines)


def _hub_offline() -> bool:
    return os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in ("1", "true", "yes", "on")


def _in_hub_cache(hub_id: str) -> bool:
    from huggingface_hub import try_to_load_from_cache

    return isinstance(try_to_load_from_cache(hub_id, "config.json"), str)


def resolve_models(profile: Profile, models_dir: str | None) -> dict[str, ResolvedModel]:
    """role -> where to load it from; MissingModelsError naming every missing model and the
    commands that fetch them. With models_dir, models load from it only (never the hub);
    without, from hub ids (the hub cache; checked now when HF_HUB_OFFLINE is set, else
    downloaded on first use)."""
    resolved: dict[str, ResolvedModel] = {}
    missing: list[ModelSpec] = []
    for spec in profile.models:
        if models_dir is not None:
            folder = Path(models_dir) / spec.folder
            if not (folder / "config.json").is_file():
                missing.append(spec)
                continue
            resolved[spec.role] = ResolvedModel(
                spec, str(folder), True, _folder_model_id(folder, spec)
            )
        else:
            if _hub_offline() and not _in_hub_cache(spec.hub_id):
                missing.append(spec)
                continue
            resolved[spec.role] = ResolvedModel(spec, spec.hub_id, _hub_offline(), spec.hub_id)
    if missing:
        raise MissingModelsError(missing_models_message(profile, models_dir, missing))
    return resolved


def _folder_model_id(folder: Path, spec: ModelSpec) -> str:
    """The id a model folder is announced as: its MODEL_ID_FILE, else the spec's hub id."""
    id_file = folder / MODEL_ID_FILE
    return id_file.read_text().strip() if id_file.is_file() else spec.hub_id


def text_towers_in(models_dir: str) -> list[ResolvedModel]:
    """The embedder folders of `models_dir` (one per profile whose embedder folder holds a
    model), with the ids a session on them announces, found as `resolve_models` finds them."""
    found: dict[str, ResolvedModel] = {}
    for profile in PROFILES.values():
        spec = profile.embedder
        folder = Path(models_dir) / spec.folder
        if spec.folder not in found and (folder / "config.json").is_file():
            found[spec.folder] = ResolvedModel(
                spec, str(folder), True, _folder_model_id(folder, spec)
            )
    return list(found.values())


def load_settings(models_dir: str | None) -> ModelSettings:
    """`DIR/semanticxr.json` as ModelSettings (defaults without it); ValueError if bad."""
    if models_dir is None:
        return ModelSettings()
    path = Path(models_dir) / SETTINGS_FILE
    if not path.is_file():
        return ModelSettings()
    values = json.loads(path.read_text())
    known = set(ModelSettings.__dataclass_fields__)
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"{path}: unknown settings {unknown}; known: {sorted(known)}")
    if values.get("vocabulary"):
        values["vocabulary"] = str(Path(models_dir) / values["vocabulary"])
    return ModelSettings(**values)
