"""``eve3d <stage> ...``: one subcommand per stage; every Snakemake rule calls one of these."""
from __future__ import annotations

import argparse
import contextlib
import csv
import functools
import json
import sys
from pathlib import Path
from collections.abc import Callable
from typing import Any

from eve3d.core.scene import Eve3dError
from eve3d.report import SUMMARY_COLUMNS


def _config(a: argparse.Namespace) -> dict:
    """The job's configuration (``eve3d.config.job_config``): ``--config``, its preset,
    ``--set``, then the stage's own flags (dests named ``SECTION.KEY``)."""
    from eve3d.config import job_config

    flags = {k: v for k, v in vars(a).items() if "." in k and v is not None}
    return job_config(a.config, a.set, flags)


def _settings(a: argparse.Namespace, cls: type, section: str, config: dict | None = None, **kw: Any) -> Any:
    """``cls`` from the job's ``section`` (``eve3d.config.stage_settings``); an error about a
    key given by a flag names the flag too."""
    from eve3d.config import stage_settings

    return _naming_flags(a, lambda: stage_settings(cls, section, _config(a) if config is None else config, **kw))


def _naming_flags(a: argparse.Namespace, build: Callable[[], Any]) -> Any:
    """``build()``, its error about a key that a flag of ``a`` gave naming that flag too."""
    from eve3d.core.settings import flag

    try:
        return build()
    except Eve3dError as e:
        key, sep, rest = str(e).partition(": ")
        name = key.rsplit(".", 1)[-1]
        if sep and any(k.endswith("." + name) and v is not None for k, v in vars(a).items()):
            raise Eve3dError(f"{key} ({flag(name)}): {rest}") from None
        raise


def _cmd_synth(a: argparse.Namespace) -> None:
    from eve3d.core.settings import SyntheticSettings
    from eve3d.synth import generate

    s = _settings(a, SyntheticSettings, "synthetic")
    generate(a.kind, Path(a.out), views=s.views, width=s.width, height=s.height, seed=s.seed,
             images_only=a.images_only, arc=s.arc, surface_samples=s.surface_samples)
    print(f"wrote {a.out}")


def _cmd_sfm(a: argparse.Namespace) -> None:
    from eve3d.core.settings import SfmSettings
    from eve3d.sfm import run_sfm

    run_sfm(Path(a.dataset), Path(a.out), _settings(a, SfmSettings, "sfm"))
    print(f"wrote {a.out}")


def _cmd_stereo_render(a: argparse.Namespace) -> None:
    from eve3d.core.io import load_scene
    from eve3d.core.settings import BaselineSettings, PretrainSettings, RenderSettings, StereoSettings, pick
    from eve3d.stereo import render_right_views

    config = _config(a)
    stereo = _settings(a, StereoSettings, "stereo", config)
    rendering = pick(RenderSettings, _settings(a, PretrainSettings, "pretrain", config))  # as the model was trained
    info = render_right_views(load_scene(a.scene), Path(a.model), Path(a.out), pick(BaselineSettings, stereo), rendering)
    b = [v["baseline"] for v in info["views"].values()]
    print(f"wrote {len(b)} right views to {a.out}/right (baseline {min(b):.4g} to {max(b):.4g})")


def _cmd_stereo_depth(a: argparse.Namespace) -> None:
    from eve3d.core.io import load_scene
    from eve3d.core.settings import MatchCheck, SgbmSettings, StereoSettings, pick

    scene = load_scene(a.scene)
    s = _settings(a, StereoSettings, "stereo")
    check = pick(MatchCheck, s)
    if s.backend == "oracle":
        from eve3d.priors.oracle import oracle_priors

        oracle_priors(scene, Path(a.out), Path(a.gt_mesh) if a.gt_mesh else None, preview=not a.no_preview)
    elif not a.stereo:
        raise Eve3dError(f"--backend {s.backend} needs --stereo (the output folder of `eve3d stereo-render`)")
    elif s.backend == "sgbm":
        from eve3d.stereo import sgbm_priors

        sgbm_priors(scene, Path(a.stereo), Path(a.out), pick(SgbmSettings, s), preview=not a.no_preview, check=check)
    elif s.backend == "mccnn":
        from eve3d.priors.mccnn import MccnnStereo
        from eve3d.stereo import stereo_priors

        stereo_priors(scene, Path(a.stereo), Path(a.out), MccnnStereo(s.mccnn, s.min_texture, s.block_size), "MC-CNN",
                      preview=not a.no_preview, check=check)
    else:
        from eve3d.priors.onnx import OnnxStereo
        from eve3d.stereo import stereo_priors

        if not s.onnx.model:
            raise Eve3dError("--backend onnx needs the model spec: stereo.onnx in --config, or --set stereo.onnx.model=FILE")
        stereo_priors(scene, Path(a.stereo), Path(a.out), OnnxStereo(s.onnx), "ONNX stereo", preview=not a.no_preview,
                      check=check)
    print(f"wrote {len(scene.cameras)} depth maps to {a.out}")


def _cmd_export_stereo(a: argparse.Namespace) -> None:
    import yaml

    from eve3d.priors.psmnet import SPEC_FILE, export_psmnet

    size = None
    if a.size:
        try:
            size = tuple(int(n) for n in a.size.lower().split("x"))
        except ValueError:
            size = ()
        if len(size) != 2:
            raise Eve3dError(f"--size {a.size!r}: expected HEIGHTxWIDTH, e.g. 256x320")
    config = export_psmnet(a.weights, a.out, size, a.max_disparity)
    model = Path(config["stereo"]["onnx"]["model"])
    print(f"wrote {model} and {model.parent / SPEC_FILE}; use it with --config {model.parent / SPEC_FILE}, "
          "or paste into your config:")
    print(yaml.safe_dump(config, sort_keys=False, default_flow_style=None), end="")


def _cmd_pretrain(a: argparse.Namespace) -> None:
    from eve3d.core.io import load_scene
    from eve3d.core.settings import PretrainSettings
    from eve3d.pretrain import pretrain

    metrics = pretrain(load_scene(a.scene), Path(a.out), _settings(a, PretrainSettings, "pretrain"))
    held = metrics["held_out"]
    if held:
        print(f"held-out views ({held['views']}): PSNR {held['psnr']:.2f} dB, SSIM {held['ssim']:.4f}")
    print(f"wrote {a.out}/point_cloud.ply ({metrics['gaussians']} Gaussians)")


def _cmd_joint(a: argparse.Namespace) -> None:
    from eve3d.config import method_settings
    from eve3d.core.io import load_scene
    from eve3d.joint import train_joint

    config = _config(a)
    settings = _naming_flags(a, lambda: method_settings(a.method, config, "--method"))
    metrics = train_joint(load_scene(a.scene), Path(a.out), settings, Path(a.priors) if a.priors else None)
    print(f"training views: PSNR {metrics['train']['psnr']:.2f} dB; wrote {a.out}/point_cloud.ply "
          f"({metrics['gaussians']} Gaussians) and {a.out}/depth/")


def _cmd_mesh(a: argparse.Namespace) -> None:
    from eve3d.core.io import load_scene
    from eve3d.core.layout import MESH_VIEWS_DIR
    from eve3d.core.settings import MeshSettings
    from eve3d.mesh import check_mesh_path, extent_report, fuse, write_mesh, write_mesh_views

    check_mesh_path(Path(a.out))
    settings = _settings(a, MeshSettings, "mesh")
    scene = load_scene(a.scene, check_images=False)
    if a.kind:
        scene.kind = a.kind
    mesh = fuse(scene, Path(a.depth), settings)
    write_mesh(mesh, Path(a.out))
    report = extent_report(mesh, scene)
    print(f"wrote {a.out}: {len(mesh.vertices)} vertices, {report['triangles']} triangles, extent {report['extent']}"
          + (f", {report['extent_ratio']:.2f}× the sparse points' 5–95 % box {report['sparse_extent']}"
             if report["extent_ratio"] is not None else ""))
    views = write_mesh_views(mesh, scene, Path(a.out).with_name(MESH_VIEWS_DIR))
    print(f"wrote {len(views)} shaded views to {views[0].parent}")


def _cmd_evaluate(a: argparse.Namespace) -> None:
    from eve3d.core.fileio import atomic_path
    from eve3d.core.io import load_scene
    from eve3d.core.settings import EvalSettings, MeshSettings
    from eve3d.evaluate import PROTOCOLS, EvalInputs, protocol_for

    config = _config(a)
    settings = _settings(a, EvalSettings, "evaluate", config)
    min_confidence = _settings(a, MeshSettings, "mesh", config).min_confidence  # the pixels the mesh fused
    scene = load_scene(a.scene, check_images=False)
    # a ground-truth key counts as given when the flag of its input is (--gt for gt_mesh)
    flags = {key: field for p in PROTOCOLS.values() for field, key in p.config_inputs.items()}
    protocol = protocol_for(a.protocol, scene.extras.get("format", "colmap"), "--protocol",
                            lambda key: getattr(a, flags[key]) is not None)
    reconstruction = a.model if protocol.scores == "model" else a.mesh
    optional = lambda v: Path(v) if v else None  # noqa: E731
    if a.check:
        inputs = EvalInputs(scene, None, Path(a.out), gt=optional(a.gt), obs_mask=optional(a.obs_mask),
                            plane=optional(a.plane), settings=settings)
        checked = {"protocol": protocol.name, "check": settings.ground_truth_check}
        if settings.ground_truth_check != "off":
            try:
                checked.update(protocol.check_ground_truth(inputs))
                print(f"the ground truth of {a.scene} lines up with its cameras ({protocol.name} protocol): "
                      + ", ".join(f"{k} {v:.3g}" for k, v in checked.items() if isinstance(v, float)))
            except Eve3dError as e:
                if settings.ground_truth_check == "error":
                    raise Eve3dError(f"{e} (evaluate.ground_truth_check: warn or off goes on regardless)") from None
                print(f"warning: {e}", file=sys.stderr)
                checked["warning"] = str(e)
        with atomic_path(Path(a.out)) as tmp:
            tmp.write_text(json.dumps(checked, indent=2))
        return
    if reconstruction is None:
        flag = "--model (a trained point_cloud.ply)" if protocol.scores == "model" else "--mesh"
        raise Eve3dError(f"the {protocol.name} protocol scores a {protocol.scores}: give {flag}")
    inputs = EvalInputs(scene, Path(reconstruction), Path(a.out), gt=optional(a.gt), obs_mask=optional(a.obs_mask),
                        plane=optional(a.plane), settings=settings)
    if bool(a.depth) != bool(a.exact_depth):
        raise Eve3dError("--depth and --exact-depth go together: the maps the mesh fused, and the exact depth of "
                         "the same views")
    metrics = protocol.run(inputs)
    if a.depth:
        from eve3d.evaluate.depth import depth_accuracy

        acc = depth_accuracy(Path(a.depth), Path(a.exact_depth), min_confidence=min_confidence)
        metrics.update({"depth_signed_error": acc["median_signed_error"], "depth_error": acc["median_rel_error"],
                        "depth_density": acc["density"], "depth_on_empty": acc["on_empty"], "depth_maps": str(a.depth)})
    if "tau" in metrics:
        print(f"tau = {metrics['tau']:.5g} ({metrics['tau_rule']})")
    metrics.update({"scene": a.scene_name, "method": a.method} if a.scene_name else {})
    from eve3d.core.layout import EVALUATION, RECORD

    with atomic_path(Path(a.out)) as tmp:
        tmp.write_text(json.dumps({RECORD: EVALUATION, **metrics}, indent=2))
    print(format_table([metrics]))


def _cmd_bench(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import rasterizer

    sizes = rasterizer.RASTERIZER_SIZES
    if a.sizes:
        try:
            sizes = [tuple(int(v) for v in item.split("x")) for item in a.sizes.split(",")]
        except ValueError:
            sizes = []
        if not sizes or any(len(s) != 3 for s in sizes):
            raise Eve3dError(f"--sizes {a.sizes!r}: expected GAUSSIANSxWIDTHxHEIGHT[,...], e.g. 5000x160x120")
    rows = rasterizer.bench_rasterizer(sizes, backend=a.backend, repeats=a.repeats)
    print(rasterizer.rasterizer_json(rows) if a.json else rasterizer.format_rasterizer_table(rows))


def _cmd_bench_training(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import training as training_bench

    for name in ("steps", "warmup", "gaussians"):
        if getattr(a, name) < (0 if name == "warmup" else 1):
            raise Eve3dError(f"--{name} {getattr(a, name)}: expected a positive number")
    report = training_bench.bench_training(a.stages or training_bench.TRAINING_STAGES, a.steps, a.warmup, a.gaussians,
                                           _config(a), a.start)
    print(json.dumps(report, indent=2) if a.json else training_bench.format_training_table(report))


def _cmd_bench_stereo(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import stereo as stereo_bench

    priors, agreement = [], []
    for folder in map(Path, a.priors):
        oracle, label = folder.parent / "oracle", f"{folder.parent.parent.name}/{folder.name}"
        if oracle.is_dir():
            priors.append(stereo_bench.prior_accuracy(folder, oracle, label))
        elif a.scene:
            from eve3d.core.io import load_scene
            from eve3d.evaluate.depth import prior_agreement

            agreement.append({**prior_agreement(load_scene(a.scene, check_images=False), folder), "data": label})
        else:
            raise Eve3dError(f"{folder}: no oracle priors beside it ({oracle}) to score against; give --scene (the "
                             f"posed dataset) to measure how neighbouring views' priors agree instead")
    moto = [stereo_bench.stereo_motorcycle(), stereo_bench.stereo_motorcycle(wls=True)]
    print(json.dumps({"motorcycle": moto, "priors": priors, "agreement": agreement}, indent=2) if a.json
          else stereo_bench.format_stereo_tables(moto, priors, agreement))


def _cmd_bench_evaluate(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import evaluate as evaluation

    if a.meshes and not (a.scene and a.gt):
        raise Eve3dError("--meshes needs --scene (the cameras) and --gt (the GT mesh)")
    rows = evaluation.bench_evaluate([("/".join(Path(m).parts[-3:]), str(m)) for m in a.meshes], a.scene, a.gt)
    print(json.dumps(rows, indent=2) if a.json else evaluation.format_evaluate_table(rows))


def _benchmark_workflow(a: argparse.Namespace) -> dict:
    """Run the workflow of a benchmark's config (unless --report-only); its resolved config."""
    import subprocess

    from eve3d.config import SNAKEFILE, load_config
    from eve3d.core.layout import Layout

    config = load_config(a.config)
    if not a.report_only:
        cmd = [sys.executable, "-m", "snakemake", "-s", str(SNAKEFILE), "--configfile", a.config,
               "--replace-workflow-config", f"-c{a.cores}", "--quiet", "rules", "progress"]
        if subprocess.run(cmd).returncode != 0:
            raise Eve3dError(f"the workflow of {a.config} failed (its logs: {Layout(config['results']).logs()}/)")
    return config


def _cmd_bench_methods(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import methods as methods_bench

    report = methods_bench.methods_report(_benchmark_workflow(a))
    print(json.dumps(report, indent=2) if a.json else methods_bench.format_methods_report(report))


def _cmd_bench_standin(a: argparse.Namespace) -> None:
    import tempfile

    from eve3d.core.io import load_scene
    from eve3d.synth import generate
    from eve3d.tools.standin import STANDIN_SCENE, write_standin

    root, name = Path(a.root), STANDIN_SCENE[a.benchmark]
    if (root / name).exists():
        raise Eve3dError(f"{root / name}: already there; give an empty folder")
    with tempfile.TemporaryDirectory() as tmp:
        scene = load_scene(generate("object", Path(tmp) / "object", views=a.views, width=a.width, height=a.height))
        folder = write_standin(a.benchmark, scene, root)
    print(f"wrote a stand-in {name} ({a.views} views, {a.width}×{a.height}) to {folder}; run it:\n"
          f"  snakemake -c2 --configfile config/benchmarks/{a.benchmark}.yaml --replace-workflow-config "
          f"--config root={root} 'only=[{name}]'")


def _cmd_bench_real(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import methods as methods_bench

    report = methods_bench.real_report(_benchmark_workflow(a))
    print(json.dumps(report, indent=2) if a.json else methods_bench.format_real_report(report))


def _cmd_bench_scale(a: argparse.Namespace) -> None:
    import tempfile

    from eve3d.tools.bench import scale

    mode = "memory" if a.memory else "pipeline"
    views, width, height = scale.SCALE_SIZE[mode]
    flags = {"synthetic.views": a.views or views, "synthetic.width": a.width or width,
             "synthetic.height": a.height or height}
    if a.iterations is not None:
        flags.update({"pretrain.iterations": a.iterations, "joint.iterations": a.iterations})
    for name in ("views", "width", "height", "iterations", "gt_points"):
        if getattr(a, name) is not None and getattr(a, name) < 1:
            raise Eve3dError(f"--{name.replace('_', '-')} {getattr(a, name)}: expected a positive number")
    from eve3d.config import job_config

    config = job_config(a.config, a.set, flags)
    with contextlib.ExitStack() as stack:
        work = Path(a.work) if a.work else Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="eve3d-scale-")))
        report = scale.bench_scale(work, config, memory=a.memory, kind=a.kind,
                                   methods=a.methods or scale.SCALE_METHODS, gt_points=a.gt_points or scale.GT_POINTS,
                                   protocols=a.protocols or scale.MEMORY_PROTOCOLS)
    print(json.dumps(report, indent=2) if a.json else scale.format_scale_report(report))


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
    from eve3d.core.layout import EVALUATION, METRICS_FILE, RECORD, TRAIN_METRICS_FILE, TRAINING, locate

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
    if a.failed:  # rows of a workflow that ended with failed jobs (eve3d.core.failures)
        try:
            rows += json.loads(Path(a.failed).read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise Eve3dError(f"{a.failed}: cannot read the failed rows ({e})") from None
    rows.sort(key=lambda r: (r["scene"], r["method"]))
    out = Path(a.out)
    _write_csv(out, SUMMARY_COLUMNS, rows)
    print(format_table(rows, SUMMARY_COLUMNS))
    if view_rows:
        view_rows.sort(key=lambda r: (r["scene"], r["stage"]))
        _write_csv(out.with_name(f"{out.stem}_views.csv"), VIEW_COLUMNS, view_rows)
        print("\nheld-out views of the training stages (at the training resolution)")
        print(format_table(view_rows, VIEW_COLUMNS))


def _cmd_report(a: argparse.Namespace) -> None:
    from eve3d.core.layout import Layout
    from eve3d.core.settings import StereoSettings
    from eve3d.report import write_report

    datasets = {}
    for item in a.dataset:
        scene, sep, folder = item.partition("=")
        if not sep:
            raise Eve3dError(f"--dataset {item!r}: expected SCENE=FOLDER")
        datasets[scene] = Path(folder)
    config = _config(a)
    backend = _settings(a, StereoSettings, "stereo", config).backend
    written = write_report(Layout(a.results), Path(a.out), datasets, backend, config.get("benchmark"))
    print(f"wrote {len(written)} report pages to {a.out}")


def _write_csv(path: Path, columns: tuple[str, ...], rows: list[dict]) -> None:
    from eve3d.core.fileio import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
            writer.writeheader()
            writer.writerows(rows)


_ARG_TYPES = {"int": int, "float": float, "str": str, "any": str}


def _yaml_list(value: str) -> list:
    import yaml

    parsed = yaml.safe_load(value)
    if not isinstance(parsed, list):
        raise argparse.ArgumentTypeError(f"expected a list such as [1, 2], got {value!r}")
    return parsed


@functools.cache
def _preset() -> dict:
    """What a stage reads without ``--config`` (the cpu preset): the flags' shown defaults."""
    from eve3d.config import job_config

    return job_config()


def _settings_flags(group, cls: type, section: str, only: tuple[str, ...] = (), skip: tuple[str, ...] = ()) -> None:
    """One flag per field of a settings class, a shorthand of ``--set SECTION.KEY=VALUE``:
    its name, kind, choices and help (the field's first docstring sentence and its default
    under the cpu preset) come from ``eve3d.core.settings``."""
    from eve3d.config import TRAINING_SECTIONS
    from eve3d.core.settings import flag, keys

    preset = _preset()
    shared = preset.get("train") or {} if section in TRAINING_SECTIONS else {}
    given = {**shared, **(preset.get(section) or {})}
    for key in keys(cls):
        if (only and key.name not in only) or key.name in skip or key.kind == "dict":
            continue
        default = given.get(key.name, key.default)
        text = key.doc.replace("``", "").split(". ")[0].rstrip(".") + "; " if key.doc else ""
        kw: dict[str, Any] = {"dest": f"{section}.{key.name}", "default": None,
                              "help": (text + f"default {json.dumps(default)}").replace("%", "%%")}
        if key.kind == "bool":
            kw["action"] = argparse.BooleanOptionalAction
        elif "choices" in key.bounds:
            kw["choices"] = list(key.bounds["choices"])
        else:
            kw.update(type=_yaml_list if key.kind == "tuple" else _ARG_TYPES[key.kind], metavar=key.kind.upper())
        group.add_argument(flag(key.name), **kw)


def _config_arguments(s: argparse.ArgumentParser) -> None:
    """``--config`` and ``--set``: the settings of a job (``_config``)."""
    s.add_argument("--config", help="a workflow config file or an inline YAML/JSON mapping of sections, merged over "
                                    "its preset (cpu unless it names one; preset: null for none)")
    s.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override one setting, e.g. --set mesh.voxel=0.01 (repeatable; over --config, under the "
                        "flags)")


def _stage(sub, name: str, func, help: str, *settings: tuple) -> argparse.ArgumentParser:
    """A stage's subcommand: ``--config``, ``--set`` and the flags of ``settings`` (tuples of
    ``_settings_flags``' arguments after the parser)."""
    s = sub.add_parser(name, help=help, description=help + ". Settings, low to high: the settings classes' "
                       "defaults, the preset, --config, --set, the flags (config/README.md).")
    _config_arguments(s)
    groups: dict[str, Any] = {}
    for cls, section, *which in settings:
        if section not in groups:
            groups[section] = s.add_argument_group(f"{section} settings (each flag = --set {section}.KEY=VALUE)")
        _settings_flags(groups[section], cls, section, *which)
    s.set_defaults(func=func)
    return s


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="eve3d", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    for add in (_add_data_parsers, _add_stereo_parsers, _add_training_parsers, _add_mesh_parsers):
        add(sub)
    s = sub.add_parser("summary", help="gather metrics.json files into a CSV and print the table")
    s.add_argument("metrics", nargs="*")
    s.add_argument("--out", required=True)
    s.add_argument("--failed", help="JSON rows of scenes and methods whose jobs failed (written by the workflow)")
    s.set_defaults(func=_cmd_summary)
    s = sub.add_parser("report", help="the report's pages from a results folder (snakemake --report gathers them)")
    s.add_argument("--results", required=True, help="the results folder (its summary.csv and benchmark files)")
    s.add_argument("--out", required=True, help="folder for summary.html, runtimes.html, charts/, scenes/")
    s.add_argument("--dataset", action="append", default=[], metavar="SCENE=FOLDER",
                   help="a scene's posed dataset (its first photo heads the scene's sheets); repeat per scene")
    _config_arguments(s)  # stereo.backend: the priors shown; benchmark: its published figures join the means
    s.set_defaults(func=_cmd_report)
    _add_bench_parser(sub)
    return p


def _add_data_parsers(sub) -> None:
    from eve3d.core.settings import SfmSettings, SyntheticSettings
    from eve3d.synth import KINDS

    s = _stage(sub, "synth", _cmd_synth, "generate a synthetic scene with exact ground truth",
               (SyntheticSettings, "synthetic"))
    s.add_argument("kind", choices=list(KINDS))
    s.add_argument("out", help="output dataset folder (replaced atomically)")
    s.add_argument("--images-only", action="store_true", help="hide the poses under gt/ (to exercise SfM)")
    s = _stage(sub, "sfm", _cmd_sfm, "pycolmap SfM (or undistortion only) → images/ + sparse/0 (PINHOLE)",
               (SfmSettings, "sfm"))
    s.add_argument("dataset", help="folder with images/ (and optionally a distorted COLMAP model)")
    s.add_argument("out")


def _add_stereo_parsers(sub) -> None:
    from eve3d.core.settings import BaselineSettings, MatchCheck, RenderSettings, SgbmSettings, StereoSettings

    s = _stage(sub, "stereo-render", _cmd_stereo_render,
               "right views of virtual stereo pairs, rendered by the pretrained model",
               (BaselineSettings, "stereo"), (RenderSettings, "pretrain"))
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--model", required=True, help="pretrained 3DGS PLY (pretrain/point_cloud.ply)")
    s.add_argument("--out", required=True, help="output folder: right/{view}.png and pairs.json (replaced atomically)")
    s = _stage(sub, "stereo-depth", _cmd_stereo_depth, "depth priors per view ({view}.npz + PNG previews)",
               (StereoSettings, "stereo", ("backend",)), (SgbmSettings, "stereo"), (MatchCheck, "stereo"))
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--out", required=True, help="output folder (replaced atomically)")
    s.add_argument("--gt-mesh", help="oracle: the mesh (default: the scene's own GT mesh)")
    s.add_argument("--stereo", help="sgbm, mccnn, onnx: the output folder of `eve3d stereo-render`")
    s.add_argument("--no-preview", action="store_true")
    s = sub.add_parser("export-stereo", help="export a stereo network to ONNX for the onnx backend and print its "
                                             "stereo.onnx config")
    s.add_argument("network", choices=["psmnet"], help="psmnet: PSMNet with its KITTI 2015 weights")
    s.add_argument("--weights", help="the checkpoint (default $EVE3D_PSMNET_WEIGHTS, else "
                                     "~/.cache/eve3d/psmnet/pretrained_model_KITTI2015.tar)")
    s.add_argument("--out", default="~/.cache/eve3d/psmnet", help="folder for psmnet.onnx and psmnet.yaml "
                                                                  "(default %(default)s)")
    s.add_argument("--max-disparity", type=int, default=192,
                   help="disparity levels, a multiple of 16 (default %(default)s, as trained: another value rescales "
                        "the output)")
    s.add_argument("--size", metavar="HEIGHTxWIDTH", help="a fixed input size (images are resized to it); default "
                                                          "any size, padded to a multiple of 16 and at least 256")
    s.set_defaults(func=_cmd_export_stereo)


def _add_training_parsers(sub) -> None:
    from eve3d.core.methods import methods
    from eve3d.core.settings import JointSettings, PretrainSettings

    s = _stage(sub, "pretrain", _cmd_pretrain, "short photometric 3DGS fit (Mini-Splatting style) → point_cloud.ply",
               (PretrainSettings, "pretrain"))
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--out", required=True, help="output folder (holds the checkpoint a killed run resumes from)")
    s = _stage(sub, "joint", _cmd_joint, "train a method's Gaussians and render its depth for meshing",
               (JointSettings, "joint", (), ("method", "priors")))  # chosen by --method
    s.add_argument("--method", required=True, help="a trained method: " + ", ".join(
        n for n, m in methods().items() if m.trains) + ", or a variant the --config defines")
    s.add_argument("--priors", help="the stereo priors (results/SCENE/priors/BACKEND) of a method that uses them")
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--out", required=True, help="output folder (holds the checkpoint a killed run resumes from)")


def _add_mesh_parsers(sub) -> None:
    from eve3d.evaluate import DEFAULT_PROTOCOL, PROTOCOLS, WITHOUT_GT
    from typing import get_args

    from eve3d.core.scene import SceneKind
    from eve3d.core.settings import EvalSettings, MeshSettings

    s = _stage(sub, "mesh", _cmd_mesh, "TSDF-fuse per-view depth maps into mesh.ply", (MeshSettings, "mesh"))
    s.add_argument("--scene", required=True)
    s.add_argument("--depth", required=True, help="folder of {view}.npz depth maps")
    s.add_argument("--out", required=True, help="mesh file to write (.ply)")
    s.add_argument("--kind", choices=get_args(SceneKind), help="override the scene kind")
    s = _stage(sub, "evaluate", _cmd_evaluate, "a reconstruction vs ground truth → metrics.json",
               (EvalSettings, "evaluate"), (MeshSettings, "mesh", ("min_confidence",)))
    s.description += " Protocols: " + "; ".join(f"{p.name}: {p.summary}" for p in PROTOCOLS.values())
    s.add_argument("--scene", required=True, help="dataset folder: cameras (visibility, alignment, masks, views)")
    s.add_argument("--mesh", help="the reconstructed mesh (protocols synthetic, dtu, tnt)")
    s.add_argument("--model", help="a trained point_cloud.ply (protocol nvs)")
    s.add_argument("--out", required=True, help="metrics.json (tnt also writes precision.ply and recall.ply beside it)")
    s.add_argument("--protocol", choices=list(PROTOCOLS),
                   help="default by dataset format when its ground truth is given: " + ", ".join(
                       f"{k} → {v}" for k, v in DEFAULT_PROTOCOL.items()) + f"; else {WITHOUT_GT}")
    s.add_argument("--gt", help="synthetic: the GT mesh; dtu: the stl…_total.ply point cloud")
    s.add_argument("--obs-mask", help="dtu: ObsMask{scan}_10.mat")
    s.add_argument("--plane", help="dtu: Plane{scan}.mat")
    s.add_argument("--depth", help="the depth maps the mesh was fused from: their median signed and absolute "
                                   "relative error against --exact-depth (pixels of confidence ≥ mesh.min_confidence) "
                                   "are added to the metrics")
    s.add_argument("--exact-depth", help="exact depth maps of the same views (results/SCENE/priors/oracle)")
    s.add_argument("--check", action="store_true",
                   help="no reconstruction: check that the ground truth lines up with the scene's cameras (dtu, "
                        "tnt), write what was measured to --out, fail with a message naming the file otherwise")
    s.add_argument("--scene-name")
    s.add_argument("--method")


def _add_bench_parser(sub) -> None:
    from eve3d.core.settings import RENDER_BACKENDS
    from eve3d.synth import KINDS

    s = sub.add_parser("bench", help="speed and memory benchmarks (print a table)")
    what = s.add_subparsers(dest="benchmark", required=True)
    r = what.add_parser("rasterizer", help="forward/backward time and peak memory of one render")
    r.add_argument("--sizes", help="GAUSSIANSxWIDTHxHEIGHT,... (default 5000x160x120,20000x320x240,100000x640x480)")
    r.add_argument("--backend", choices=RENDER_BACKENDS, default="auto")
    r.add_argument("--repeats", type=int, default=5, help="timed runs per size (median; one more warms up)")
    r.add_argument("--json", action="store_true", help="machine-readable output")
    r.set_defaults(func=_cmd_bench)
    tr = what.add_parser("training", help="mean time of each part of a training step (projection, rasteriser, "
                                          "losses, their backward, optimiser, densification) on the generated object")
    tr.add_argument("--stages", nargs="+", metavar="STAGE",
                    help="pretrain and/or trained methods (default: pretrain pgsr eve3d)")
    tr.add_argument("--steps", type=int, default=30, help="timed steps per stage (mean)")
    tr.add_argument("--warmup", type=int, default=3, help="untimed steps before them")
    tr.add_argument("--gaussians", type=int, default=35_000,
                    help="Gaussians of the initial model (sparse points, or eve3d's prior points)")
    tr.add_argument("--start", type=int, help="step of the schedule to start from (default: where every joint-stage "
                                              "term is on, max of dn_from, mv_from, prior_from, joint_from)")
    _config_arguments(tr)
    tr.add_argument("--json", action="store_true", help="machine-readable output")
    tr.set_defaults(func=_cmd_bench_training)
    st = what.add_parser("stereo", help="sgbm on the Motorcycle pair; priors of synthetic scenes vs exact depth")
    st.add_argument("--priors", nargs="*", default=[], metavar="DIR",
                    help="prior folders (results/{scene}/priors/{backend}) to score against the oracle folder beside them")
    st.add_argument("--scene", help="posed dataset of --priors that have no oracle beside them (a real capture): "
                                    "their density and the agreement of neighbouring views")
    st.add_argument("--json", action="store_true", help="machine-readable output")
    st.set_defaults(func=_cmd_bench_stereo)
    ev = what.add_parser("evaluate", help="time of the synthetic protocol on meshes with floaters (and on given meshes)")
    ev.add_argument("--meshes", nargs="*", default=[], metavar="MESH", help="further meshes to time, e.g. a demo's")
    ev.add_argument("--scene", help="dataset whose cameras the given meshes are scored with")
    ev.add_argument("--gt", help="GT mesh of the given meshes")
    ev.add_argument("--json", action="store_true", help="machine-readable output")
    ev.set_defaults(func=_cmd_bench_evaluate)
    from eve3d.core.datasets import BENCHMARKS

    sd = what.add_parser("standin", help="a generated object written as a benchmark's download lays out one scene, "
                                         "with its ground-truth files: try or time a benchmark config without it")
    sd.add_argument("benchmark", choices=list(BENCHMARKS))
    sd.add_argument("root", help="the download's folder to write (the config's root)")
    sd.add_argument("--views", type=int, default=49, help="photos (DTU has 49; T&T 150-1100; Mip-NeRF 360 125-311)")
    sd.add_argument("--width", type=int, default=1600, help="photo width (DTU 1600; T&T 1920; Mip-NeRF 360 ~5000)")
    sd.add_argument("--height", type=int, default=1200)
    sd.set_defaults(func=_cmd_bench_standin)
    sc = what.add_parser("scale", help="every stage of the pipeline on a large generated room, each in a process "
                                       "of its own: wall time and peak memory (--memory: the TSDF and the evaluation "
                                       "at their memory targets, without training)")
    sc.add_argument("--memory", action="store_true",
                    help="no training: fuse the exact depth of VIEWS views at WIDTHxHEIGHT (default 300 at 1920x1080) "
                         "and score fused meshes against --gt-points ground-truth points (synthetic, tnt, dtu)")
    sc.add_argument("--kind", choices=list(KINDS), default="room", help="the generated scene (default room)")
    sc.add_argument("--views", type=int, help="views of the generated scene (default 300)")
    sc.add_argument("--width", type=int, help="its image width (default 960; --memory: the depth maps', 1920)")
    sc.add_argument("--height", type=int, help="its image height (default 540; --memory: 1080)")
    sc.add_argument("--iterations", type=int, help="pretrain and joint iterations (the preset's 1500 at cpu); the "
                                                   "schedule's other steps stay as configured (--set to move them)")
    sc.add_argument("--methods", nargs="+", metavar="METHOD", help="trained methods (default: pgsr eve3d)")
    sc.add_argument("--gt-points", type=int, help="--memory: ground-truth points (and synthetic samples), default 10M")
    sc.add_argument("--protocols", nargs="+", choices=["synthetic", "tnt", "dtu"],
                    help="--memory: the evaluations to run (default: all three)")
    sc.add_argument("--work", help="folder for the generated data, outputs and each stage's log (kept; new or empty); "
                                   "default a temporary folder")
    _config_arguments(sc)
    sc.add_argument("--json", action="store_true", help="machine-readable output")
    sc.set_defaults(func=_cmd_bench_scale)
    for name, func, config, help in [
            ("methods", _cmd_bench_methods, "methods", "run every method on the generated object and room (Snakemake) "
                                                        "and print scores, times and the priors' accuracy"),
            ("real", _cmd_bench_real, "real", "run a real capture as a user would (photos and their path, Snakemake) "
                                              "and print views registered, stage times, held-out PSNR/SSIM, the "
                                              "priors' density and agreement, the meshes' size")]:
        me = what.add_parser(name, help=help)
        me.add_argument("--config", default=f"config/bench/{config}.yaml", help="workflow config of the benchmark")
        me.add_argument("--cores", type=int, default=2)
        me.add_argument("--report-only", action="store_true", help="print the table of a finished run without running")
        me.add_argument("--json", action="store_true", help="machine-readable output")
        me.set_defaults(func=func)


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
