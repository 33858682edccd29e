"""The import rule of docs/architecture.md: stages use the library, never each other; the
library never imports a stage, the front (``cli``, ``config``) or the tools; the core imports
only itself. And the house's size limits: functions, classes and modules."""
import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "eve3d"
STAGES = {"synth", "sfm", "pretrain", "stereo", "joint", "mesh", "evaluate", "report"}
FRONT = {"cli", "config", "__main__"}
LIBRARY = {"core": {"core"}, "gaussians": {"core", "gaussians"}, "priors": {"core", "gaussians", "priors"}}
"""Each library package and what it may import."""
TOOLS = {"tools"}


def part(path: Path) -> str:
    """The top-level part of the package that ``path`` belongs to (``core``, ``joint``, …)."""
    return path.relative_to(PACKAGE).parts[0].removesuffix(".py")


def imported_parts(path: Path) -> set[str]:
    """The top-level parts of ``eve3d`` that the module at ``path`` imports, at any depth."""
    parts = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module] if node.module != "eve3d" else [f"eve3d.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        parts |= {name.split(".")[1] for name in names if name.startswith("eve3d.")}
    return parts


def test_every_part_of_the_package_is_placed():
    placed = STAGES | FRONT | set(LIBRARY) | TOOLS | {"__init__"}
    assert {part(p) for p in PACKAGE.rglob("*.py")} <= placed


def test_stages_use_the_library_and_never_each_other():
    wrong = {}
    for path in PACKAGE.rglob("*.py"):
        own = part(path)
        used = imported_parts(path) - {own}
        if own in STAGES:
            bad = used - set(LIBRARY)
        elif own in LIBRARY:
            bad = used - LIBRARY[own]
        else:
            continue
        if bad:
            wrong[str(path.relative_to(PACKAGE))] = sorted(bad)
    assert not wrong, f"imports against the rule (module: what it may not import): {wrong}"


STAGE_RUNS = {"synth": {"run_synth"}, "sfm": {"run_sfm"}, "pretrain": {"run_pretrain"},
              "stereo": {"run_stereo_render", "run_stereo_depth", "run_export_stereo"}, "joint": {"run_joint"},
              "mesh": {"run_mesh"},
              "evaluate": {"run_evaluate", "run_ground_truth_check"},
              "report": {"run_summary", "run_show_summary", "run_report"}}
"""What each stage exposes to the front (docs/architecture.md, "Stages and the front")."""


def stage_source(stage: str) -> Path:
    return PACKAGE / stage / "__init__.py" if (PACKAGE / stage).is_dir() else PACKAGE / f"{stage}.py"


def test_each_stage_runs_from_its_settings_and_keyword_paths():
    for stage, names in STAGE_RUNS.items():
        functions = {n.name: n for n in ast.parse(stage_source(stage).read_text()).body if isinstance(n, ast.FunctionDef)}
        for name in names:
            assert name in functions, f"{stage} has no {name}()"
            args = functions[name].args
            assert args.kwonlyargs, f"{stage}.{name}: its paths are keyword arguments"
            if name not in ("run_summary", "run_show_summary", "run_export_stereo"):  # these have no settings section
                assert args.args[0].arg == "settings", f"{stage}.{name}: its settings come first"


def test_the_cli_calls_a_stage_only_through_its_run_functions():
    """Beside the run functions the CLI may read a stage's registries (UPPERCASE names) for
    its flags' choices, nothing else."""
    cli = ast.parse((PACKAGE / "cli.py").read_text())
    for node in ast.walk(cli):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[1:2] and \
                node.module.split(".")[1] in STAGES:
            stage = node.module.split(".")[1]
            wrong = {a.name for a in node.names} - STAGE_RUNS[stage]
            assert all(name.isupper() for name in wrong), f"cli.py imports {sorted(wrong)} from {node.module}"


LIMITS = {"function": 60, "class": 120, "module": 600}
"""The house's size limits, in lines (docs/architecture.md): a definition longer than these
holds more than one concept and is split where they divide."""


def test_no_definition_outgrows_the_house_limits():
    over = []
    for path in sorted(PACKAGE.rglob("*.py")):
        source = path.read_text()
        name = str(path.relative_to(PACKAGE))
        if len(source.splitlines()) > LIMITS["module"]:
            over.append(f"{name}: {len(source.splitlines())} lines")
        for node in ast.walk(ast.parse(source)):
            kind = ("function" if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                    else "class" if isinstance(node, ast.ClassDef) else None)
            if kind and node.end_lineno - node.lineno + 1 > LIMITS[kind]:
                over.append(f"{name}: {kind} {node.name}, {node.end_lineno - node.lineno + 1} lines")
    assert not over, f"over the limits {LIMITS}: {over}"
