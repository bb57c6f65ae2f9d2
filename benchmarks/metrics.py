"""Image errors against a reference: relMSE, RMSE, FLIP, and the sRGB preview they share.

* ``rmse`` = sqrt(mean (x - ref)^2);
* ``relmse`` = mean((x - ref)^2 / (ref^2 + EPS)) over pixels and channels (``EPS`` = 0.01 keeps
  black pixels from dominating); ``relmse_self`` is a reference's own expected relMSE from its
  variance layer, mean(var / (ref^2 + EPS));
* FLIP: mean NVIDIA FLIP (``flip_evaluator``, "LDR") between sRGB previews (linear values
  clipped to [0, 1], sRGB curve) of the reference and the image; :class:`Flip` returns None
  with a reason when flip_evaluator is missing or fails.
"""
from __future__ import annotations

import numpy as np

EPS = 0.01


def srgb(x) -> np.ndarray:
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def rel_sq_error(x, ref) -> np.ndarray:
    """Per pixel and channel (x - ref)^2 / (ref^2 + EPS)."""
    x, ref = np.asarray(x, np.float64), np.asarray(ref, np.float64)
    return (x - ref) ** 2 / (ref ** 2 + EPS)


def relmse(x, ref, mask=None) -> float:
    e = rel_sq_error(x, ref)
    return float(np.mean(e if mask is None else e[mask]))


def rmse(x, ref) -> float:
    x, ref = np.asarray(x, np.float64), np.asarray(ref, np.float64)
    return float(np.sqrt(np.mean((x - ref) ** 2)))


def relmse_self(ref, var) -> float:
    """Expected relMSE of a reference from its variance layer."""
    ref, var = np.asarray(ref, np.float64), np.asarray(var, np.float64)
    return float(np.mean(var / (ref ** 2 + EPS)))


def signed_relative_error(x, ref) -> float:
    """mean((x - ref) / sqrt(ref^2 + EPS)): a render's signed error, for bias diagnostics."""
    x, ref = np.asarray(x, np.float64), np.asarray(ref, np.float64)
    return float(np.mean((x - ref) / np.sqrt(ref ** 2 + EPS)))


class Flip:
    """Mean FLIP between sRGB previews; None (with ``reason``) when unavailable."""

    DESCRIPTION = ("flip_evaluator.evaluate(ref, test, 'LDR') on sRGB previews (clip to [0,1], "
                   "sRGB curve), mean of the error map")

    def __init__(self):
        self.reason = None
        try:
            import flip_evaluator
            self.mod = flip_evaluator
        except Exception as e:  # pragma: no cover - depends on the installation
            self.mod, self.reason = None, f"import flip_evaluator failed: {e!r}"

    def __call__(self, ref_srgb, test):
        if self.mod is None:
            return None
        try:
            _, mean, _ = self.mod.evaluate(np.ascontiguousarray(ref_srgb, dtype=np.float32),
                                           np.ascontiguousarray(srgb(test), dtype=np.float32),
                                           "LDR", inputsRGB=True, applyMagma=False)
            return float(mean)
        except Exception as e:  # pragma: no cover
            self.reason = f"flip_evaluator.evaluate failed: {e!r}"
            self.mod = None
            return None


def errors(img, ref, ref_srgb, flip=None, keep=None) -> dict:
    """Errors of one render: rmse, relmse, flip (None without ``flip``), finite, and relmse over
    the pixels of mask ``keep`` (None without a mask or with an empty one).  A render with
    NaN/Inf gets None everywhere and ``finite`` False."""
    finite = bool(np.all(np.isfinite(img)))
    if not finite:
        return {"rmse": None, "relmse": None, "flip": None, "finite": False,
                "relmse_masked": None}
    e = rel_sq_error(img, ref)
    return {"rmse": rmse(img, ref), "relmse": float(np.mean(e)),
            "flip": flip(ref_srgb, img) if flip is not None else None, "finite": True,
            "relmse_masked": (float(np.mean(e[keep])) if keep is not None and keep.any()
                              else None)}
