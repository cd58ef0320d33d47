"""A detector emulator: ground-truth instance images turned into realistic detections.

Profiles:
  "none"      every visible non-background object with >= min_pixels pixels is detected with
              its true label, score 1 and its exact mask; depth is untouched.
  "standard"  ~10% missed detections (more for small ones), ~10% labels swapped for a
              semantically close one (Category.confusions), masks eroded or dilated by 1-2 px,
              Kinect-like depth noise (std 1.2 mm + 1.9 mm * (z - 0.4)^2), and in ~5% of frames a
              spurious blob with a random label that lives for up to 3 frames.
  "bleed"     "standard" with the mask and depth bleeding of an outside room: every mask is
              dilated by BLEED_EXTRA_PX more (3-4 px) onto whatever lies behind, below or
              in front of it, never eroded, and depth is smeared across depth edges (flying
              pixels: a pixel next to a jump of over FLYING_EDGE_M takes, with probability
              FLYING_RATE, a depth between the two sides).

Everything is deterministic given (seed, frame_index), whatever order frames are asked in.
Detection ids are per frame (1..K) and unrelated to scene instance ids, as with a real
detector; background classes are never reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from world.categories import CATEGORIES
from world.render import View
from world.scene import Scene

NOISE_PROFILES: tuple[str, ...] = ("none", "standard", "bleed")

BLEED_EXTRA_PX = 2
""""bleed": pixels added to every mask's dilation radius (1-2 px in "standard")."""
FLYING_EDGE_M = 0.05
""""bleed": a depth jump (3x3 neighbourhood range) over this is an edge..."""
FLYING_RATE = 0.5
"""...and each pixel on it takes a depth between its sides with this probability."""

MISS_RATE = 0.08
SMALL_MISS_RATE = 0.2
"""Miss rate for detections under SMALL_PX pixels (small and far objects are missed more)."""
SMALL_PX = 400
CONFUSION_RATE = 0.1
SPURIOUS_RATE = 0.05
SPURIOUS_LIFETIME_FRAMES = 3


@dataclass
class NoisyDetections:
    """What the device sends as its perception output for one frame.

    depth_m:      float32 [H, W] metres, noisy for "standard" (the view's own array for "none")
    instance_ids: uint16 [H, W] detection id per pixel, 0 = no detection
    instances:    [{"id": int, "label": str, "score": float}], one per id in instance_ids
    sources:      {detection id: scene instance id it was made from, 0 for a spurious one};
                  ground truth for tests and evaluation, not something a device would send
    """

    depth_m: np.ndarray
    instance_ids: np.ndarray
    instances: list[dict]
    sources: dict[int, int] = field(default_factory=dict)


class DetectionModel:
    """Turns rendered views of one scene into detections under a noise profile."""

    def __init__(
        self, scene: Scene, profile: str = "standard", seed: int = 0, min_pixels: int = 50
    ):
        if profile not in NOISE_PROFILES:
            raise ValueError(
                f"unknown noise profile {profile!r}; valid profiles: {', '.join(NOISE_PROFILES)}"
            )
        self.scene = scene
        self.profile = profile
        self.seed = int(seed)
        self.min_pixels = int(min_pixels)
        max_id = max((o.instance_id for o in scene.objects), default=0)
        self._category = [""] * (max_id + 1)
        self._detectable = np.zeros(max_id + 1, bool)
        for obj in scene.objects:
            self._category[obj.instance_id] = obj.category
            self._detectable[obj.instance_id] = not obj.is_background
        self._labels = sorted(CATEGORIES)

    def detect(self, view: View, frame_index: int) -> NoisyDetections:
        """Detections of one rendered view; `frame_index` seeds this frame's noise."""
        ids = view.instance_ids
        counts = np.bincount(ids.ravel(), minlength=len(self._detectable))[: len(self._detectable)]
        visible = np.flatnonzero((counts >= self.min_pixels) & self._detectable)
        if self.profile == "none":
            return self._perfect(view, visible)
        rng = np.random.default_rng([self.seed, int(frame_index), 1])
        return self._standard(view, visible, counts, rng, int(frame_index))

    def _perfect(self, view: View, visible: np.ndarray) -> NoisyDetections:
        lut = np.zeros(len(self._detectable), np.uint16)
        lut[visible] = np.arange(1, len(visible) + 1)
        instances = [
            {"id": k + 1, "label": self._category[int(i)], "score": 1.0}
            for k, i in enumerate(visible)
        ]
        sources = {k + 1: int(i) for k, i in enumerate(visible)}
        return NoisyDetections(view.depth_m, lut[view.instance_ids], instances, sources)

    def _standard(
        self,
        view: View,
        visible: np.ndarray,
        counts: np.ndarray,
        rng: np.random.Generator,
        frame_index: int,
    ) -> NoisyDetections:
        h, w = view.instance_ids.shape
        # Fixed number of draws per visible object keeps each object's fate independent of
        # what else is on screen only through the order of `visible`, which is sorted.
        draws = rng.random((len(visible), 4))
        kept: list[int] = []
        labels: list[str] = []
        scores: list[float] = []
        for k, instance in enumerate(visible):
            small = counts[instance] < SMALL_PX
            if draws[k, 0] < (SMALL_MISS_RATE if small else MISS_RATE):
                continue
            label = self._category[int(instance)]
            confusions = CATEGORIES[label].confusions
            if confusions and draws[k, 1] < CONFUSION_RATE:
                label = confusions[int(draws[k, 2] * len(confusions)) % len(confusions)]
                score = 0.3 + 0.4 * draws[k, 3]
            else:
                score = min(1.0, 0.55 + 0.45 * draws[k, 3] - (0.1 if small else 0.0))
            kept.append(int(instance))
            labels.append(label)
            scores.append(round(float(max(0.3, score)), 3))

        lut = np.zeros(len(self._detectable), np.uint16)
        lut[kept] = np.arange(1, len(kept) + 1)
        clean = lut[view.instance_ids]
        out = clean.copy()
        # Boundary noise, large masks first so that small objects' dilations win over them.
        order = sorted(range(len(kept)), key=lambda k: -counts[kept[k]])
        slices = ndimage.find_objects(clean)
        for k in order:
            det = k + 1
            box = slices[k]
            if box is None:
                continue
            pad = 3
            ys = slice(max(0, box[0].start - pad), min(h, box[0].stop + pad))
            xs = slice(max(0, box[1].start - pad), min(w, box[1].stop + pad))
            mask = clean[ys, xs] == det
            radius = int(rng.integers(1, 3))
            region = out[ys, xs]
            erode = rng.random() < 0.5
            if self.profile == "bleed":
                radius, erode = radius + BLEED_EXTRA_PX, False
                grown = slice(max(0, ys.start - BLEED_EXTRA_PX), min(h, ys.stop + BLEED_EXTRA_PX))
                grown_x = slice(max(0, xs.start - BLEED_EXTRA_PX), min(w, xs.stop + BLEED_EXTRA_PX))
                ys, xs = grown, grown_x
                mask = clean[ys, xs] == det
                region = out[ys, xs]
            # Repaint the whole (eroded or grown) mask: a smaller object, processed later,
            # takes its pixels back from a larger neighbour's dilation.
            if erode:
                eroded = ndimage.binary_erosion(mask, iterations=radius)
                region[mask & ~eroded & (region == det)] = 0
                region[eroded] = det
            else:
                region[ndimage.binary_dilation(mask, iterations=radius)] = det

        instances = [
            {"id": k + 1, "label": labels[k], "score": scores[k]} for k in range(len(kept))
        ]
        spurious = self._spurious_blob(h, w, frame_index)
        if spurious is not None:
            blob, label, score = spurious
            det = len(kept) + 1
            out[blob] = det
            instances.append({"id": det, "label": label, "score": score})
        present = np.bincount(out.ravel(), minlength=len(instances) + 1)
        instances = [d for d in instances if present[d["id"]] > 0]
        sources = {d["id"]: kept[d["id"] - 1] if d["id"] <= len(kept) else 0 for d in instances}

        depth = view.depth_m
        z = depth.astype(np.float32)
        sigma = 0.0012 + 0.0019 * np.square(np.maximum(z - 0.4, 0.0))
        noisy = z + sigma * rng.standard_normal(z.shape, dtype=np.float32)
        noisy = np.where(z > 0, np.maximum(noisy, 0.0), 0.0).astype(np.float32)
        if self.profile == "bleed":
            noisy = self._flying_pixels(noisy, frame_index)
        return NoisyDetections(noisy, out, instances, sources)

    def _flying_pixels(self, depth_m: np.ndarray, frame_index: int) -> np.ndarray:
        """Depth smeared across its edges: pixels beside a jump over FLYING_EDGE_M take, with
        probability FLYING_RATE, a depth uniformly between the nearest and the farthest
        surface of their 3x3 neighbourhood (the mixed returns of a real depth sensor)."""
        rng = np.random.default_rng([self.seed, int(frame_index), 3])
        valid = depth_m > 0
        near = ndimage.minimum_filter(np.where(valid, depth_m, np.inf), size=3)
        far = ndimage.maximum_filter(depth_m, size=3)
        edge = valid & np.isfinite(near) & (far - near > FLYING_EDGE_M)
        flying = edge & (rng.random(depth_m.shape) < FLYING_RATE)
        mixed = near + rng.random(depth_m.shape, dtype=np.float32) * (far - near)
        return np.where(flying, mixed, depth_m).astype(np.float32)

    def _spurious_blob(self, h: int, w: int, frame_index: int):
        """(mask, label, score) of a false detection, or None; lives for a few frames."""
        block = frame_index // SPURIOUS_LIFETIME_FRAMES
        rng = np.random.default_rng([self.seed, block, 2])
        if rng.random() >= SPURIOUS_RATE * SPURIOUS_LIFETIME_FRAMES / 2:
            return None
        # Present on a random sub-run of the block's frames, drifting slightly.
        first = int(rng.integers(0, SPURIOUS_LIFETIME_FRAMES))
        offset = frame_index % SPURIOUS_LIFETIME_FRAMES
        if offset < first:
            return None
        cy, cx = rng.uniform(0.15, 0.85) * h, rng.uniform(0.15, 0.85) * w
        ry, rx = rng.uniform(0.04, 0.12) * h, rng.uniform(0.04, 0.12) * w
        drift = rng.normal(0, 0.01, 2) * (offset - first)
        cy, cx = cy + drift[0] * h, cx + drift[1] * w
        yy, xx = np.ogrid[:h, :w]
        mask = ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1.0
        label = self._labels[int(rng.integers(len(self._labels)))]
        return mask, label, round(float(rng.uniform(0.3, 0.55)), 3)
