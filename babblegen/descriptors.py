"""Behaviour descriptors: an image in, a packed bit code out, compared by Hamming distance.

Codes are uint64 arrays of shape ``(ceil(n_bits / 64),)``. Bits are packed most significant first, so a
code read as one big-endian integer equals the integer imagehash builds from its bit array; when ``n_bits``
is not a multiple of 64 the padding zeros go in front (the most significant end) of the first word. Hence
``to_hex(code, n_bits)`` equals ``str(imagehash_object)`` and padding never changes a Hamming distance.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "DESCRIPTORS",
    "ChangePHash",
    "Descriptor",
    "PHash",
    "describe_rollout",
    "from_hex",
    "make_descriptor",
    "n_words_for",
    "pack_bits",
    "to_hex",
    "unpack_bits",
]


@runtime_checkable
class Descriptor(Protocol):
    """Maps an ``(H, W, 3)`` uint8 image to a packed bit code of ``n_bits`` bits."""

    name: str
    n_bits: int

    def __call__(self, image: np.ndarray) -> np.ndarray: ...

    def config(self) -> dict[str, Any]: ...


def n_words_for(n_bits: int) -> int:
    """Number of uint64 words holding ``n_bits`` bits."""
    return (int(n_bits) + 63) // 64


def pack_bits(bits: np.ndarray) -> np.ndarray:
    """Pack a flat boolean array (most significant bit first) into uint64 words, zero padding in front."""
    b = np.asarray(bits, dtype=bool).ravel()
    n_words = n_words_for(b.size)
    padded = np.zeros(n_words * 64, dtype=bool)
    padded[padded.size - b.size :] = b
    return np.packbits(padded).view(">u8").astype(np.uint64)


def unpack_bits(words: np.ndarray, n_bits: int) -> np.ndarray:
    """Inverse of :func:`pack_bits`: the last ``n_bits`` bits of the code as a boolean array."""
    w = np.asarray(words, dtype=np.uint64).ravel()
    bits = np.unpackbits(w.astype(">u8").view(np.uint8)).astype(bool)
    return bits[bits.size - n_bits :]


def to_hex(words: np.ndarray, n_bits: int | None = None) -> str:
    """Lower-case hex of a code; with ``n_bits``, trimmed to ``ceil(n_bits / 4)`` digits like imagehash."""
    w = np.asarray(words, dtype=np.uint64).ravel()
    s = "".join(f"{int(x):016x}" for x in w)
    if n_bits is not None:
        width = (int(n_bits) + 3) // 4
        if width > len(s) or s[: len(s) - width].strip("0"):
            raise ValueError(f"code {s} does not fit in {n_bits} bits")
        s = s[len(s) - width :]
    return s


def from_hex(s: str, n_words: int) -> np.ndarray:
    """Parse a hex string (as written by :func:`to_hex` or imagehash) into ``n_words`` uint64 words."""
    value = int(s, 16)
    if value.bit_length() > 64 * n_words:
        raise ValueError(f"hex string {s!r} does not fit in {n_words} uint64 words")
    return np.frombuffer(value.to_bytes(8 * n_words, "big"), dtype=">u8").astype(np.uint64)


class PHash:
    """Perceptual hash (``imagehash.phash``) of an image, optionally of a crop of it.

    ``crop = (x0, y0, x1, y1)`` are fractions of the image width and height. The code has ``hash_size ** 2``
    bits (64 by default).
    """

    def __init__(
        self,
        hash_size: int = 8,
        crop: tuple[float, float, float, float] | None = None,
        highfreq_factor: int = 4,
        name: str = "phash",
    ) -> None:
        if int(hash_size) < 2:
            raise ValueError(f"hash_size must be >= 2, got {hash_size}")
        if int(highfreq_factor) < 1:
            raise ValueError(f"highfreq_factor must be >= 1, got {highfreq_factor}")
        if crop is not None:
            crop = tuple(float(c) for c in crop)  # type: ignore[assignment]
            if len(crop) != 4:
                raise ValueError(f"crop must be (x0, y0, x1, y1), got {crop}")
            x0, y0, x1, y1 = crop
            if not (0.0 <= x0 < x1 <= 1.0 and 0.0 <= y0 < y1 <= 1.0):
                raise ValueError(f"crop fractions must satisfy 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1: {crop}")
        self.name = name
        self.hash_size = int(hash_size)
        self.highfreq_factor = int(highfreq_factor)
        self.crop = crop
        self.n_bits = self.hash_size**2

    @property
    def n_words(self) -> int:
        """Number of uint64 words per code."""
        return n_words_for(self.n_bits)

    def pil_image(self, image: np.ndarray) -> Any:
        """The (cropped) PIL image that is hashed."""
        from PIL import Image

        img = np.asarray(image)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) uint8 image, got {img.shape} {img.dtype}")
        h, w = img.shape[:2]
        if self.crop is not None:
            x0, y0, x1, y1 = self.crop
            c0, c1 = int(round(x0 * w)), max(int(round(x1 * w)), int(round(x0 * w)) + 1)
            r0, r1 = int(round(y0 * h)), max(int(round(y1 * h)), int(round(y0 * h)) + 1)
            img = img[r0:r1, c0:c1]
        return Image.fromarray(np.ascontiguousarray(img))

    def __call__(self, image: np.ndarray) -> np.ndarray:
        import imagehash

        h = imagehash.phash(self.pil_image(image), hash_size=self.hash_size, highfreq_factor=self.highfreq_factor)
        return pack_bits(h.hash)

    def hex(self, code: np.ndarray) -> str:
        """Hex string of a code of this descriptor, identical to ``str(imagehash.phash(...))``."""
        return to_hex(code, self.n_bits)

    def config(self) -> dict[str, Any]:
        """Keyword arguments that rebuild this descriptor through :func:`make_descriptor`."""
        return {
            "name": self.name,
            "hash_size": self.hash_size,
            "crop": None if self.crop is None else list(self.crop),
            "highfreq_factor": self.highfreq_factor,
        }

    def __repr__(self) -> str:
        return f"PHash(hash_size={self.hash_size}, crop={self.crop}, highfreq_factor={self.highfreq_factor})"


class ChangePHash(PHash):
    """What the movement changed in the scene, from raw pixels: the pHash of the gated difference between the
    after and before images. A pixel counts as changed where some channel differs by ``threshold`` or more (of
    255); fewer than ``min_area`` (a fraction of the image) changed pixels is "nothing changed", one shared code
    (all zeros, about half the bits away from any hashed change), so flicker and sub-pixel settling earn no
    novelty. Otherwise the hash is of the changed pixels' magnitude (zero elsewhere): where the scene changed and
    by how much, not what it looked like. With varied starts the after image differs from episode to episode
    even when the arm touched nothing; this measures the arm's doing alone. Called with ``before`` too
    (`describe_rollout`)."""

    compares_before = True

    def __init__(
        self, hash_size: int = 16, threshold: int = 24, min_area: float = 0.001, name: str = "change16", **kw: Any
    ) -> None:
        super().__init__(hash_size=hash_size, name=name, **kw)
        if not 1 <= int(threshold) <= 255:
            raise ValueError(f"threshold must be in 1..255, got {threshold}")
        if not 0.0 <= float(min_area) < 1.0:
            raise ValueError(f"min_area must be a fraction in [0, 1), got {min_area}")
        self.threshold, self.min_area = int(threshold), float(min_area)

    def change(self, image: np.ndarray, before: np.ndarray) -> np.ndarray:
        """(H, W) uint8: each pixel's largest channel difference where it reaches the threshold, 0 elsewhere."""
        diff = np.abs(np.asarray(image, dtype=np.int16) - np.asarray(before, dtype=np.int16)).max(axis=2)
        return np.where(diff >= self.threshold, diff, 0).astype(np.uint8)

    def __call__(self, image: np.ndarray, before: np.ndarray | None = None) -> np.ndarray:
        if before is None:
            raise ValueError(f"descriptor {self.name!r} compares the after image with the before image: pass both")
        change = self.change(image, before)
        if np.count_nonzero(change) < self.min_area * change.size:
            return np.zeros(self.n_words, dtype=np.uint64)
        return super().__call__(np.repeat(change[..., None], 3, axis=2))

    def config(self) -> dict[str, Any]:
        return {**super().config(), "threshold": self.threshold, "min_area": self.min_area}

    def __repr__(self) -> str:
        return f"ChangePHash(hash_size={self.hash_size}, threshold={self.threshold}, min_area={self.min_area})"


def describe_rollout(descriptor: Descriptor, rollout: Any) -> np.ndarray:
    """A rollout's behaviour code: the descriptor of its after image (and of its before image too, for a
    descriptor that compares them)."""
    if getattr(descriptor, "compares_before", False):
        return descriptor(rollout.after_image, rollout.before_image)  # type: ignore[call-arg]
    return descriptor(rollout.after_image)


# The built-in tabletop's head camera sees the wall and the table's front face above and below the table top;
# this crop keeps the table top, where every outcome happens (fractions of width and height).
TABLE_CROP = (0.0, 0.25, 1.0, 0.88)

DESCRIPTORS: dict[str, Callable[..., Descriptor]] = {
    "phash": lambda **kw: PHash(**{"name": "phash", **kw}),
    "phash16": lambda **kw: PHash(**{"hash_size": 16, "name": "phash16", **kw}),
    "phash16_table": lambda **kw: PHash(**{"hash_size": 16, "crop": TABLE_CROP, "name": "phash16_table", **kw}),
    "change16": lambda **kw: ChangePHash(**{"name": "change16", **kw}),
}


def make_descriptor(name: str, **kwargs: Any) -> Descriptor:
    """Build a registered descriptor by name; ``make_descriptor(**d.config())`` rebuilds ``d``."""
    try:
        factory = DESCRIPTORS[name]
    except KeyError:
        raise ValueError(f"unknown descriptor {name!r}; known: {sorted(DESCRIPTORS)}") from None
    if kwargs.get("crop") is not None:
        kwargs["crop"] = tuple(kwargs["crop"])
    return factory(**kwargs)
