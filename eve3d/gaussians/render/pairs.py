"""``torch`` backend: sparse pixel–Gaussian pairs in plain PyTorch, with an analytic backward.

Runs on any device PyTorch does and needs no compiler: the fallback when the C++ ``cpu``
backend cannot be built, and an independent implementation the tests compare it with.

Forward, without grad:

1. List the (pixel, Gaussian) pairs inside each Gaussian's bounding box.
2. Keep pairs with α = min(0.999, o·exp(−σ)) ≥ 1/255; order them by pixel, then depth.
3. Exclusive transmittance T per pair as a per-pixel segmented cumulative sum of
   log(1 − α) (float64: long pair lists lose no precision); drop the pairs from the one that
   would take T to ≤ 1e-4 on (gsplat's early stop).
4. Accumulate w = α·T times the features into the pixels with ``index_add``.

Backward (``_Composite``): per pair, ∂L/∂α_i = T_i (g·f_i + g_α) − S_i / (1 − α_i), where
S_i is the sum over the pairs behind it in the same pixel of w_j (g·f_j + g_α); then the
chain rule through α = o·exp(−σ) to opacity, conic and 2D mean, scattered to the Gaussians.
Only the pair lists are kept between the passes (about 24 bytes per pair), and the pairs
are listed in bands of rows when they exceed a budget, so memory stays bounded.
"""
from __future__ import annotations

import math

import torch

from eve3d.core.timing import step_part
from eve3d.gaussians.render.projection import ALPHA_MAX, ALPHA_MIN, T_MIN, Projected, front_to_back


@step_part("rasterize")
def rasterize(proj: Projected, opacities: torch.Tensor, features: torch.Tensor, width: int, height: int,
              absgrad: torch.Tensor | None = None, max_pairs: int = 4_000_000
              ) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Alpha-composite ``features`` (N, C) front to back.

    Returns the blended features (H, W, C), alpha (H, W) and the number of pairs composited.
    ``absgrad`` (N, 2), when given, receives Σ over pairs of |∂L/∂mean2d| in the backward pass.
    """
    visible, boxes = front_to_back(proj, width, height)
    means2d, conics, opac = proj.means2d[visible], proj.conics[visible], opacities[visible]
    with torch.no_grad():
        columns = _Columns(means2d, conics, opac)
        bands = [_list_pairs(boxes, y0, y1, width, columns) for y0, y1 in _row_bands(boxes, height, max_pairs)]
        gid, pix, weight, trans = (torch.cat(parts) for parts in zip(*bands))
    image, alpha = _Composite.apply(means2d, conics, opac, features[visible], gid, pix, weight, trans,
                                    width, height * width, visible, absgrad)
    return image.reshape(height, width, -1), alpha.reshape(height, width), gid.numel()


class _Columns:
    """Per-Gaussian values as contiguous 1D columns: gathers by pair are fastest that way."""

    def __init__(self, means2d, conics, opac):
        self.mx, self.my = means2d.detach().T.contiguous()
        self.a, self.b, self.c = conics.detach().T.contiguous()
        self.o = opac.detach().contiguous()

    def alpha(self, gid, px, py):
        """α per pair, the unclamped α and the offsets dx, dy from the Gaussian centre."""
        def take(col):
            return col.index_select(0, gid)

        dx = px.to(self.mx.dtype) + 0.5 - take(self.mx)
        dy = py.to(self.mx.dtype) + 0.5 - take(self.my)
        sigma = 0.5 * (take(self.a) * dx * dx + take(self.c) * dy * dy) + take(self.b) * dx * dy
        raw = take(self.o) * torch.exp(-sigma)
        return raw.clamp_max(ALPHA_MAX), raw, dx, dy


def _row_bands(boxes: torch.Tensor, height: int, max_pairs: int) -> list[tuple[int, int]]:
    """Split rows into bands of at most ``max_pairs`` box pixels (one band if it fits)."""
    w = (boxes[:, 2] - boxes[:, 0] + 1).clamp_min(0)
    valid = (boxes[:, 3] >= boxes[:, 1]) & (w > 0)
    per_row = torch.zeros(height + 1, dtype=torch.long, device=boxes.device)
    per_row.index_add_(0, boxes[valid, 1], w[valid])
    per_row.index_add_(0, boxes[valid, 3] + 1, -w[valid])
    per_row = per_row.cumsum(0)[:height].cpu()
    if per_row.sum() <= max_pairs:
        return [(0, height)]
    bands, start, acc = [], 0, 0
    for y, n in enumerate(per_row.tolist()):
        if acc and acc + n > max_pairs:
            bands.append((start, y))
            start, acc = y, 0
        acc += n
    bands.append((start, height))
    return bands


def _list_pairs(boxes, y0, y1, width, columns: _Columns):
    """Pairs of rows [y0, y1) that pass the α and transmittance rules, sorted by pixel then
    depth: Gaussian index, pixel index, weight α·T and transmittance T."""
    x0, by0, x1, by1 = boxes.T
    ya, yb = by0.clamp_min(y0), by1.clamp_max(y1 - 1)
    bw, bh = x1 - x0 + 1, yb - ya + 1
    hit = ((bw > 0) & (bh > 0)).nonzero()[:, 0]
    counts = bw[hit] * bh[hit]
    gid = torch.repeat_interleave(hit, counts)
    k = torch.arange(gid.numel(), device=gid.device) - torch.repeat_interleave(torch.cumsum(counts, 0) - counts,
                                                                              counts)
    bw_g = bw.index_select(0, gid)
    row = torch.div(k, bw_g, rounding_mode="floor")
    px = x0.index_select(0, gid) + (k - row * bw_g)
    py = ya.index_select(0, gid) + row
    alpha, _, _, _ = columns.alpha(gid, px, py)
    ok = (alpha >= ALPHA_MIN).nonzero()[:, 0]
    pix = (py * width + px).index_select(0, ok)
    # Pairs were listed Gaussian by Gaussian in depth order: a stable sort by pixel keeps it.
    pix, order = torch.sort(pix.int(), stable=True)
    order = ok.index_select(0, order)
    gid, alpha = gid.index_select(0, order), alpha.index_select(0, order)
    log_1ma = torch.log1p(-alpha.double())
    log_t = _exclusive_segment_cumsum(log_1ma, pix)
    ok = (log_t + log_1ma > math.log(T_MIN)).nonzero()[:, 0]
    trans = torch.exp(log_t.index_select(0, ok)).to(alpha.dtype)
    return gid.index_select(0, ok), pix.index_select(0, ok).long(), alpha.index_select(0, ok) * trans, trans


def _exclusive_segment_cumsum(x: torch.Tensor, pix: torch.Tensor) -> torch.Tensor:
    """For a pixel-sorted pair list, the sum of ``x`` over the earlier pairs of the same pixel."""
    excl = torch.cumsum(x, 0) - x
    if x.numel() == 0:
        return excl
    is_start = torch.ones_like(pix, dtype=torch.bool)
    is_start[1:] = pix[1:] != pix[:-1]
    segment = torch.cumsum(is_start, 0) - 1
    return excl - excl[is_start].index_select(0, segment)


class _Composite(torch.autograd.Function):
    """Front-to-back compositing of listed pairs; analytic backward (see module docstring)."""

    @staticmethod
    def forward(ctx, means2d, conics, opac, feats, gid, pix, weight, trans, width, npix, visible, absgrad):
        weighted = weight[:, None] * feats.index_select(0, gid)
        image = torch.zeros(npix, feats.shape[1], dtype=feats.dtype, device=feats.device).index_add_(0, pix, weighted)
        alpha = torch.zeros(npix, dtype=feats.dtype, device=feats.device).index_add_(0, pix, weight)
        ctx.save_for_backward(means2d, conics, opac, feats, gid, pix, weight, trans)
        ctx.width, ctx.visible, ctx.absgrad = width, visible, absgrad
        return image, alpha

    @staticmethod
    def backward(ctx, grad_image, grad_alpha):
        means2d, conics, opac, feats, gid, pix, weight, trans = ctx.saved_tensors
        g_img = grad_image.index_select(0, pix)
        # ∂L/∂w_i = g·f_i + g_α; the pairs behind i in its pixel depend on α_i through T.
        dl_dw = (g_img * feats.index_select(0, gid)).sum(1) + grad_alpha.index_select(0, pix)
        h = (weight * dl_dw).double()
        behind = torch.zeros(grad_image.shape[0], dtype=h.dtype, device=h.device).index_add_(0, pix, h)
        behind = behind.index_select(0, pix) - _exclusive_segment_cumsum(h, pix) - h
        columns = _Columns(means2d, conics, opac)
        alpha, raw, dx, dy = columns.alpha(gid, pix % ctx.width, torch.div(pix, ctx.width, rounding_mode="floor"))
        dl_dalpha = trans * dl_dw - (behind / (1 - alpha.double())).to(alpha.dtype)
        dl_dalpha = torch.where(raw > ALPHA_MAX, torch.zeros_like(dl_dalpha), dl_dalpha)  # clamped: flat
        dl_dsigma = -dl_dalpha * raw
        n = means2d.shape[0]

        def scatter(values):
            return values.new_zeros(n).index_add_(0, gid, values)

        grads: list[torch.Tensor | None] = [None] * 12
        if ctx.needs_input_grad[0] or ctx.absgrad is not None:
            def take(col):
                return col.index_select(0, gid)

            a, b, c = take(columns.a), take(columns.b), take(columns.c)
            dmx, dmy = -dl_dsigma * (a * dx + b * dy), -dl_dsigma * (b * dx + c * dy)
            grads[0] = torch.stack([scatter(dmx), scatter(dmy)], dim=1)
            if ctx.absgrad is not None:
                abs_sums = torch.stack([scatter(dmx.abs()), scatter(dmy.abs())], dim=1)
                ctx.absgrad.index_add_(0, ctx.visible, abs_sums.to(ctx.absgrad.dtype))
        if ctx.needs_input_grad[1]:
            grads[1] = torch.stack([scatter(0.5 * dl_dsigma * dx * dx), scatter(dl_dsigma * dx * dy),
                                    scatter(0.5 * dl_dsigma * dy * dy)], dim=1)
        if ctx.needs_input_grad[2]:
            grads[2] = scatter(dl_dalpha * raw / columns.o.index_select(0, gid))
        if ctx.needs_input_grad[3]:
            per_channel = (weight[:, None] * g_img).T.contiguous()
            grads[3] = torch.stack([scatter(values) for values in per_channel], dim=1)
        return tuple(grads)
