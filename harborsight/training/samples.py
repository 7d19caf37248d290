"""The stream of training samples: sample ``n`` is a pure function of ``(seed, n)``
(the frame drawn, vessels pasted, the augmentation; :mod:`harborsight.training.loop`'s
docstring gives the rules), and the DataLoader processes that draw them."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import torch

from harborsight.errors import InputError
from harborsight.training.augment import AugmentConfig, augment, augment_weighted
from harborsight.training.copy_paste import VesselBank, paste_vessels
from harborsight.training.dataset import SegmentationFrames, small_object_weights


class TrainingSamples(torch.utils.data.Dataset):
    """Item ``n`` is the run's ``n``-th augmented sample (module docstring), whatever the
    worker or the order of the requests: ``(image, labels, pixel weights)``, and with
    ``clean_view`` the image before its photometric augmentation last."""

    def __init__(self, frames: SegmentationFrames, seed: int, augmentation: AugmentConfig,
                 small_object_weight: float = 1.0, small_object_area_px: float = 1000.0,
                 data_weights: list[float] | None = None, clean_view: bool = False,
                 copy_paste: list[float] | None = None) -> None:
        self.frames = frames
        self.clean_view = clean_view
        self.seed = seed
        self.groups: list[np.ndarray] = []
        self.group_p = np.zeros(0)
        if data_weights is not None:
            folder = {Path(d): k for k, d in enumerate(frames.data_dirs)}
            of_frame = np.array([folder[r.dataset_dir] for r in frames.records])
            kept = [k for k, w in enumerate(data_weights) if w > 0 and (of_frame == k).any()]
            if not kept:
                raise InputError(None, "data_weights", "no training frame in a dataset of "
                                 "positive weight")
            self.groups = [np.flatnonzero(of_frame == k) for k in kept]
            weights = np.array([data_weights[k] for k in kept], float)
            self.group_p = weights / weights.sum()
        self.augmentation = augmentation
        self.small_object_weight = small_object_weight
        self.small_object_area_px = small_object_area_px
        self._perm_epoch = -1
        self._perm = np.arange(0)
        self.paste_p = np.zeros(len(frames))     # P(paste vessels) of each frame's folder
        self._banks: dict[Path, VesselBank] = {}
        if copy_paste is not None:
            by_folder = {Path(d): p for d, p in zip(frames.data_dirs, copy_paste, strict=True)}
            self.paste_p = np.array([by_folder.get(r.dataset_dir, 0.0) for r in frames.records])

    def vessel_bank(self, folder: Path) -> VesselBank:
        """The vessels of ``folder``'s training frames (cut once, on first use)."""
        if folder not in self._banks:
            indices = [i for i, r in enumerate(self.frames.records) if r.dataset_dir == folder]
            self._banks[folder] = VesselBank.from_frames(self.frames, indices)
        return self._banks[folder]

    def frame_index(self, n: int) -> int:
        if self.groups:
            rng = np.random.default_rng([self.seed, 2, n])
            group = self.groups[int(rng.choice(len(self.groups), p=self.group_p))]
            return int(group[rng.integers(len(group))])
        size = len(self.frames)
        epoch = n // size
        if epoch != self._perm_epoch:
            self._perm = np.random.default_rng([self.seed, epoch]).permutation(size)
            self._perm_epoch = epoch
        return int(self._perm[n % size])

    def __len__(self) -> int:  # the stream is unbounded; the sampler decides what is drawn
        return 2**62

    def __getitem__(self, n: int) -> tuple[np.ndarray, ...]:
        index = self.frame_index(n)
        image, labels = self.frames[index]
        if self.paste_p[index] > 0:
            paste_rng = np.random.default_rng([self.seed, 3, n])
            if paste_rng.random() < self.paste_p[index]:
                bank = self.vessel_bank(self.frames.records[index].dataset_dir)
                image, labels, _ = paste_vessels(image, labels, bank, paste_rng, frame=index)
        rng = np.random.default_rng([self.seed, 1, n])
        if self.small_object_weight <= 1.0:
            image, labels, *clean = augment(image, labels, rng, self.augmentation,
                                            clean_view=self.clean_view)
            return (image, labels, np.ones(labels.shape, np.float32), *clean)
        weights = small_object_weights(self.frames.instances(index, labels.shape), labels,
                                       self.small_object_area_px, self.small_object_weight)
        return augment_weighted(image, labels, weights, rng, self.augmentation,
                                clean_view=self.clean_view)


def data_workers(requested: int | None, device: torch.device) -> int:
    """DataLoader processes: as requested, else none on the CPU (the training step already
    uses every core, and workers would compete with it) and ``min(8, cores - 1)`` with CUDA."""
    if requested is not None:
        return requested
    return 0 if device.type == "cpu" else max(0, min(8, (os.cpu_count() or 1) - 1))


def worker_init(_: int) -> None:
    cv2.setNumThreads(1)
