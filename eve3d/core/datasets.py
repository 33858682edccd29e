"""Benchmarks as users download them: where each scene's files lie under one ``root``, and
the checks that stop a misplaced or mismatched file before any training.

A benchmark config (``config/benchmarks/{dtu,tnt,mipnerf360}.yaml``) names its layout
(``benchmark: dtu``), the folder of the download (``root``, in the file or on the command
line: ``--config root=/data/DTU``) and its scenes by their released names; each scene is
expanded here into an ordinary workflow scene (``path`` and its ground-truth keys). The
checks here only look for files (planning runs them on every run); the ones that read the
cameras and the ground truth run in the workflow's ``check_ground_truth`` job, before any
training (``eve3d.evaluate.Protocol.check_ground_truth``).

The trees each layout expects (docs/benchmarks.md)::

    dtu:        {root}/scan24/{images or image, mask, cameras.npz[, sparse/0]}   2DGS / NeuS / IDR release
                {root}/Points/stl/stl024_total.ply                                official DTU evaluation
                {root}/ObsMask/ObsMask24_10.mat, {root}/ObsMask/Plane24.mat
    tnt:        {root}/Barn/{images, sparse/0}                                     GOF / 2DGS COLMAP release
                {root}/Barn/{Barn_COLMAP_SfM.log, Barn_trans.txt, Barn.json, Barn.ply}   official evaluation files
    mipnerf360: {root}/garden/{images, images_2, images_4, images_8, sparse/0}    360_v2.zip as released
"""
from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from eve3d.core.errors import Eve3dError


def _expected(path: Path, what: str, root: Path, named: bool = False) -> Eve3dError:
    """The error for a file that is not where the layout puts it. For a file whose name
    names its scene (``named``: ``ObsMask24_10.mat``, ``Barn.ply``), also the place a file
    of that name was found instead under ``root``."""
    found = next((p for p in root.rglob(path.name) if p != path), None) if named and root.is_dir() else None
    where = f"; found {found}: move it there" if found else ""
    return Eve3dError(f"{path}: not found ({what}){where}")


def _need(path: Path, what: str, root: Path, folder: bool = False, named: bool = False) -> Path:
    if not (path.is_dir() if folder else path.is_file()):
        raise _expected(path, what, root, named)
    return path


# --------------------------------------------------------------------------- DTU

def dtu_scan(name: str) -> int:
    match = re.fullmatch(r"scan(\d+)", name)
    if not match:
        raise Eve3dError(f"{name}: a DTU scene is named scanN (scan24, scan37, ...)")
    return int(match.group(1))


def dtu_files(root: Path, name: str) -> dict[str, Path]:
    """The official evaluation files of scan ``name`` (DTUeval-python's paths: only the STL
    number is zero-padded)."""
    scan = dtu_scan(name)
    return {"stl": root / "Points" / "stl" / f"stl{scan:03d}_total.ply",
            "obs_mask": root / "ObsMask" / f"ObsMask{scan}_10.mat",
            "plane": root / "ObsMask" / f"Plane{scan}.mat"}


def dtu_scene(root: Path, name: str) -> dict:
    folder = _need(root / name, "the scan's folder of the 2DGS/NeuS/IDR release", root, folder=True)
    _need(folder / "cameras.npz", "the scan's cameras (world_mat_i, scale_mat_i)", root)
    if not any((folder / d).is_dir() for d in ("images", "image")):
        raise _expected(folder / "images", "the scan's photos (images/ or image/)", root)
    _need(folder / "mask", "the object masks the DTU protocol culls the mesh with", root, folder=True)
    files = dtu_files(root, name)
    for key, path in files.items():
        _need(path, f"DTU's official {'Points/stl point cloud' if key == 'stl' else 'ObsMask folder file'} "
                    f"of {name}", root, named=True)
    return {"path": str(folder), "dtu": {k: str(v) for k, v in files.items()}}


# --------------------------------------------------------------------------- Tanks and Temples

def tnt_scene(root: Path, name: str) -> dict:
    folder = _need(root / name, "the scene's folder of the GOF/2DGS COLMAP release", root, folder=True)
    _need(folder / "images", "the scene's photos", root, folder=True)
    from eve3d.core.io.colmap import find_colmap_model

    if find_colmap_model(folder) is None:
        raise _expected(folder / "sparse" / "0", "the scene's COLMAP model (cameras, images, points3D)", root)
    from eve3d.core.io.tnt import ground_truth_files

    for path in ground_truth_files(folder, name).values():
        _need(path, f"the official T&T evaluation file of {name}", root, named=True)
    return {"path": str(folder)}


# --------------------------------------------------------------------------- Mip-NeRF 360

def mipnerf360_scene(root: Path, name: str) -> dict:
    folder = _need(root / name, "the scene's folder of 360_v2.zip", root, folder=True)
    _need(folder / "images", "the scene's full-size photos", root, folder=True)
    from eve3d.core.io.colmap import find_colmap_model

    if find_colmap_model(folder) is None:
        raise _expected(folder / "sparse" / "0", "the scene's COLMAP model", root)
    return {"path": str(folder)}


# --------------------------------------------------------------------------- registry

@dataclass(frozen=True)
class Benchmark:
    name: str
    title: str
    scene: Callable[[Path, str], dict]
    """(root, released scene name) → the workflow scene's keys, after checking its files."""
    protocol: str
    """The evaluation protocol its scenes are scored by (``eve3d.evaluate.PROTOCOLS``)."""
    standin: str
    """``function`` of :mod:`eve3d.tools.standin` that writes a generated scene in this layout
    (``eve3d bench standin``, the workflow tests' miniatures), and the released scene it is
    written as: ``write_tnt_release:Barn``."""
    published: tuple[tuple[str, str, float], ...] = ()
    """(method, summary.csv column, value): the means over the benchmark's scenes that the
    Eve3D paper reports (GPU, half resolution; DESIGN §4), shown beside a run's means."""

    def published_rows(self) -> list[dict]:
        rows: dict[str, dict] = {}
        for method, metric, value in self.published:
            rows.setdefault(method, {"source": "published (Eve3D paper)", "method": method})[metric] = value
        return list(rows.values())


BENCHMARKS: dict[str, Benchmark] = {b.name: b for b in (
    Benchmark("dtu", "DTU (2DGS/NeuS release, official Points/stl and ObsMask)", dtu_scene, "dtu",
              "write_dtu_release:scan24", published=(("pgsr", "chamfer", 0.52),)),
    Benchmark("tnt", "Tanks and Temples (GOF/2DGS COLMAP release, official evaluation files)", tnt_scene, "tnt",
              "write_tnt_release:Barn",
              published=(("eve3d", "fscore", 0.58), ("eve3d-fast", "fscore", 0.56), ("pgsr", "fscore", 0.51),
                         ("stereo-tsdf", "fscore", 0.35))),
    Benchmark("mipnerf360", "Mip-NeRF 360 (360_v2.zip as released)", mipnerf360_scene, "nvs",
              "write_mipnerf360_release:room"),
)}


def expand_benchmark(config: dict, source: str = "config") -> dict:
    """``config`` with each scene of its benchmark (``benchmark``, ``root``) expanded into a
    workflow scene: the layout's keys, the scene's own keys over them. Errors name the
    key or the file."""
    name = config.get("benchmark")
    if name is None:
        return config
    if name not in BENCHMARKS:
        raise Eve3dError(f"{source}: benchmark: unknown benchmark {name!r}; choose one of {', '.join(BENCHMARKS)}")
    if not config.get("root"):
        raise Eve3dError(f"{source}: root: set the folder of the {BENCHMARKS[name].title} download, in the "
                         f"file or on the command line (snakemake --configfile {source} --config root=/data/...)")
    root = Path(str(config["root"])).expanduser()
    if not root.is_dir():
        raise Eve3dError(f"{source}: root: {root} is not a folder")
    for scene, own in config["scenes"].items():
        try:
            config["scenes"][scene] = {**BENCHMARKS[name].scene(root, scene), "protocol": BENCHMARKS[name].protocol,
                                       **(own or {})}
        except Eve3dError as e:
            raise Eve3dError(f"{source}: scenes.{scene} ({name} benchmark): {e}") from None
    return config
