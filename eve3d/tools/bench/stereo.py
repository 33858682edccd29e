"""``eve3d bench stereo``: SGBM on a Middlebury-like pair, and the priors' accuracy against the exact depth."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from eve3d.core.errors import Eve3dError
from eve3d.evaluate.depth import WEAK_TEXTURE


def stereo_motorcycle(block_size: int = 5, lr_threshold: float = 1.0, wls: bool = False) -> dict:
    """``sgbm`` on the Middlebury Motorcycle pair that scikit-image ships (real photos,
    ground-truth disparity; inf = unknown): density (confident / known pixels), end-point
    error and bad-2.0 (% of confident pixels off by more than 2 px)."""
    from skimage import data

    from eve3d.core.settings_stereo import SgbmSettings
    from eve3d.priors.sgbm import sgbm_disparity

    left, right, gt = data.stereo_motorcycle()
    known = np.isfinite(gt)
    start = time.perf_counter()
    disp, confidence = sgbm_disparity(left, right, float(np.max(gt[known])),
                                      SgbmSettings(block_size=block_size, lr_threshold=lr_threshold, wls=wls))
    seconds = time.perf_counter() - start
    used = known & (confidence >= 0.5)
    err = np.abs(disp[used] - gt[used])
    return {"data": "Motorcycle (Middlebury, skimage)", "backend": "sgbm+wls" if wls else "sgbm", "size": f"{left.shape[1]}x{left.shape[0]}",
            "density": float(used.sum() / known.sum()), "epe": float(err.mean()),
            "bad2": float((err > 2).mean() * 100), "seconds": seconds}


def prior_accuracy(priors_dir, reference_dir, scene: str = "") -> dict:
    """:func:`eve3d.evaluate.depth.depth_accuracy` of one folder of priors
    (``results/{scene}/priors/{backend}``), named by its backend; on a generated scene's
    weakly textured pixels too, from its photos (``results/{scene}/input/images``)."""
    from pathlib import Path

    from eve3d.core.layout import Layout
    from eve3d.evaluate.depth import depth_accuracy

    scene_dir = Path(priors_dir).parent.parent
    images = Layout(scene_dir.parent).input(scene_dir.name) / "images"
    return {**depth_accuracy(priors_dir, reference_dir, scene, images=images if images.is_dir() else None),
            "backend": Path(priors_dir).name}


def format_stereo_tables(moto: list[dict], priors: list[dict], agreement: list[dict] = ()) -> str:
    lines = ["real pair (Middlebury Motorcycle): confident pixels only",
             "backend  size     density  EPE px  bad-2.0 %  seconds"]
    lines += [f"{r['backend']:<8} {r['size']:<8} {r['density']:7.3f}  {r['epe']:6.3f}  {r['bad2']:9.2f}  "
              f"{r['seconds']:7.2f}" for r in moto]
    if priors:
        lines += ["", "synthetic scenes: priors against the exact depth, confident pixels"]
        lines += prior_lines("scene / priors", [r["data"] for r in priors], priors)
    if agreement:
        lines += ["", "without ground truth: neighbouring views' priors against each other, confident pixels"]
        lines += agreement_lines(agreement)
    return "\n".join(lines)


def agreement_lines(rows: list[dict]) -> list[str]:
    """A table of :func:`eve3d.evaluate.depth.prior_agreement` rows."""
    width = max(len("priors"), *(len(r["data"]) for r in rows))
    lines = [f"{'priors':<{width}} {'density':>8} {'median disagreement':>20} {'over 5 %':>9} {'compared':>9}"]
    for r in rows:
        median = "-" if r["median_disagreement"] is None else f"{r['median_disagreement'] * 100:.2f} %"
        over = "-" if r["disagree_5"] is None else f"{r['disagree_5'] * 100:.1f} %"
        lines.append(f"{r['data']:<{width}} {r['density']:8.3f} {median:>20} {over:>9} {r['compared']:>9,}")
    return lines


def prior_lines(title: str, labels: list[str], rows: list[dict]) -> list[str]:
    """A table of :func:`prior_accuracy` rows, one label each."""
    width = max(len(title), *map(len, labels))
    weak = any("weak_share" in r for r in rows)
    lines = [f"{title:<{width}} {'median signed':>13} {'median rel. error':>17} {'density':>8} {'off >5 %':>9} "
             f"{'off >10 %':>9} {'on empty':>9}" + (f" {'weak texture: share':>19} {'density':>8} {'signed':>8} {'error':>8}"
                                                   if weak else "")]

    def percent(v, f=".2f"):
        return "-" if v is None else f"{v * 100:{f}} %"

    for label, r in zip(labels, rows):
        line = f"{label:<{width}} "
        if r["median_signed_error"] is None:  # no confident pixel with an exact depth
            line += f"{'-':>13} {'-':>17} {r['density']:8.3f} {'-':>9} {'-':>9} "
        else:
            line += (f"{r['median_signed_error'] * 100:+11.2f} % {r['median_rel_error'] * 100:15.2f} % "
                     f"{r['density']:8.3f} {r['wrong_5'] * 100:7.1f} % {r['wrong_10'] * 100:7.1f} % ")
        line += f"{percent(r.get('on_empty')):>9}"
        if weak:
            signed = r.get("weak_signed_error")
            line += (f" {percent(r.get('weak_share'), '.1f'):>19} {r.get('weak_density', 0):8.3f} "
                     f"{'-' if signed is None else f'{signed * 100:+.2f} %':>8} {percent(r.get('weak_rel_error')):>8}")
        lines.append(line)
    if weak:
        lines.append(f"weak texture: pixels with a surface whose photo varies less than {WEAK_TEXTURE:g} grey levels "
                     f"over the matcher's window")
    return lines


def run_bench_stereo(priors: list[Path], scene: Path | None = None, as_json: bool = False) -> None:
    """``eve3d bench stereo``: the Motorcycle pair, then each prior folder scored against the
    oracle beside it, or (a real capture, no oracle) its views' agreement over ``scene``."""
    import json

    rows, agreement = [], []
    for folder in map(Path, priors):
        oracle, label = folder.parent / "oracle", f"{folder.parent.parent.name}/{folder.name}"
        if oracle.is_dir():
            rows.append(prior_accuracy(folder, oracle, label))
        elif scene:
            from eve3d.core.io import load_scene
            from eve3d.evaluate.depth import prior_agreement

            agreement.append({**prior_agreement(load_scene(scene, check_images=False), folder), "data": label})
        else:
            raise Eve3dError(f"{folder}: no oracle priors beside it ({oracle}) to score against; give --scene (the "
                             f"posed dataset) to measure how neighbouring views' priors agree instead")
    moto = [stereo_motorcycle(), stereo_motorcycle(wls=True)]
    print(json.dumps({"motorcycle": moto, "priors": rows, "agreement": agreement}, indent=2) if as_json
          else format_stereo_tables(moto, rows, agreement))
