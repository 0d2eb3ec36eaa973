"""Resampling on the generator's device: OpenCV's area and bilinear resize and its Gaussian blur, for images laid
out (B, H, W[, C]) as torch tensors.

On the CPU the tensors' memory goes to OpenCV itself (``cv2.resize``, ``cv2.GaussianBlur``: SIMD kernels no torch
op matches on two cores). On an accelerator each axis is a table of taps (source index, weight) applied by
index-select and multiply-add, built once per size in NumPy from OpenCV's definitions (INTER_AREA shrinking and
growing, INTER_LINEAR, the float Gaussian kernel with its reflect-101 border) and kept on the device. On float images
the taps agree with OpenCV to float rounding. On uint8 images OpenCV takes shortcuts the taps do not: an area
shrink by integer factors rounds half up (the taps, half to even), and a growing axis (INTER_AREA up, INTER_LINEAR)
uses 11-bit weights; the generator's one uint8 resize, the GelSight Mini's 240×320 to 128×160, takes OpenCV's
general path and the taps give its bytes exactly (tests/test_gen_resample.py runs the taps on CPU tensors).
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np
import torch

Taps = tuple[torch.Tensor, torch.Tensor]  # (index int64 (n_out, K), weight float32 (n_out, K))


def _neighbour_taps(left: np.ndarray, frac: np.ndarray, n_in: int) -> tuple[np.ndarray, np.ndarray]:
    """Taps blending source pixels ``left`` and ``left + 1`` with weight ``frac`` on the right one, (n_out, 2); at
    the edges (``left`` before the first or at the last pixel) the nearest pixel alone."""
    frac = np.where((left < 0) | (left >= n_in - 1), 0.0, frac).astype(np.float32)
    index = np.clip(np.stack([left, left + 1], 1), 0, n_in - 1).astype(np.int64)
    return index, np.stack([1.0 - frac, frac], 1).astype(np.float32)


def linear_taps(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear taps with half-pixel centres and edge clamping (INTER_LINEAR): (index, weight) (n_out, 2)."""
    x = (np.arange(n_out) + 0.5) * (n_in / n_out) - 0.5
    left = np.floor(x)
    return _neighbour_taps(left, (x - left).astype(np.float32), n_in)


def _area_up_taps(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """INTER_AREA's taps where the axis grows: a sharp linear blend between neighbours (OpenCV's area_mode)."""
    scale = n_in / n_out
    left = np.floor(np.arange(n_out) * scale)
    frac = (np.arange(n_out) + 1) - (left + 1) / scale
    return _neighbour_taps(left, np.where(frac <= 0, 0.0, frac - np.floor(frac)).astype(np.float32), n_in)


def area_taps(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """Area taps (INTER_AREA): shrinking, each output pixel the mean of the input it covers, fractional pixels
    weighted by their covered share; growing, ``_area_up_taps``. (index, weight) (n_out, K)."""
    if n_in < n_out:
        return _area_up_taps(n_in, n_out)
    scale = n_in / n_out
    k = int(np.ceil(scale)) + 1
    start = np.arange(n_out) * scale
    first = np.floor(start).astype(np.int64)
    index = first[:, None] + np.arange(k)
    overlap = np.minimum(start[:, None] + scale, index + 1) - np.maximum(start[:, None], index)
    weight = np.clip(overlap, 0.0, None) / scale
    used = weight.any(0)  # an integer factor leaves its last tap empty
    return np.clip(index, 0, n_in - 1)[:, used], weight[:, used].astype(np.float32)


def _reflect101(index: np.ndarray, n: int) -> np.ndarray:
    """Indices reflected into [0, n) without repeating the edge pixel (OpenCV's BORDER_REFLECT_101)."""
    if n == 1:
        return np.zeros_like(index)
    period = 2 * n - 2
    index = np.abs(index) % period
    return np.where(index >= n, period - index, index)


def gaussian_taps(n: int, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Gaussian blur taps along an axis of ``n`` pixels: OpenCV's kernel for float images at ``sigma`` px (size
    round(8 sigma + 1), odd), reflect-101 border. (index, weight) (n, size)."""
    size = int(round(sigma * 8 + 1)) | 1
    offsets = np.arange(size) - size // 2
    kernel = np.exp(-(offsets.astype(np.float64) ** 2) / (2 * sigma * sigma))
    kernel = (kernel / kernel.sum()).astype(np.float32)
    index = _reflect101(np.arange(n)[:, None] + offsets, n)
    return index.astype(np.int64), np.broadcast_to(kernel, index.shape).copy()


@lru_cache(maxsize=64)
def _device_taps(kind: str, n_in: int, n_out: int, param: float, device: str) -> Taps:
    """The taps of ``kind`` as tensors on ``device`` (built once per size and device)."""
    make = {"area": lambda: area_taps(n_in, n_out), "linear": lambda: linear_taps(n_in, n_out),
            "gaussian": lambda: gaussian_taps(n_in, param)}[kind]
    index, weight = make()
    return torch.from_numpy(index).to(device), torch.from_numpy(weight).to(device)


def _along(x: torch.Tensor, dim: int, taps: Taps) -> torch.Tensor:
    """``x`` resampled along ``dim``: the sum over k of x[index[:, k]] * weight[:, k] along that axis."""
    index, weight = taps
    shape = (-1,) + (1,) * (x.ndim - 1 - dim)
    out = x.index_select(dim, index[:, 0]) * weight[:, 0].view(shape)
    for k in range(1, index.shape[1]):
        out = out + x.index_select(dim, index[:, k]) * weight[:, k].view(shape)
    return out


def _opencv(x: torch.Tensor, fn) -> torch.Tensor:
    """``fn`` on each image of the CPU tensor ``x`` (B, H, W[, C]) through its NumPy view, stacked back."""
    return torch.from_numpy(np.stack([fn(image) for image in x.numpy()]))


def resize(x: torch.Tensor, hw: tuple[int, int], kind: str, taps: bool | None = None) -> torch.Tensor:
    """(B, H, W[, C]) -> (B, H', W'[, C]) with hw = (H', W'), kind "area" or "linear"; uint8 stays uint8 (the taps
    round half to even), float stays float32. An image already of that size is returned as it is. ``taps``: True runs the
    accelerator's kernel wherever the tensor is, None (default) OpenCV's on the CPU."""
    if tuple(x.shape[1:3]) == tuple(hw):
        return x
    if not (x.device.type != "cpu" if taps is None else taps):
        flag = cv2.INTER_AREA if kind == "area" else cv2.INTER_LINEAR
        out = _opencv(x, lambda im: cv2.resize(im, hw[::-1], interpolation=flag))
        return out if out.ndim == x.ndim else out[..., None]  # OpenCV drops a trailing channel of 1
    out = x.float()
    for dim, n_out in ((2, hw[1]), (1, hw[0])):  # width first, then height, as OpenCV
        if out.shape[dim] != n_out:
            out = _along(out, dim, _device_taps(kind, out.shape[dim], n_out, 0.0, str(out.device)))
    return out.round().clamp_(0, 255).to(torch.uint8) if x.dtype == torch.uint8 else out


def gaussian_blur(x: torch.Tensor, sigma: float, taps: bool | None = None) -> torch.Tensor:
    """float32 (B, H, W) blurred by a Gaussian of ``sigma`` px (finite, > 0), as ``cv2.GaussianBlur(image, (0, 0),
    sigma)``; ``taps`` as ``resize``. ValueError for another sigma (0 would give NaN taps, or an OpenCV assertion)."""
    if not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma: expected a finite number of pixels > 0, got {sigma!r}")
    if not (x.device.type != "cpu" if taps is None else taps):
        return _opencv(x, lambda im: cv2.GaussianBlur(im, (0, 0), sigma))
    device = str(x.device)
    out = _along(x, 2, _device_taps("gaussian", x.shape[2], x.shape[2], sigma, device))
    return _along(out, 1, _device_taps("gaussian", x.shape[1], x.shape[1], sigma, device))
