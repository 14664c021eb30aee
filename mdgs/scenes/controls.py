"""Control signals for the scenes, deterministic by seed.

A :class:`Controller` returns the controls of one frame for a batch of trajectories;
controls are held for the frame's substeps (zero-order hold). Open-loop controllers
(:class:`OpenLoop`) are a precomputed table; closed-loop ones (the Cubli's balance
controller) read the batch's ``qpos``/``qvel`` at the frame, like a robot's controller
running at the frame rate. Every random choice comes from the trajectory's own
``numpy.random.Generator``, so a trajectory does not depend on which batch, worker or
shard computes it.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

__all__ = ["Controller", "OpenLoop", "smooth_signal", "smooth_targets"]


class Controller(Protocol):
    closed_loop: bool

    def __call__(self, frame: int, qpos: np.ndarray, qvel: np.ndarray) -> np.ndarray:
        """Controls ``[R, nu]`` of frame ``frame`` given ``qpos [R, nq]``, ``qvel [R, nv]``."""
        ...


class OpenLoop:
    """Controls from a table ``[R, F, nu]``."""

    closed_loop = False

    def __init__(self, table: np.ndarray):
        self.table = np.ascontiguousarray(table, dtype=np.float64)

    def __call__(self, frame: int, qpos=None, qvel=None) -> np.ndarray:
        return self.table[:, frame]

    def block(self, start: int, stop: int) -> np.ndarray:
        return self.table[:, start:stop]


def smooth_signal(
    rng: np.random.Generator,
    n: int,
    dt: float,
    channels: int,
    *,
    fmin: float = 0.2,
    fmax: float = 2.0,
    terms: int = 4,
) -> np.ndarray:
    """Band-limited random signal in [-1, 1]: a sum of ``terms`` sinusoids per channel.

    Frequencies are uniform in ``[fmin, fmax]`` Hz, phases uniform, amplitudes uniform
    and normalised by their sum (so the signal never leaves [-1, 1]). Shape ``[n, channels]``.
    """
    t = np.arange(n)[:, None, None] * dt
    f = rng.uniform(fmin, fmax, (1, channels, terms))
    ph = rng.uniform(0, 2 * np.pi, (1, channels, terms))
    a = rng.uniform(0.2, 1.0, (1, channels, terms))
    a = a / a.sum(-1, keepdims=True)
    return (a * np.sin(2 * np.pi * f * t + ph)).sum(-1)


def smooth_targets(
    rng: np.random.Generator,
    n: int,
    dt: float,
    low: np.ndarray,
    high: np.ndarray,
    start: np.ndarray | None = None,
    **kw,
) -> np.ndarray:
    """Smooth targets inside ``[low, high]`` per channel (e.g. joint angles for servos).

    The signal oscillates about a random centre; with ``start`` given it begins there
    and blends to the random motion over the first quarter of the horizon.
    """
    low, high = np.asarray(low, float), np.asarray(high, float)
    mid, half = (low + high) / 2, (high - low) / 2
    centre = mid + half * rng.uniform(-0.4, 0.4, low.shape)
    s = smooth_signal(rng, n, dt, low.shape[0], **kw)
    out = centre + 0.6 * half * s
    if start is not None:
        w = np.clip(np.arange(n) / max(1, n // 4), 0, 1)[:, None]
        w = 0.5 - 0.5 * np.cos(np.pi * w)
        out = (1 - w) * np.asarray(start, float) + w * out
    return np.clip(out, low, high)
