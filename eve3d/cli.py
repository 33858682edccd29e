"""``eve3d <stage> ...``: one subcommand per stage; every Snakemake rule calls one of these."""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

from eve3d.scene import Eve3dError


def _cmd_synth(a: argparse.Namespace) -> None:
    from eve3d.synth import generate

    generate(a.kind, Path(a.out), views=a.views, width=a.width, height=a.height, seed=a.seed,
             images_only=a.images_only, arc=a.arc)
    print(f"wrote {a.out}")


def _cmd_sfm(a: argparse.Namespace) -> None:
    from eve3d.settings import SfmSettings
    from eve3d.sfm import run_sfm

    settings = SfmSettings(matcher=a.matcher, camera_model=a.camera_model, single_camera=not a.per_image_camera,
                           max_image_size=a.max_image_size, min_registered_fraction=a.min_registered_fraction,
                           seed=a.seed, threads=a.threads)
    run_sfm(Path(a.dataset), Path(a.out), settings)
    print(f"wrote {a.out}")


def _cmd_stereo_render(a: argparse.Namespace) -> None:
    from eve3d.io import load_scene
    from eve3d.settings import BaselineSettings, RenderSettings, from_namespace
    from eve3d.stereo import render_right_views

    info = render_right_views(load_scene(a.scene), Path(a.model), Path(a.out),
                              from_namespace(BaselineSettings, a, "stereo"), RenderSettings(backend=a.backend))
    b = [v["baseline"] for v in info["views"].values()]
    print(f"wrote {len(b)} right views to {a.out}/right (baseline {min(b):.4g} to {max(b):.4g})")


def _cmd_stereo_depth(a: argparse.Namespace) -> None:
    from eve3d.io import load_scene
    from eve3d.settings import MatchCheck, from_namespace

    scene = load_scene(a.scene)
    check = from_namespace(MatchCheck, a, "stereo")
    if a.backend == "oracle":
        from eve3d.priors.oracle import oracle_priors

        oracle_priors(scene, Path(a.out), Path(a.gt_mesh) if a.gt_mesh else None, preview=not a.no_preview)
    elif not a.stereo:
        raise Eve3dError(f"--backend {a.backend} needs --stereo (the output folder of `eve3d stereo-render`)")
    elif a.backend == "sgbm":
        from eve3d.settings import SgbmSettings
        from eve3d.stereo import sgbm_priors

        settings = from_namespace(SgbmSettings, a, "stereo")
        sgbm_priors(scene, Path(a.stereo), Path(a.out), settings, preview=not a.no_preview, check=check)
    else:
        from eve3d.config import load_mapping
        from eve3d.priors.onnx import OnnxStereo
        from eve3d.settings import OnnxSpec, from_mapping
        from eve3d.stereo import stereo_priors

        if not a.onnx:
            raise Eve3dError("--backend onnx needs --onnx SPEC (a YAML/JSON file or inline JSON; config stereo.onnx)")
        spec = from_mapping(OnnxSpec, load_mapping(a.onnx, "--onnx"), "stereo.onnx")
        stereo_priors(scene, Path(a.stereo), Path(a.out), OnnxStereo(spec), "ONNX stereo", preview=not a.no_preview,
                      check=check)
    print(f"wrote {len(scene.cameras)} depth maps to {a.out}")


def _cmd_pretrain(a: argparse.Namespace) -> None:
    from eve3d.config import stage_settings, training_config
    from eve3d.io import load_scene
    from eve3d.pretrain import pretrain
    from eve3d.settings import PretrainSettings

    settings = stage_settings(PretrainSettings, "pretrain", training_config(a.config, a.set))
    metrics = pretrain(load_scene(a.scene), Path(a.out), settings)
    held = metrics["held_out"]
    if held:
        print(f"held-out views ({held['views']}): PSNR {held['psnr']:.2f} dB, SSIM {held['ssim']:.4f}")
    print(f"wrote {a.out}/point_cloud.ply ({metrics['gaussians']} Gaussians)")


def _cmd_joint(a: argparse.Namespace) -> None:
    from eve3d.config import stage_settings, training_config
    from eve3d.io import load_scene
    from eve3d.joint import train_joint
    from eve3d.methods import method
    from eve3d.settings import JointSettings

    config = training_config(a.config, a.set)
    m = method(a.method, config["variants"], "--method")
    if not m.trains:
        raise Eve3dError(f"--method {m.name}: {m.summary}; it is not trained by the joint stage")
    settings = stage_settings(JointSettings, "joint", config, overrides=m.settings, method=m.name)
    metrics = train_joint(load_scene(a.scene), Path(a.out), settings, Path(a.priors) if a.priors else None)
    print(f"training views: PSNR {metrics['train']['psnr']:.2f} dB; wrote {a.out}/point_cloud.ply "
          f"({metrics['gaussians']} Gaussians) and {a.out}/depth/")


def _add_training_options(s: argparse.ArgumentParser) -> None:
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--out", required=True, help="output folder (holds the checkpoint a killed run resumes from)")
    s.add_argument("--config", help="workflow config file (its preset, train/pretrain/joint sections), or an "
                                    "inline JSON mapping; default: the cpu preset")
    s.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one setting, e.g. --set pretrain.iterations=500 (repeatable)")


def _cmd_mesh(a: argparse.Namespace) -> None:
    from eve3d.io import load_scene
    from eve3d.mesh import check_mesh_path, fuse, write_mesh
    from eve3d.settings import MeshSettings

    check_mesh_path(Path(a.out))
    scene = load_scene(a.scene, check_images=False)
    if a.kind:
        scene.kind = a.kind
    settings = MeshSettings(voxel=a.voxel, coarsen=a.coarsen, trunc_factor=a.trunc_factor, depth_max=a.depth_max,
                            min_confidence=a.min_confidence, weight_threshold=a.weight_threshold,
                            largest_cluster=a.largest_cluster, min_cluster_fraction=a.min_cluster_fraction)
    mesh = fuse(scene, Path(a.depth), settings)
    write_mesh(mesh, Path(a.out))
    print(f"wrote {a.out}: {len(mesh.vertices)} vertices, {len(mesh.triangles)} triangles")


def _cmd_evaluate(a: argparse.Namespace) -> None:
    from eve3d.evaluate import EvalInputs, protocol_for
    from eve3d.fileio import atomic_path
    from eve3d.io import load_scene
    from eve3d.settings import EvalSettings, from_namespace

    scene = load_scene(a.scene, check_images=False)
    protocol = protocol_for(a.protocol, scene.extras.get("format", "colmap"), "--protocol")
    reconstruction = a.model if protocol.scores == "model" else a.mesh
    if reconstruction is None:
        flag = "--model (a trained point_cloud.ply)" if protocol.scores == "model" else "--mesh"
        raise Eve3dError(f"the {protocol.name} protocol scores a {protocol.scores}: give {flag}")
    settings = from_namespace(EvalSettings, a, "evaluate")
    optional = lambda v: Path(v) if v else None  # noqa: E731
    inputs = EvalInputs(scene, Path(reconstruction), Path(a.out), gt=optional(a.gt), obs_mask=optional(a.obs_mask),
                        plane=optional(a.plane), settings=settings)
    if bool(a.depth) != bool(a.exact_depth):
        raise Eve3dError("--depth and --exact-depth go together: the maps the mesh fused, and the exact depth of "
                         "the same views")
    metrics = protocol.run(inputs)
    if a.depth:
        from eve3d.evaluate.depth import depth_accuracy

        acc = depth_accuracy(Path(a.depth), Path(a.exact_depth), min_confidence=a.min_confidence)
        metrics.update({"depth_signed_error": acc["median_signed_error"], "depth_error": acc["median_rel_error"],
                        "depth_density": acc["density"], "depth_maps": str(a.depth)})
    if "tau" in metrics:
        print(f"tau = {metrics['tau']:.5g} ({metrics['tau_rule']})")
    metrics.update({"scene": a.scene_name, "method": a.method} if a.scene_name else {})
    from eve3d.layout import EVALUATION, RECORD

    with atomic_path(Path(a.out)) as tmp:
        tmp.write_text(json.dumps({RECORD: EVALUATION, **metrics}, indent=2))
    print(format_table([metrics]))


SUMMARY_COLUMNS = ("scene", "method", "protocol", "tau", "accuracy", "completeness", "chamfer",
                   "precision", "recall", "fscore", "depth_signed_error", "depth_error", "psnr", "ssim")


def _cmd_bench(a: argparse.Namespace) -> None:
    from eve3d import bench

    sizes = bench.RASTERIZER_SIZES
    if a.sizes:
        try:
            sizes = [tuple(int(v) for v in item.split("x")) for item in a.sizes.split(",")]
        except ValueError:
            sizes = []
        if not sizes or any(len(s) != 3 for s in sizes):
            raise Eve3dError(f"--sizes {a.sizes!r}: expected GAUSSIANSxWIDTHxHEIGHT[,...], e.g. 5000x160x120")
    rows = bench.bench_rasterizer(sizes, backend=a.backend, repeats=a.repeats)
    print(bench.rasterizer_json(rows) if a.json else bench.format_rasterizer_table(rows))


def _cmd_bench_stereo(a: argparse.Namespace) -> None:
    from eve3d import bench

    priors = []
    for folder in map(Path, a.priors):
        oracle = folder.parent / "oracle"
        if not oracle.is_dir():
            raise Eve3dError(f"{folder}: no oracle priors beside it ({oracle}) to score against")
        priors.append(bench.prior_accuracy(folder, oracle, f"{folder.parent.parent.name}/{folder.name}"))
    moto = [bench.stereo_motorcycle(), bench.stereo_motorcycle(wls=True)]
    print(json.dumps({"motorcycle": moto, "priors": priors}, indent=2) if a.json
          else bench.format_stereo_tables(moto, priors))


def _cmd_bench_evaluate(a: argparse.Namespace) -> None:
    from eve3d import bench

    if a.meshes and not (a.scene and a.gt):
        raise Eve3dError("--meshes needs --scene (the cameras) and --gt (the GT mesh)")
    rows = bench.bench_evaluate([("/".join(Path(m).parts[-3:]), str(m)) for m in a.meshes], a.scene, a.gt)
    print(json.dumps(rows, indent=2) if a.json else bench.format_evaluate_table(rows))


def _cmd_bench_methods(a: argparse.Namespace) -> None:
    import subprocess

    from eve3d import bench
    from eve3d.config import REPO, load_config
    from eve3d.layout import Layout

    config = load_config(a.config)
    if not a.report_only:
        cmd = [sys.executable, "-m", "snakemake", "-s", str(REPO / "Snakefile"), "--configfile", a.config,
               "--replace-workflow-config", f"-c{a.cores}", "--quiet", "rules", "progress"]
        if subprocess.run(cmd).returncode != 0:
            raise Eve3dError(f"the workflow of {a.config} failed (its logs: {Layout(config['results']).logs()}/)")
    report = bench.methods_report(config)
    print(json.dumps(report, indent=2) if a.json else bench.format_methods_report(report))


def format_table(rows: list[dict], columns: tuple[str, ...] = SUMMARY_COLUMNS) -> str:
    """A plain-text table of metric rows (missing values as '-')."""
    def cell(v):
        return f"{v:.4g}" if isinstance(v, float) else ("-" if v is None else str(v))

    cols = [c for c in columns if any(c in r for r in rows)]
    table = [cols] + [[cell(r.get(c)) for c in cols] for r in rows]
    widths = [max(len(row[i]) for row in table) for i in range(len(cols))]
    lines = ["  ".join(v.ljust(w) for v, w in zip(row, widths)) for row in table]
    return "\n".join([lines[0], "  ".join("-" * w for w in widths)] + lines[1:])


VIEW_COLUMNS = ("scene", "stage", "views", "psnr", "ssim")


def _cmd_summary(a: argparse.Namespace) -> None:
    from eve3d.layout import EVALUATION, METRICS_FILE, RECORD, TRAIN_METRICS_FILE, TRAINING, locate

    rows, view_rows = [], []
    for path in map(Path, a.metrics):
        try:
            m = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise Eve3dError(f"{path}: cannot read metrics ({e})") from None
        if not isinstance(m, dict) or m.get(RECORD) not in (EVALUATION, TRAINING):
            found = f"{RECORD!r} is {m[RECORD]!r}" if isinstance(m, dict) and RECORD in m else f"no {RECORD!r} field"
            raise Eve3dError(f"{path}: {found}; a metrics record says what it holds: {RECORD!r}: {EVALUATION!r} "
                             f"({METRICS_FILE}, written by eve3d evaluate) or {TRAINING!r} ({TRAIN_METRICS_FILE}, "
                             f"written by pretrain and joint); rerun the stage that wrote it (snakemake --forcerun evaluate)")
        record = m[RECORD]
        scene, stage = locate(path)  # names the row when the record does not
        if record == TRAINING:  # a training stage's novel-view metrics
            view_rows.append({"scene": scene, "stage": stage, **m["held_out"]})
            continue
        m.setdefault("scene", scene)
        m.setdefault("method", stage)
        rows.append(m)
    rows.sort(key=lambda r: (r["scene"], r["method"]))
    out = Path(a.out)
    _write_csv(out, SUMMARY_COLUMNS, rows)
    print(format_table(rows, SUMMARY_COLUMNS))
    if view_rows:
        view_rows.sort(key=lambda r: (r["scene"], r["stage"]))
        _write_csv(out.with_name(f"{out.stem}_views.csv"), VIEW_COLUMNS, view_rows)
        print("\nheld-out views of the training stages (at the training resolution)")
        print(format_table(view_rows, VIEW_COLUMNS))


def _write_csv(path: Path, columns: tuple[str, ...], rows: list[dict]) -> None:
    from eve3d.fileio import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)


def build_parser() -> argparse.ArgumentParser:
    from eve3d.settings import BASELINE_MODES, SGM_MODES, BaselineSettings, MatchCheck, MeshSettings, SgbmSettings
    from eve3d.synth import KINDS

    p = argparse.ArgumentParser(prog="eve3d", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("synth", help="generate a synthetic scene with exact ground truth")
    s.add_argument("kind", choices=list(KINDS))
    s.add_argument("out", help="output dataset folder (replaced atomically)")
    s.add_argument("--views", type=int, default=32)
    s.add_argument("--width", type=int, default=320)
    s.add_argument("--height", type=int, default=240)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--arc", type=float, default=360.0, help="azimuth range of the cameras in degrees")
    s.add_argument("--images-only", action="store_true", help="hide the poses under gt/ (to exercise SfM)")
    s.set_defaults(func=_cmd_synth)

    s = sub.add_parser("sfm", help="pycolmap SfM (or undistortion only) → images/ + sparse/0 (PINHOLE)")
    s.add_argument("dataset", help="folder with images/ (and optionally a distorted COLMAP model)")
    s.add_argument("out")
    s.add_argument("--matcher", choices=["exhaustive", "sequential"], default="exhaustive")
    s.add_argument("--camera-model", default="SIMPLE_RADIAL")
    s.add_argument("--per-image-camera", action="store_true", help="one camera per image instead of one shared")
    s.add_argument("--max-image-size", type=int, default=3200)
    s.add_argument("--min-registered-fraction", type=float, default=0.9)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--threads", type=int, default=1,
                   help="1 (default): bit-reproducible; -1: every core, faster but varies between runs")
    s.set_defaults(func=_cmd_sfm)

    s = sub.add_parser("stereo-render", help="right views of virtual stereo pairs, rendered by the pretrained model")
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--model", required=True, help="pretrained 3DGS PLY (pretrain/point_cloud.ply)")
    s.add_argument("--out", required=True, help="output folder: right/{view}.png and pairs.json (replaced atomically)")
    base = BaselineSettings()
    s.add_argument("--baseline", choices=BASELINE_MODES, default=base.baseline,
                   help="disparity: B per view for --target-disparity at its median depth; radius: the paper's "
                        "B = --baseline-factor × scene radius")
    s.add_argument("--baseline-factor", type=float, default=base.baseline_factor,
                   help="radius mode: B = factor × scene radius")
    s.add_argument("--target-disparity", type=float, default=base.target_disparity,
                   help="disparity mode: disparity at the view's median depth, as a fraction of the image width")
    s.add_argument("--max-baseline", type=float, default=base.max_baseline,
                   help="disparity mode: B at most this fraction of the view's median depth")
    s.add_argument("--backend", choices=["auto", "cpu", "torch", "gsplat"], default="auto")
    s.set_defaults(func=_cmd_stereo_render)

    s = sub.add_parser("stereo-depth", help="depth priors per view ({view}.npz + PNG previews)")
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--out", required=True, help="output folder (replaced atomically)")
    s.add_argument("--backend", choices=["oracle", "sgbm", "onnx"], default="oracle",
                   help="oracle = exact depth of a scene with a known mesh; sgbm = OpenCV SGBM on the stereo pairs; "
                        "onnx = a stereo network exported to ONNX (--onnx)")
    s.add_argument("--onnx", help="onnx: the model spec, a YAML/JSON file or inline JSON (keys: eve3d.settings.OnnxSpec)")
    s.add_argument("--gt-mesh", help="mesh for the oracle (default: the scene's own GT mesh)")
    s.add_argument("--stereo", help="sgbm: the output folder of `eve3d stereo-render`")
    sgbm = SgbmSettings()
    s.add_argument("--sgm-mode", choices=list(SGM_MODES), default=sgbm.sgm_mode,
                   help="sgbm: cost aggregation: hh = 8 directions in two passes (unbiased on slanted surfaces); "
                        "hh4 = 4; 3way and sgbm = single pass (faster, less memory, biased on slopes)")
    s.add_argument("--block-size", type=int, default=sgbm.block_size)
    s.add_argument("--uniqueness", type=int, default=sgbm.uniqueness)
    s.add_argument("--lr-threshold", type=float, default=sgbm.lr_threshold, help="left–right check tolerance in pixels")
    s.add_argument("--min-texture", type=float, default=sgbm.min_texture,
                   help="grey-level std (0-255) over the block below which a pixel is not confident")
    s.add_argument("--wls", action="store_true",
                   help="sgbm: WLS-filter the disparity (dense; confidence = the filter's confidence map)")
    s.add_argument("--wls-lambda", type=float, default=sgbm.wls_lambda, help="WLS smoothness weight")
    s.add_argument("--wls-sigma", type=float, default=sgbm.wls_sigma, help="WLS colour sensitivity")
    check = MatchCheck()
    s.add_argument("--ncc-threshold", type=float, default=check.ncc_threshold,
                   help="sgbm/onnx: confident only where the photo and the right view warped back by the disparity "
                        "have at least this NCC (0 = off)")
    s.add_argument("--ncc-window", type=int, default=check.ncc_window, help="NCC window (px)")
    s.add_argument("--range-margin", type=float, default=check.range_margin,
                   help="not confident within this many px of either end of the disparity range searched")
    s.add_argument("--mv-ncc-threshold", type=float, default=check.mv_ncc_threshold,
                   help="sgbm/onnx: confident only where at least --mv-views of the --mv-neighbours best neighbours' "
                        "photos, warped by the prior depth, have at least this NCC with the photo (0 = off)")
    s.add_argument("--mv-views", type=int, default=check.mv_views)
    s.add_argument("--mv-neighbours", type=int, default=check.mv_neighbours)
    s.add_argument("--no-preview", action="store_true")
    s.set_defaults(func=_cmd_stereo_depth)

    s = sub.add_parser("pretrain", help="short photometric 3DGS fit (Mini-Splatting style) → point_cloud.ply")
    _add_training_options(s)
    s.set_defaults(func=_cmd_pretrain)

    s = sub.add_parser("joint", help="train a method's Gaussians and render its depth for meshing")
    from eve3d.methods import methods

    s.add_argument("--method", required=True, help="a trained method: " + ", ".join(
        n for n, m in methods().items() if m.trains) + ", or a variant the --config defines")
    s.add_argument("--priors", help="the stereo priors (results/SCENE/priors/BACKEND) of a method that uses them")
    _add_training_options(s)
    s.set_defaults(func=_cmd_joint)

    s = sub.add_parser("mesh", help="TSDF-fuse per-view depth maps into mesh.ply")
    s.add_argument("--scene", required=True)
    s.add_argument("--depth", required=True, help="folder of {view}.npz depth maps")
    s.add_argument("--out", required=True, help="mesh file to write (.ply)")
    s.add_argument("--kind", choices=["object", "scene"], help="override the scene kind")
    s.add_argument("--voxel", type=float)
    s.add_argument("--coarsen", type=float, default=1.0)
    s.add_argument("--trunc-factor", type=float, default=4.0)
    s.add_argument("--depth-max", type=float)
    s.add_argument("--min-confidence", type=float, default=MeshSettings.min_confidence)
    s.add_argument("--weight-threshold", type=float, default=1.0)
    s.add_argument("--largest-cluster", action=argparse.BooleanOptionalAction, default=None)
    s.add_argument("--min-cluster-fraction", type=float, default=0.01)
    s.set_defaults(func=_cmd_mesh)

    from eve3d.evaluate import DEFAULT_PROTOCOL, PROTOCOLS
    from eve3d.settings import EvalSettings

    defaults = EvalSettings()
    s = sub.add_parser("evaluate", help="a reconstruction vs ground truth → metrics.json",
                       description="Protocols: " + "; ".join(f"{p.name}: {p.summary}" for p in PROTOCOLS.values()))
    s.add_argument("--scene", required=True, help="dataset folder: cameras (visibility, alignment, masks, views)")
    s.add_argument("--mesh", help="the reconstructed mesh (protocols synthetic, dtu, tnt)")
    s.add_argument("--model", help="a trained point_cloud.ply (protocol nvs)")
    s.add_argument("--out", required=True, help="metrics.json (tnt also writes precision.ply and recall.ply beside it)")
    s.add_argument("--protocol", choices=list(PROTOCOLS),
                   help="default by dataset format: " + ", ".join(f"{k} → {v}" for k, v in DEFAULT_PROTOCOL.items()))
    s.add_argument("--gt", help="synthetic: the GT mesh; dtu: the stl…_total.ply point cloud")
    s.add_argument("--tau", type=float, help="distance threshold; default: the protocol's rule")
    s.add_argument("--tau-fraction", type=float, default=defaults.tau_fraction,
                   help="synthetic: τ = this × the visible GT's bounding-box diagonal")
    s.add_argument("--samples", type=int, default=defaults.samples, help="synthetic: surface samples per mesh")
    s.add_argument("--min-views", type=int, default=defaults.min_views,
                   help="synthetic: cameras that must see a GT point for it to count as visible")
    s.add_argument("--obs-mask", help="dtu: ObsMask{scan}_10.mat")
    s.add_argument("--plane", help="dtu: Plane{scan}.mat")
    s.add_argument("--dtu-density", type=float, default=defaults.dtu_density)
    s.add_argument("--dtu-max-dist", type=float, default=defaults.dtu_max_dist)
    s.add_argument("--depth", help="the depth maps the mesh was fused from: their median signed and absolute "
                                   "relative error against --exact-depth are added to the metrics")
    s.add_argument("--exact-depth", help="exact depth maps of the same views (results/SCENE/priors/oracle)")
    s.add_argument("--min-confidence", type=float, default=MeshSettings.min_confidence,
                   help="--depth pixels scored: confidence at least this (the mesh's mesh.min_confidence)")
    s.add_argument("--scene-name")
    s.add_argument("--method")
    s.set_defaults(func=_cmd_evaluate)

    s = sub.add_parser("summary", help="gather metrics.json files into a CSV and print the table")
    s.add_argument("metrics", nargs="+")
    s.add_argument("--out", required=True)
    s.set_defaults(func=_cmd_summary)

    _add_bench_parser(sub)
    return p


def _add_bench_parser(sub) -> None:
    s = sub.add_parser("bench", help="speed and memory benchmarks (print a table)")
    what = s.add_subparsers(dest="benchmark", required=True)
    r = what.add_parser("rasterizer", help="forward/backward time and peak memory of one render")
    r.add_argument("--sizes", help="GAUSSIANSxWIDTHxHEIGHT,... (default 5000x160x120,20000x320x240,100000x640x480)")
    r.add_argument("--backend", choices=["auto", "cpu", "torch", "gsplat"], default="auto")
    r.add_argument("--repeats", type=int, default=5, help="timed runs per size (median; one more warms up)")
    r.add_argument("--json", action="store_true", help="machine-readable output")
    r.set_defaults(func=_cmd_bench)
    st = what.add_parser("stereo", help="sgbm on the Motorcycle pair; priors of synthetic scenes vs exact depth")
    st.add_argument("--priors", nargs="*", default=[], metavar="DIR",
                    help="prior folders (results/{scene}/priors/{backend}) to score against the oracle folder beside them")
    st.add_argument("--json", action="store_true", help="machine-readable output")
    st.set_defaults(func=_cmd_bench_stereo)
    ev = what.add_parser("evaluate", help="time of the synthetic protocol on meshes with floaters (and on given meshes)")
    ev.add_argument("--meshes", nargs="*", default=[], metavar="MESH", help="further meshes to time, e.g. a demo's")
    ev.add_argument("--scene", help="dataset whose cameras the given meshes are scored with")
    ev.add_argument("--gt", help="GT mesh of the given meshes")
    ev.add_argument("--json", action="store_true", help="machine-readable output")
    ev.set_defaults(func=_cmd_bench_evaluate)
    me = what.add_parser("methods", help="run every method on the generated object and room (Snakemake) and print "
                                         "scores, times and the priors' accuracy")
    me.add_argument("--config", default="config/bench/methods.yaml", help="workflow config of the benchmark")
    me.add_argument("--cores", type=int, default=2)
    me.add_argument("--report-only", action="store_true", help="print the table of a finished run without running")
    me.add_argument("--json", action="store_true", help="machine-readable output")
    me.set_defaults(func=_cmd_bench_methods)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except Eve3dError as e:
        print(f"eve3d {args.command}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
