"""Image errors against a reference: relMSE, RMSE, FLIP, CIEDE2000, and the sRGB preview they share.

* ``rmse`` = sqrt(mean (x - ref)^2);
* ``relmse`` = mean((x - ref)^2 / (ref^2 + EPS)) over pixels and channels (``EPS`` = 0.01 keeps
  black pixels from dominating); ``relmse_self`` is a reference's own expected relMSE from its
  variance layer, mean(var / (ref^2 + EPS));
* FLIP: mean NVIDIA FLIP (``flip_evaluator``, "LDR") between sRGB previews (linear values
  clipped to [0, 1], sRGB curve) of the reference and the image; :class:`Flip` returns None
  with a reason when flip_evaluator is missing or fails;
* ``de2000``: mean CIEDE2000 colour difference over the pixels (colour-science's ``delta_E``,
  method "CIE 2000") between the display-referred images (linear sRGB clipped to [0, 1], as
  FLIP sees them, converted to XYZ and CIE L*a*b* with sRGB's D65 white); about 1 is a
  just-noticeable difference.  :class:`Ciede2000` returns None with a reason when
  colour-science is missing.
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


class Ciede2000:
    """Mean CIEDE2000 between display-referred images (module docstring); None (with
    ``reason``) when colour-science is unavailable.  The reference's L*a*b* is computed once
    per reference array."""

    DESCRIPTION = ("colour.delta_E(Lab(ref), Lab(test), method='CIE 2000') (colour-science), "
                   "Lab of the linear sRGB images clipped to [0,1] with sRGB's D65 white, mean "
                   "over the pixels")

    def __init__(self):
        self.reason = None
        self._ref = (None, None)
        try:
            import warnings

            import colour
            warnings.filterwarnings("ignore", module="colour")
            self.colour = colour
            self.space = colour.RGB_COLOURSPACES["sRGB"]
        except Exception as e:  # pragma: no cover - depends on the installation
            self.colour, self.reason = None, f"import colour failed: {e!r}"

    def lab(self, x) -> np.ndarray:
        rgb = np.clip(np.asarray(x, dtype=np.float64)[..., :3], 0.0, 1.0)
        xyz = self.colour.RGB_to_XYZ(rgb, self.space, apply_cctf_decoding=False)
        return self.colour.XYZ_to_Lab(xyz, self.space.whitepoint)

    def __call__(self, ref, test):
        if self.colour is None:
            return None
        try:
            if self._ref[0] is not ref:
                self._ref = (ref, self.lab(ref))
            d = self.colour.delta_E(self._ref[1], self.lab(test), method="CIE 2000")
            return float(np.mean(d))
        except Exception as e:  # pragma: no cover
            self.reason = f"colour.delta_E failed: {e!r}"
            self.colour = None
            return None


def de2000(x, ref) -> float | None:
    """Mean CIEDE2000 of one image against a reference (:class:`Ciede2000`)."""
    return Ciede2000()(ref, x)


def errors(img, ref, ref_srgb, flip=None, keep=None, ciede=None) -> dict:
    """Errors of one render: rmse, relmse, flip (None without ``flip``), de2000 (None without
    ``ciede``, a :class:`Ciede2000`), finite, and relmse over the pixels of mask ``keep`` (None
    without a mask or with an empty one).  A render with NaN/Inf gets None everywhere and
    ``finite`` False."""
    finite = bool(np.all(np.isfinite(img)))
    if not finite:
        return {"rmse": None, "relmse": None, "flip": None, "de2000": None, "finite": False,
                "relmse_masked": None}
    e = rel_sq_error(img, ref)
    return {"rmse": rmse(img, ref), "relmse": float(np.mean(e)),
            "flip": flip(ref_srgb, img) if flip is not None else None,
            "de2000": ciede(ref, img) if ciede is not None else None, "finite": True,
            "relmse_masked": (float(np.mean(e[keep])) if keep is not None and keep.any()
                              else None)}
