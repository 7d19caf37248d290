"""A training run's settings (:class:`TrainConfig`): what they may be, what a resumed run
may change, and the equivalent ``harborsight train`` command line. Every checkpoint
keeps them as a plain dict."""

from __future__ import annotations

import dataclasses
import math
import shlex
from dataclasses import dataclass

from harborsight.errors import InputError
from harborsight.perception.classes import NUM_CLASSES
from harborsight.perception.networks import NETWORKS, create_network, layer_groups

#: Weights of the auxiliary (deep-supervision) losses per network, as their references train:
#: BiSeNetV2 1.0 on each of its 4 heads (CoinCheung/BiSeNet), DDRNet 0.4 on its one head
#: (ydhongHIT/DDRNet), FC-HarDNet none.
DEFAULT_AUX_WEIGHTS: dict[str, tuple[float, ...]] = {
    "bisenetv2": (1.0, 1.0, 1.0, 1.0),
    "ddrnet23_slim": (0.4,),
    "ddrnet23": (0.4,),
    "fchardnet70": (),
}

#: Config fields a resumed run may change; any other difference is refused.
RESUMABLE_CHANGES = frozenset({"out_dir", "iterations", "val_every", "checkpoint_every",
                               "num_workers", "threads", "device"})

#: what a distillation teacher can see (TrainConfig.distill_view)
DISTILL_VIEWS = ("augmented", "clean")


@dataclass
class TrainConfig:
    """Everything that defines a training run (saved in every checkpoint)."""

    model: str
    data_dirs: list[str]
    out_dir: str
    iterations: int = 10000
    batch_size: int = 8
    lr: float = 0.01
    momentum: float = 0.9
    weight_decay: float = 5e-4
    poly_power: float = 0.9
    warmup_iterations: int = 0                         # W: linear LR warm-up (0: none)
    warmup_ratio: float = 0.1                          # r: LR factor at iteration 0
    crop_hw: tuple[int, int] = (360, 360)
    aux_weights: tuple[float, ...] | None = None      # None: DEFAULT_AUX_WEIGHTS[model]
    bootstrap_start_iteration: int = 1000
    bootstrap_end_iteration: int = 9000
    bootstrap_end_fraction: float = 0.2
    small_object_weight: float = 1.0                   # w_max of the small-object weights (1: off)
    small_object_area_px: float = 1000.0               # A_ref: objects this large or larger keep 1
    augment: bool = True                               # False: random crop only
    colour_jitter: float = 0.25                        # brightness, contrast, saturation: x in [1-j, 1+j]
    haze: float = 0.0                                  # probability of the haze augmentation
    train_split: str = "train"
    val_split: str = "val"
    val_every: int = 1000                              # 0: no validation (and no best.pt)
    checkpoint_every: int = 500
    seed: int = 0
    device: str = "auto"                               # auto: cuda if available, else cpu
    amp: bool = True                                   # fp16 autocast, CUDA only
    num_workers: int | None = None                     # None: 0 on CPU, min(8, cores-1) on CUDA
    threads: int | None = None                         # torch CPU threads (None: torch's default)
    init_from: str | None = None                       # checkpoint whose weights start the run
    data_weights: list[float] | None = None            # sampling weight per data_dirs entry
    val_dirs: list[str] | None = None                  # validation datasets (None: data_dirs)
    fit_large_hw: tuple[int, int] | None = None        # stretch larger frames to this (H, W)
    freeze_batchnorm: bool = False                     # BatchNorm running statistics kept
    freeze_layers: tuple[str, ...] | None = None       # network layer groups not trained
    distill: float = 0.0                               # λ of the distillation loss (0: off)
    distill_temperature: float = 2.0                   # T of the distillation loss
    distill_view: str = "augmented"                    # what the teacher sees: augmented, clean
    copy_paste: list[float] | None = None              # per data_dirs entry: P(paste vessels)

    def __post_init__(self) -> None:
        self.data_dirs = [str(d) for d in self.data_dirs]
        self.out_dir = str(self.out_dir)
        self.init_from = None if self.init_from is None else str(self.init_from)
        if self.data_weights is not None:
            self.data_weights = [float(w) for w in self.data_weights]
        if self.val_dirs is not None:
            self.val_dirs = [str(d) for d in self.val_dirs]
        if self.copy_paste is not None:
            self.copy_paste = [float(p) for p in self.copy_paste]
        self.crop_hw = (int(self.crop_hw[0]), int(self.crop_hw[1]))
        if self.fit_large_hw is not None:
            self.fit_large_hw = (int(self.fit_large_hw[0]), int(self.fit_large_hw[1]))
        if self.aux_weights is not None:
            self.aux_weights = tuple(float(w) for w in self.aux_weights)
        if self.freeze_layers is not None:
            self.freeze_layers = tuple(str(g) for g in self.freeze_layers)
        self.validate()

    def validate(self) -> None:
        """Raise :class:`InputError` naming the field for settings that cannot train."""
        def bad(name: str, message: str) -> InputError:
            return InputError(None, name, message)

        if self.model not in NETWORKS:
            raise bad("model", f"unknown network {self.model!r}; choose from {sorted(NETWORKS)}")
        if not self.data_dirs:
            raise bad("data_dirs", "give at least one dataset folder")
        if self.data_weights is not None:
            if len(self.data_weights) != len(self.data_dirs):
                raise bad("data_weights", f"{len(self.data_weights)} weight(s) for "
                          f"{len(self.data_dirs)} dataset folder(s)")
            if min(self.data_weights) < 0 or not sum(self.data_weights) > 0:
                raise bad("data_weights", f"must be >= 0 with a positive sum, got {self.data_weights}")
        if self.copy_paste is not None:
            if len(self.copy_paste) != len(self.data_dirs):
                raise bad("copy_paste", f"{len(self.copy_paste)} probabilit(ies) for "
                          f"{len(self.data_dirs)} dataset folder(s)")
            if not all(0.0 <= p <= 1.0 for p in self.copy_paste):
                raise bad("copy_paste", f"must be probabilities in [0, 1], got {self.copy_paste}")
        if self.val_dirs is not None and not self.val_dirs:
            raise bad("val_dirs", "give at least one validation dataset folder, or none at all")
        if self.batch_size < 2:
            raise bad("batch_size", f"must be at least 2, got {self.batch_size}: the networks' "
                      "BatchNorm layers after global pooling (1x1 maps) cannot normalise over a "
                      "single image in training mode")
        for name in ("iterations", "checkpoint_every"):
            if getattr(self, name) < 1:
                raise bad(name, f"must be at least 1, got {getattr(self, name)}")
        for name in ("val_every", "num_workers", "warmup_iterations"):
            if (getattr(self, name) or 0) < 0:
                raise bad(name, f"must be >= 0, got {getattr(self, name)}")
        if self.threads is not None and self.threads < 1:
            raise bad("threads", f"must be at least 1, got {self.threads}")
        if not 0.0 < self.warmup_ratio <= 1.0:
            raise bad("warmup_ratio", f"must be in (0, 1], got {self.warmup_ratio}")
        if min(self.crop_hw) < 1:
            raise bad("crop_hw", f"must be positive, got {self.crop_hw}")
        if self.fit_large_hw is not None and min(self.fit_large_hw) < 1:
            raise bad("fit_large_hw", f"must be positive, got {self.fit_large_hw}")
        if self.lr <= 0:
            raise bad("lr", f"must be positive, got {self.lr}")
        if not 0.0 < self.bootstrap_end_fraction <= 1.0:
            raise bad("bootstrap_end_fraction", "must be in (0, 1]")
        if self.small_object_weight < 1.0:
            raise bad("small_object_weight", f"must be at least 1 (1: off), got "
                      f"{self.small_object_weight}")
        if not 0.0 <= self.colour_jitter < 1.0:
            raise bad("colour_jitter", f"must be in [0, 1), got {self.colour_jitter}")
        if not 0.0 <= self.haze <= 1.0:
            raise bad("haze", f"must be a probability in [0, 1], got {self.haze}")
        if not (self.distill >= 0.0 and math.isfinite(self.distill)):
            raise bad("distill", f"must be a weight >= 0, got {self.distill}")
        if self.distill > 0 and not self.init_from:
            raise bad("distill", "distils from the network the run starts from: give "
                      "--init-from too")
        if not (self.distill_temperature > 0 and math.isfinite(self.distill_temperature)):
            raise bad("distill_temperature", f"must be positive, got {self.distill_temperature}")
        if self.distill_view not in DISTILL_VIEWS:
            raise bad("distill_view", f"must be one of {', '.join(DISTILL_VIEWS)}, "
                      f"got {self.distill_view!r}")
        if self.distill_view != "augmented" and self.distill <= 0:
            raise bad("distill_view", "is what the teacher of --distill sees: give --distill")
        if self.small_object_area_px <= 0:
            raise bad("small_object_area_px", f"must be positive, got {self.small_object_area_px}")
        if self.freeze_layers is not None:
            groups = layer_groups(create_network(self.model, NUM_CLASSES, aux_heads=True))
            unknown = [g for g in self.freeze_layers if g not in groups]
            if not self.freeze_layers or unknown:
                raise bad("freeze_layers", f"unknown layer group(s) {', '.join(unknown) or '(none given)'}; "
                          f"{self.model} has: {', '.join(groups)}")
            if "aux_heads" in self.freeze_layers:
                raise bad("freeze_layers", "aux_heads are training-only heads whose loss "
                          "trains the network: freeze network layers, or drop them with "
                          "--aux-weight 0")
            if set(self.freeze_layers) >= set(groups) - {"aux_heads"}:
                raise bad("freeze_layers", "would freeze the whole network: nothing left to train")
        expected = len(DEFAULT_AUX_WEIGHTS[self.model])
        if self.aux_weights is not None and len(self.aux_weights) != expected:
            raise bad("aux_weights", f"{self.model} has {expected} auxiliary head(s), got "
                      f"{len(self.aux_weights)} weight(s)")
        if self.device not in ("auto", "cpu") and not self.device.startswith("cuda"):
            raise bad("device", f"expected auto, cpu or cuda[:N], got {self.device!r}")

    @property
    def effective_aux_weights(self) -> tuple[float, ...]:
        return self.aux_weights if self.aux_weights is not None else DEFAULT_AUX_WEIGHTS[self.model]

    def to_dict(self) -> dict:
        data = dataclasses.asdict(self)
        data["crop_hw"] = list(self.crop_hw)
        data["fit_large_hw"] = None if self.fit_large_hw is None else list(self.fit_large_hw)
        data["aux_weights"] = None if self.aux_weights is None else list(self.aux_weights)
        data["freeze_layers"] = None if self.freeze_layers is None else list(self.freeze_layers)
        return data

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in data.items() if k in known})

    def command_line(self) -> str:
        """An equivalent ``harborsight train`` command (options that differ from defaults)."""
        parts = ["harborsight", "train", "--model", self.model]
        for k, d in enumerate(self.data_dirs):
            parts += ["--data", d if self.data_weights is None else f"{d}:{self.data_weights[k]:g}"]
        for d in self.val_dirs or []:
            parts += ["--val-data", d]
        parts += ["--out", self.out_dir]
        defaults = TrainConfig.__dataclass_fields__
        for name, option in _CLI_OPTIONS.items():
            value = getattr(self, name)
            if value == defaults[name].default:
                continue
            if isinstance(value, bool):
                parts.append(f"--{option}" if value else f"--no-{option}")
            elif name in ("crop_hw", "fit_large_hw"):
                parts += [f"--{option}", f"{value[0]}x{value[1]}"]
            elif name == "aux_weights":
                for w in value:
                    parts += ["--aux-weight", f"{w:g}"]
            elif name == "freeze_layers":
                parts += [f"--{option}", ",".join(value)]
            elif name == "copy_paste":
                parts += [x for d, p in zip(self.data_dirs, value, strict=True) if p > 0
                          for x in (f"--{option}", f"{d}:{p:g}")]
            else:
                parts += [f"--{option}", str(value)]
        return shlex.join(parts)


#: TrainConfig field -> CLI option name (harborsight.cli.train).
_CLI_OPTIONS = {
    "iterations": "iterations", "batch_size": "batch-size", "lr": "lr", "momentum": "momentum",
    "weight_decay": "weight-decay", "poly_power": "poly-power",
    "warmup_iterations": "warmup", "warmup_ratio": "warmup-ratio", "crop_hw": "crop",
    "aux_weights": "aux-weight", "bootstrap_start_iteration": "bootstrap-start",
    "bootstrap_end_iteration": "bootstrap-end", "bootstrap_end_fraction": "bootstrap-fraction",
    "small_object_weight": "small-object-weight", "small_object_area_px": "small-object-area",
    "augment": "augment", "colour_jitter": "colour-jitter", "haze": "haze", "train_split": "train-split",
    "val_split": "val-split",
    "val_every": "val-every", "checkpoint_every": "checkpoint-every", "seed": "seed",
    "device": "device", "amp": "amp", "num_workers": "workers", "threads": "threads",
    "init_from": "init-from", "fit_large_hw": "fit-large", "freeze_batchnorm": "freeze-batchnorm",
    "freeze_layers": "freeze-layers",
    "distill": "distill", "distill_temperature": "distill-temperature",
    "distill_view": "distill-view", "copy_paste": "copy-paste",
}
