"""``cpu`` backend: the projection (``csrc/projection.cpp``) and tile-based compositing
(``csrc/rasterize.cpp``) in C++, each with an analytic backward, on OpenMP threads.

The projection fuses what :func:`eve3d.gaussians.render.projection.project_gaussians` does in many
small PyTorch operations (with their autograd graph, about a third of a render's forward and
backward at training sizes); that function stays the reference the tests compare this one
with. The kernels are compiled on first use with ``torch.utils.cpp_extension`` and registered
as torch operators (``torch.ops.eve3d``), then cached in ``$TORCH_EXTENSIONS_DIR`` or
``~/.cache/torch_extensions``. Memory is the image, the tile
lists and one gradient buffer per thread: no per-pair storage, so it stays bounded at any size.
"""
from __future__ import annotations

import functools
import os
import platform
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.timing import step_part
from eve3d.gaussians.render.projection import CameraTensors, Projected

SOURCES = [Path(__file__).parent / "csrc" / name
           for name in ("rasterize.cpp", "projection.cpp", "roundtrip.cpp", "losses.cpp", "ops.cpp", "bindings.cpp")]


def build_tag() -> str:
    """A short hash of this CPU's model and instruction sets and of this checkout's folder. The
    extension is compiled for the machine it runs on (``-march=native`` on x86-64: faster
    compositing than the generic x86-64 build, docs/results.md), so a build cache shared
    between machines (a cluster's home folder) keeps one build per kind of CPU rather than
    loading one that another CPU cannot execute; and one per checkout, since torch rebuilds
    when the sources' paths change (two clones sharing one build rebuilt each other's,
    minutes each time)."""
    import hashlib

    ident = str(Path(__file__).parent) + platform.machine() + platform.processor()
    try:
        lines = Path("/proc/cpuinfo").read_text().splitlines()
        ident += "".join(sorted({ln for ln in lines if ln.startswith(("model name", "flags", "Features"))}))
    except OSError:
        pass
    return hashlib.sha1(ident.encode()).hexdigest()[:10]


@functools.lru_cache(maxsize=1)
def extension():
    """The compiled kernels as torch operators, ``torch.ops.eve3d`` (``csrc/kernels.h``: the
    kernels on plain arrays; ``csrc/ops.cpp``: their tensor side; ``csrc/bindings.cpp``: the
    registration); raises if they cannot be built (no compiler, no OpenMP)."""
    from torch.utils.cpp_extension import load

    # torch builds with ninja; the pip-installed one sits beside this interpreter.
    os.environ["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])
    print("eve3d: loading the C++ rasteriser (compiled once for this CPU and checkout, then cached)", file=sys.stderr)
    native = ["-march=native"] if platform.machine() in ("x86_64", "AMD64") else []
    load(name=f"eve3d_rasterize_{build_tag()}", sources=[str(p) for p in SOURCES], is_python_module=False,
         extra_cflags=["-O3", *native, "-fno-trapping-math", "-fopenmp"], extra_ldflags=["-fopenmp"], verbose=False)
    return torch.ops.eve3d


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


def fused_here(image: torch.Tensor, maps: Sequence[torch.Tensor] = ()) -> bool:
    """Whether a loss runs in the extension: CPU tensors, neighbours' maps of one size (the
    multi-view terms stack them; the image losses pass none), and an extension that builds here."""
    return image.device.type == "cpu" and all(m.shape == maps[0].shape for m in maps) and available()


def project(means: torch.Tensor, quats: torch.Tensor, scales: torch.Tensor, opacities: torch.Tensor,
            cam: CameraTensors, near: float = 0.01, far: float = 1e10, antialiased: bool = False
            ) -> tuple[Projected, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`eve3d.gaussians.render.projection.project_gaussians` in C++: the projection, the
    opacities the rasteriser uses, camera-space normals (N, 3) and plane distances (N,)."""
    if means.device.type != "cpu":
        raise Eve3dError(f"render backend 'cpu' needs CPU tensors, got {means.device}; use 'gsplat' or 'torch'")
    means2d, conics, depths, radii, compensation, normals, distances, opac = _FusedProjection.apply(
        means, quats, scales, opacities, cam, near, far, antialiased)
    return Projected(means2d, conics, depths, radii, compensation), opac, normals, distances


class _FusedProjection(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, cam, near, far, antialiased):
        camera = (cam.R.to(means.dtype), cam.t.to(means.dtype), cam.fx, cam.fy, cam.cx, cam.cy, cam.width,
                  cam.height, near)
        outputs = extension().project_forward(means.detach(), quats.detach(), scales.detach(), opacities.detach(),
                                              *camera, far, antialiased)
        ctx.save_for_backward(means, quats, scales, opacities)
        ctx.camera, ctx.antialiased = camera, antialiased
        ctx.mark_non_differentiable(outputs[3])  # radii
        return tuple(outputs)

    @staticmethod
    def backward(ctx, g_means2d, g_conics, g_depths, _, g_compensation, g_normals, g_distances, g_opac):
        means, quats, scales, opacities = ctx.saved_tensors
        grads = extension().project_backward(means.detach(), quats.detach(), scales.detach(), opacities.detach(),
                                             *ctx.camera, ctx.antialiased, g_means2d, g_conics, g_depths,
                                             g_compensation, g_normals, g_distances, g_opac)
        return (*grads, None, None, None, None)


@step_part("rasterize")
def rasterize(proj: Projected, opacities: torch.Tensor, features: torch.Tensor, width: int, height: int,
              absgrad: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, int]:
    """Alpha-composite ``features`` (N, C) front to back.

    Returns the blended features (H, W, C), alpha (H, W) and the number of pairs composited.
    ``absgrad`` (N, 2), when given, receives Σ over pixels of |∂L/∂mean2d| in the backward pass.
    """
    if features.device.type != "cpu":
        raise Eve3dError(f"render backend 'cpu' needs CPU tensors, got {features.device}; use 'gsplat' or 'torch'")
    visible, boxes = extension().front_to_back(proj.radii, proj.depths.detach(), proj.means2d.detach(), width, height)
    # The C++ side reads the visible Gaussians through their indices: no gathers here, and its
    # gradients come back for all N.
    inputs = [x.contiguous() for x in (proj.means2d, proj.conics, opacities, features)]
    image, alpha, n_pairs = _TileComposite.apply(*inputs, boxes.cpu(), width, height, visible, absgrad)
    return image.reshape(height, width, -1), alpha.reshape(height, width), int(n_pairs)


class _TileComposite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opac, feats, boxes, width, height, visible, absgrad):
        image, final_t, consumed, offsets, ids, n_pairs = extension().forward(
            means2d.detach(), conics.detach(), opac.detach(), feats.detach(), boxes, visible, width, height)
        ctx.save_for_backward(means2d, conics, opac, feats, offsets, ids, final_t, consumed)
        ctx.size, ctx.absgrad = (width, height), absgrad
        ctx.mark_non_differentiable(n_pairs)
        return image, 1 - final_t, n_pairs

    @staticmethod
    def backward(ctx, grad_image, grad_alpha, _):
        means2d, conics, opac, feats, offsets, ids, final_t, consumed = ctx.saved_tensors
        d_means, d_conics, d_opac, d_feats, d_abs = extension().backward(
            means2d.detach(), conics.detach(), opac.detach(), feats.detach(), offsets, ids, final_t, consumed,
            grad_image.contiguous(), grad_alpha.contiguous(), *ctx.size)
        if ctx.absgrad is not None:
            ctx.absgrad.add_(d_abs.to(ctx.absgrad.dtype))
        return d_means, d_conics, d_opac, d_feats, None, None, None, None, None
