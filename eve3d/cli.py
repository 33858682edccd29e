"""``eve3d <stage> ...``: one subcommand per stage; every Snakemake rule calls one of these."""
from __future__ import annotations

import argparse
import functools
import json
import os
import sys
from collections.abc import Callable
from typing import Any

from eve3d.core import timing
from eve3d.core.cores import CoreShare
from eve3d.core.errors import Eve3dError


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
    from eve3d.core.settings_fields import flag

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
    from eve3d.synth import run_synth

    run_synth(_settings(a, SyntheticSettings, "synthetic"), kind=a.kind, out=a.out, images_only=a.images_only,
              capture=a.capture)


def _cmd_sfm(a: argparse.Namespace) -> None:
    from eve3d.core.settings import SfmSettings
    from eve3d.sfm import run_sfm

    run_sfm(_settings(a, SfmSettings, "sfm"), dataset=a.dataset, out=a.out)


def _cmd_stereo_render(a: argparse.Namespace) -> None:
    from eve3d.core.settings import PretrainSettings, RenderSettings
    from eve3d.core.settings_fields import pick
    from eve3d.core.settings_stereo import StereoSettings
    from eve3d.stereo import run_stereo_render

    config = _config(a)
    rendering = pick(RenderSettings, _settings(a, PretrainSettings, "pretrain", config))  # as the model was trained
    run_stereo_render(_settings(a, StereoSettings, "stereo", config), rendering, scene=a.scene, model=a.model,
                      out=a.out)


def _cmd_stereo_depth(a: argparse.Namespace) -> None:
    from eve3d.core.settings_stereo import StereoSettings
    from eve3d.stereo import run_stereo_depth

    run_stereo_depth(_settings(a, StereoSettings, "stereo"), scene=a.scene, out=a.out, stereo=a.stereo,
                     gt_mesh=a.gt_mesh, preview=not a.no_preview)


def _cmd_export_stereo(a: argparse.Namespace) -> None:
    from eve3d.stereo import run_export_stereo

    run_export_stereo(a.size, a.max_disparity, weights=a.weights, out=a.out)


def _cmd_pretrain(a: argparse.Namespace) -> None:
    from eve3d.core.settings import PretrainSettings
    from eve3d.pretrain import run_pretrain

    run_pretrain(_settings(a, PretrainSettings, "pretrain"), scene=a.scene, out=a.out)


def _cmd_joint(a: argparse.Namespace) -> None:
    from eve3d.config import method_settings
    from eve3d.joint import run_joint

    config = _config(a)
    run_joint(_naming_flags(a, lambda: method_settings(a.method, config, "--method")), scene=a.scene, out=a.out,
              priors=a.priors)


def _cmd_mesh(a: argparse.Namespace) -> None:
    from eve3d.core.settings import MeshSettings
    from eve3d.mesh import run_mesh

    run_mesh(_settings(a, MeshSettings, "mesh"), scene=a.scene, depth=a.depth, out=a.out, kind=a.kind)


def _cmd_evaluate(a: argparse.Namespace) -> None:
    from eve3d.core.settings import EvalSettings, MeshSettings
    from eve3d.evaluate import GROUND_TRUTH_INPUTS, run_evaluate, run_ground_truth_check

    config = _config(a)
    settings = _settings(a, EvalSettings, "evaluate", config)
    paths = dict(scene=a.scene, out=a.out, protocol=a.protocol,
                 ground_truth={name: getattr(a, name) for name in GROUND_TRUTH_INPUTS})
    if a.check:
        run_ground_truth_check(settings, **paths)
        return
    run_evaluate(settings, _settings(a, MeshSettings, "mesh", config), **paths, mesh=a.mesh, model=a.model,
                 depth=a.depth, exact_depth=a.exact_depth,
                 row={"scene": a.scene_name, "method": a.method} if a.scene_name else None)


def _cmd_profile(a: argparse.Namespace) -> None:
    from eve3d.tools.profile import run_profile

    run_profile(log=a.log, workdir=a.workdir, markdown=a.markdown)


def _cmd_summary(a: argparse.Namespace) -> None:
    from eve3d.report import run_show_summary, run_summary

    if a.show:
        run_show_summary(summary=a.out)
    else:
        run_summary(a.metrics, out=a.out, failed=a.failed)


def _cmd_report(a: argparse.Namespace) -> None:
    from eve3d.core.settings_stereo import StereoSettings
    from eve3d.report import run_report

    config = _config(a)
    run_report(_settings(a, StereoSettings, "stereo", config), config.get("benchmark"), results=a.results,
               out=a.out, datasets=dict(a.dataset), ground_truth=dict(a.gt))


def _cmd_bench_rasterizer(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import rasterizer

    rasterizer.run_bench_rasterizer(a.sizes or rasterizer.RASTERIZER_SIZES, a.backend, a.repeats, a.json)


def _cmd_bench_training(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import training

    training.run_bench_training(_config(a), a.stages or training.TRAINING_STAGES, a.steps, a.warmup, a.gaussians,
                                a.start, a.json)


def _cmd_bench_stereo(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import stereo

    stereo.run_bench_stereo(a.priors, a.scene, a.json)


def _cmd_bench_evaluate(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import evaluate

    evaluate.run_bench_evaluate(a.meshes, a.scene, a.gt, a.json)


def _cmd_bench_methods(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import methods

    methods.run_bench_workflow(a.benchmark, a.config, a.cores, a.report_only, a.json)


def _cmd_bench_degrade(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import degrade

    degrade.run_bench_degrade(a.config, a.cores, a.report_only, a.json)


def _cmd_bench_standin(a: argparse.Namespace) -> None:
    from eve3d.tools import standin

    standin.run_bench_standin(a.benchmark, a.root, a.views, a.width, a.height)


def _cmd_bench_scale(a: argparse.Namespace) -> None:
    from eve3d.tools.bench import scale

    scale.run_bench_scale(a.config, a.set, memory=a.memory, kind=a.kind, size=(a.views, a.width, a.height),
                          iterations=a.iterations, methods=a.methods, gt_points=a.gt_points, protocols=a.protocols,
                          work=a.work, as_json=a.json)


# -- argument types: a wrong value is argparse's error, naming the flag ----------------------

def _positive(text: str) -> int:
    value = int(text) if text.lstrip("-").isdigit() else 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive number")
    return value


def _at_least_zero(text: str) -> int:
    if not text.isdigit():
        raise argparse.ArgumentTypeError(f"{text!r}: expected a number ≥ 0")
    return int(text)


def _numbers_by_x(text: str, count: int, example: str) -> tuple[int, ...]:
    """``text`` such as ``256x320``: ``count`` positive integers."""
    parts = text.lower().split("x")
    if len(parts) != count or not all(p.isdigit() and int(p) > 0 for p in parts):
        raise argparse.ArgumentTypeError(f"{text!r}: expected {example}")
    return tuple(map(int, parts))


def _height_width(text: str) -> tuple[int, int]:
    return _numbers_by_x(text, 2, "HEIGHTxWIDTH, e.g. 256x320")


def _rasterizer_sizes(text: str) -> list[tuple[int, int, int]]:
    return [_numbers_by_x(item, 3, "GAUSSIANSxWIDTHxHEIGHT[,...], e.g. 5000x160x120") for item in text.split(",")]


def _scene_folder(text: str) -> tuple[str, str]:
    scene, sep, folder = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"{text!r}: expected SCENE=PATH")
    return scene, folder


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
    from eve3d.core.settings_fields import flag, keys

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
    s.add_argument("--show", action="store_true", help="print the tables of the summary.csv at --out, as written")
    s.set_defaults(func=_cmd_summary)
    s = sub.add_parser("profile", help="where a workflow run's wall time went, job by job and inside each job "
                       "(from Snakemake's log of the run and each job's timing line)")
    s.add_argument("--log", help="a Snakemake log (.snakemake/log/*.snakemake.log); default: the newest in --workdir")
    s.add_argument("--workdir", default=".", help="the folder the workflow ran in (default: here)")
    s.add_argument("--markdown", action="store_true", help="print Markdown tables (for docs/)")
    s.set_defaults(func=_cmd_profile)
    s = sub.add_parser("report", help="the report's pages from a results folder (snakemake --report gathers them)")
    s.add_argument("--results", required=True, help="the results folder (its summary.csv and benchmark files)")
    s.add_argument("--out", required=True, help="folder for summary.html, runtimes.html, charts/, scenes/, scenes3d/")
    s.add_argument("--dataset", action="append", default=[], type=_scene_folder, metavar="SCENE=FOLDER",
                   help="a scene's posed dataset (its first photo heads the scene's sheets, its cameras are "
                   "drawn in its 3D view); repeat per scene")
    s.add_argument("--gt", action="append", default=[], type=_scene_folder, metavar="SCENE=FILE",
                   help="a scene's GT surface (mesh or point cloud), shown in its 3D view; repeat per scene")
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
    s.add_argument("--capture", action="store_true",
                   help="write it as a user brings a posed capture: images/ and a COLMAP text model, the GT mesh "
                        "in gt/mesh.ply for the config's gt_mesh, nothing that says it was generated")
    s = _stage(sub, "sfm", _cmd_sfm, "pycolmap SfM (or undistortion only) → images/ + sparse/0 (PINHOLE)",
               (SfmSettings, "sfm"))
    s.add_argument("dataset", help="folder with images/ (and optionally a distorted COLMAP model)")
    s.add_argument("out")


def _add_stereo_parsers(sub) -> None:
    from eve3d.core.settings import RenderSettings
    from eve3d.core.settings_stereo import (PRIOR_BACKENDS, BaselineSettings, MatchCheck, RealPairSettings, SgbmSettings,
                                           StereoSettings)

    s = _stage(sub, "stereo-render", _cmd_stereo_render,
               "right views of virtual stereo pairs, rendered by the pretrained model",
               (BaselineSettings, "stereo"), (RenderSettings, "pretrain"))
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--model", required=True, help="pretrained 3DGS PLY (pretrain/point_cloud.ply)")
    s.add_argument("--out", required=True, help="output folder: right/{view}.png and pairs.json (replaced atomically)")
    s = _stage(sub, "stereo-depth", _cmd_stereo_depth, "depth priors per view ({view}.npz + PNG previews)",
               (StereoSettings, "stereo", ("backend",)), (RealPairSettings, "stereo"), (SgbmSettings, "stereo"),
               (MatchCheck, "stereo"))
    s.add_argument("--scene", required=True, help="posed dataset folder")
    s.add_argument("--out", required=True, help="output folder (replaced atomically)")

    def by_input(reads):
        return ", ".join(b.name for b in PRIOR_BACKENDS.values() if b.reads == reads)

    s.add_argument("--gt-mesh", help=f"{by_input('gt_mesh')}: the mesh (default: the scene's own GT mesh)")
    s.add_argument("--stereo", help=f"{by_input('pairs')}: the output folder of `eve3d stereo-render`")
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
    s.add_argument("--size", type=_height_width, metavar="HEIGHTxWIDTH", help="a fixed input size (images are resized to it); default "
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
    from typing import get_args

    from eve3d.core.scene import SceneKind
    from eve3d.core.settings import EvalSettings, MeshSettings
    from eve3d.core.settings_fields import flag
    from eve3d.evaluate import DEFAULT_PROTOCOL, GROUND_TRUTH_INPUTS, PROTOCOLS, WITHOUT_GT

    s = _stage(sub, "mesh", _cmd_mesh, "TSDF-fuse per-view depth maps into mesh.ply", (MeshSettings, "mesh"))
    s.add_argument("--scene", required=True)
    s.add_argument("--depth", required=True, help="folder of {view}.npz depth maps")
    s.add_argument("--out", required=True, help="mesh file to write (.ply)")
    s.add_argument("--kind", choices=get_args(SceneKind), help="override the scene kind")
    s = _stage(sub, "evaluate", _cmd_evaluate, "a reconstruction vs ground truth → metrics.json",
               (EvalSettings, "evaluate"), (MeshSettings, "mesh", ("min_confidence",)))
    s.description += " Protocols: " + "; ".join(f"{p.name}: {p.summary}" for p in PROTOCOLS.values())
    s.add_argument("--scene", required=True, help="dataset folder: cameras (visibility, alignment, masks, views)")
    scoring = {what: ", ".join(p.name for p in PROTOCOLS.values() if p.scores == what) for what in ("mesh", "model")}
    s.add_argument("--mesh", help=f"the reconstructed mesh (protocols {scoring['mesh']})")
    s.add_argument("--model", help=f"a trained point_cloud.ply (protocols {scoring['model']})")
    s.add_argument("--out", required=True, help="metrics.json (a mesh's protocol also writes precision.ply and "
                                                "recall.ply beside it)")
    s.add_argument("--protocol", choices=list(PROTOCOLS),
                   help="default by dataset format when its ground truth is given: " + ", ".join(
                       f"{k} → {v}" for k, v in DEFAULT_PROTOCOL.items()) + f"; else {WITHOUT_GT}")
    for name, keys in GROUND_TRUTH_INPUTS.items():  # what the workflow's scene config gives each protocol
        s.add_argument(flag(name), help="; ".join(f"{p}: the scene's {key}" for p, key in keys.items()))
    s.add_argument("--depth", help="the depth maps the mesh was fused from: their median signed and absolute "
                                   "relative error against --exact-depth (pixels of confidence ≥ mesh.min_confidence) "
                                   "are added to the metrics")
    s.add_argument("--exact-depth", help="exact depth maps of the same views (results/SCENE/priors/oracle)")
    s.add_argument("--check", action="store_true",
                   help="no reconstruction: check that the ground truth lines up with the scene's cameras ("
                        + ", ".join(p.name for p in PROTOCOLS.values() if p.check) + "), write what was measured to "
                        "--out, fail with a message naming the file otherwise")
    s.add_argument("--scene-name")
    s.add_argument("--method")


def _add_bench_parser(sub) -> None:
    """``eve3d bench rasterizer``, ``training``, ``stereo`` and ``evaluate``: one part timed."""
    from eve3d.core.settings import RENDER_BACKENDS

    s = sub.add_parser("bench", help="speed and memory benchmarks (print a table)")
    what = s.add_subparsers(dest="benchmark", required=True)
    r = what.add_parser("rasterizer", help="forward/backward time and peak memory of one render")
    r.add_argument("--sizes", type=_rasterizer_sizes, help="GAUSSIANSxWIDTHxHEIGHT,... (default 5000x160x120,20000x320x240,100000x640x480)")
    r.add_argument("--backend", choices=RENDER_BACKENDS, default="auto")
    r.add_argument("--repeats", type=int, default=5, help="timed runs per size (median; one more warms up)")
    r.add_argument("--json", action="store_true", help="machine-readable output")
    r.set_defaults(func=_cmd_bench_rasterizer)
    tr = what.add_parser("training", help="mean time of each part of a training step (projection, rasteriser, "
                                          "losses, their backward, optimiser, densification) on the generated object")
    tr.add_argument("--stages", nargs="+", metavar="STAGE",
                    help="pretrain and/or trained methods (default: pretrain pgsr eve3d)")
    tr.add_argument("--steps", type=_positive, default=30, help="timed steps per stage (mean)")
    tr.add_argument("--warmup", type=_at_least_zero, default=3, help="untimed steps before them")
    tr.add_argument("--gaussians", type=_positive, default=35_000,
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

    _add_bench_run_parsers(what)


def _add_bench_run_parsers(what) -> None:
    """``eve3d bench standin``, ``scale``, ``methods`` and ``real``: benchmarks that run stages."""
    from eve3d.core.datasets import BENCHMARKS
    from eve3d.synth import KINDS
    from eve3d.tools.bench.scale import MEMORY_PROTOCOLS

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
                         "and score fused meshes against --gt-points ground-truth points ("
                         + ", ".join(MEMORY_PROTOCOLS) + ")")
    sc.add_argument("--kind", choices=list(KINDS), default="room", help="the generated scene (default room)")
    sc.add_argument("--views", type=_positive, help="views of the generated scene (default 300)")
    sc.add_argument("--width", type=_positive, help="its image width (default 960; --memory: the depth maps', 1920)")
    sc.add_argument("--height", type=_positive, help="its image height (default 540; --memory: 1080)")
    sc.add_argument("--iterations", type=_positive, help="pretrain and joint iterations (the preset's 1500 at cpu); the "
                                                   "schedule's other steps stay as configured (--set to move them)")
    sc.add_argument("--methods", nargs="+", metavar="METHOD", help="trained methods (default: pgsr eve3d)")
    sc.add_argument("--gt-points", type=_positive, help="--memory: ground-truth points (and synthetic samples), default 10M")
    sc.add_argument("--protocols", nargs="+", choices=MEMORY_PROTOCOLS,
                    help="--memory: the evaluations to run (default: all)")
    sc.add_argument("--work", help="folder for the generated data, outputs and each stage's log (kept; new or empty); "
                                   "default a temporary folder")
    _config_arguments(sc)
    sc.add_argument("--json", action="store_true", help="machine-readable output")
    sc.set_defaults(func=_cmd_bench_scale)
    for name, func, config, help in [
            ("methods", _cmd_bench_methods, "methods", "run every method on the generated object and room (Snakemake) "
                                                        "and print scores, times and the priors' accuracy"),
            ("real", _cmd_bench_methods, "real", "run a real capture as a user would (photos and their path, Snakemake) "
                                              "and print views registered, stage times, held-out PSNR/SSIM, the "
                                              "priors' density and agreement, the meshes' size"),
            ("degrade", _cmd_bench_degrade, "degrade", "run the methods against the exact depth with a stereo prior's "
                                                       "errors, one profile of errors at a time (Snakemake), and print F")]:
        me = what.add_parser(name, help=help)
        me.add_argument("--config", default=f"config/bench/{config}.yaml", help="workflow config of the benchmark")
        me.add_argument("--cores", type=int, default=2)
        me.add_argument("--report-only", action="store_true", help="print the table of a finished run without running")
        me.add_argument("--json", action="store_true", help="machine-readable output")
        me.set_defaults(func=func)


_WITHOUT_OPEN3D = (_cmd_pretrain, _cmd_stereo_render, _cmd_joint)
"""The commands whose process never uses open3d: the training stages, which a GPU machine without
it runs."""


_TRAINING = (_cmd_pretrain, _cmd_joint)
"""The commands whose threads follow the cores the other jobs leave (``eve3d.core.cores``)."""


def _core_share(func: Callable) -> CoreShare:
    """The job's registration among the jobs sharing the cores, where the workflow shares them:
    a training command takes its share, any other keeps the threads Snakemake gave it."""
    threads = os.environ.get("OMP_NUM_THREADS", "")
    return CoreShare.from_environment(None if func in _TRAINING else int(threads) if threads.isdigit() else 1)


def main(argv: list[str] | None = None) -> int:
    """``eve3d ARGV``; None: this process's own command line (the ``eve3d`` script, ``python -m
    eve3d``). A training command in a process of its own marks open3d absent, so that reading
    a COLMAP model does not import it first to keep pycolmap's zlib in order (a second of the
    job's start, ``core.io.colmap.import_pycolmap``), and a use of it fails here as it would
    on that machine."""
    args = build_parser().parse_args(argv)
    if argv is None and args.func in _WITHOUT_OPEN3D:
        sys.modules.setdefault("open3d", None)
    try:
        with _core_share(args.func):
            args.func(args)
    except Eve3dError as e:
        print(f"eve3d {args.command}: error: {e}", file=sys.stderr)
        return 2
    line = timing.summary()  # where a stage's time went (`eve3d profile` reads it from the job's log)
    timing.reset()
    if line:
        print(line, file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
