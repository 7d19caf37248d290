"""Training augmentation in numpy + OpenCV, seeded by a :class:`numpy.random.Generator`.

Order of operations on an image ``I`` (uint8 BGR, H x W) and its labels ``L`` (uint8):

1. geometric, applied to both (labels with nearest-neighbour so class ids stay exact):
   horizontal mirror ``x -> W-1-x`` and vertical flip ``y -> H-1-y`` (the paper's "mirrored
   and flipped images"); random scale ``s ~ U(scale_min, scale_max)``; a random crop of
   ``crop_hw`` after padding the image with zeros and the labels with 255 (ignore) where it is
   smaller than the crop;
2. photometric, on the image only, each with its own probability: haze (the atmospheric
   scattering model ``I·t + A·(1-t)``, transmission ``t`` and a bright, near-grey airlight
   ``A``: lifted blacks, dimmed whites and paler colours, as in hazy orthophotos), colour
   jitter (brightness
   ``I·b``, contrast ``(I-μ)·c+μ`` with ``μ`` the mean grey, saturation ``g+(I-g)·s`` with
   ``g`` the per-pixel grey, hue shift ``h+Δh`` in HSV), Gaussian blur (σ in pixels),
   additive Gaussian noise (σ in grey levels), JPEG re-encoding (quality 0-100).

:func:`augment_weighted` carries a per-pixel loss weight map through step 1 with the labels.
Both can also return the *clean view*: the image after step 1 only, pixel for pixel where the
augmented image is but without the photometric changes (what a distillation teacher sees).

Every random number comes from the generator passed in, so a given seed gives the same
sample whatever the worker process that draws it.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from harborsight.perception.classes import IGNORE


@dataclass(frozen=True)
class AugmentConfig:
    """Probabilities and ranges of every augmentation; ``crop_hw`` (rows, cols) or ``None``."""

    crop_hw: tuple[int, int] | None = (360, 360)
    p_mirror: float = 0.5
    p_flip: float = 0.5
    p_scale: float = 1.0
    scale_min: float = 0.75
    scale_max: float = 1.5
    p_haze: float = 0.0             # 0: no haze, and no random number drawn for it
    haze_transmission: tuple[float, float] = (0.45, 0.95)
    haze_airlight_grey: tuple[float, float] = (140.0, 235.0)
    haze_tint_grey: float = 15.0    # per-channel offset of the airlight in [-tint, tint]
    p_colour: float = 0.8
    brightness: float = 0.25        # factor in [1-b, 1+b]
    contrast: float = 0.25          # factor in [1-c, 1+c]
    saturation: float = 0.25        # factor in [1-s, 1+s]
    hue_deg: float = 8.0            # shift in [-h, h] degrees
    p_blur: float = 0.2
    blur_sigma_px: tuple[float, float] = (0.3, 1.5)
    p_noise: float = 0.2
    noise_sigma_grey: tuple[float, float] = (2.0, 8.0)
    p_jpeg: float = 0.2
    jpeg_quality: tuple[int, int] = (40, 90)

    @classmethod
    def geometric_only(cls, crop_hw: tuple[int, int] | None) -> AugmentConfig:
        """Only the fixed-size crop (at scale 1): what validation-like training needs."""
        return cls(crop_hw=crop_hw, p_mirror=0.0, p_flip=0.0, p_scale=0.0, p_haze=0.0,
                   p_colour=0.0, p_blur=0.0, p_noise=0.0, p_jpeg=0.0)


def mirror(image: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left-right mirror of both: column x becomes column W-1-x."""
    return image[:, ::-1].copy(), labels[:, ::-1].copy()


def flip(image: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Top-bottom flip of both: row y becomes row H-1-y."""
    return image[::-1].copy(), labels[::-1].copy()


def rescale(image: np.ndarray, labels: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Resize both by ``scale`` (image bilinear, labels nearest-neighbour)."""
    image, (labels,) = _rescale(image, [labels], scale)
    return image, labels


def random_crop(image: np.ndarray, labels: np.ndarray, crop_hw: tuple[int, int],
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Pad to at least ``crop_hw`` (image 0, labels 255, bottom/right) then crop at a random
    offset ``(y0, x0)`` with ``y0 ~ U{0..H-h}``, ``x0 ~ U{0..W-w}``."""
    image, (labels,) = _random_crop(image, [labels], [IGNORE], crop_hw, rng)
    return image, labels


def _rescale(image: np.ndarray, maps: list[np.ndarray], scale: float
             ) -> tuple[np.ndarray, list[np.ndarray]]:
    h, w = maps[0].shape
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return (cv2.resize(image, size, interpolation=cv2.INTER_LINEAR),
            [cv2.resize(m, size, interpolation=cv2.INTER_NEAREST_EXACT) for m in maps])


def _random_crop(image: np.ndarray, maps: list[np.ndarray], pad_values: list[float],
                 crop_hw: tuple[int, int], rng: np.random.Generator
                 ) -> tuple[np.ndarray, list[np.ndarray]]:
    """:func:`random_crop` of the image and of every per-pixel map, at one offset."""
    ch, cw = crop_hw
    h, w = maps[0].shape
    pad_h, pad_w = max(ch - h, 0), max(cw - w, 0)
    if pad_h or pad_w:
        image = cv2.copyMakeBorder(image, 0, pad_h, 0, pad_w, cv2.BORDER_CONSTANT, value=(0, 0, 0))
        maps = [cv2.copyMakeBorder(m, 0, pad_h, 0, pad_w, cv2.BORDER_CONSTANT, value=v)
                for m, v in zip(maps, pad_values, strict=True)]
        h, w = maps[0].shape
    y0 = int(rng.integers(0, h - ch + 1))
    x0 = int(rng.integers(0, w - cw + 1))
    return (np.ascontiguousarray(image[y0:y0 + ch, x0:x0 + cw]),
            [np.ascontiguousarray(m[y0:y0 + ch, x0:x0 + cw]) for m in maps])


def haze(image: np.ndarray, transmission: float, airlight_bgr) -> np.ndarray:
    """Koschmieder's model of light scattered by the air between scene and camera:
    ``I' = I·t + A·(1 - t)`` per channel, ``t`` the transmission (1: clear air) and ``A``
    the airlight colour (BGR grey levels). Rounded and clipped to 0..255."""
    airlight = np.asarray(airlight_bgr, np.float32) * np.float32(1.0 - transmission)
    hazy = image.astype(np.float32) * np.float32(transmission) + airlight
    return np.clip(np.rint(hazy), 0, 255).astype(np.uint8)


def colour_jitter(image: np.ndarray, rng: np.random.Generator, brightness: float,
                  contrast: float, saturation: float, hue_deg: float) -> np.ndarray:
    """Brightness, contrast, saturation, hue (module docstring), in that order."""
    x = image.astype(np.float32)
    x *= rng.uniform(1.0 - brightness, 1.0 + brightness)
    grey = cv2.cvtColor(np.clip(x, 0, 255), cv2.COLOR_BGR2GRAY)
    c = rng.uniform(1.0 - contrast, 1.0 + contrast)
    x = (x - grey.mean()) * c + grey.mean()
    x = np.clip(x, 0, 255)
    grey = cv2.cvtColor(x, cv2.COLOR_BGR2GRAY)[..., None]
    x = grey + (x - grey) * rng.uniform(1.0 - saturation, 1.0 + saturation)
    x = np.clip(x, 0, 255) / 255.0
    hsv = cv2.cvtColor(x, cv2.COLOR_BGR2HSV)  # float32: H in degrees [0, 360)
    hsv[..., 0] = np.mod(hsv[..., 0] + rng.uniform(-hue_deg, hue_deg), 360.0)
    x = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR) * 255.0
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Gaussian blur with a kernel of ``2·ceil(3σ)+1`` pixels."""
    k = 2 * int(np.ceil(3.0 * sigma_px)) + 1
    return cv2.GaussianBlur(image, (k, k), sigma_px)


def gaussian_noise(image: np.ndarray, rng: np.random.Generator, sigma_grey: float) -> np.ndarray:
    """``I + N(0, σ²)`` per pixel and channel, rounded and clipped to 0..255."""
    noisy = image.astype(np.float32) + rng.normal(0.0, sigma_grey, image.shape).astype(np.float32)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def jpeg_reencode(image: np.ndarray, quality: int) -> np.ndarray:
    """Encode as JPEG at ``quality`` and decode again (block and ringing artefacts)."""
    ok, buffer = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV always encodes a uint8 BGR image
        raise RuntimeError("JPEG encoding failed")
    return cv2.imdecode(buffer, cv2.IMREAD_COLOR)


def augment(image: np.ndarray, labels: np.ndarray, rng: np.random.Generator,
            config: AugmentConfig, clean_view: bool = False):
    """One augmented (image, labels) pair; see the module docstring for the order. With
    ``clean_view``: (image, labels, clean image), the clean image that of step 1 alone.

    The seven on/off decisions are drawn first, one number each, so changing one probability
    does not change which of the other operations fire. Haze, when its probability is not 0,
    is drawn before them; at 0 nothing is drawn for it, so every other draw is as it was
    before haze existed.
    """
    image, (labels,), clean = _augment(image, [labels], [IGNORE], rng, config)
    return (image, labels, np.ascontiguousarray(clean)) if clean_view else (image, labels)


def augment_weighted(image: np.ndarray, labels: np.ndarray, weights: np.ndarray,
                     rng: np.random.Generator, config: AugmentConfig, clean_view: bool = False):
    """:func:`augment` with a per-pixel loss weight map carried through the same geometric
    operations (nearest-neighbour, padded with 0): (image, labels, weights[, clean image]).
    For a given ``rng`` state the image and labels are exactly those :func:`augment` returns."""
    if weights.shape != labels.shape:
        raise ValueError(f"weights {weights.shape} and labels {labels.shape} differ in size")
    image, (labels, weights), clean = _augment(image, [labels, weights], [IGNORE, 0.0], rng,
                                               config)
    if clean_view:
        return image, labels, weights, np.ascontiguousarray(clean)
    return image, labels, weights


def _augment(image: np.ndarray, maps: list[np.ndarray], pad_values: list[float],
             rng: np.random.Generator, config: AugmentConfig
             ) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """The augmentation of :func:`augment`; ``maps[0]`` are the labels, every map follows
    the geometric operations. Returns (image, maps, the image after the geometric step)."""
    if image.shape[:2] != maps[0].shape:
        raise ValueError(f"image {image.shape[:2]} and labels {maps[0].shape} differ in size")
    hazing = None
    if config.p_haze > 0.0 and rng.random() < config.p_haze:
        hazing = (rng.uniform(*config.haze_transmission),
                  rng.uniform(*config.haze_airlight_grey)
                  + rng.uniform(-config.haze_tint_grey, config.haze_tint_grey, 3))
    fire = rng.random(7)
    if fire[0] < config.p_mirror:
        image, maps = image[:, ::-1].copy(), [m[:, ::-1].copy() for m in maps]
    if fire[1] < config.p_flip:
        image, maps = image[::-1].copy(), [m[::-1].copy() for m in maps]
    scale = rng.uniform(config.scale_min, config.scale_max)
    if fire[2] < config.p_scale and scale != 1.0:
        image, maps = _rescale(image, maps, scale)
    if config.crop_hw is not None:
        image, maps = _random_crop(image, maps, pad_values, config.crop_hw, rng)
    clean = image           # the photometric steps below make new arrays: no copy needed
    if hazing is not None:
        image = haze(image, *hazing)
    if fire[3] < config.p_colour:
        image = colour_jitter(image, rng, config.brightness, config.contrast, config.saturation,
                              config.hue_deg)
    if fire[4] < config.p_blur:
        image = gaussian_blur(image, rng.uniform(*config.blur_sigma_px))
    if fire[5] < config.p_noise:
        image = gaussian_noise(image, rng, rng.uniform(*config.noise_sigma_grey))
    if fire[6] < config.p_jpeg:
        image = jpeg_reencode(image, int(rng.integers(config.jpeg_quality[0],
                                                      config.jpeg_quality[1] + 1)))
    return np.ascontiguousarray(image), [np.ascontiguousarray(m) for m in maps], clean
