"""The probability that a blob candidate is a blob centre: two small neural networks.

The weights are in ``carapost/resources/blob_model.json`` (package data), fitted on
synthetic images with known truth by ``scripts/train_blob_model.py``.

Examples
--------
>>> import numpy as np
>>> from carapost.algorithms.blobs import FEATURE_NAMES
>>> from carapost.algorithms.blobs.score import blob_probability, load_model
>>> [net.w1.shape for net in load_model()]
[(63, 32), (63, 32)]
>>> p = blob_probability(np.zeros((3, len(FEATURE_NAMES))))
>>> p.shape, bool(((p >= 0) & (p <= 1)).all())
((3,), True)
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources
from typing import NamedTuple

import numpy as np

from carapost.algorithms.blobs.detections import FEATURE_NAMES

__all__ = ["MODEL_KINDS", "MODEL_INPUTS", "MODEL_HIDDEN", "ScoreNet", "load_model",
           "use_model", "net_logit", "blob_probability"]

#: The two models of ``blob_model.json``: candidates from ordinary seeds and candidates
#: from seeds found by splitting an over-size region (indexed by the ``split`` feature),
#: with the number of leading FEATURE_NAMES each one uses (all but ``split``).
MODEL_KINDS = ("seed", "split")
MODEL_INPUTS = {"seed": 63, "split": 63}


#: Hidden units of each network (one tanh layer).
MODEL_HIDDEN = 32


class ScoreNet(NamedTuple):
    """A neural network with one tanh hidden layer giving log-odds.

    Attributes
    ----------
    mean, scale : ndarray [n]
        Feature normalisation: the network sees ``(features - mean) / scale``.
    w1 : ndarray [n, H]; b1 : ndarray [H]
        Hidden layer.
    w2 : ndarray [H]; b2 : float
        Output (log-odds).
    """

    mean: np.ndarray
    scale: np.ndarray
    w1: np.ndarray
    b1: np.ndarray
    w2: np.ndarray
    b2: float


@lru_cache(maxsize=1)
def load_model() -> tuple[ScoreNet, ...]:
    """Load the networks of ``blob_model.json``, one per entry of MODEL_KINDS.

    Raises
    ------
    RuntimeError
        If the file does not fit this detector (other features or model form).
    """
    text = resources.files("carapost").joinpath("resources/blob_model.json").read_text()
    m = json.loads(text)
    stale = RuntimeError("carapost/resources/blob_model.json does not match this detector "
                         "(features or model form); re-run scripts/train_blob_model.py")
    if tuple(m.get("features", ())) != FEATURE_NAMES or set(m.get("models", {})) != set(
            MODEL_KINDS):
        raise stale
    out = []
    for kind in MODEL_KINDS:
        n = MODEL_INPUTS[kind]
        try:
            k = m["models"][kind]
            net = ScoreNet(*(np.asarray(k[f], np.float64) for f in ScoreNet._fields[:5]),
                           float(k["b2"]))
        except (KeyError, TypeError):
            raise stale from None
        if net.w1.shape != (n, len(net.b1)) or net.w2.shape != net.b1.shape or (
                net.mean.shape != (n,)):
            raise stale
        out.append(net)
    return tuple(out)


#: Networks set by :func:`use_model` in place of the file's (None: the file's).
_override: tuple[ScoreNet, ...] | None = None


def use_model(nets: tuple[ScoreNet, ...] | None) -> None:
    """Score with ``nets`` (one per MODEL_KINDS) instead of ``blob_model.json``.

    For the training script, which collects candidates with a neutral model when the
    shipped one no longer fits the features; ``None`` goes back to the file's networks.
    """
    global _override
    _override = None if nets is None else tuple(nets)


def net_logit(net: ScoreNet, features: np.ndarray) -> np.ndarray:
    """Log-odds of a network for candidates [N, F] (its leading MODEL_INPUTS features)."""
    x = (features[:, : net.mean.size] - net.mean) / net.scale
    return np.tanh(x @ net.w1 + net.b1) @ net.w2 + net.b2


def blob_probability(features: np.ndarray) -> np.ndarray:
    """Calibrated probability that each candidate is a blob centre.

    A small network (one hidden layer, trained on log-loss with an L2 penalty strong
    enough that it carries over to images unlike its synthetic training images, such as
    photos of printed dot grids). Candidates from split seeds (``split`` feature 1) have
    a network of their own: they are rarer, and a dark feature next to them changes what
    their other features mean.

    Parameters
    ----------
    features : ndarray [N, len(FEATURE_NAMES)]

    Returns
    -------
    ndarray [N] float64 in 0-1
    """
    features = np.asarray(features, np.float64)
    kind = (features[:, -1] > 0.5).astype(np.int64)
    z = np.zeros(len(features))
    for k, net in enumerate(load_model() if _override is None else _override):
        sel = kind == k
        if sel.any():
            z[sel] = net_logit(net, features[sel])
    return 1.0 / (1.0 + np.exp(-np.clip(z, -40, 40)))
