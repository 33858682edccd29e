"""``eve3d bench methods`` and ``eve3d bench real``: a workflow's methods side by side (F-score,
Chamfer, the priors' accuracy, floaters), and a real capture from photos to meshes and scores."""
from __future__ import annotations

import json

import numpy as np

from eve3d.config import named_methods
from eve3d.tools.bench.stereo import agreement_lines, prior_accuracy, prior_lines


def _mean(values: list) -> float | None:
    """The mean, or None when any value is missing."""
    return None if None in values else float(np.mean(values))


def _cell(value, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def methods_report(config: dict) -> dict:
    """The table of ``eve3d bench methods`` from a finished workflow run of ``config``
    (resolved): per scene and method the synthetic protocol's scores and the wall time of
    the method's own stages (joint + mesh; the stages the priors share are listed per
    scene), the means over scenes, and per scene the depth maps' accuracy against the oracle
    depth: D* (``priors/{backend}``), every learnable method's final D̂ and every trained
    method's rendered depth D (the maps its mesh fuses)."""
    from eve3d.core.layout import Layout, benchmark_seconds, job_name
    from eve3d.core.methods import methods

    layout, backend = Layout(config["results"]), config["stereo"]["backend"]
    known = methods(config.get("variants"))
    rows, shared, priors = [], {}, []
    for scene in config["scenes"]:
        names = named_methods(config, scene)
        for name in names:
            path = layout.metrics(scene, name)
            if not path.is_file():
                continue
            m = json.loads(path.read_text())
            stages = [layout.benchmark(scene, "mesh", name)] + (
                [layout.benchmark(scene, "joint", name)] if known[name].trains else [])
            times = [benchmark_seconds(p) for p in stages]
            rows.append({"scene": scene, "method": name, **{k: m.get(k) for k in (
                "chamfer", "precision", "recall", "fscore")},
                "seconds": None if None in times else sum(times)})
        shared[scene] = {job_name(*job): benchmark_seconds(layout.benchmark(scene, *job))
                         for job in (("pretrain",), ("stereo_render",), ("stereo_depth", backend))}
        oracle = layout.priors(scene, "oracle")
        if oracle.is_dir():
            star = layout.priors(scene, backend)
            if star.is_dir():
                priors.append({**prior_accuracy(star, oracle, scene), "priors": f"D* ({backend})"})
            for name in names:
                for maps, what in ((layout.learned_priors(scene, name), "D̂"), (layout.depth(scene, name), "D")):
                    if maps.is_dir():
                        priors.append({**prior_accuracy(maps, oracle, scene), "priors": f"{what} of {name}"})
    means = []
    for name in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == name]
        means.append({"scene": f"mean of {len(mine)}", "method": name, **{
            k: _mean([r[k] for r in mine]) for k in ("chamfer", "precision", "recall", "fscore", "seconds")}})
    return {"rows": rows, "means": means, "shared_seconds": shared, "priors": priors}


def format_methods_report(report: dict) -> str:
    head = f"{'scene':<22} {'method':<18} {'chamfer':>9} {'precision':>9} {'recall':>7} {'F':>7} {'seconds':>8}"
    lines = [head, "-" * len(head)]
    for r in report["rows"] + report["means"]:
        cells = (_cell(r[k], spec) for k, spec in (("chamfer", "9.5f"), ("precision", "9.4f"), ("recall", "7.4f"),
                                                     ("fscore", "7.4f"), ("seconds", "8.0f")))
        lines.append(f"{r['scene']:<22} {r['method']:<18} " + " ".join(cells))
    lines += ["", "seconds = the method's own stages (joint + mesh); shared by every method that uses the priors:"]
    for scene, stages in report["shared_seconds"].items():
        lines.append(f"  {scene}: " + ", ".join(f"{k} {_cell(v, '.0f')} s" for k, v in stages.items()))
    if report["priors"]:
        lines += ["", "depth against the exact depth, on confident pixels (priors: M^c; rendered D: alpha ≥ 0.5);",
                  "on empty: the share of the pixels without a surface that have a confident depth (floaters);",
                  "signed: positive = too far"]
        lines += prior_lines("scene / priors", [f"{r['data']} / {r['priors']}" for r in report["priors"]],
                             report["priors"])
    return "\n".join(lines)


def real_report(config: dict) -> dict:
    """The table of ``eve3d bench real`` from a finished workflow run of ``config``
    (resolved): per scene the photos and the views SfM registered, every job's wall time,
    the held-out PSNR/SSIM of the pretrain and of each trained method, the priors' density
    and the agreement of neighbouring views' priors, and each mesh's triangles and extent
    against the sparse points' 5–95 % box."""
    from pathlib import Path

    import open3d as o3d

    from eve3d.core.io import load_scene
    from eve3d.core.layout import PRETRAIN, Layout, benchmark_seconds
    from eve3d.core.photos import scan_photos
    from eve3d.evaluate.depth import prior_agreement
    from eve3d.mesh import extent_report

    layout, backend = Layout(config["results"]), config["stereo"]["backend"]
    scenes = []
    for name, sc in config["scenes"].items():
        posed = layout.sfm(name) if layout.sfm(name).is_dir() else Path(sc["path"])
        scene = load_scene(posed, check_images=False)
        row = {"scene": name, "photos": len(scan_photos(Path(sc["path"]) / "images")), "registered": len(scene.cameras),
               "points": 0 if scene.points is None else len(scene.points)}
        row["seconds"] = {p.stem: benchmark_seconds(p) for p in sorted(layout.benchmarks(name).glob("*.tsv"))}
        held = {}
        pre = layout.train_metrics(name, PRETRAIN)
        if pre.is_file():
            held[PRETRAIN] = json.loads(pre.read_text()).get("held_out", {})
        meshes = {}
        for method in named_methods(config, name):
            if layout.metrics(name, method).is_file():
                m = json.loads(layout.metrics(name, method).read_text())
                held[method] = {k: m.get(k) for k in ("psnr", "ssim", "views")}
            if layout.mesh(name, method).is_file():
                meshes[method] = extent_report(o3d.io.read_triangle_mesh(str(layout.mesh(name, method))), scene)
        row["held_out"], row["meshes"] = held, meshes
        priors = layout.priors(name, backend)
        row["priors"] = prior_agreement(scene, priors) if priors.is_dir() else None
        scenes.append(row)
    return {"scenes": scenes}


def format_real_report(report: dict) -> str:
    lines = []
    for r in report["scenes"]:
        total = sum(v for v in r["seconds"].values() if v is not None)
        lines += [f"{r['scene']}: {r['registered']} of {r['photos']} photos registered, {r['points']:,} sparse points",
                  "", f"{'job':<28} {'seconds':>8}"]
        lines += [f"{job:<28} {_cell(sec, '8.0f')}" for job, sec in r["seconds"].items()]
        lines += [f"{'total':<28} {total:8.0f}  ({total / 60:.1f} min)", "",
                  f"{'held-out views':<16} {'PSNR dB':>8} {'SSIM':>7} {'views':>6}"]
        lines += [f"{m:<16} {_cell(h.get('psnr'), '8.2f')} {_cell(h.get('ssim'), '7.4f')} {_cell(h.get('views'), '6d')}"
                  for m, h in r["held_out"].items()]
        if r["priors"]:
            lines += ["", "priors, neighbouring views against each other (confident pixels)"]
            lines += agreement_lines([{**r["priors"], "data": "priors"}])
        if r["meshes"]:
            lines += ["", f"{'mesh':<16} {'triangles':>10} {'extent':>26} {'× sparse 5–95 % box':>20}"]
            lines += [f"{m:<16} {x['triangles']:>10,} {' × '.join(f'{e:.2f}' for e in x['extent']):>26} "
                      f"{_cell(x['extent_ratio'], '20.2f')}" for m, x in r["meshes"].items()]
            box = next(iter(r["meshes"].values()))["sparse_extent"]
            if box:
                lines.append(f"sparse points' 5–95 % box: {' × '.join(f'{e:.2f}' for e in box)}")
        lines.append("")
    return "\n".join(lines)


def run_bench_workflow(kind: str, config_file: str, cores: int = 2, report_only: bool = False,
                       as_json: bool = False) -> None:
    """``eve3d bench methods`` and ``eve3d bench real`` (``kind``): run the workflow of a
    benchmark's config (unless ``report_only``), then print the table (or JSON) of
    :func:`methods_report` or :func:`real_report`."""
    import subprocess
    import sys

    from eve3d.config import SNAKEFILE, load_config
    from eve3d.core.errors import Eve3dError
    from eve3d.core.layout import Layout

    report, table = WORKFLOW_BENCHES[kind]
    config = load_config(config_file)
    if not report_only:
        cmd = [sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "--configfile", config_file,
               "--replace-workflow-config", f"-c{cores}", "--quiet", "rules", "progress"]
        if subprocess.run(cmd).returncode != 0:
            raise Eve3dError(f"the workflow of {config_file} failed (its logs: {Layout(config['results']).logs()}/)")
    measured = report(config)
    print(json.dumps(measured, indent=2) if as_json else table(measured))


WORKFLOW_BENCHES = {"methods": (methods_report, format_methods_report), "real": (real_report, format_real_report)}
"""``eve3d bench`` tool → (the report of a finished workflow run, its table)."""
