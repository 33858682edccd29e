"""``cpu`` backend: tile-based compositing in C++ (``csrc/rasterize.cpp``), OpenMP threads.

Projection stays in PyTorch (autograd); only the per-pixel loops are native. The extension
is compiled on first use with ``torch.utils.cpp_extension`` (about 40 s, then cached in
``$TORCH_EXTENSIONS_DIR`` or ``~/.cache/torch_extensions``). Memory is the image, the tile
lists and one gradient buffer per thread: no per-pair storage, so it stays bounded at any size.
"""
from __future__ import annotations

import functools
import os
import sys
from pathlib import Path

import torch

from eve3d.render.projection import Projected, front_to_back
from eve3d.scene import Eve3dError

SOURCE = Path(__file__).parent / "csrc" / "rasterize.cpp"


@functools.lru_cache(maxsize=1)
def extension():
    """The compiled extension; raises if it cannot be built (no compiler, no OpenMP)."""
    from torch.utils.cpp_extension import load

    # torch builds with ninja; the pip-installed one sits beside this interpreter.
    os.environ["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])
    print("eve3d: loading the C++ rasteriser (compiled once, about 40 s, then cached)", file=sys.stderr)
    return load(name="eve3d_rasterize", sources=[str(SOURCE)], extra_cflags=["-O3", "-fopenmp"],
                extra_ldflags=["-fopenmp"], verbose=False)


@functools.lru_cache(maxsize=1)
def available() -> bool:
    """Whether the extension builds and loads here (tries once per process)."""
    try:
        extension()
    except Exception as exc:  # noqa: BLE001 (any build failure means: use the torch backend)
        print(f"eve3d: the C++ rasteriser is unavailable ({type(exc).__name__}: {exc}); "
              "using the slower pure-PyTorch backend", file=sys.stderr)
        return False
    return True


def rasterize(proj: Projected, opacities: torch.Tensor, features: torch.Tensor, width: int, height: int,
              absgrad: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Alpha-composite ``features`` (N, C) front to back.

    Returns the blended features (H, W, C), alpha (H, W) and the number of pairs composited.
    ``absgrad`` (N, 2), when given, receives Σ over pixels of |∂L/∂mean2d| in the backward pass.
    """
    if features.device.type != "cpu":
        raise Eve3dError(f"render backend 'cpu' needs CPU tensors, got {features.device}; use 'gsplat' or 'torch'")
    visible, boxes = front_to_back(proj, width, height)
    inputs = [x[visible].contiguous() for x in (proj.means2d, proj.conics, opacities, features)]
    image, alpha, n_pairs = _TileComposite.apply(*inputs, boxes.cpu(), width, height, visible, absgrad)
    return image.reshape(height, width, -1), alpha.reshape(height, width), int(n_pairs)


class _TileComposite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opac, feats, boxes, width, height, visible, absgrad):
        image, final_t, consumed, offsets, ids, n_pairs = extension().forward(
            means2d.detach(), conics.detach(), opac.detach(), feats.detach(), boxes, width, height)
        ctx.save_for_backward(means2d, conics, opac, feats, offsets, ids, final_t, consumed)
        ctx.size, ctx.visible, ctx.absgrad = (width, height), visible, absgrad
        ctx.mark_non_differentiable(n_pairs)
        return image, 1 - final_t, n_pairs

    @staticmethod
    def backward(ctx, grad_image, grad_alpha, _):
        means2d, conics, opac, feats, offsets, ids, final_t, consumed = ctx.saved_tensors
        d_means, d_conics, d_opac, d_feats, d_abs = extension().backward(
            means2d.detach(), conics.detach(), opac.detach(), feats.detach(), offsets, ids, final_t, consumed,
            grad_image.contiguous(), grad_alpha.contiguous(), *ctx.size)
        if ctx.absgrad is not None:
            ctx.absgrad.index_add_(0, ctx.visible, d_abs.to(ctx.absgrad.dtype))
        return d_means, d_conics, d_opac, d_feats, None, None, None, None, None
