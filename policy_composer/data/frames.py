"""Decode a recorded dataset into memory for training: camera frames at a model's image size plus labels.

The datasets here are thousands of frames, so decoding once and training from RAM costs only the network
per epoch, not video decoding. Every model of the project (the CNN policy, the VAE, the dynamics models, the
goal scorers) loads its data through `load_frames`, so the checks of `open_dataset` guard all of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
import torch.nn.functional as F
from tqdm import tqdm

from policy_composer.data.features import DatasetError, image_key
from policy_composer.data.verify import open_dataset

LABELS = ("observation.state", "observation.environment_state", "action", "progress", "stage", "gear_offset",
          "predicates", "controller", "episode_index", "frame_index")


def to_model_image(rgb: torch.Tensor, size: int, window: tuple[float, float, float] | None = None) -> torch.Tensor:
    """(B, H, W, 3) uint8 or (B, 3, H, W) float in [0, 1] -> (B, 3, size, size) float in [0, 1], of the square
    `window` (top, left, side as fractions of the image) if given."""
    if rgb.dtype == torch.uint8:
        rgb = rgb.permute(0, 3, 1, 2).float() / 255.0
    if window is not None:
        h, w = rgb.shape[-2:]
        top, left, side = round(window[0] * h), round(window[1] * w), round(window[2] * h)
        rgb = rgb[..., top:top + side, left:left + side]
    if rgb.shape[-1] != size:
        rgb = F.interpolate(rgb, size=(size, size), mode="bilinear", antialias=True, align_corners=False)
    return rgb.clamp(0, 1)


def random_shift(images: torch.Tensor, shift: int, generator: torch.Generator) -> torch.Tensor:
    """Translate each image by up to `shift` pixels, padding with its border (DrQ's augmentation)."""
    if shift <= 0:
        return images
    n, _, h, w = images.shape
    padded = F.pad(images, (shift,) * 4, mode="replicate")
    dx, dy = torch.randint(0, 2 * shift + 1, (2, n), generator=generator)
    return torch.stack([padded[i, :, dy[i]:dy[i] + h, dx[i]:dx[i] + w] for i in range(n)])


def load_frames(root: str | Path, cameras: tuple[str, ...], size: int, episodes: list[int] | None = None,
                required: dict | None = None, progress: bool = True,
                window: tuple[float, float, float] | None = None) -> dict[str, torch.Tensor]:
    """Every frame of `episodes` (default: all): one uint8 (N, 3, size, size) tensor per camera (of its `window`,
    see to_model_image) under its image key, and each label of LABELS the dataset has, flattened to (N,) where it
    is a scalar."""
    keys = [image_key(c) for c in cameras]
    ds = open_dataset(root, required={**{k: None for k in keys}, **(required or {})}, episodes=episodes)
    loader = torch.utils.data.DataLoader(ds, batch_size=64, shuffle=False, num_workers=0)
    parts: dict[str, list[torch.Tensor]] = {}
    for batch in tqdm(loader, desc=f"decoding {Path(root).name} ({', '.join(cameras)})", unit="batch",
                      disable=not progress):
        for k in keys:
            parts.setdefault(k, []).append((to_model_image(batch[k], size, window) * 255).round().to(torch.uint8))
        for k in LABELS:
            if k in batch:
                v = batch[k]
                parts.setdefault(k, []).append(v.reshape(len(v)) if v.dim() == 2 and v.shape[1] == 1 else v)
    return {k: torch.cat(v) for k, v in parts.items()}


def check_distinct(roots: Sequence[str | Path]) -> None:
    """Refuse a dataset listed twice: its frames would weigh twice in the training, silently."""
    seen: dict[Path, str | Path] = {}
    for root in roots:
        same = seen.setdefault(Path(root).resolve(), root)
        if same is not root:
            raise DatasetError(f"--dataset lists {root} twice{f' (as {same})' if str(same) != str(root) else ''}: "
                               "its frames would count twice; list each dataset once")


def episode_bounds(episode_index: torch.Tensor) -> list[tuple[int, int]]:
    """[(start, end)) row ranges of each episode in a frame table sorted by episode."""
    change = (episode_index[1:] != episode_index[:-1]).nonzero().flatten() + 1
    edges = [0, *change.tolist(), len(episode_index)]
    return list(zip(edges[:-1], edges[1:]))
