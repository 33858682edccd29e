# Configuration and input functions shared by every rule.
import dataclasses
import json
import os
import shlex
import sys
import time
from pathlib import Path

REPO = str(Path(workflow.basedir).parent)  # workflow/Snakefile: the checkout whose package the jobs run
sys.path.insert(0, REPO)
from eve3d.config import (has_gt_mesh, method_settings, named_methods, resolve_config, scene_protocol, scene_sections,
                          scene_value, stage_settings)
from eve3d.core.cores import ENV as CORE_SHARE_ENV
from eve3d.core.errors import Eve3dError
from eve3d.core.io.loader import has_poses
from eve3d.core.layout import PRETRAIN, Layout
from eve3d.core.settings import PretrainSettings, RenderSettings
from eve3d.core.settings_fields import flag, pick
from eve3d.core.settings_stereo import PRIOR_BACKENDS, BaselineSettings

try:
    _resolved = resolve_config(dict(config), source="config (config/config.yaml and --config/--configfile)")
except Eve3dError as e:
    raise WorkflowError(str(e))
config.clear()
config.update(_resolved)

STARTED = int(time.time())  # whole seconds: a file system may keep coarser times than the clock
LAYOUT = Layout(config["results"])  # every path under the results folder (eve3d/core/layout.py)
SCENES = list(config["scenes"])
from eve3d.core.methods import GAUSSIAN_DEVICE, methods

try:
    PROTOCOL = {s: scene_protocol(s, config["scenes"][s]) for s in SCENES}
    METHOD = methods(config["variants"])  # the registry with the config's variants
except Eve3dError as e:
    raise WorkflowError(f"config: {e}")
TRAINED = [name for name, m in METHOD.items() if m.trains]  # methods the joint stage trains


def scene_methods(scene):
    """A scene's methods: its own, else the config's, else the default of what its protocol
    scores (eve3d.config.named_methods). A protocol that scores renderings (nvs) keeps
    the trained ones; `oracle` (the exact depth of a GT mesh) runs only where there is a GT mesh."""
    sc = config["scenes"][scene]
    names = named_methods(config, scene, PROTOCOL[scene].scores)
    if PROTOCOL[scene].scores == "model":
        names = [m for m in names if METHOD[m].trains]
    return [m for m in names if METHOD[m].fuses != "oracle" or has_gt_mesh(sc)]


for _where, _names in [("methods", config.get("methods") or [])] + [
        (f"scenes.{s}.methods", config["scenes"][s].get("methods", [])) for s in SCENES]:
    _unknown = [m for m in _names if m not in METHOD]
    if _unknown:
        raise WorkflowError(f"config: {_where}: unknown method(s) {', '.join(_unknown)} (methods: "
                            f"{', '.join(METHOD)}; define others under variants:)")
METHODS = sorted({m for s in SCENES for m in scene_methods(s)})
# The training sections are checked now (the others by resolve_config), so that a typo stops
# the workflow before any job runs.
for _scene in SCENES:  # a scene's own train keys go over the section
    _sections = scene_sections(config, _scene)
    try:
        stage_settings(PretrainSettings, "pretrain", _sections)
        for _name in TRAINED:
            method_settings(_name, _sections, "methods")
    except Eve3dError as e:
        raise WorkflowError(f"config: scenes.{_scene}: {e}")
# Jobs run `python -m eve3d`: the interpreter that runs Snakemake (a venv) comes first on
# PATH, a conda env (--use-conda) prepends its own; PYTHONPATH finds this checkout's package.
os.environ["PATH"] = os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", "")
EVE3D = f"PYTHONPATH={shlex.quote(REPO)}${{PYTHONPATH:+:$PYTHONPATH}} python -m eve3d"
CONDA_ENV = "../envs/eve3d.yaml"

wildcard_constraints:
    scene="|".join(map(re.escape, SCENES)) if SCENES else "$^",
    method="|".join(map(re.escape, METHODS)) if METHODS else "$^",


# What a cluster job asks for beyond the profile's time, memory and cores
# (profiles/slurm): one GPU where its stage runs on one, of the site's model where
# EVE3D_SLURM_GPU_MODEL names it. A local run ignores these.
GPU_MODEL = os.environ.get("EVE3D_SLURM_GPU_MODEL", "")


def all_cores():
    """A job that takes every core (OpenMP in the CPU rasteriser, SfM's matching): a local
    run's --cores; a cluster job's cores are the profile's set-threads (no --cores there)."""
    return workflow.resource_settings.cores or 1


def training_threads():
    """Threads of a training job and of a stereo network's job: the run's cores over
    `training_jobs`, the jobs meant to run side by side (the demo: pgsr beside the chain
    pretrain → stereo → eve3d; docs/development.md, "Where a run's time goes")."""
    return max(1, all_cores() // config["training_jobs"])


# Training jobs side by side (`training_jobs` above 1, the demo) share the cores: each
# registers in the run's folder and, once alone, takes every core (eve3d.core.cores). Through
# the environment the jobs inherit, not their shell command, so that it triggers no rerun; a
# cluster's jobs (training_jobs 1) keep their own cores.
if config["training_jobs"] > 1:
    os.environ[CORE_SHARE_ENV] = f"{LAYOUT.core_share()}:{all_cores()}"


def after_training(wildcards):
    """Priority of a method's mesh and score: a trained method's come first, since they wait
    on the longest jobs, while `oracle`'s and `stereo-tsdf`'s could have run at any time
    (docs/results.md, "Figures behind the code's choices")."""
    return 1 if wildcards.method in TRAINED else 0


def device_resources(device):
    """The resources of a job that runs on ``device(wildcards)``: "gpu" or "cpu"."""
    resources = {"gpu": lambda wc: int(device(wc) == "gpu")}
    if GPU_MODEL:
        resources["gpu_model"] = lambda wc: GPU_MODEL if device(wc) == "gpu" else ""
    return resources


ON_GAUSSIAN_DEVICE = device_resources(lambda wc: GAUSSIAN_DEVICE)  # training, and rendering a trained model


def scene_config(scene):
    return config["scenes"][scene]


def raw_dataset(wildcards):
    """The dataset as the user brings it (generated for synthetic scenes)."""
    sc = scene_config(wildcards.scene)
    return LAYOUT.input(wildcards.scene) if "synthetic" in sc else sc["path"]


def needs_sfm(scene):
    sc = scene_config(scene)
    if "synthetic" in sc:
        return False  # generated with exact poses
    return not has_poses(Path(sc["path"]))


def posed_dataset(wildcards):
    """The dataset with PINHOLE poses: the input itself, or the SfM stage's output."""
    if needs_sfm(wildcards.scene):
        return LAYOUT.sfm(wildcards.scene)
    return raw_dataset(wildcards)


def gt_mesh(wildcards):
    """GT mesh file (inside the generated dataset for synthetic scenes)."""
    sc = scene_config(wildcards.scene)
    if "gt_mesh" in sc:
        return sc["gt_mesh"]
    if "synthetic" in sc:
        return LAYOUT.generated_gt_mesh(wildcards.scene)
    raise WorkflowError(f"scenes.{wildcards.scene}: no gt_mesh (needed by the oracle and the synthetic protocol)")


def gt_input(wildcards):
    """What a rule that reads the GT mesh depends on: the generated dataset folder (a
    directory output holds the mesh) or the user's mesh file."""
    return raw_dataset(wildcards) if "synthetic" in scene_config(wildcards.scene) else gt_mesh(wildcards)


def stereo_priors(scene, backend=None):
    """The folder of a scene's depth priors from ``backend``; by default the ones methods
    use (stereo.backend)."""
    return LAYOUT.priors(scene, backend or config["stereo"]["backend"])


def joint_inputs(wildcards):
    """The posed dataset, its ground-truth check, and the stereo priors of a method that uses them."""
    inputs = {"scene": posed_dataset(wildcards), "checked": ground_truth_checked(wildcards)}
    if METHOD[wildcards.method].needs_priors:
        inputs["priors"] = stereo_priors(wildcards.scene)
    return inputs


def depth_source(wildcards):
    """Per-view depth maps that a method's mesh fuses."""
    fuses = METHOD[wildcards.method].fuses
    if fuses == "oracle":
        return stereo_priors(wildcards.scene, "oracle")
    if fuses == "priors":  # the GS2Mesh-style baseline: fuse the priors as they are
        return stereo_priors(wildcards.scene)
    return LAYOUT.depth(wildcards.scene, wildcards.method)


def stereo_depth_inputs(wildcards):
    inputs = {"scene": posed_dataset(wildcards)}
    if PRIOR_BACKENDS[wildcards.backend].reads == "gt_mesh":
        inputs["gt"] = gt_input(wildcards)
    else:
        inputs["stereo"] = LAYOUT.stereo(wildcards.scene)
    return inputs


def job_config(*sections, **values):
    """The one route from the config to a job: the resolved sections it reads, as one inline
    JSON --config (`preset: null`: they are merged and filled already). Snakemake reruns a
    job when this changes, so a setting reruns exactly the jobs that read its section."""
    job = {"preset": None, **{name: config[name] for name in sections}, **values}
    return shlex.quote(json.dumps(job, sort_keys=True))


def training_job(stage, scene, method=None):
    """A training stage's job config: `train` (with the scene's own train keys over it) and
    the stage's section (the scene's protocol adds what it asks of the joint stage: nvs holds
    views out) and the config's variants this method starts from (a variant's settings rerun
    that variant only)."""
    section = dict(config[stage])
    if stage == "joint":
        section.update(PROTOCOL[scene].joint_settings)
    chain = {}  # the config's variants this method starts from, itself first
    while method in config["variants"] and method not in chain:
        chain[method] = config["variants"][method]
        method = chain[method].get("method", method)
    return job_config(train=scene_sections(config, scene)["train"], **{stage: section},
                      **({"variants": chain} if chain else {}))


def render_job(scene):
    """stereo-render's job config: the `stereo` section's baseline keys (a change to the
    matching or its checks does not render the right views again), and the render settings
    the pretrain trained the scene with (the right views are rasterised the same way)."""
    rendering = pick(RenderSettings, stage_settings(PretrainSettings, "pretrain", scene_sections(config, scene)))
    baseline = {f.name: config["stereo"][f.name] for f in dataclasses.fields(BaselineSettings)}
    return job_config(stereo=baseline, pretrain=dataclasses.asdict(rendering))


def stereo_depth_args(wildcards, input):
    if PRIOR_BACKENDS[wildcards.backend].reads == "gt_mesh":
        return f"--gt-mesh {gt_mesh(wildcards)}"
    return f"--stereo {input.stereo}"


def metrics_files():
    return [LAYOUT.metrics(s, m) for s in SCENES for m in scene_methods(s)]


def mesh_files():
    """Every method's mesh, whatever the protocol scores (nvs scores the trained models)."""
    return [LAYOUT.mesh(s, m) for s in SCENES for m in scene_methods(s)]


def pretrain_metrics():
    """The pretrain stage's records (held-out view metrics), for scenes where a method
    trains or uses stereo priors (rendered by the pretrained model)."""
    users = {name for name, m in METHOD.items() if m.trains or m.needs_priors}
    return [LAYOUT.train_metrics(s, PRETRAIN) for s in SCENES if set(scene_methods(s)) & users]


def mesh_args(wildcards):
    kind = scene_config(wildcards.scene).get("kind")
    return "--config " + job_config("mesh") + (f" --kind {kind}" if kind else "")


def scores_depth(scene):
    """Whether a scene's meshes are scored with the depth maps they were fused from against
    the exact depth (a GT mesh gives it: the oracle's maps)."""
    return PROTOCOL[scene].scores == "mesh" and has_gt_mesh(scene_config(scene))


def ground_truth_inputs(wildcards):
    """The posed dataset and the ground-truth files the protocol names (eve3d.evaluate.PROTOCOLS)."""
    sc, protocol = scene_config(wildcards.scene), PROTOCOL[wildcards.scene]
    inputs = {"scene": posed_dataset(wildcards)}
    for name, key in protocol.config_inputs.items():
        inputs[name] = gt_input(wildcards) if key == "gt_mesh" else scene_value(sc, key)
    return inputs


def ground_truth_file(wildcards, key):
    """The file a protocol's ground-truth config key names: for `gt_mesh` the scene's GT mesh
    (a generated one lies inside its dataset folder), else the scene's own value."""
    return gt_mesh(wildcards) if key == "gt_mesh" else scene_value(scene_config(wildcards.scene), key)


def ground_truth_args(wildcards):
    """The protocol and its ground-truth flags."""
    protocol = PROTOCOL[wildcards.scene]
    args = [f"--protocol {protocol.name}"]
    for name, key in protocol.config_inputs.items():
        args.append(f"{flag(name)} {ground_truth_file(wildcards, key)}")
    return " ".join(args)


def ground_truth_checked(wildcards):
    """The check that the scene's ground truth lines up with its cameras, for protocols that
    have one: training waits for it, so a misplaced file stops the run first. Ancient: a
    rerun of the check (an evaluate setting changed) does not retrain anything."""
    return [ancient(LAYOUT.ground_truth_check(wildcards.scene))] if PROTOCOL[wildcards.scene].check else []


def check_job(wildcards):
    """The ground-truth check's job config: what it reads of `evaluate` (τ, and whether a
    failed check stops the run), so that another scoring setting does not rerun it."""
    settings = evaluate_settings(wildcards.scene)
    return job_config(evaluate={key: settings[key] for key in ("tau", "ground_truth_check")})


def evaluate_inputs(wildcards):
    """The method's reconstruction (mesh, or trained model for nvs), the posed dataset, the
    ground-truth files the protocol names and, where the exact depth is known, the depth
    maps the mesh fused and the exact ones."""
    protocol = PROTOCOL[wildcards.scene]
    reconstruction = LAYOUT.mesh if protocol.scores == "mesh" else LAYOUT.model
    inputs = {**ground_truth_inputs(wildcards), "reconstruction": reconstruction(wildcards.scene, wildcards.method)}
    if scores_depth(wildcards.scene):
        inputs["depth"] = depth_source(wildcards)
        inputs["exact_depth"] = stereo_priors(wildcards.scene, "oracle")
    return inputs


def evaluate_settings(scene):
    """The `evaluate` section with the scene's own `evaluate` keys over it."""
    return {**config["evaluate"], **scene_config(scene).get("evaluate", {})}


def evaluate_args(wildcards, input):
    """The protocol, its inputs, and the job config: the `evaluate` section with the scene's
    own keys over it, and `mesh` (the depth maps are scored where the mesh fused them)."""
    args = [ground_truth_args(wildcards), f"--{PROTOCOL[wildcards.scene].scores} {input.reconstruction}"]
    if scores_depth(wildcards.scene):
        args.append(f"--depth {input.depth} --exact-depth {input.exact_depth}")
    return " ".join(args + ["--config", job_config("mesh", evaluate=evaluate_settings(wildcards.scene))])


def report_args(wildcards):
    """Each scene's posed dataset (its first photo heads the report's sheets, its cameras are
    drawn in the 3D view), its GT surface where its protocol has one, and the job config:
    `stereo` (the priors shown) and the benchmark whose published figures join the means."""
    from types import SimpleNamespace

    args = []
    for s in SCENES:
        scene = SimpleNamespace(scene=s)
        args.append(f"--dataset {shlex.quote(f'{s}={posed_dataset(scene)}')}")
        key = PROTOCOL[s].config_inputs.get("gt")
        if key:
            args.append(f"--gt {shlex.quote(f'{s}={ground_truth_file(scene, key)}')}")
    benchmark = {"benchmark": config["benchmark"]} if config.get("benchmark") else {}
    return " ".join(args + ["--config", job_config("stereo", **benchmark)])
