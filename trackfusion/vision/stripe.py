"""Laser-stripe centre per image column, to sub-pixel, vectorised over columns and frames.

Per column: the brightest row (the first one, as ``cv2.reduceArgMax`` finds it; :func:`peak_rows`),
then the centre of gravity of the intensity above a threshold
(the background plus ``threshold_fraction`` of the peak's height above it) in a window around
it. Thresholding gives the weights compact support, so the centre of a symmetric stripe profile
is unbiased whatever the window's position relative to it. A column has no stripe when its peak
is less than ``min_peak_dn`` above the background, when the thresholded profile is wider than
``max_width_px`` (a blob rather than a line), or near glare: a column with at least
``glare_min_saturated_px`` saturated pixels (a laser line of this width saturates one or two),
and ``glare_margin_columns`` on either side of it (the glint's tails). Written with numpy because OpenCV has no
column-wise sub-pixel peak detector; the background is the median of every 8th pixel of every 8th row.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class StripeSettings:
    min_peak_dn: float = 20.0
    threshold_fraction: float = 0.3
    half_window_px: int = 6
    max_width_px: float = 4.0
    saturated_dn: int = 250
    glare_min_saturated_px: int = 4
    glare_margin_columns: int = 20


def stripe_centres(images: np.ndarray, settings: StripeSettings = StripeSettings(),
                   with_glare: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Stripe row centres (B, W) [px, row index of pixel centres] of grey images (B, H, W) (or
    (H, W) -> (W,)); NaN where a column has no stripe (module docstring). ``with_glare`` also
    returns the glare columns (B, W) (or (W,)), margin included."""
    imgs = np.asarray(images)
    single = imgs.ndim == 2
    if single:
        imgs = imgs[None]
    B, H, W = imgs.shape
    bg = np.median(imgs[:, ::8, ::8].reshape(B, -1), axis=1).astype(np.float32)[:, None]
    peak_row = peak_rows(imgs)                                          # (B, W)
    # pixels by flat index (np.take: twice np.take_along_axis's speed here)
    column = np.arange(B)[:, None, None] * (H * W) + np.arange(W)      # (B, 1, W) flat index of row 0
    flat = imgs.reshape(-1)
    peak = np.take(flat, column[:, 0] + peak_row * W).astype(np.float32)
    k = settings.half_window_px
    offs = np.arange(-k, k + 1)[None, :, None]
    rows = np.clip(peak_row[:, None, :] + offs, 0, H - 1)               # (B, 2k+1, W)
    vals = np.take(flat, column + rows * W).astype(np.float32)
    height = peak - bg
    thr = bg + settings.threshold_fraction * height
    w = np.maximum(vals - thr[:, None, :], 0.0)
    w = np.where(rows == peak_row[:, None, :] + offs, w, 0.0)           # no clipped duplicates
    sw = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        centre = (w * offs).sum(axis=1) / sw
        width = np.sqrt(np.maximum((w * (offs - centre[:, None, :]) ** 2).sum(axis=1) / sw, 0.0))
    glare = glare_columns(imgs, settings)
    ok = (height >= settings.min_peak_dn) & (sw > 0) & (width <= settings.max_width_px) & ~glare
    out = np.where(ok, peak_row + centre, np.nan)
    if with_glare:
        return (out[0], glare[0]) if single else (out, glare)
    return out[0] if single else out


def peak_rows(imgs: np.ndarray) -> np.ndarray:
    """The brightest row (B, W) of each column of grey images (B, H, W), the first of equal ones:
    the images transposed (``cv2.transpose``, into one (B, W, H) buffer) so that each column is
    a contiguous row for numpy's SIMD argmax -- 3x ``cv2.reduceArgMax`` over the rows, the same
    indices."""
    B, H, W = imgs.shape
    cols = np.empty((B, W, H), imgs.dtype)
    for im, out in zip(imgs, cols):
        cv2.transpose(im, out)
    return cols.argmax(axis=2)


def glare_columns(imgs: np.ndarray, settings: StripeSettings) -> np.ndarray:
    """Columns (B, W) hit by glare (module docstring), dilated by the margin (``cv2.dilate``)."""
    # saturated pixels per column (OpenCV threshold + column sums: 8x numpy's here)
    counts = np.stack([cv2.reduce(cv2.threshold(im, settings.saturated_dn - 1, 1, cv2.THRESH_BINARY)[1], 0,
                                  cv2.REDUCE_SUM, dtype=cv2.CV_32S).ravel() for im in imgs])
    sat = counts >= settings.glare_min_saturated_px
    if not sat.any():
        return sat
    k = np.ones((1, 2 * settings.glare_margin_columns + 1), np.uint8)
    return cv2.dilate(sat.astype(np.uint8), k) > 0
