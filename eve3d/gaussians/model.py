"""The Gaussian model: parameters, 3DGS initialisation, spherical harmonics, standard PLY I/O.

Parameters live in one dict of leaf tensors (activations applied on use), so that
densification can duplicate, split and remove rows with one shared operation per dict and
every parameter keeps its own optimiser state. Saved as the standard 3DGS PLY
(x, y, z, nx, ny, nz, f_dc_*, f_rest_*, opacity, scale_*, rot_*) that common viewers open.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from eve3d.core.errors import Eve3dError
from eve3d.core.fileio import atomic_path
from eve3d.core.layout import ENVIRONMENT_FILE
from eve3d.gaussians.environment import Environment

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658,
         1.445305721320277, -0.5900435899266435)


SURFACE_NEIGHBOURS = 8
"""Points around each initial point whose spread tells whether they lie on a surface."""
PLANAR_RATIO = 0.1
"""A neighbourhood is planar when its smallest principal variance is at most this share of
the middle one (surface samples: about 0; points drawn in a volume: about 0.5)."""
LINE_RATIO = 0.01
"""...and its middle variance above this share of the largest: points along a line span no
plane (random samples of a plane: 0.07 at the least of 400, 0.4 typically)."""


def surface_frames(points: np.ndarray, tree=None) -> tuple[np.ndarray, np.ndarray]:
    """For each point, whether its ``SURFACE_NEIGHBOURS`` nearest points lie on a surface
    (bool (N,)), and quaternions (w, x, y, z) (N, 4) of a frame whose third axis is the
    normal of their best-fitting plane (the principal direction of least variance)."""
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    tree = tree or cKDTree(points)
    _, idx = tree.query(points, k=SURFACE_NEIGHBOURS + 1)
    around = points[idx]
    around -= around.mean(axis=1, keepdims=True)
    variances, axes = np.linalg.eigh(np.einsum("nki,nkj->nij", around, around))  # ascending
    frames = axes[:, :, ::-1].copy()  # largest, middle, smallest (the normal) as columns
    frames[np.linalg.det(frames) < 0, :, 0] *= -1
    planar = (variances[:, 0] <= PLANAR_RATIO * variances[:, 1]) & (variances[:, 1] > LINE_RATIO * variances[:, 2])
    return planar, Rotation.from_matrix(frames).as_quat()[:, [3, 0, 1, 2]]


def sh_coefficients(degree: int) -> int:
    """Coefficients per colour channel for SH up to ``degree``."""
    return (degree + 1) ** 2


def rgb_to_sh(rgb: torch.Tensor) -> torch.Tensor:
    return (rgb - 0.5) / SH_C0


def eval_sh(degree: int, sh: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """Colours (N, 3) from SH coefficients (N, K, 3) along unit view directions (N, 3),
    with 3DGS's +0.5 offset and clamp at 0. Uses the first (degree + 1)² coefficients."""
    out = SH_C0 * sh[:, 0]
    if degree > 0:
        x, y, z = (dirs[:, i:i + 1] for i in range(3))
        out = out - SH_C1 * y * sh[:, 1] + SH_C1 * z * sh[:, 2] - SH_C1 * x * sh[:, 3]
        if degree > 1:
            xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
            out = (out + SH_C2[0] * xy * sh[:, 4] + SH_C2[1] * yz * sh[:, 5]
                   + SH_C2[2] * (2 * zz - xx - yy) * sh[:, 6] + SH_C2[3] * xz * sh[:, 7]
                   + SH_C2[4] * (xx - yy) * sh[:, 8])
            if degree > 2:
                out = (out + SH_C3[0] * y * (3 * xx - yy) * sh[:, 9] + SH_C3[1] * xy * z * sh[:, 10]
                       + SH_C3[2] * y * (4 * zz - xx - yy) * sh[:, 11]
                       + SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh[:, 12]
                       + SH_C3[4] * x * (4 * zz - xx - yy) * sh[:, 13] + SH_C3[5] * z * (xx - yy) * sh[:, 14]
                       + SH_C3[6] * x * (xx - 3 * yy) * sh[:, 15])
    return (out + 0.5).clamp_min(0)


class GaussianModel:
    """N Gaussians. ``params``: means (N, 3), quats (N, 4) (w, x, y, z), log_scales (N, 3),
    logit_opacities (N,), sh0 (N, 1, 3), shN (N, K − 1, 3) for SH degree ``sh_degree``;
    ``environment``: what lies behind them at infinity (None: a constant background)."""

    NAMES = ("means", "quats", "log_scales", "logit_opacities", "sh0", "shN")

    def __init__(self, params: dict[str, torch.Tensor], sh_degree: int, environment: Environment | None = None):
        missing = set(self.NAMES) - set(params)
        if missing:
            raise Eve3dError(f"Gaussian model lacks parameters: {', '.join(sorted(missing))}")
        self.params = params
        self.sh_degree = sh_degree
        self.environment = environment

    def __len__(self) -> int:
        return self.params["means"].shape[0]

    @property
    def scales(self) -> torch.Tensor:
        return self.params["log_scales"].exp()

    @property
    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.params["logit_opacities"])

    def colors(self, camera_center: torch.Tensor, degree: int | None = None) -> torch.Tensor:
        """(N, 3) colours seen from a camera centre, SH up to ``degree`` (default: all)."""
        sh = torch.cat([self.params["sh0"], self.params["shN"]], dim=1)
        dirs = torch.nn.functional.normalize(self.params["means"] - camera_center, dim=-1)
        return eval_sh(self.sh_degree if degree is None else min(degree, self.sh_degree), sh, dirs)

    @classmethod
    def from_points(cls, points: np.ndarray, colors: np.ndarray | None, sh_degree: int = 3,
                    opacity: float = 0.1, thickness: float = 1.0) -> "GaussianModel":
        """3DGS initialisation: scales = √(mean squared distance to the 3 nearest neighbours),
        the given opacity, colours as the SH DC term. ``thickness`` 1: 3DGS's isotropic balls
        with identity rotations. Below 1: where the points around one lie on a surface
        (:func:`surface_frames`), a disc in that surface's plane whose thin axis, along its
        normal, is ``thickness`` × the others; elsewhere still a ball."""
        from scipy.spatial import cKDTree

        points = np.asarray(points, dtype=np.float64)
        if len(points) < 4:
            raise Eve3dError(f"need at least 4 points to initialise Gaussians, got {len(points)}")
        tree = cKDTree(points)
        dist, _ = tree.query(points, k=4)
        scale = np.sqrt(np.maximum((dist[:, 1:] ** 2).mean(axis=1), 1e-14))
        n = len(points)
        quats = np.tile([1.0, 0, 0, 0], (n, 1))
        log_scales = np.log(np.repeat(scale[:, None], 3, axis=1))
        if thickness < 1 and n > SURFACE_NEIGHBOURS:
            planar, frame_quats = surface_frames(points, tree)
            quats[planar] = frame_quats[planar]
            log_scales[planar, 2] += math.log(thickness)
        rgb = np.full((n, 3), 0.5) if colors is None else np.asarray(colors, dtype=np.float64)

        def f32(a):
            return torch.tensor(a, dtype=torch.float32)

        params = {
            "means": f32(points),
            "quats": f32(quats),
            "log_scales": f32(log_scales),
            "logit_opacities": f32(np.full(n, math.log(opacity / (1 - opacity)))),
            "sh0": rgb_to_sh(f32(rgb))[:, None, :],
            "shN": torch.zeros(n, sh_coefficients(sh_degree) - 1, 3),
        }
        return cls(params, sh_degree)

    def to(self, device: torch.device | str) -> "GaussianModel":
        """The same Gaussians as float32 contiguous tensors on ``device`` (no autograd history)."""
        return GaussianModel({k: v.detach().to(device).float().contiguous() for k, v in self.params.items()},
                             self.sh_degree, None if self.environment is None else self.environment.to(device))

    def save_ply(self, path: Path) -> None:
        """Standard 3DGS binary PLY, written atomically (:func:`write_ply`), and the
        environment beside it (``environment.npz``; one left by an earlier run is removed)."""
        write_ply(self.params, path)
        beside = Path(path).with_name(ENVIRONMENT_FILE)
        if self.environment is not None:
            self.environment.save(beside)
        else:
            beside.unlink(missing_ok=True)
            beside.with_suffix(".png").unlink(missing_ok=True)

    @classmethod
    def load_ply(cls, path: Path) -> "GaussianModel":
        """Read a 3DGS PLY (:func:`read_ply`) and the environment beside it, if any."""
        beside = Path(path).with_name(ENVIRONMENT_FILE)
        return cls(*read_ply(path), Environment.load(beside) if beside.exists() else None)


def write_ply(params: dict[str, torch.Tensor], path: Path) -> None:
    """Gaussians' parameters as a standard 3DGS binary PLY, written atomically."""
    p = {k: v.detach().cpu().float().numpy() for k, v in params.items()}
    n = len(p["means"])
    columns = [p["means"], np.zeros((n, 3), np.float32), p["sh0"].reshape(n, 3),
               p["shN"].transpose(0, 2, 1).reshape(n, -1),  # channel-major, as 3DGS stores f_rest
               p["logit_opacities"][:, None], p["log_scales"], p["quats"]]
    names = (["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)]
             + [f"f_rest_{i}" for i in range(columns[3].shape[1])] + ["opacity"]
             + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])
    data = np.ascontiguousarray(np.hstack(columns), dtype="<f4")
    header = "ply\nformat binary_little_endian 1.0\n" f"element vertex {n}\n" + "".join(
        f"property float {name}\n" for name in names) + "end_header\n"
    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(data.tobytes())



def read_ply(path: Path) -> tuple[dict[str, torch.Tensor], int]:
    """Parameters and SH degree from a 3DGS PLY (binary little-endian, float properties)."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise Eve3dError(f"{path}: not a PLY file")
    header = raw[:end].decode("ascii", errors="replace").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise Eve3dError(f"{path}: only binary little-endian 3DGS PLY files are supported")
    names = [line.split()[-1] for line in header if line.startswith("property")]
    if any(not line.startswith("property float ") for line in header if line.startswith("property")):
        raise Eve3dError(f"{path}: every vertex property must be float (a 3DGS PLY)")
    count = next(int(line.split()[-1]) for line in header if line.startswith("element vertex"))
    body = raw[end + len(b"end_header\n"):]
    if len(body) < count * len(names) * 4:
        raise Eve3dError(f"{path}: truncated ({len(body)} bytes of data for {count} Gaussians)")
    data = np.frombuffer(body, dtype="<f4", count=count * len(names)).reshape(count, len(names))
    col = {name: i for i, name in enumerate(names)}
    need = ["x", "y", "z", "opacity"] + [f"f_dc_{i}" for i in range(3)] + [f"scale_{i}" for i in range(3)] + [
        f"rot_{i}" for i in range(4)]
    missing = [name for name in need if name not in col]
    if missing:
        raise Eve3dError(f"{path}: missing 3DGS properties {', '.join(missing)}")

    def take(keys):
        return torch.from_numpy(data[:, [col[k] for k in keys]].copy())

    rest = sorted((k for k in col if k.startswith("f_rest_")), key=lambda k: int(k.split("_")[-1]))
    k_rest = len(rest) // 3
    degree = round(math.sqrt(k_rest + 1)) - 1
    if sh_coefficients(degree) - 1 != k_rest or len(rest) % 3:
        raise Eve3dError(f"{path}: {len(rest)} f_rest properties do not match any SH degree")
    params = {
        "means": take(["x", "y", "z"]),
        "quats": take([f"rot_{i}" for i in range(4)]),
        "log_scales": take([f"scale_{i}" for i in range(3)]),
        "logit_opacities": take(["opacity"])[:, 0],
        "sh0": take([f"f_dc_{i}" for i in range(3)])[:, None, :],
        "shN": take(rest).reshape(count, 3, k_rest).transpose(1, 2).contiguous(),
    }
    return params, degree
