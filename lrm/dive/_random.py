"""Deterministic randomness for a simulated dive.

Two needs: random *draws* made once per module or per ship (periods, phases,
leans), and sensor *noise* that must be the same for sample ``k`` whether it
is asked for alone, in a batch, or from another thread. The first uses a
seeded `numpy.random.Generator`; the second a counter-based hash (SplitMix64
of seed, sample index and channel, then Box-Muller), which needs no state.
"""

from __future__ import annotations

import zlib

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def stable_key(*parts: int | str) -> int:
    """A 32-bit key from ints and strings, stable across runs (unlike `hash`)."""
    text = "\x1f".join(str(p) for p in parts)
    return zlib.crc32(text.encode())


def generator(seed: int, *parts: int | str) -> np.random.Generator:
    """A generator for one named stream of draws under ``seed``."""
    return np.random.default_rng([int(seed) % (2**63), stable_key(*parts)])


def _splitmix64(x: np.ndarray) -> np.ndarray:
    # Arrays of uint64 wrap around silently, which is what the hash wants.
    z = x + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


def _uniform(key: int, index: np.ndarray, channel: int) -> np.ndarray:
    base = np.uint64((int(key) * 0x100000001B3 + channel * 0x9E3779B1) % (2**64))
    z = _splitmix64(_splitmix64(index.astype(np.uint64) ^ base) + np.uint64(channel))
    return ((z >> np.uint64(11)).astype(np.float64) + 0.5) * 2.0**-53


def hashed_normal(key: int, index: np.ndarray, channel: int) -> np.ndarray:
    """Standard normal deviates, one per entry of ``index`` (any ints), for a channel.

    The same ``(key, index, channel)`` always gives the same number.
    """
    signed = np.atleast_1d(np.asarray(index, dtype=np.int64))
    idx = np.where(signed >= 0, 2 * signed, -2 * signed - 1)  # zigzag: negatives get their own values
    u1 = _uniform(key, idx, 2 * channel)
    u2 = _uniform(key, idx, 2 * channel + 1)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)
