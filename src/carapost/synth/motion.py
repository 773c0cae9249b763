"""Smooth random motion as functions of continuous time: expressions, head slip, rig flex.

Every signal is drawn once from a seeded generator and can then be evaluated at any time
(seconds), so sub-frame samples (motion blur) and shifted clocks (an out-of-sync camera)
come from the same motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from carapost.synth.face import MODES

PRESETS = ("rom", "speech", "fast", "blink")


@dataclass
class SmoothSignal:
    """Sum of sinusoids ``sum_i a_i sin(2 pi f_i t + p_i)``, vectorised over channels.

    Attributes have shape (K, n): K channels, n sinusoids each.
    """

    amp: NDArray[np.float64]
    freq: NDArray[np.float64]
    phase: NDArray[np.float64]

    @classmethod
    def random(cls, rng: np.random.Generator, channels: int, n: int, fmin: float, fmax: float
               ) -> SmoothSignal:
        """Random signal with unit RMS per channel and frequencies in [fmin, fmax] Hz."""
        freq = rng.uniform(fmin, fmax, (channels, n))
        amp = rng.uniform(0.5, 1.0, (channels, n)) / np.sqrt(freq / fmin)
        amp /= np.sqrt(0.5 * np.sum(amp**2, axis=1, keepdims=True))
        return cls(amp, freq, rng.uniform(0.0, 2 * np.pi, (channels, n)))

    def __call__(self, t: ArrayLike) -> NDArray[np.float64]:
        """Values at times ``t`` (s): shape ``t.shape + (K,)``."""
        t = np.asarray(t, dtype=np.float64)[..., None, None]
        return np.sum(self.amp * np.sin(2 * np.pi * self.freq * t + self.phase), axis=-1)


def _bumps(t: NDArray[np.float64], centres: NDArray[np.float64], width: float
           ) -> NDArray[np.float64]:
    """Train of smooth pulses of height 1 (clipped) at ``centres`` (s)."""
    if centres.size == 0:
        return np.zeros_like(t)
    v = np.exp(-0.5 * ((t[..., None] - centres) / width) ** 2).sum(axis=-1)
    return np.minimum(v, 1.0)


@dataclass
class SyllableTrain:
    """Opening-closing cycles of the mouth, one raised-cosine pulse per syllable.

    Attributes have shape (n,): each syllable's start (s), duration (s) and peak in
    [0, 1] (0 for a pause). The pulses touch end to end, so the signal and its slope are
    continuous.
    """

    start: NDArray[np.float64]
    duration: NDArray[np.float64]
    peak: NDArray[np.float64]

    @classmethod
    def random(cls, rng: np.random.Generator, span: float) -> SyllableTrain:
        """Syllables covering ``[0, span]`` s, the first one begun before 0.

        Durations 0.14-0.32 s (3-7 syllables per second), peaks 0.6-1, and one pause
        (0.2-0.6 s) in eight. The fastest opening, ``pi peak / duration``, is 22 per
        second: through the jaw mode a lower-lip speed of about 220 mm/s at most, and a
        99th percentile of the face markers' speeds (in the head's frame) of 110-150 mm/s,
        as in a real facial capture (an optical take of singing at 100 Hz: 149 mm/s).
        A sum of sinusoids through ``tanh``, used before, was a near-square wave whose
        edges moved the lips twice as fast (290 mm/s at the 99th percentile, 540 at most).
        """
        n = int(span / 0.14) + 3
        # one row of draws per syllable, so a longer take of the same seed starts with
        # the same syllables
        first = rng.uniform()
        u = rng.uniform(size=(n, 4))
        pause = u[:, 2] < 0.125
        dur = np.where(pause, 0.2 + 0.4 * u[:, 3], 0.14 + 0.18 * u[:, 0])
        peak = np.where(pause, 0.0, 0.6 + 0.4 * u[:, 1])
        start = np.concatenate([[0.0], np.cumsum(dur[:-1])]) - first * dur[0]
        return cls(start, dur, peak)

    def __call__(self, t: ArrayLike) -> NDArray[np.float64]:
        """Values in [0, 1] at times ``t`` (s): shape ``t.shape``."""
        t = np.asarray(t, dtype=np.float64)
        i = np.clip(np.searchsorted(self.start, t, side="right") - 1, 0, len(self.start) - 1)
        u = np.clip((t - self.start[i]) / self.duration[i], 0.0, 1.0)
        return self.peak[i] * (0.5 - 0.5 * np.cos(2 * np.pi * u))


def _smooth_env(t: NDArray[np.float64], t0: float, t1: float, ramp: float) -> NDArray[np.float64]:
    """1 inside [t0, t1] with smooth (raised-cosine) ramps of length ``ramp`` outside."""
    up = np.clip((t - (t0 - ramp)) / ramp, 0, 1)
    down = np.clip(((t1 + ramp) - t) / ramp, 0, 1)
    s = np.minimum(up, down)
    return 0.5 - 0.5 * np.cos(np.pi * s)


class ExpressionMotion:
    """Activations of the expression modes (`carapost.synth.face.MODES`) over time.

    Parameters
    ----------
    preset : str
        ``"rom"`` (neutral start, then every mode in turn, then combinations),
        ``"speech"`` (the jaw and lips open and close once per syllable, 3-7 per
        second; occasional smile/brow, blinks),
        ``"fast"`` (speech at three times the speed) or ``"blink"`` (calm face, frequent
        blinks).
    duration : float
        Length of the take (s); the ROM schedule is stretched to fit it.
    rng : numpy.random.Generator
    """

    def __init__(self, preset: str, duration: float, rng: np.random.Generator) -> None:
        if preset not in PRESETS:
            raise ValueError(f"preset must be one of {PRESETS}, got {preset!r}")
        self.preset = preset
        self.duration = float(duration)
        self.speed = 3.0 if preset == "fast" else 1.0
        span = max(self.duration, 0.1) * self.speed + 1.0
        # The syllables get a generator of their own, seeded from exactly as many draws as
        # an earlier sum-of-sinusoids syllable signal took, so the other signals (smile,
        # brow, blinks) of every seed are what they were.
        self.syllable = SyllableTrain.random(
            np.random.default_rng((rng.uniform(size=15) * 2**32).astype(np.uint64)), span)
        self.slow = SmoothSignal.random(rng, len(MODES), 4, 0.08, 0.6)
        if preset == "blink":
            gaps = rng.uniform(0.7, 1.3, int(span / 0.7) + 2)
        else:
            gaps = rng.uniform(2.0, 4.5, int(span / 2.0) + 2)
        self.blinks = np.cumsum(gaps) - 0.5 * gaps[0]
        self.blink_width = 0.045

    def __call__(self, t: ArrayLike) -> NDArray[np.float64]:
        """Activations in [0, 1] at times ``t`` (s): shape ``t.shape + (len(MODES),)``."""
        t = np.asarray(t, dtype=np.float64)
        out = np.zeros(t.shape + (len(MODES),))
        if self.preset == "rom":
            return self._rom(t)
        ts = t * self.speed
        slow = 0.5 + 0.5 * np.tanh(1.2 * self.slow(ts) - 0.9)  # mostly low, sometimes high
        syl = self.syllable(ts)
        if self.preset == "blink":
            out[..., 0] = 0.1 * syl
            out[..., 1:4] = 0.3 * slow[..., 1:4]
            out[..., 5] = 0.2 * slow[..., 5]
        else:
            out[..., 0] = 0.55 * syl * (0.6 + 0.4 * slow[..., 0])
            out[..., 1] = 0.8 * slow[..., 1]
            out[..., 2] = 0.7 * slow[..., 2]
            out[..., 3] = 0.6 * slow[..., 3] * (1 - syl)
            out[..., 5] = 0.6 * slow[..., 5] * syl
        out[..., 4] = _bumps(ts, self.blinks, self.blink_width)
        return np.clip(out, 0.0, 1.0)

    def _rom(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        k = len(MODES)
        neutral = min(0.5, 0.1 * self.duration)
        # each mode alone, then two combined poses; each segment ramps up, holds, ramps down
        seg = (self.duration - neutral) / (k + 2)
        out = np.zeros(t.shape + (k,))
        for i in range(k + 2):
            t0 = neutral + i * seg
            env = _smooth_env(t, t0 + 0.3 * seg, t0 + 0.7 * seg, 0.25 * seg)
            if i < k:
                out[..., i] += env
            elif i == k:  # wide open laugh
                out[..., 0] += 0.8 * env
                out[..., 1] += env
                out[..., 2] += 0.6 * env
            else:  # pucker with raised brows and curled lips
                out[..., 3] += env
                out[..., 2] += env
                out[..., 5] += 0.7 * env
        return np.clip(out, 0.0, 1.0)


class RigidJitter:
    """Small smooth rigid motion: rotation vector (rad) and translation (mm) over time.

    Parameters
    ----------
    rng : numpy.random.Generator
    channels : int
        Number of independent bodies (e.g. cameras).
    rot_rms : float
        RMS of each rotation-vector component (rad).
    trans_rms : float
        RMS of each translation component (mm).
    fmin, fmax : float
        Frequency band (Hz).
    """

    def __init__(self, rng: np.random.Generator, channels: int, rot_rms: float,
                 trans_rms: float, fmin: float, fmax: float) -> None:
        self.channels = channels
        self.signal = SmoothSignal.random(rng, 6 * channels, 4, fmin, fmax)
        self.rot_rms = rot_rms
        self.trans_rms = trans_rms

    def __call__(self, t: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Rotation vectors and translations at times ``t``: each ``t.shape + (channels, 3)``."""
        t = np.asarray(t, dtype=np.float64)
        v = self.signal(t).reshape(t.shape + (self.channels, 6))
        return self.rot_rms * v[..., :3], self.trans_rms * v[..., 3:]
